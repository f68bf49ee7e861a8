"""Binary registration of two anonymous planar observations (Stegagno's slides 47-48; Franchi, Oriolo, Stegagno 2010).

Robot ``i`` sees the other robots as anonymous points ``O_i`` ``(m_i, 2)`` [m] in its own frame (x forward, y
left); robot ``j`` sees ``O_j`` in its frame. A *binary registration* is every relative pose ``T = (x, y, theta)``
of frame ``j`` in frame ``i`` under which the two observations agree:

* ``i`` sees ``j`` at some point ``a`` of ``O_i`` and ``j`` sees ``i`` at some point ``b`` of ``O_j`` (mutual
  detection), so ``t = O_i[a]`` and ``R(theta) O_j[b] + t = 0``;
* every other point of ``O_j`` mapped into frame ``i`` (``R O_j[l] + t``) matches one point of ``O_i`` (one to one)
  within the noise gate, except at most ``max_unmatched`` points on each side that the other robot should have
  seen (points beyond the other's ``max_range``, or within a gate of it, are never required to match: clutter,
  misses and the range limit).

Noise model: every measured point has isotropic Gaussian noise of std ``sigma`` [m] per axis in its observer's
frame (a range-bearing sensor with range std ``s_r`` at range ``r`` and bearing std ``s_b`` is approximated by
``sigma = max(s_r, r s_b)``; the caller chooses). Optional measured *relative headings* (``headings_i[a]``: the
heading of the robot seen at ``O_i[a]``, in frame ``i``; NaN where unknown) with std ``sigma_heading`` [rad] gate
the rotation: ``theta`` must agree with ``headings_i[a]`` and with ``-headings_j[b]``.

Each accepted candidate is refined by weighted least squares over all its correspondences (closed-form 2-D
Procrustes) and comes with a first-order covariance in exponential coordinates with right perturbation, the
convention of :mod:`swarmloc.gaussian` (``T_true = T_est exp(hat(y))``, ``y ~ N(0, cov)``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from swarmloc.gaussian import symmetric
from swarmloc.lie import SE2, between_xyt, wrap_angle

__all__ = [
    "Registration",
    "as_points",
    "binary_register",
    "gate_by_prior",
    "points_from_range_bearing",
    "visible",
    "xyt_cov_to_exp",
]


@dataclass(frozen=True)
class Registration:
    """One feasible relative pose of frame ``j`` in frame ``i``.

    ``pose``: ``(x [m], y [m], theta [rad])``; ``cov``: ``(3, 3)`` covariance of its exponential coordinates (right
    perturbation); ``a``: index in ``O_i`` of the point that is robot ``j``; ``b``: index in ``O_j`` of robot ``i``;
    ``pairs``: ``(k, 2)`` indices ``(in O_i, in O_j)`` of the other matched points; ``cost``: sum of squared
    normalized residuals of the refined fit (about chi-square with ``2 (k + 2) - 3`` degrees of freedom).
    """

    pose: np.ndarray
    cov: np.ndarray
    a: int
    b: int
    pairs: np.ndarray
    cost: float


def as_points(obs: object, where: str = "observation") -> np.ndarray:
    """Validate an observation: a finite float array ``(m, 2)`` (``m`` may be 0); raise ValueError."""
    p = np.asarray(obs, dtype=float)
    if p.size == 0:
        return np.zeros((0, 2))
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"{where}: expected points of shape (m, 2), got {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError(f"{where}: points must be finite")
    return p


def points_from_range_bearing(z: object) -> np.ndarray:
    """Points ``(m, 2)`` [m] from range-bearing rows ``(m, 2)`` ``(range [m], bearing [rad])``."""
    z = np.asarray(z, dtype=float).reshape(-1, 2)
    return np.column_stack([z[:, 0] * np.cos(z[:, 1]), z[:, 0] * np.sin(z[:, 1])])


def xyt_cov_to_exp(pose: np.ndarray, cov_xyt: np.ndarray) -> np.ndarray:
    """Covariance of ``(x, y, theta)`` -> covariance of right-perturbation exponential coordinates at ``pose``
    (first order: ``delta t = R y_v``, ``delta theta = y_alpha``)."""
    A = np.eye(3)
    A[:2, :2] = SE2.rotation(np.asarray(pose[2], float)).T
    C = A @ cov_xyt @ A.T
    return symmetric(C)


def _procrustes(pi: np.ndarray, pj: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """Weighted 2-D rigid fit ``pi ~ R pj + t``: returns ``(x, y, theta)`` and the weighted squared residual."""
    W = w.sum()
    ci, cj = (w[:, None] * pi).sum(0) / W, (w[:, None] * pj).sum(0) / W
    qi, qj = pi - ci, pj - cj
    sn = (w * (qj[:, 0] * qi[:, 1] - qj[:, 1] * qi[:, 0])).sum()
    cs = (w * (qj[:, 0] * qi[:, 0] + qj[:, 1] * qi[:, 1])).sum()
    th = float(np.arctan2(sn, cs))
    R = SE2.rotation(np.asarray(th))
    t = ci - R @ cj
    r = pi - (pj @ R.T + t)
    return np.array([t[0], t[1], th]), float((w * (r * r).sum(1)).sum())


def _fit_cov(pose: np.ndarray, pj: np.ndarray, var: np.ndarray) -> np.ndarray:
    """First-order covariance (exponential coordinates) of the fit from residual variances ``var`` per pair."""
    R = SE2.rotation(np.asarray(pose[2]))
    q = pj @ R.T  # R p_j
    J = np.zeros((len(pj), 2, 3))
    J[:, 0, 0] = J[:, 1, 1] = 1.0
    J[:, 0, 2], J[:, 1, 2] = -q[:, 1], q[:, 0]
    info = np.einsum("kai,kaj,k->ij", J, J, 1.0 / var)
    return xyt_cov_to_exp(pose, np.linalg.inv(info))


def visible(p: np.ndarray, max_range: float, fov: float, margin: np.ndarray | float) -> np.ndarray:
    """Points ``(..., 2)`` inside range and field of view by at least ``margin`` [m] (expected to be seen)."""
    r = np.hypot(p[..., 0], p[..., 1])
    ok = r <= max_range - margin
    if fov < 2 * np.pi:
        ok &= np.abs(np.arctan2(p[..., 1], p[..., 0])) <= fov / 2 - margin / np.maximum(r, 1e-9)
    return ok


def _rough_theta(Pi: np.ndarray, Pj: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Rotation of candidate ``(a, b)`` from the mutual detection alone: ``R(theta) O_j[b]`` points opposite
    ``O_i[a]``."""
    return wrap_angle(np.arctan2(-Pi[A, 1], -Pi[A, 0]) - np.arctan2(Pj[B, 1], Pj[B, 0]))


