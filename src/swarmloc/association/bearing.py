"""Bearing-only anonymous mutual localization, the registration stage (slide 70; Stegagno, Cognetti, Franchi,
Oriolo, IROS 2011), in the all-see-all model. PARTIAL: exact for noise-free bearings; with noise the poses are
the triangulations' (no least-squares refinement) and loose gates admit extra candidates; no filter recovers the
scale, and PMR's ranges, misses, clutter and belief gates are not carried over.

Every robot measures the *bearings* [rad] of the others in its own frame, anonymously; no ranges. Robot ``ego``
searches every assignment of identities to bearings with relative poses that explain all of them, up to one common
scale (the distance from ego to the first neighbour placed is 1):

* the first neighbour ``j``: ego sees it at bearing ``a``, it sees ego at ``b``: ``p_j = (cos a, sin a)`` and
  ``theta_j = a - b + pi`` (the mutual bearings fix the relative orientation, not the distance);
* every next robot ``k``: ego's ray ``a_k`` and ``j``'s ray ``c`` meet in front of both (positive depths: the
  triangulation), ``k`` sees ego at one of its bearings (which fixes ``theta_k``), and every robot already placed
  must find ``k`` among its unused bearings and be found among ``k``'s, within ``gate * sigma`` (one to one);
* a solution must use every bearing of every robot exactly once.

Each check's gate widens with the uncertainty of what it compares: a triangulated position moves by about
``sigma sqrt(s^2 + r^2) / |sin(gamma)|`` (depths ``s``, ``r``, angle ``gamma`` between the rays), a heading by the
bearing noise plus that position error seen from ego; a predicted bearing from ``r`` to ``t`` at distance ``d``
has std ``sqrt(2 sigma^2 + sd_theta_r^2 + (sd_p_r^2 + sd_p_t^2) / d^2)`` (first order, no correlations).

Found while testing: with three robots the problem always has two solutions, the configuration and its mirror
image (each robot's two bearings are known only up to its heading, i.e. only their difference, and the mirror
triangle has the same three angles); from four robots on a generic configuration has one.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from swarmloc.lie import wrap_angle

__all__ = ["BearingSolution", "bearing_registration"]


@dataclass(frozen=True)
class BearingSolution:
    """Poses ``(x, y, theta)`` of every robot in ego's frame up to one scale (ego: zeros; the first neighbour at
    distance 1), and ``features[r]``: index of ``r`` among ego's bearings (ego: None); ``cost``: sum of squared
    normalized bearing residuals."""

    poses: dict[int, np.ndarray]
    features: dict[int, int | None]
    cost: float


def _bearing(frm: np.ndarray, to: np.ndarray) -> float:
    """Bearing of point ``to`` seen from pose ``frm`` ``(x, y, theta)``."""
    return float(wrap_angle(np.arctan2(to[1] - frm[1], to[0] - frm[0]) - frm[2]))


def _triangulate(p0: np.ndarray, a0: float, p1: np.ndarray, a1: float) -> tuple[np.ndarray, bool, float]:
    """Intersection of the rays ``p0 + s (cos a0, sin a0)`` and ``p1 + r (cos a1, sin a1)``; True when ``s, r > 0``;
    and the factor ``sqrt(s^2 + r^2) / |sin(a1 - a0)|`` [scale units per rad] by which bearing noise moves it."""
    e0, e1 = np.array([np.cos(a0), np.sin(a0)]), np.array([np.cos(a1), np.sin(a1)])
    M = np.column_stack([e0, -e1])
    det = np.linalg.det(M)
    if abs(det) < 1e-12:
        return p0, False, np.inf
    s, r = np.linalg.solve(M, p1[:2] - p0[:2])
    return p0[:2] + s * e0, bool(s > 0 and r > 0), float(np.hypot(s, r) / abs(det))


def _checked_bearings(bearings: Mapping[int, object], ego: int, sigma: float) -> dict[int, np.ndarray]:
    """``bearings`` as float arrays, after checking ego is there, ``sigma`` > 0 and all see all (``n - 1`` each)."""
    if ego not in bearings:
        raise ValueError(f"bearing_registration: no bearings of ego robot {ego!r}")
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"bearing_registration: sigma must be a finite number > 0, got {sigma!r}")
    B = {r: np.asarray(v, float).reshape(-1) for r, v in bearings.items()}
    n = len(B)
    for r, v in B.items():
        if len(v) != n - 1 or not np.isfinite(v).all():
            raise ValueError(f"bearing_registration: robot {r} must have {n - 1} finite bearings, got {v}")
    return B


def _candidates(
    B: dict[int, np.ndarray], ego: int, a: int, j: int | None, poses: dict[int, np.ndarray],
    sd: dict[int, tuple[float, float]], used: dict[int, dict[int, int]], sigma: float,
) -> list[tuple[np.ndarray, float]]:  # fmt: skip
    """Positions (and their std [scale units]) of the next robot on ego's ray ``a``: at distance 1 for the first
    neighbour (``j`` None), else where the ray meets a free ray of the first neighbour ``j`` in front of both."""
    if j is None:
        return [(np.array([np.cos(B[ego][a]), np.sin(B[ego][a])]), 0.0)]
    cands = []
    for c in [x for x in range(len(B[j])) if x not in used[j]]:
        p, ok, f = _triangulate(np.zeros(3), B[ego][a], poses[j], poses[j][2] + B[j][c])
        if ok:
            sd_ray = np.hypot(sigma, sd[j][1])  # j's ray: its bearing and its heading
            cands.append((p, f * np.hypot(sigma, sd_ray) + sd[j][0]))
    return cands


def _matches(
    B: dict[int, np.ndarray], ego: int, k: int, pk: np.ndarray, sd_k: tuple[float, float],
    poses: dict[int, np.ndarray], sd: dict[int, tuple[float, float]], used: dict[int, dict[int, int]],
    trial: list[tuple[int, int, int]], sigma: float, gate: float,
) -> float | None:  # fmt: skip
    """Match ``k`` at ``pk`` with every robot placed (ego aside) both ways among the free bearings, within the gate:
    appends the matches ``(robot, bearing index, robot seen)`` to ``trial`` and returns their cost, None if any
    fails."""
    add = 0.0
    for m in poses:
        if m == ego:
            continue
        dist = float(np.hypot(*(pk[:2] - poses[m][:2])))
        for r, target, frm, sd_r in ((m, k, poses[m], sd[m]), (k, m, pk, sd_k)):
            taken = {x for rr, x, _ in trial if rr == r}
            pred = _bearing(frm, (pk if target == k else poses[m]))
            free = [x for x in range(len(B[r])) if x not in used[r] and x not in taken]
            if not free:
                return None
            d = np.abs(wrap_angle(B[r][free] - pred))
            x = int(np.argmin(d))
            var = 2 * sigma**2 + sd_r[1] ** 2 + (sd[m][0] ** 2 + sd_k[0] ** 2) / max(dist, 1e-9) ** 2
            if d[x] > gate * np.sqrt(var):
                return None
            trial.append((r, free[x], target))
            add += float(d[x] ** 2 / var)
    return add


def _distinct(out: list[BearingSolution]) -> list[BearingSolution]:
    """``out`` by cost, each solution once (one reached through other matchings of the bearings is the same)."""
    out.sort(key=lambda s: s.cost)
    unique: list[BearingSolution] = []
    for sol in out:
        same = (
            sol.features == u.features
            and all(np.abs(sol.poses[r][:2] - u.poses[r][:2]).max() <= 0.05 for r in sol.poses)
            and all(abs(wrap_angle(sol.poses[r][2] - u.poses[r][2])) <= 0.1 for r in sol.poses)
            for u in unique
        )
        if not any(same):
            unique.append(sol)
    return unique


def bearing_registration(
    bearings: Mapping[int, object], ego: int, sigma: float, *, gate: float = 5.0, max_solutions: int = 10_000
) -> list[BearingSolution]:
    """Every solution of the bearing-only problem for ``ego`` (module docstring): ``bearings``: robot id -> its
    anonymous bearings ``(m,)`` [rad] (all see all: ``m = n - 1``); ``sigma`` [rad] > 0: bearing noise std."""
    B = _checked_bearings(bearings, ego, sigma)
    others = sorted(r for r in B if r != ego)
    out: list[BearingSolution] = []
    if not others:
        return [BearingSolution({ego: np.zeros(3)}, {ego: None}, 0.0)]
    poses: dict[int, np.ndarray] = {ego: np.zeros(3)}
    sd: dict[int, tuple[float, float]] = {ego: (0.0, 0.0)}  # (position std [scale units], heading std [rad])
    used: dict[int, dict[int, int]] = {r: {} for r in B}  # used[r][bearing index] = robot it was matched to

    def place(depth: int, cost: float) -> None:
        if len(out) >= max_solutions:
            return
        if depth == len(others):
            feats = {r: next((x for x, m in used[ego].items() if m == r), None) for r in B}
            feats[ego] = None
            out.append(BearingSolution({r: p.copy() for r, p in poses.items()}, feats, cost))
            return
        k = others[depth]
        for a in [x for x in range(len(B[ego])) if x not in used[ego]]:
            for p, sd_p in _candidates(B, ego, a, None if depth == 0 else others[0], poses, sd, used, sigma):
                if any(np.hypot(*(p - q[:2])) < 1e-9 for q in poses.values()):
                    continue
                for b in [x for x in range(len(B[k])) if x not in used[k]]:
                    th = float(wrap_angle(np.arctan2(-p[1], -p[0]) - B[k][b]))
                    pk = np.array([p[0], p[1], th])
                    sd_k = (sd_p, float(np.hypot(sigma, sd_p / np.hypot(p[0], p[1]))))
                    trial = [(ego, a, k), (k, b, ego)]
                    add = _matches(B, ego, k, pk, sd_k, poses, sd, used, trial, sigma, gate)
                    if add is None:
                        continue
                    for r, x, t in trial:
                        used[r][x] = t
                    poses[k], sd[k] = pk, sd_k
                    place(depth + 1, cost + add)
                    del poses[k], sd[k]
                    for r, x, _ in trial:
                        del used[r][x]

    place(0, 0.0)
    return _distinct(out)
