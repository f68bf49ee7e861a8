"""Probabilistic multiple registration (PMR; Stegagno's slides 45-60, Franchi, Oriolo, Stegagno 2010).

Robot ``ego`` holds its own anonymous observation and those its neighbours sent (each signed with its sender's id,
its content anonymous). PMR runs the ``n (n - 1) / 2`` binary registrations among all of them
(:func:`~swarmloc.association.registration.binary_register`) and combines them, branch by branch, into every
geometrically feasible *global solution*: a pose of every reachable neighbour in ego's frame and which of ego's
points each one is. A partial solution is extended with neighbour ``j`` by each registration of ``j`` against an
already placed robot (its BFS parent in the graph of non-empty registrations); the extension is kept only if it is

* *reconcilable* (slide 48): ``j`` is not put on the feature of another robot (the same point of ego's
  observation; for a robot ego does not see, a position within ``gate * sigma`` of another robot's);
* *consistent* with every placed robot ``k``: the implied ``T_k^-1 T_j`` agrees (Mahalanobis, chi-square gate)
  with one of the registrations of the pair ``(k, j)``; when that pair has none, the two must be out of each
  other's view (range, field of view), unless misses are allowed (``max_unmatched > 0``);
* optionally *plausible under the current belief* (slide 59): ``log(mu_j^-1 T_j)`` within ``belief_gate`` of the
  belief ``(mu_j, Sigma_j)`` with the registration's covariance added (a Gaussian gate). The beliefs also give
  every pair whose two robots both have one a prior for its binary registration, which drops the candidates far
  from it before they are matched: with good beliefs PMR costs about its ``n (n - 1) / 2`` registrations.

Rotational symmetry (slide 45). With perfect all-see-all measurements a configuration ``P`` of ``n >= 3`` robots
has a unique solution iff ``P`` has no rotational symmetry, and never more than ``(n - 1)!``. Derivation of the
count used by the tests (:func:`solution_count_theory`): every solution maps robot ``j`` to ``g_j(p_j)`` for a
proper rotation ``g_j`` of the symmetry group ``G`` of ``P`` (order ``m``, cyclic, about the centroid ``c``),
bijectively onto ``P`` with ego fixed. ``G`` acts freely off ``c``, so ``P`` splits into orbits of size ``m`` and
possibly ``{c}``; a solution permutes each orbit, giving ``m!`` per orbit without ego, ``(m - 1)!`` for ego's orbit,
and a factor ``m`` (its orientation) for a non-ego robot at ``c``. A regular ``k``-gon (``c`` not a robot, ``n = k``)
thus has ``(k - 1)!`` solutions (not ``k``, the order of its symmetry group: with ``k = 3`` the two solutions
are the truth and the swap of the other two robots) and a ``k``-gon with a robot at its centre
(``n = k + 1``) has ``k!`` -- both ``(n - 1)!``, the maximum of slide 45. With ``n = 2`` the pair is symmetric under
a half turn but the solution is unique: the theorem needs ``n >= 3``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np

from swarmloc.association.registration import Registration, as_points, binary_register, gate_by_prior, visible
from swarmloc.gaussian import GroupGaussian, mahalanobis2, symmetric
from swarmloc.lie import SE2, between_xyt, compose_xyt, invert_xyt

__all__ = [
    "CHI2_3_999",
    "PMRResult",
    "Solution",
    "multiple_registration",
    "rotational_symmetry_order",
    "solution_count_theory",
    "symmetry_metric",
]

CHI2_3_999 = 16.266
"""99.9% quantile of chi-square with 3 degrees of freedom (the default consistency and belief gates)."""


@dataclass(frozen=True)
class Solution:
    """One global solution in ego's frame: ``poses[j]`` ``(x, y, theta)`` and ``covs[j]`` (exponential coordinates,
    right perturbation) of every placed robot (ego: zeros), ``features[j]``: index of ``j`` in ego's observation
    (None when ego does not see it), ``cost``: sum of the registrations' normalized squared residuals."""

    poses: dict[int, np.ndarray]
    covs: dict[int, np.ndarray]
    features: dict[int, int | None]
    cost: float