def _prior_ok(
    Pi: np.ndarray, Pj: np.ndarray, A: np.ndarray, B: np.ndarray, th: np.ndarray, s2: float,
    prior: tuple[np.ndarray, np.ndarray], prior_gate: float,
) -> np.ndarray:  # fmt: skip
    """Which rough candidates ``(O_i[A], th)`` lie within ``prior_gate`` of the prior (its covariance plus the
    candidate's own from the noise ``s2`` [m^2] of the two mutual detections)."""
    ri, rj = np.hypot(Pi[A, 0], Pi[A, 1]), np.hypot(Pj[B, 0], Pj[B, 1])
    mu, pc = np.asarray(prior[0], float).reshape(3), np.asarray(prior[1], float).reshape(3, 3)
    cand = np.column_stack([Pi[A], th])
    y = SE2.log(SE2.from_xytheta(between_xyt(mu, cand)), validate=False)
    C = pc + np.zeros((A.size, 3, 3))
    C[:, 0, 0] += s2
    C[:, 1, 1] += s2
    C[:, 2, 2] += s2 / ri**2 + s2 / rj**2
    return np.einsum("ki,ki->k", y, np.linalg.solve(C, y[..., None])[..., 0]) <= prior_gate


def gate_by_prior(
    regs: list[Registration], obs_i: object, obs_j: object, sigma: float,
    prior: tuple[np.ndarray, np.ndarray], prior_gate: float = 16.266,
) -> list[Registration]:  # fmt: skip
    """The registrations of :func:`binary_register` without a prior that it returns with ``prior``: the prior
    drops rough candidates one by one, before they are matched, so gating a computed list afterwards gives the same
    list (lets one unprimed registration of a scan serve every robot's own belief)."""
    if not regs:
        return []
    Pi, Pj = as_points(obs_i, "gate_by_prior: obs_i"), as_points(obs_j, "gate_by_prior: obs_j")
    A, B = np.array([r.a for r in regs]), np.array([r.b for r in regs])
    ok = _prior_ok(Pi, Pj, A, B, _rough_theta(Pi, Pj, A, B), sigma * sigma, prior, prior_gate)
    return [r for r, k in zip(regs, ok, strict=True) if k]


