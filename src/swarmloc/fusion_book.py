"""Serial and parallel fusion of K.-T. Song, C.-Y. Tsai and C.-H. Chiu Huang, *Multi-robot cooperative sensing and
localization* (in *Robot Localization and Map Building*, InTech 2010; ``shared/seeds/004_*.txt``), eqs (1)-(42).

Conventions
-----------
* Planar pose ``(x, y, theta)`` in the world frame, metres and radians; a relative observation
  ``M_Eij = (x_e, y_e, theta_e)`` of robot ``j`` by robot ``i`` is in ``i``'s body frame (x forward, y left), as in
  :mod:`swarmloc.events`. Covariances are ``3 x 3`` (``2 x 2`` for the position-only form of eqs 40-41) and are
  *additive* in these coordinates (the chapter's ``Mbar = M + noise``), not exponential coordinates on SE(2).
* Every function broadcasts over leading axes: means ``(..., d)``, covariances ``(..., d, d)``.
* Headings of fused estimates are wrapped to ``(-pi, pi]``; before a heading is averaged, each input heading is
  unwrapped to within ``pi`` of the first input's, so estimates at ``+179 deg`` and ``-179 deg`` fuse to ``180 deg``.
* Invalid input (wrong shape, NaN/inf, non-symmetric or non-positive-definite covariance) raises ``ValueError``
  naming the function and the argument.

What implements what
--------------------
* :func:`serial_jacobian`: the Jacobian ``J`` of eqs (1)-(3) under eq. (4) (corrected, see below).
* :func:`serial_fusion`: eqs (7)-(8) (measured position ``M_Rij`` and covariance ``C_Rij = J diag(C_Ri, C_Eij) J^T``,
  the observer's own uncertainty propagated to first order), and, when robot ``j``'s prior ``(M_Rj, C_Rj)`` is
  given, its parallel fusion with that prior, eqs (22)-(24).
* :func:`serial_fusion_known_heading`: eqs (40)-(41), the position-only form used in the chapter's experiments
  (headings restricted to multiples of 90 deg and taken as exact).
* :func:`merge`: the binary parallel-fusion operator ``o`` of eqs (28)-(29): Kalman gain (22), updated position (23)
  and updated covariance (24), computed in the symmetric form (32).
* :func:`parallel_fusion`: eqs (34)-(35) (and 36-39): the fold of :func:`merge` over all estimates of one robot at one
  instant. It equals the information-form product of Gaussians ``C* = (sum C_k^-1)^-1``,
  ``M* = C* sum C_k^-1 M_k`` (the minimiser of the generalisation of criterion (9)), and ``C* <= C_k`` in the Loewner
  order for every input ``k`` (which implies eq. 33 for the spectral and Frobenius norms).
* :func:`book_two_robot_scenario`: the set-up of sec. 5 (robots H1 and H2, headings in {0, 90, 180, 270} deg, odometry
  of eq. 42, covariances of Remark 2); :func:`run_book_fusion` runs eqs (40)-(42) with parallel fusion over it.

Misprints found (checked numerically)
-------------------------------------
* **Jacobian under eq. (4), third row.** It is printed ``[0 1 0 0 1]`` (five entries, with a 1 in the ``y_r``
  column). Differentiating eq. (3), ``theta = theta_r + theta_e``, gives ``[0, 0, 1, 0, 0, 1]``. Evidence: for
  ``M_Ri = (1, 2, 0.7)``, ``M_Eij = (1.5, -0.8, 0.3)``, ``C_Ri = diag(0.01, 0.02, 0.003)``,
  ``C_Eij = diag(0.004, 0.006, 0.002)``, a 400 000-sample Monte Carlo of eqs (1)-(3) gives
  ``var(theta) = 0.00498`` and ``cov(x, theta) = -0.00106``; the corrected row gives ``0.00500`` and ``-0.00106``,
  the printed row (read as ``[0, 1, 0, 0, 0, 1]``) gives ``0.022`` and ``0`` (it adds ``var(y_r)`` to the heading
  variance and drops the heading-position correlation). Rows 1 and 2 are right.
* Eqs (9)-(33) and (40)-(41) check out: the three forms of (12), the gain identities (18), (20), the expansions (15),
  (16), (19), (21) and the symmetric form (32) agree to rounding on random SPD matrices, and (32) is the product of
  Gaussians. The chapter's step from the norm bound (33) to "therefore associative" is not a derivation, but the
  operator *is* associative and commutative (it adds information matrices), so eqs (34)-(39) hold in any order.
* **Remark 2 units.** The per-step covariance increments and the stereo covariances are printed without units and,
  read per move in cm^2 or m^2, do not reproduce the standard deviations of Tables 2-4 (46 moves of H1 with
  ``0.0596`` per move give ``sigma_x`` = 1.66 cm or 1.66 m at point F; Table 2 prints 18.1 cm). Read as dm^2
  (``1e-2 m^2``) per move they give ~16.6 cm there, the right order; :func:`book_two_robot_scenario` uses that
  reading (an assumption, stated again there). The chapter does not give an initial covariance either.

Serial-fusion results from different observers are fused as if independent of each other and of the prior (the
chapter's assumption, eqs 6, 9 and 34-35); correlations created by repeated fixes from the same observer and by earlier
fusions are ignored. Over :func:`book_two_robot_scenario` this is consistent when observations are sparse (one per
run: final NEES/dof 1.01 over 200 seeds, dead reckoning alone 1.0) but overconfident when the robots observe each other
at every move (``observe_every=1``: NEES/dof ~2.5); ``tests/test_fusion_book.py`` checks both.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarmloc.events import Detection, Event, Kind, Odometry, Truth, sim_order
from swarmloc.gaussian import check_covariance, symmetric
from swarmloc.lie import SE2, wrap_angle
from swarmloc.lie.checks import as_tangent


def _broadcast(where: str, **arrays: tuple[np.ndarray, int]) -> tuple[int, ...]:
    """Common batch shape of arrays given as ``name=(array, core_ndim)``; ValueError naming them if incompatible."""
    shapes = {name: a.shape[: a.ndim - k] for name, (a, k) in arrays.items()}
    try:
        return np.broadcast_shapes(*shapes.values())
    except ValueError:
        desc = ", ".join(f"'{n}' {s}" for n, s in shapes.items())
        raise ValueError(f"{where}: batch shapes of the arguments do not broadcast: {desc}") from None


def serial_jacobian(observer_mean: object, z: object) -> np.ndarray:
    """Jacobian ``J (..., 3, 6)`` of eqs (1)-(3) with respect to ``M = [M_Ri; M_Eij]`` (eq. 4, third row corrected).

    ``J = [[1, 0, -x_e s - y_e c, c, -s, 0], [0, 1, x_e c - y_e s, s, c, 0], [0, 0, 1, 0, 0, 1]]`` with
    ``c, s = cos theta_r, sin theta_r``.
    """
    where = "serial_jacobian"
    m = as_tangent(observer_mean, 3, where, "observer_mean")
    e = as_tangent(z, 3, where, "z")
    return _jacobian(m, e)


def _jacobian(m: np.ndarray, e: np.ndarray) -> np.ndarray:
    m, e = np.broadcast_arrays(m, e)
    th, xe, ye = m[..., 2], e[..., 0], e[..., 1]
    c, s = np.cos(th), np.sin(th)
    one, zero = np.ones_like(th), np.zeros_like(th)
    rows = [
        [one, zero, -xe * s - ye * c, c, -s, zero],
        [zero, one, xe * c - ye * s, s, c, zero],
        [zero, zero, one, zero, zero, one],
    ]
    return np.stack([np.stack(r, -1) for r in rows], -2)


def serial_fusion(
    observer_mean: object,
    observer_cov: object,
    z: object,
    z_cov: object,
    prior_mean: object | None = None,
    prior_cov: object | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Serial fusion, eqs (7)-(8): robot ``i`` at ``(observer_mean, observer_cov)`` (``M_Ri, C_Ri``) observes robot
    ``j`` at relative pose ``z`` (``M_Eij``, in ``i``'s body frame) with covariance ``z_cov`` (``C_Eij``).

    Returns ``(M_Rij, C_Rij)``: ``M_Rij = M_Ri + blockdiag(R(theta_r), 1) M_Eij`` (heading wrapped) and
    ``C_Rij = J blockdiag(C_Ri, C_Eij) J^T`` with ``J`` from :func:`serial_jacobian`.

    If ``prior_mean``/``prior_cov`` (robot ``j``'s own ``M_Rj, C_Rj``) are given, the result is instead the parallel
    fusion of that prior with ``(M_Rij, C_Rij)``, eqs (22)-(24) (see :func:`merge`). Shapes: means ``(..., 3)``,
    covariances ``(..., 3, 3)``, broadcast over leading axes.
    """
    where = "serial_fusion"
    m = as_tangent(observer_mean, 3, where, "observer_mean")
    Cr = check_covariance(observer_cov, 3, where, "observer_cov")
    e = as_tangent(z, 3, where, "z")
    Ce = check_covariance(z_cov, 3, where, "z_cov")
    if (prior_mean is None) != (prior_cov is None):
        raise ValueError(f"{where}: arguments 'prior_mean' and 'prior_cov' must be given together")
    pm = pc = None
    shapes: dict[str, tuple[np.ndarray, int]] = {
        "observer_mean": (m, 1),
        "observer_cov": (Cr, 2),
        "z": (e, 1),
        "z_cov": (Ce, 2),
    }
    if prior_mean is not None:
        pm = as_tangent(prior_mean, 3, where, "prior_mean")
        pc = check_covariance(prior_cov, 3, where, "prior_cov")
        shapes |= {"prior_mean": (pm, 1), "prior_cov": (pc, 2)}
    batch = _broadcast(where, **shapes)

    m = np.broadcast_to(m, (*batch, 3))
    e = np.broadcast_to(e, (*batch, 3))
    R = SE2.rotation(m[..., 2])
    xy = m[..., :2] + np.einsum("...ij,...j->...i", R, e[..., :2])
    mean = np.concatenate([xy, wrap_angle(m[..., 2:] + e[..., 2:])], axis=-1)

    J = _jacobian(m, e)
    B = np.zeros((*batch, 6, 6))
    B[..., :3, :3] = Cr
    B[..., 3:, 3:] = Ce
    cov = symmetric(J @ B @ np.swapaxes(J, -1, -2))
    if pm is None or pc is None:  # given together (checked above)
        return mean, cov
    return _merge(pm, pc, mean, cov, wrap_theta=True)