@dataclass
class PMRResult:
    """All solutions (lowest cost first), the number of binary registrations run, the partial solutions expanded
    (``branches``), the robots no registration chain reaches from ego, and whether ``max_solutions`` cut it short."""

    solutions: list[Solution]
    registrations: int
    branches: int
    unreached: list[int] = field(default_factory=list)
    truncated: bool = False

    def hypotheses(self, robot: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """Distinct ``(pose (3,), cov (3, 3))`` of ``robot`` over all solutions (the PF bank's measurement)."""
        out: list[tuple[np.ndarray, np.ndarray]] = []
        for s in self.solutions:
            if robot in s.poses and not any(np.allclose(s.poses[robot], p, atol=1e-9) for p, _ in out):
                out.append((s.poses[robot], s.covs[robot]))
        return out


def _maha2(pred: np.ndarray, ref: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``y^T cov^-1 y`` with ``y = log(ref^-1 pred)`` for planar poses ``(..., 3)`` (batched over ``ref``/``cov``)."""
    return mahalanobis2(SE2.log(SE2.from_xytheta(between_xyt(ref, pred)), validate=False), cov)


def _ad(pose: np.ndarray) -> np.ndarray:
    return SE2.Ad(SE2.from_xytheta(pose))


def _carried(rel: np.ndarray, cov: np.ndarray, cov_rel: np.ndarray) -> np.ndarray:
    """Right-perturbation covariance of ``T rel`` from ``T``'s ``cov`` and ``rel``'s ``cov_rel`` (independent):
    ``Ad(rel^-1) cov Ad(rel^-1)^T + cov_rel``."""
    A = _ad(invert_xyt(rel))
    return A @ cov @ A.T + cov_rel


def _relative(
    pose_r: np.ndarray, cov_r: np.ndarray, pose_s: np.ndarray, cov_s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pose of ``s`` in ``r``'s frame, ``rel = T_r^-1 T_s``, and its covariance (:func:`_carried` of ``cov_r`` and
    ``cov_s``: both poses in one frame, independent)."""
    rel = between_xyt(pose_r, pose_s)
    return rel, _carried(rel, cov_r, cov_s)


class PairSettings(TypedDict):
    """The settings of :func:`binary_register` that every pair of one :func:`multiple_registration` shares."""

    gate: float
    max_unmatched: int
    max_range: float
    fov: float
    sigma_range: float | None
    sigma_heading: float


def _pair_registrations(
    ids: list[int], obs: dict[int, np.ndarray], sigma: float, known: dict[int, tuple[np.ndarray, np.ndarray]],
    headings: Mapping[int, object], belief_gate: float, cache: dict[tuple[int, int], list[Registration]] | None,
    settings: PairSettings,
) -> dict[tuple[int, int], list[Registration]]:  # fmt: skip
    """:func:`binary_register` of every pair ``(r, s)``, ``r`` before ``s`` in ``ids``, with the prior the beliefs
    ``known`` give when both have one (through ``cache`` as :func:`multiple_registration` says)."""
    reg: dict[tuple[int, int], list[Registration]] = {}
    for x, r in enumerate(ids):
        for s in ids[x + 1 :]:
            prior = _relative(*known[r], *known[s]) if r in known and s in known else None
            hi, hj = headings.get(r), headings.get(s)
            if cache is None:
                reg[(r, s)] = binary_register(obs[r], obs[s], sigma, headings_i=hi, headings_j=hj, prior=prior,
                                              prior_gate=belief_gate, **settings)  # fmt: skip
                continue
            if (r, s) not in cache:
                cache[(r, s)] = binary_register(obs[r], obs[s], sigma, headings_i=hi, headings_j=hj, **settings)
            full = cache[(r, s)]
            reg[(r, s)] = full if prior is None else gate_by_prior(full, obs[r], obs[s], sigma, prior, belief_gate)
    return reg


class _Relations:
    """Registrations of frame ``j`` in frame ``k`` for any ordered pair (the stored direction inverted when needed),
    computed once each; ``stacked[(k, j)]``: their poses ``(m, 3)`` and covariances ``(m, 3, 3)`` when any."""

    def __init__(self, reg: dict[tuple[int, int], list[Registration]]) -> None:
        self.reg = reg
        self.cache: dict[tuple[int, int], list[tuple[np.ndarray, np.ndarray, Registration]]] = {}
        self.stacked: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def __call__(self, k: int, j: int) -> list[tuple[np.ndarray, np.ndarray, Registration]]:
        """``(pose, cov, registration)`` of frame ``j`` in frame ``k``."""
        if (k, j) not in self.cache:
            if (k, j) in self.reg:
                self.cache[(k, j)] = [(r.pose, r.cov, r) for r in self.reg[(k, j)]]
            else:
                out = []
                for r in self.reg[(j, k)]:
                    A = _ad(r.pose)  # cov of T^-1 in right perturbation: Ad(T) cov Ad(T)^T
                    out.append((invert_xyt(r.pose), A @ r.cov @ A.T, r))
                self.cache[(k, j)] = out
            c = self.cache[(k, j)]
            if c:
                self.stacked[(k, j)] = (np.array([p for p, _, _ in c]), np.array([v for _, v, _ in c]))
        return self.cache[(k, j)]


def _bfs(ego: int, ids: list[int], reg: dict[tuple[int, int], list[Registration]]) -> tuple[dict[int, int], list[int]]:
    """BFS from ``ego`` over the graph of pairs with at least one registration: each reached robot's parent, and
    the reached robots in BFS order (ego aside)."""
    parent: dict[int, int] = {}
    order: list[int] = []
    seen, queue = {ego}, deque([ego])
    while queue:
        k = queue.popleft()
        for j in ids:
            if j not in seen and (reg.get((k, j)) or reg.get((j, k))):
                seen.add(j)
                parent[j] = k
                order.append(j)
                queue.append(j)
    return parent, order


def _feature(points: np.ndarray, pose: np.ndarray, tol: float) -> int | None:
    """Index of the point of ``points`` ``(m, 2)`` nearest the position of ``pose``, None if none within ``tol``."""
    if not len(points):
        return None
    d2 = ((points - pose[:2]) ** 2).sum(1)
    return int(np.argmin(d2)) if d2.min() <= tol**2 else None


def _consistent(
    j: int, pj: np.ndarray, cj: np.ndarray, k0: int, poses: dict[int, np.ndarray], covs: dict[int, np.ndarray],
    rels: _Relations, *, sigma: float, gate: float, consistency_gate: float, max_unmatched: int, max_range: float,
    fov: float,
) -> bool:  # fmt: skip
    """Whether ``j`` at ``(pj, cj)`` agrees with every placed robot but its parent ``k0`` (module docstring): the
    implied relative pose within ``consistency_gate`` of one registration of the pair; with none, the two out of each
    other's view unless misses are allowed (``max_unmatched > 0``)."""
    for k in poses:
        if k == k0:
            continue
        pred, cpred = _relative(poses[k], covs[k], pj, cj)
        if not rels(k, j):
            back = invert_xyt(pred)
            mutual = visible(pred[:2], max_range, fov, 2 * gate * sigma) and visible(
                back[:2], max_range, fov, 2 * gate * sigma
            )
            if max_unmatched == 0 and mutual:
                return False
            continue
        P_kj, C_kj = rels.stacked[(k, j)]
        if not (_maha2(pred, P_kj, cpred + C_kj) <= consistency_gate).any():
            return False
    return True


def multiple_registration(
    observations: Mapping[int, object],
    ego: int,
    sigma: float,
    *,
    gate: float = 5.0,
    consistency_gate: float = CHI2_3_999,
    max_unmatched: int = 0,
    max_range: float = np.inf,
    fov: float = 2 * np.pi,
    sigma_range: float | None = None,
    headings: Mapping[int, object] | None = None,
    sigma_heading: float = 0.05,
    beliefs: Mapping[int, GroupGaussian] | None = None,
    belief_gate: float = CHI2_3_999,
    max_solutions: int = 100_000,
    cache: dict[tuple[int, int], list[Registration]] | None = None,
) -> PMRResult:
    """Every feasible global solution for ``ego`` (module docstring).

    ``observations``: robot id -> its anonymous points ``(m, 2)`` [m] in its own frame (ego's included);
    ``headings``: optional robot id -> measured headings ``(m,)`` [rad] of those points (NaN: unknown); ``beliefs``:
    optional robot id -> current belief of its pose in ego's frame (a :class:`GroupGaussian` on SE(2));
    ``sigma``, ``gate``, ``max_unmatched``, ``max_range``, ``fov``, ``sigma_range`` as in :func:`binary_register`.
    ``cache``: a dict kept by the caller for *these observations and settings* (one scan): each ordered pair's
    registration without a prior is computed once into it and gated by each call's beliefs
    (:func:`~swarmloc.association.registration.gate_by_prior`: the same lists as registering with the prior), so the
    robots of a team running PMR on one scan share the binary registrations.
    """
    if ego not in observations:
        raise ValueError(f"multiple_registration: no observation of ego robot {ego!r}")
    if not (isinstance(max_solutions, int) and max_solutions >= 1):
        raise ValueError(f"multiple_registration: max_solutions must be an integer >= 1, got {max_solutions!r}")
    ids = [ego] + sorted(r for r in observations if r != ego)
    obs = {r: as_points(observations[r], f"multiple_registration: observation of robot {r}") for r in ids}
    # beliefs of the poses in ego's frame (ego: exactly the identity) give each pair a prior for its registration
    known: dict[int, tuple[np.ndarray, np.ndarray]] = {ego: (np.zeros(3), np.zeros((3, 3)))}
    for r, b in (beliefs or {}).items():
        if r in obs and r != ego:
            known[r] = (SE2.to_xytheta(b.mean), np.asarray(b.cov, float))
    settings = PairSettings(gate=gate, max_unmatched=max_unmatched, max_range=max_range, fov=fov,
                            sigma_range=sigma_range, sigma_heading=sigma_heading)  # fmt: skip
    reg = _pair_registrations(ids, obs, sigma, known, headings or {}, belief_gate, cache, settings)
    rels = _Relations(reg)
    parent, order = _bfs(ego, ids, reg)
    unreached = [r for r in ids if r != ego and r not in parent]
    solutions: list[Solution] = []
    branches = 0
    truncated = False
    poses = {ego: np.zeros(3)}
    covs = {ego: np.zeros((3, 3))}
    feats: dict[int, int | None] = {ego: None}

    def extend(depth: int, cost: float) -> None:
        nonlocal branches, truncated
        if len(solutions) >= max_solutions:
            truncated = True
            return
        branches += 1
        if depth == len(order):
            solutions.append(Solution(dict(poses), dict(covs), dict(feats), cost))
            return
        j = order[depth]
        k0 = parent[j]
        for rel, crel, r in rels(k0, j):
            if k0 == ego:  # ego is ids[0]: reg[(ego, j)] holds j's pose in ego's frame, r.a its point there
                pj, cj = rel, crel
                fj: int | None = r.a
            else:
                pj, cj = compose_xyt(poses[k0], rel), symmetric(_carried(rel, covs[k0], crel))  # T_k C
                fj = _feature(obs[ego], pj, 2 * gate * sigma)
            if fj is not None and fj in feats.values():
                continue  # two robots on one feature
            if fj is None and any(((pj[:2] - poses[k][:2]) ** 2).sum() <= (gate * sigma) ** 2 for k in poses):
                continue  # one robot (unseen by ego) on top of another
            if beliefs is not None and j in beliefs:
                b = beliefs[j]
                mu = SE2.to_xytheta(b.mean)
                if float(_maha2(pj, mu, b.cov + cj)) > belief_gate:
                    continue
            if not _consistent(j, pj, cj, k0, poses, covs, rels, sigma=sigma, gate=gate, max_range=max_range, fov=fov,
                               consistency_gate=consistency_gate, max_unmatched=max_unmatched):  # fmt: skip
                continue
            poses[j], covs[j], feats[j] = pj, cj, fj
            extend(depth + 1, cost + r.cost)
            del poses[j], covs[j], feats[j]
            if truncated:
                return

    extend(0, 0.0)
    solutions.sort(key=lambda s: s.cost)
    return PMRResult(solutions, len(reg), branches, unreached, truncated)


# ------------------------------------------------------------------------------------------------ symmetry
def _candidate_rotations(Q: np.ndarray, ctol: float, rtol: float) -> np.ndarray:
    """Non-trivial rotation angles about the origin mapping one point of ``Q`` (centred, farther than ``ctol`` from
    the origin) onto another whose radius differs by at most ``rtol`` [m]."""
    r = np.hypot(Q[:, 0], Q[:, 1])
    a = np.arctan2(Q[:, 1], Q[:, 0])
    off = r > ctol
    k, l_ = np.nonzero(off[:, None] & off[None, :] & (np.abs(r[:, None] - r[None, :]) <= rtol))
    phi = (a[l_] - a[k]) % (2 * np.pi)
    return phi[(phi > 1e-9) & (phi < 2 * np.pi - 1e-9)]


def _rotation_misfit(Q: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Hausdorff distance [m] between ``R(phi) Q`` and ``Q`` for every angle ``phi`` ``(C,)``."""
    c, s = np.cos(phi), np.sin(phi)
    RQ = np.stack([c[:, None] * Q[:, 0] - s[:, None] * Q[:, 1], s[:, None] * Q[:, 0] + c[:, None] * Q[:, 1]], -1)
    D = np.sqrt(((RQ[:, :, None, :] - Q[None, None, :, :]) ** 2).sum(-1))  # (C, n, n)
    return np.maximum(D.min(2).max(1), D.min(1).max(1))


def symmetry_metric(points: object) -> float:
    """Rotational-symmetry metric [m] of a configuration ``(n, 2)``: the smallest Hausdorff distance between the
    configuration (centred on its centroid) and a non-trivial rotation of it, over the rotations that carry one
    point onto another. 0 for a configuration with rotational symmetry (and for ``n <= 1``); positive otherwise,
    growing with the distance to the nearest symmetric one (an upper bound on it, up to a factor)."""
    P = as_points(points, "symmetry_metric")
    if len(P) <= 1:
        return 0.0
    Q = P - P.mean(0)
    phi = _candidate_rotations(Q, 1e-12, np.inf)
    if phi.size == 0:
        return 0.0  # every point at the centroid
    return float(_rotation_misfit(Q, phi).min())


def rotational_symmetry_order(points: object, tol: float = 1e-6) -> int:
    """Order ``m`` of the group of rotations (about the centroid) that map the configuration onto itself within
    ``tol`` [m] (1: no symmetry)."""
    P = as_points(points, "rotational_symmetry_order")
    if len(P) <= 1:
        return 1
    Q = P - P.mean(0)
    phi = _candidate_rotations(Q, tol, 2 * tol)
    phi = np.unique(np.round(phi[_rotation_misfit(Q, phi) <= tol], 6)) if phi.size else phi
    return 1 + int(phi.size)


def solution_count_theory(points: object, ego_index: int, tol: float = 1e-6) -> int:
    """Number of solutions of the static anonymous mutual-localization problem (perfect, all-see-all) for robots at
    ``points`` ``(n, 2)`` with ego at ``points[ego_index]`` (derivation in the module docstring)."""
    P = as_points(points, "solution_count_theory")
    n = len(P)
    if not 0 <= ego_index < n:
        raise ValueError(f"solution_count_theory: ego_index {ego_index} out of range for {n} points")
    m = rotational_symmetry_order(P, tol)
    Q = P - P.mean(0)
    at_c = np.hypot(Q[:, 0], Q[:, 1]) <= tol
    n_free = n - int(at_c.sum())
    orbits = n_free // m
    count = 1
    if at_c[ego_index]:
        count *= math.factorial(m) ** orbits
    else:
        count *= math.factorial(m - 1) * math.factorial(m) ** (orbits - 1)
        if at_c.any():
            count *= m
    return count