def _candidates(
    Pi: np.ndarray, Pj: np.ndarray, s2: float, s_r: float, gate: float, hi: np.ndarray | None,
    hj: np.ndarray | None, sigma_heading: float, prior: tuple[np.ndarray, np.ndarray] | None, prior_gate: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Candidates ``(a, b)``, robot ``j`` is ``O_i[a]`` and sees ``i`` at ``O_j[b]``, with their rough rotations:
    equal positive ranges (both noisy: std ``s_r sqrt(2)``), then the measured headings (NaN: unknown) and the
    prior when given, each within its gate."""
    ri, rj = np.hypot(Pi[:, 0], Pi[:, 1]), np.hypot(Pj[:, 0], Pj[:, 1])
    A, B = np.nonzero((np.abs(ri[:, None] - rj[None, :]) <= gate * s_r * np.sqrt(2)) & (ri[:, None] > 0))
    A, B = A[rj[B] > 0], B[rj[B] > 0]
    th = _rough_theta(Pi, Pj, A, B)
    for h, of_j in ((hi, False), (hj, True)):  # i's heading of j is th; j's heading of i is -th
        if h is not None:
            hk = h[B] if of_j else h[A]
            d = np.abs(wrap_angle(th + hk)) if of_j else np.abs(wrap_angle(th - hk))
            ok = np.isnan(hk) | (d <= gate * np.sqrt(sigma_heading**2 + s2 / ri[A] ** 2 + s2 / rj[B] ** 2))
            A, B, th = A[ok], B[ok], th[ok]
    if prior is not None and A.size:
        ok = _prior_ok(Pi, Pj, A, B, th, s2, prior, prior_gate)
        A, B, th = A[ok], B[ok], th[ok]
    return A, B, th


def _distances(
    Pi: np.ndarray, Pj: np.ndarray, A: np.ndarray, B: np.ndarray, th: np.ndarray, s2: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``O_j`` mapped into frame ``i`` by every candidate at once, ``Q`` ``(K, mj, 2)``, its rotations ``R``, the
    error covariances ``C`` ``(K, mj, 2, 2)`` of its points, and their squared Mahalanobis distances ``D2``
    ``(K, mj, mi)`` to ``O_i`` (inf where a point cannot match: robot ``j`` itself, robot ``i`` seen by ``j``)."""
    ri, rj = np.hypot(Pi[:, 0], Pi[:, 1]), np.hypot(Pj[:, 0], Pj[:, 1])
    R = SE2.rotation(th)
    Q = np.einsum("kab,lb->kla", R, Pj) + Pi[A][:, None, :]
    # linearized error covariance of Q[k, l] - (its true match in O_i), from the independent noises of a, b, O_j[l]
    # and the O_i point: dtheta/da = (-a_y, a_x)/|a|^2, dtheta/db = (b_y, -b_x)/|b|^2, dQ/da = I + u ga^T with
    # u = J R O_j[l] (the correlation through a matters: it can double the variance at lever arms ~ |a|)
    u = np.stack([-(Q[..., 1] - Pi[A][:, None, 1]), Q[..., 0] - Pi[A][:, None, 0]], -1)  # (K, mj, 2)
    ga = np.stack([-Pi[A, 1], Pi[A, 0]], -1) / (ri[A] ** 2)[:, None]
    gb2 = 1.0 / rj[B] ** 2  # |dtheta/db|^2
    M = np.eye(2) + u[..., :, None] * ga[:, None, None, :]  # (K, mj, 2, 2)
    C = s2 * (M @ np.swapaxes(M, -1, -2) + gb2[:, None, None, None] * u[..., :, None] * u[..., None, :] + 2 * np.eye(2))
    det = C[..., 0, 0] * C[..., 1, 1] - C[..., 0, 1] ** 2
    dx = Q[:, :, None, :] - Pi[None, None, :, :]  # (K, mj, mi, 2)
    D2 = (C[..., 1, 1, None] * dx[..., 0] ** 2 - 2 * C[..., 0, 1, None] * dx[..., 0] * dx[..., 1]
          + C[..., 0, 0, None] * dx[..., 1] ** 2) / det[..., None]  # fmt: skip
    K = np.arange(A.size)
    D2[K, :, A] = np.inf  # robot j itself is not one of j's observations
    D2[K, B, :] = np.inf  # robot i (seen by j at b) is the origin of frame i, not a point of O_i
    return R, Q, C, D2


def _refined(
    Pi: np.ndarray, Pj: np.ndarray, a: int, b: int, D2: np.ndarray, expect_j: np.ndarray, expect_i: np.ndarray,
    s2: float, gate: float, max_unmatched: int,
) -> Registration | None:  # fmt: skip
    """Candidate ``(a, b)`` matched one to one (the assignment minimizing ``sum(min(d2, gate^2))``, pairs at the
    cap unmatched) and refined over all its correspondences; None when more than ``max_unmatched`` points either
    side expected to match do not."""
    cost = np.minimum(D2, gate * gate)
    rows, cols = linear_sum_assignment(cost)
    hit = cost[rows, cols] < gate * gate
    used_j, used_i = set(rows[hit].tolist()), set(cols[hit].tolist())
    pairs = list(zip(cols[hit].tolist(), rows[hit].tolist(), strict=True))
    un_j = sum(1 for l_ in np.nonzero(expect_j)[0] if int(l_) not in used_j)
    un_i = sum(1 for m_ in np.nonzero(expect_i)[0] if int(m_) not in used_i)
    if un_j > max_unmatched or un_i > max_unmatched:
        return None
    pr = np.array(pairs, dtype=int).reshape(-1, 2)
    # refine over all correspondences: (0 <-> O_j[b]), (O_i[a] <-> 0), (O_i[m] <-> O_j[l]); residual variance
    # s2 when one side is exact, 2 s2 when both are measured
    pi_ = np.vstack([[0.0, 0.0], Pi[a], Pi[pr[:, 0]]])
    pj_ = np.vstack([Pj[b], [0.0, 0.0], Pj[pr[:, 1]]])
    v = np.concatenate([[s2, s2], np.full(len(pr), 2 * s2)])
    pose, fit = _procrustes(pi_, pj_, 1.0 / v)
    return Registration(pose, _fit_cov(pose, pj_, v), a, b, pr, fit)


def binary_register(
    obs_i: object,
    obs_j: object,
    sigma: float,
    *,
    gate: float = 5.0,
    max_unmatched: int = 0,
    max_range: float = np.inf,
    fov: float = 2 * np.pi,
    sigma_range: float | None = None,
    headings_i: object | None = None,
    headings_j: object | None = None,
    sigma_heading: float = 0.05,
    prior: tuple[np.ndarray, np.ndarray] | None = None,
    prior_gate: float = 16.266,
) -> list[Registration]:
    """Every feasible pose of frame ``j`` in frame ``i`` (module docstring), best (lowest cost) first.

    ``sigma`` [m] > 0: point noise std per axis; ``gate``: in standard deviations; ``max_unmatched``: points each
    side may leave unmatched among those the other robot should see (0: the ideal all-see-all model);
    ``max_range`` [m], ``fov`` [rad] (centred ahead): the sensors' limits (points the other robot could not see are
    not expected to match); ``sigma_range`` [m] (default ``sigma``): std of a measured range, for the test that
    the two robots measured the same distance between them (a range-bearing sensor's range noise is often far
    below its tangential noise). ``prior``: ``(pose (3,), cov (3, 3))``, a belief of the answer (exponential
    coordinates, right perturbation): candidates farther than ``prior_gate`` (Mahalanobis squared, the rough
    candidate's own uncertainty added) are dropped before they are matched and refined (slide 59's selection by the
    current belief, applied early: it is what keeps PMR's cost down once the beliefs are good).
    """
    Pi, Pj = as_points(obs_i, "binary_register: obs_i"), as_points(obs_j, "binary_register: obs_j")
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"binary_register: sigma must be a finite number > 0, got {sigma!r}")
    if not max_unmatched >= 0:
        raise ValueError(f"binary_register: max_unmatched must be >= 0, got {max_unmatched!r}")
    mi, mj = len(Pi), len(Pj)
    if mi == 0 or mj == 0:
        return []
    hi = None if headings_i is None else np.asarray(headings_i, float).reshape(mi)
    hj = None if headings_j is None else np.asarray(headings_j, float).reshape(mj)
    ri, rj = np.hypot(Pi[:, 0], Pi[:, 1]), np.hypot(Pj[:, 0], Pj[:, 1])
    s2 = sigma * sigma
    s_r = sigma if sigma_range is None else float(sigma_range)
    A, B, th = _candidates(Pi, Pj, s2, s_r, gate, hi, hj, sigma_heading, prior, prior_gate)
    if A.size == 0:
        return []
    R, Q, C, D2 = _distances(Pi, Pj, A, B, th, s2)
    within = D2 <= gate * gate
    # which points the other robot should have seen (inside its range by a margin of the gate)
    sd_j = np.sqrt(C[..., 0, 0] + C[..., 1, 1])
    expect_j = visible(Q, max_range, fov, gate * sd_j) & (np.arange(mj) != B[:, None])
    Pi_in_j = np.einsum("kba,kmb->kma", R, Pi[None, :, :] - Pi[A][:, None, :])  # O_i in frame j: R^T (p - t)
    lever = np.hypot(Pi_in_j[..., 0], Pi_in_j[..., 1])
    sd_i = sigma * np.sqrt(2 + (1 + lever / ri[A][:, None]) ** 2 + (lever / rj[B][:, None]) ** 2)
    expect_i = visible(Pi_in_j, max_range, fov, gate * sd_i) & (np.arange(mi) != A[:, None])
    has_j = within.any(2)
    has_i = within.any(1)
    keep = ((expect_j & ~has_j).sum(1) <= max_unmatched) & ((expect_i & ~has_i).sum(1) <= max_unmatched)
    out: list[Registration] = []
    for k in np.nonzero(keep)[0]:
        reg = _refined(Pi, Pj, int(A[k]), int(B[k]), D2[k], expect_j[k], expect_i[k], s2, gate, max_unmatched)
        if reg is not None:
            out.append(reg)
    out.sort(key=lambda r: r.cost)
    return out