def serial_fusion_known_heading(
    observer_xy: object, observer_cov: object, heading: object, z: object, z_cov: object
) -> tuple[np.ndarray, np.ndarray]:
    """Position-only serial fusion with exact observer heading, eqs (40)-(41) (the chapter's experiments).

    ``observer_xy (..., 2)`` and ``observer_cov (..., 2, 2)`` are ``M_Ri, C_Ri``; ``heading (...)`` is ``theta_r``
    [rad]; ``z (..., 2)`` and ``z_cov (..., 2, 2)`` are ``M_Eij, C_Eij`` in the observer's frame. Returns
    ``(M_Rij, C_Rij)`` with ``M_Rij = M_Ri + R(theta_r) M_Eij`` and ``C_Rij = C_Ri + R C_Eij R^T`` (eq. 41 with
    ``J = [I, R]``).
    """
    where = "serial_fusion_known_heading"
    p = as_tangent(observer_xy, 2, where, "observer_xy")
    Cr = check_covariance(observer_cov, 2, where, "observer_cov")
    try:
        th = np.asarray(heading, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: argument 'heading' is not a numeric array ({exc})") from None
    if not np.isfinite(th).all():
        raise ValueError(f"{where}: argument 'heading' contains NaN or inf")
    e = as_tangent(z, 2, where, "z")
    Ce = check_covariance(z_cov, 2, where, "z_cov")
    _broadcast(
        where, observer_xy=(p, 1), observer_cov=(Cr, 2), heading=(th, 0), z=(e, 1), z_cov=(Ce, 2)
    )  # validates shapes
    R = SE2.rotation(th)
    mean = p + np.einsum("...ij,...j->...i", R, e)
    cov = symmetric(Cr + R @ Ce @ np.swapaxes(R, -1, -2))
    return mean, cov


def _merge(
    ma: np.ndarray, Ca: np.ndarray, mb: np.ndarray, Cb: np.ndarray, wrap_theta: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Eqs (22)-(24) without validation: ``K = C_a (C_a + C_b)^-1``, ``m = m_a + K (m_b - m_a)``,
    ``C = C_a (C_a + C_b)^-1 C_b`` (eq. 32, symmetrised)."""
    S = Ca + Cb
    # K = Ca S^-1  <=>  K^T = S^-1 Ca (S, Ca symmetric)
    K = np.swapaxes(np.linalg.solve(S, Ca), -1, -2)
    d = mb - ma
    if wrap_theta and d.shape[-1] == 3:
        d = d.copy()
        d[..., 2] = wrap_angle(d[..., 2])
    mean = ma + np.einsum("...ij,...j->...i", K, d)
    if wrap_theta and mean.shape[-1] == 3:
        mean[..., 2] = wrap_angle(mean[..., 2])
    cov = symmetric(K @ Cb)
    return mean, cov


def _as_pair(
    where: str, mean_name: str, cov_name: str, ma: object, Ca: object, d: int | None
) -> tuple[np.ndarray, np.ndarray, int]:
    try:
        arr = np.asarray(ma, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: argument '{mean_name}' is not a numeric array ({exc})") from None
    if arr.ndim < 1 or arr.shape[-1] not in (2, 3):
        raise ValueError(f"{where}: argument '{mean_name}' must have shape (..., 2) or (..., 3), got {arr.shape}")
    dim = arr.shape[-1] if d is None else d
    m = as_tangent(arr, dim, where, mean_name)
    C = check_covariance(Ca, dim, where, cov_name)
    return m, C, dim


def merge(
    mean_a: object, cov_a: object, mean_b: object, cov_b: object, *, wrap_theta: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """The parallel-fusion operator ``(M_a, C_a) o (M_b, C_b)`` of eqs (28)-(29): Kalman gain (22)
    ``K = C_a (C_a + C_b)^-1``, updated position (23) ``M_a + K (M_b - M_a)``, updated covariance (24)/(32)
    ``(I - K) C_a = C_a (C_a + C_b)^-1 C_b``.

    Means ``(..., d)``, covariances ``(..., d, d)``, ``d`` = 2 or 3; for ``d = 3`` and ``wrap_theta`` the heading
    difference and the result's heading are wrapped to ``(-pi, pi]``.
    """
    where = "merge"
    ma, Ca, d = _as_pair(where, "mean_a", "cov_a", mean_a, cov_a, None)
    mb, Cb, _ = _as_pair(where, "mean_b", "cov_b", mean_b, cov_b, d)
    _broadcast(where, mean_a=(ma, 1), cov_a=(Ca, 2), mean_b=(mb, 1), cov_b=(Cb, 2))
    return _merge(ma, Ca, mb, Cb, wrap_theta)


def parallel_fusion(
    estimates: Sequence[tuple[object, object]], *, wrap_theta: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Parallel fusion of all estimates of one robot at one instant, eqs (34)-(35): ``M_1 o M_2 o ... o M_n``.

    ``estimates`` is a non-empty sequence of ``(mean (..., d), cov (..., d, d))`` pairs (``d`` = 2 or 3, the same for
    all; leading axes broadcast) -- typically robot ``j``'s prior ``(M_Rj, C_Rj)`` and the serial-fusion results
    ``(M_Rij, C_Rij)`` of every observer ``i``. Computed as the chapter does, by folding :func:`merge` left to right;
    the result equals the information-weighted combination ``C* = (sum_k C_k^-1)^-1``,
    ``M* = C* sum_k C_k^-1 M_k`` (headings unwrapped near the first estimate's when ``d = 3`` and ``wrap_theta``),
    and ``C* <= C_k`` in the Loewner order for each ``k``. Returns ``(M*, C*)``.
    """
    where = "parallel_fusion"
    if isinstance(estimates, (str, bytes)) or not isinstance(estimates, Sequence):
        raise ValueError(f"{where}: argument 'estimates' must be a sequence of (mean, cov) pairs, got {estimates!r}")
    if len(estimates) == 0:
        raise ValueError(f"{where}: argument 'estimates' is empty")
    pairs = []
    d = None
    for k, item in enumerate(estimates):
        if not isinstance(item, (tuple, list)) or len(item) != 2:
            raise ValueError(f"{where}: argument 'estimates[{k}]' must be a (mean, cov) pair, got {item!r}")
        m, C, d = _as_pair(where, f"estimates[{k}] mean", f"estimates[{k}] cov", item[0], item[1], d)
        pairs.append((m, C))
    _broadcast(
        where,
        **{f"estimates[{k}]": (C, 2) for k, (_, C) in enumerate(pairs)},
        **{f"estimates[{k}] mean": (m, 1) for k, (m, _) in enumerate(pairs)},
    )
    mean, cov = pairs[0]
    mean = np.array(mean, dtype=float)
    if wrap_theta and d == 3:
        mean[..., 2] = wrap_angle(mean[..., 2])
    cov = np.array(cov, dtype=float)
    for m, C in pairs[1:]:
        mean, cov = _merge(mean, cov, m, C, wrap_theta)
    return mean, cov


# --------------------------------------------------------------------------------------------------------------------
# The chapter's two-robot experiment (sec. 5, experiment 2)

BOOK_ODOM_COV = {1: np.diag([0.0596, 0.0248]) * 1e-2, 2: np.diag([0.0478, 0.0513]) * 1e-2}
"""Per-move world-frame odometry covariance increment of H1 (id 1) and H2 (id 2) [m^2] (Remark 2, read as dm^2)."""

BOOK_OBS_COV = {1: np.diag([0.0430, 0.0532]) * 1e-2, 2: np.diag([0.0595, 0.0793]) * 1e-2}
"""Stereo observation covariance ``C_E12`` (observer H1) and ``C_E21`` (observer H2) in the observer's frame [m^2]
(Remark 2, read as dm^2)."""

BOOK_ROUTES = {
    1: ((0.4, -0.1, 90), ((90, 6), (180, 4), (270, 6), (0, 4))),
    2: ((-0.3, -1.0, 0), ((0, 5), (90, 9), (180, 5), (270, 9))),
}
"""Start ``(x [m], y [m], heading [deg])`` and a loop of legs ``(heading [deg], moves)`` for H1 and H2 (the chapter
gives no routes; these stay inside the ~2 x 3.5 m area of Tables 2-4 and bring the robots into each other's view)."""


@dataclass(frozen=True)
class BookObservation:
    """Robot ``observer`` sees ``target`` after move ``step``: ``z`` = ``(x_e, y_e)`` in the observer's frame [m]."""

    step: int
    observer: int
    target: int
    z: np.ndarray
    cov: np.ndarray


@dataclass(frozen=True)
class BookScenario:
    """The chapter's two-robot experiment (ids 1 = H1, 2 = H2), as swarmloc events and as the chapter's own data.

    ``events``: time-ordered :class:`Odometry` (one per move, ``dt`` s), :class:`Detection` (``kind="pose"``) and
    :class:`Truth`. ``headings[k, r]`` is robot ``r``'s (exact) heading during move ``k`` and after it (index by
    ``robots.index(r)``), ``odometry[k, r]`` the odometry displacement ``(dx, dy)`` of move ``k`` in the world frame
    (eq. 42), ``odom_cov[r]`` its covariance increment per translation move, ``truth[k, r]`` the true pose after ``k``
    moves (``truth[0]`` = start, ``k`` from 0 to ``n_moves``), ``observations`` the stereo fixes.
    """

    robots: tuple[int, ...]
    dt: float
    start: np.ndarray
    start_cov: np.ndarray
    headings: np.ndarray
    odometry: np.ndarray
    odom_cov: dict[int, np.ndarray]
    truth: np.ndarray
    observations: list[BookObservation]
    events: list[Event] = field(repr=False)


def _plan(robot: int, n_moves: int) -> list[tuple[str, int]]:
    """Robot's first ``n_moves`` moves along its :data:`BOOK_ROUTES` loop, ``(kind, heading [deg])``: a ``"turn"``
    of +-90 deg whenever the leg heading changes, then the leg's ``"move"`` translations."""
    (_, _, h0), legs = BOOK_ROUTES[robot]
    plan: list[tuple[str, int]] = []
    h = h0
    while len(plan) < n_moves:
        for leg_h, moves in legs:
            while h != leg_h:
                h = (h + (90 if (leg_h - h) % 360 <= 180 else -90)) % 360
                plan.append(("turn", h))
            plan.extend([("move", h)] * moves)
    return plan[:n_moves]


def _observe(
    rng: np.random.Generator, i: int, j: int, pi: np.ndarray, pj: np.ndarray, max_range: float, fov_deg: float
) -> tuple[np.ndarray, float] | None:
    """Robot ``i`` at true pose ``pi`` observing ``j`` at ``pj`` (:func:`book_two_robot_scenario`): the noisy
    relative position ``z`` in ``i``'s frame and the exact relative heading [rad], None when out of view."""
    Rt = SE2.rotation(pi[2])
    rel = Rt.T @ (pj[:2] - pi[:2])
    rng_ij = np.hypot(*rel)
    bearing = np.arctan2(rel[1], rel[0])
    if rng_ij > max_range or abs(bearing) > np.deg2rad(fov_deg) / 2:
        return None
    z = rel + rng.multivariate_normal(np.zeros(2), BOOK_OBS_COV[i])
    return z, float(wrap_angle(np.array(pj[2] - pi[2])))


def _pose_detection(i: int, j: int, t: float, z: np.ndarray, te: float, theta_var: float) -> Detection:
    """The observation as a ``"pose"`` :class:`Detection`: ``(x_e, y_e, te)`` with ``R_e^T C_Eij R_e`` in the
    position block and ``theta_var`` for the heading (:func:`book_two_robot_scenario`)."""
    Re = SE2.rotation(np.array(te))
    cov = np.zeros((3, 3))
    cov[:2, :2] = symmetric(Re.T @ BOOK_OBS_COV[i] @ Re)
    cov[2, 2] = theta_var
    return Detection(i, t, Kind.POSE, np.array([z[0], z[1], te]), cov, target=j)


def book_two_robot_scenario(
    seed: int = 0,
    *,
    n_moves: int = 60,
    step: float = 0.2,
    dt: float = 1.0,
    max_range: float = 3.0,
    fov_deg: float = 60.0,
    start_sigma: float = 0.03,
    observe_every: int = 1,
    detection_theta_var: float = 1e-10,
) -> BookScenario:
    """Sec. 5, experiment 2: H1 and H2 drive axis-aligned loops (headings only 0/90/180/270 deg, eq. 42) and observe
    each other with stereo vision.

    Each move lasts ``dt`` s and is either a translation of ``step`` m along the current heading (odometry reports
    ``v = step / dt``; the true displacement adds world-frame noise with the robot's :data:`BOOK_ODOM_COV`) or an
    exact in-place turn of +-90 deg (``v = 0``, ``w = +-pi / (2 dt)``, no noise: the chapter takes headings as known).
    The routes are :data:`BOOK_ROUTES`; both start at their nominal poses with true position error
    ``N(0, start_sigma^2 I)`` (the chapter gives no initial covariance). After every ``observe_every``-th move, robot
    ``i`` observes ``j`` when ``j`` is within ``max_range`` m and ``fov_deg / 2`` of ``i``'s heading:
    ``z = R(theta_i)^T (p_j - p_i) + n``, ``n ~ N(0, C_Eij)`` (:data:`BOOK_OBS_COV`). As a swarmloc
    :class:`Detection` (``kind="pose"``) it carries ``z = (x_e, y_e, theta_j - theta_i)`` and the covariance of
    ``m_true^-1 m_measured`` in exponential coordinates: ``R_e^T C_Eij R_e`` in the position block
    (``R_e = R(theta_j - theta_i)``) and ``detection_theta_var`` for the exact heading (positive so the covariance is
    SPD). Units of Remark 2 are read as dm^2 (see the module docstring).
    """
    if n_moves < 1:
        raise ValueError(f"book_two_robot_scenario: argument 'n_moves' must be >= 1, got {n_moves!r}")
    if not (step > 0 and dt > 0 and max_range > 0 and 0 < fov_deg <= 360 and start_sigma >= 0):
        raise ValueError("book_two_robot_scenario: arguments 'step', 'dt', 'max_range', 'fov_deg' must be positive")
    if observe_every < 1:
        raise ValueError(f"book_two_robot_scenario: argument 'observe_every' must be >= 1, got {observe_every!r}")
    rng = np.random.default_rng(seed)
    robots = (1, 2)
    n_r = len(robots)
    plans = {r: _plan(r, n_moves) for r in robots}
    start = np.array([[*BOOK_ROUTES[r][0][:2], np.deg2rad(BOOK_ROUTES[r][0][2])] for r in robots], dtype=float)
    start_cov = np.broadcast_to(start_sigma**2 * np.eye(2), (n_r, 2, 2)).copy()
    truth = np.zeros((n_moves + 1, n_r, 3))
    truth[0] = start
    truth[0, :, :2] += start_sigma * rng.standard_normal((n_r, 2))
    headings = np.zeros((n_moves, n_r))
    odometry = np.zeros((n_moves, n_r, 2))
    events: list[Event] = [Truth(r, 0.0, truth[0, a].copy()) for a, r in enumerate(robots)]
    observations: list[BookObservation] = []

    for k in range(n_moves):
        t0, t1 = k * dt, (k + 1) * dt
        for a, r in enumerate(robots):
            kind, h = plans[r][k]
            th = np.deg2rad(h)
            headings[k, a] = th
            truth[k + 1, a] = truth[k, a]
            truth[k + 1, a, 2] = wrap_angle(np.array(th))
            if kind == "turn":
                dth = wrap_angle(np.array(th - truth[k, a, 2]))
                events.append(Odometry(r, t0, t1, 0.0, float(dth / dt)))
            else:
                d = step * np.array([np.cos(th), np.sin(th)])
                d = np.round(d, 12)
                odometry[k, a] = d
                noise = rng.multivariate_normal(np.zeros(2), BOOK_ODOM_COV[r])
                truth[k + 1, a, :2] += d + noise
                events.append(Odometry(r, t0, t1, step / dt, 0.0))
        if (k + 1) % observe_every:
            continue
        for a, i in enumerate(robots):
            for b, j in enumerate(robots):
                seen = None if i == j else _observe(rng, i, j, truth[k + 1, a], truth[k + 1, b], max_range, fov_deg)
                if seen is not None:
                    z, te = seen
                    observations.append(BookObservation(k + 1, i, j, z, BOOK_OBS_COV[i].copy()))
                    events.append(_pose_detection(i, j, t1, z, te, detection_theta_var))
        events.extend(Truth(r, t1, truth[k + 1, a].copy()) for a, r in enumerate(robots))

    if observe_every > 1:  # Truth after moves without an observation round
        have = {(e.robot, e.t) for e in events if isinstance(e, Truth)}
        for k in range(n_moves):
            t1 = (k + 1) * dt
            events.extend(Truth(r, t1, truth[k + 1, a].copy()) for a, r in enumerate(robots) if (r, t1) not in have)
    events.sort(key=sim_order)
    odom_cov = {r: BOOK_ODOM_COV[r].copy() for r in robots}
    return BookScenario(robots, dt, start, start_cov, headings, odometry, odom_cov, truth, observations, events)


def run_book_fusion(
    scenario: BookScenario, *, cooperative: bool = True, server: Any = None
) -> tuple[np.ndarray, np.ndarray]:
    """Run the chapter's localization over ``scenario``: dead reckoning (eq. 42, covariance grown by Remark 2's
    increment on every translation move) and, if ``cooperative``, after each move the serial fusion (eqs 40-41) of
    every observation of robot ``j`` by the observers' pre-update estimates, parallel-fused with ``j``'s prior
    (eqs 34-35), all treated as independent as in the chapter (overconfident with frequent observations; see the
    module docstring). Returns ``means (n_moves + 1, n_robots, 2)`` and ``covs (n_moves + 1, n_robots, 2, 2)``.

    ``server``: a :class:`swarmloc.net.server.BeliefServer` (the chapter's server, the same class the network
    runtime serves over Zenoh). Every robot then stores its Gaussian there after each move (as an SE(2) belief,
    its known heading with variance 1e-10, step ``k`` as the stamp) and the observers' estimates are read back
    from it instead of from memory.
    """
    sc = scenario
    n_moves, n_r = sc.headings.shape
    means = np.zeros((n_moves + 1, n_r, 2))
    covs = np.zeros((n_moves + 1, n_r, 2, 2))
    means[0] = sc.start[:, :2]
    covs[0] = sc.start_cov
    by_step: dict[int, list[BookObservation]] = {}
    for ob in sc.observations:
        by_step.setdefault(ob.step, []).append(ob)
    for k in range(n_moves):
        for a, r in enumerate(sc.robots):
            moved = bool(np.any(sc.odometry[k, a] != 0))
            means[k + 1, a] = means[k, a] + sc.odometry[k, a]
            covs[k + 1, a] = covs[k, a] + (sc.odom_cov[r] if moved else 0.0)
        if not cooperative or (k + 1) not in by_step:
            continue
        pre_m, pre_c = means[k + 1].copy(), covs[k + 1].copy()
        if server is not None:
            pre_m, pre_c = _through_server(server, sc, k, pre_m, pre_c)
        for b, j in enumerate(sc.robots):
            obs = [ob for ob in by_step[k + 1] if ob.target == j]
            if not obs:
                continue
            ests = [(pre_m[b], pre_c[b])]
            for ob in obs:
                a = sc.robots.index(ob.observer)
                ests.append(serial_fusion_known_heading(pre_m[a], pre_c[a], sc.headings[k, a], ob.z, ob.cov))
            means[k + 1, b], covs[k + 1, b] = parallel_fusion(ests)
    return means, covs


def _through_server(
    server: Any, sc: BookScenario, k: int, m: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Store every robot's belief after move ``k`` on the server and read the team's beliefs back from it."""
    from swarmloc.gaussian import GroupGaussian
    from swarmloc.lie import SE2

    out_m, out_c = m.copy(), c.copy()
    for a, r in enumerate(sc.robots):
        g = SE2.from_xytheta([m[a, 0], m[a, 1], sc.headings[k, a]])
        R = g[:2, :2]
        cov = np.zeros((3, 3))
        cov[:2, :2] = R.T @ c[a] @ R  # exponential coordinates (right perturbation): the error in the body frame
        cov[2, 2] = 1e-10
        server.put(r, float(k + 1), GroupGaussian(SE2, g, cov))
    for a, r in enumerate(sc.robots):
        b = server.gaussian(r, float(k + 1))
        R = b.mean[:2, :2]
        out_m[a] = b.mean[:2, 2]
        out_c[a] = R @ b.cov[:2, :2] @ R.T
    return out_m, out_c
