"""The centralized EKFs (``cekf``, ``iekf``) and ``diekf`` on the engine: the team's joint state replayed in one
compiled loop (numba).

:class:`swarmloc.estimators.CentralizedEKF` keeps the joint Cartesian state ``X = (x_1, y_1, theta_1, ...)`` of
the ``n`` robots and its ``3n x 3n`` covariance; this module does what that node does over a whole
:class:`~swarmloc.engine.detections.Timeline`, in one call compiled by numba (:func:`replay_joint`), so a
recording replays without a Python step per input:

* **Prediction.** Robot ``k`` moves from its clock to a stamp with the command in force (the scalar prediction
  the engine's other kernels share, :func:`swarmloc.engine.scalar.predict_source`); its shear ``Phi`` and process
  covariance are kept pending, composed as the node composes them, and applied to the joint covariance only when
  an update needs it (:func:`swarmloc.estimators.cekf.flush_pending`, the same arithmetic).
* **Order.** At a stamp the detection groups fuse in observer order (each detection in the group's canonical
  order; the observer and a detected robot are predicted to the stamp and stay there, as the node stores them),
  then each robot with a command there moves to the stamp and starts it (after the updates: an update moves
  every correlated robot's heading, so predicting a robot before or after it differs); a record is every robot's
  marginal predicted to the stamp, not stored (:meth:`~swarmloc.node.base.Node.belief_at`).
* **Update.** One detection at a time, the node's Joseph form touching only the observer's and the target's three
  columns (:func:`swarmloc.kernels.cartesian.kalman_update_blocks`), every kind of
  :data:`swarmloc.sensors.models.MODELS` (absolute fixes, relative poses, range-bearing, range, bearing of robots
  and map landmarks), then the gate and the finite, positive-definite check of
  :func:`swarmloc.node.update.gated_kalman`.

**The invariant EKFs** (``invariant=True``). The same loop in world-frame errors
(:mod:`swarmloc.kernels.invariant`): a prediction adds ``N^-1 Q N^-T`` to the robot's block and nothing else (no
shear), Jacobian blocks are ``H_c N(x)``, and the correction moves each robot on the group, ``exp(hat(K r)) g``:
the centralized :class:`~swarmloc.estimators.InvariantEKF` (``iekf``). With each robot's start (``t0 (n,)``) it is
``diekf``'s team (:class:`~swarmloc.estimators.DistributedInvariantEKF`): its nodes' replicas together are this
joint state, so only what the nodes decide apart from the filter differs: a robot starts at its own first input and
is asked only from then on (:func:`screen_started`), and a detected robot moves to the stamp only when it takes the
update (a gated or refused detection leaves it where it was).

Results equal the nodes' to rounding (tests/test_engine_cekf.py, tests/test_engine_invariant.py: 1e-10 on
simulated teams, 1e-9 relative on MRCLAM, every outcome count and reason). Units: metres, radians, seconds; angles
wrapped to (-pi, pi].
"""

from __future__ import annotations

import math
from functools import cache
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from swarmloc.engine.codes import (
    ABSOLUTE,
    FUSED,
    GATED,
    NO_LANDMARK,
    POSE,
    R_DEGENERATE,
    R_LANDMARKS_OFF,
    R_NO_LANDMARK,
    R_NONFINITE,
    R_NOT_STARTED,
    R_NUMERICAL,
    R_OFF,
    R_SELF,
    R_TEAM,
    R_UNUSABLE,
    REJECTED,
    UNKNOWN,
    UNKNOWN_ROBOT,
    UNUSABLE,
)
from swarmloc.engine.detections import Timeline
from swarmloc.engine.scalar import predict_source
from swarmloc.kernels.invariant import cartesian_to_world_cov
from swarmloc.motion import UnicycleNoise
from swarmloc.node.update import Gate
from swarmloc.sensors.models import KIND_ORDER, MIN_RANGE, MODELS

RANGE_BEARING, RANGE, BEARING = KIND_ORDER["range_bearing"], KIND_ORDER["range"], KIND_ORDER["bearing"]
_PI = math.pi
_TAU = 2 * math.pi


@njit(error_model="numpy")
def wrap(a: float) -> float:
    """An angle [rad] wrapped to (-pi, pi] (the formula of :func:`swarmloc.lie.wrap_angle`), compiled."""
    return _PI - (_PI - a) % _TAU


@njit(error_model="numpy")
def _compose(pend: np.ndarray, has: np.ndarray, k: int, dx: float, dy: float, q: np.ndarray) -> None:
    """Robot ``k``'s pending ``(a, b, Q upper)`` after one more prediction (:func:`~swarmloc.estimators.cekf.
    compose_pending`)."""
    if not has[k]:
        pend[k, 0], pend[k, 1] = -dy, dx
        pend[k, 2:] = q
        has[k] = True
        return
    q00, q01, q02, q11, q12, q22 = pend[k, 2], pend[k, 3], pend[k, 4], pend[k, 5], pend[k, 6], pend[k, 7]
    a02, a12 = q02 - dy * q22, q12 + dx * q22
    pend[k, 0] -= dy
    pend[k, 1] += dx
    pend[k, 2] = q00 - 2 * dy * q02 + dy * dy * q22 + q[0]
    pend[k, 3] = q01 - dy * q12 + dx * a02 + q[1]
    pend[k, 4] = a02 + q[2]
    pend[k, 5] = q11 + 2 * dx * q12 + dx * dx * q22 + q[3]
    pend[k, 6] = a12 + q[4]
    pend[k, 7] = q22 + q[5]


@njit(error_model="numpy")
def flush(P: np.ndarray, pend: np.ndarray, has: np.ndarray) -> None:
    """Every robot's pending prediction applied to the joint ``P`` (:func:`~swarmloc.estimators.cekf.flush_pending`)."""
    N = P.shape[0]
    for k in range(has.shape[0]):
        if not has[k]:
            continue
        i = 3 * k
        a, b = pend[k, 0], pend[k, 1]
        if a != 0.0 or b != 0.0:  # no shear (the invariant filters' predictions): only the noise
            for c in range(N):
                row = P[i + 2, c]
                P[i, c] += a * row
                P[i + 1, c] += b * row
            for r in range(N):
                col = P[r, i + 2]
                P[r, i] += a * col
                P[r, i + 1] += b * col
        u = pend[k, 2:]
        P[i, i] += u[0]
        P[i, i + 1] += u[1]
        P[i, i + 2] += u[2]
        P[i + 1, i] += u[1]
        P[i + 1, i + 1] += u[3]
        P[i + 1, i + 2] += u[4]
        P[i + 2, i] += u[2]
        P[i + 2, i + 1] += u[4]
        P[i + 2, i + 2] += u[5]
        has[k] = False


@njit(error_model="numpy")
def inverse(S: np.ndarray) -> tuple[np.ndarray, bool]:
    """Inverse of a 1x1, 2x2 or 3x3 ``S`` by cofactors; ``(S, False)`` when it is singular."""
    m = S.shape[0]
    out = np.empty_like(S)
    if m == 1:
        det = S[0, 0]
        if det == 0.0:
            return S, False
        out[0, 0] = 1.0 / det
        return out, True
    if m == 2:
        det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
        if det == 0.0:
            return S, False
        out[0, 0], out[0, 1], out[1, 0], out[1, 1] = S[1, 1] / det, -S[0, 1] / det, -S[1, 0] / det, S[0, 0] / det
        return out, True
    for r in range(3):
        for c in range(3):
            r1, r2, c1, c2 = (c + 1) % 3, (c + 2) % 3, (r + 1) % 3, (r + 2) % 3
            out[r, c] = S[r1, c1] * S[r2, c2] - S[r1, c2] * S[r2, c1]
    det = S[0, 0] * out[0, 0] + S[0, 1] * out[1, 0] + S[0, 2] * out[2, 0]
    if det == 0.0:
        return S, False
    return out / det, True


@njit(error_model="numpy")
def usable(P: np.ndarray) -> bool:
    """Finite and positive definite (:func:`swarmloc.node.update.usable_covariance`: a Cholesky factorization)."""
    N = P.shape[0]
    if N == 3 and np.isfinite(P).all():  # the node's leading minors with a margin, for a team of one
        m2 = P[0, 0] * P[1, 1] - P[1, 0] * P[1, 0]
        m3 = (P[0, 0] * (P[1, 1] * P[2, 2] - P[2, 1] * P[2, 1]) - P[1, 0] * (P[1, 0] * P[2, 2] - P[2, 1] * P[2, 0])
              + P[2, 0] * (P[1, 0] * P[2, 1] - P[1, 1] * P[2, 0]))  # fmt: skip
        tr = P[0, 0] + P[1, 1] + P[2, 2]
        if P[0, 0] > 0 and m2 > 1e-9 * tr * tr and m3 > 1e-9 * tr * tr * tr:
            return True
    if not np.isfinite(P).all():
        return False
    L = np.zeros_like(P)
    for j in range(N):
        d = P[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0:
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, N):
            s = P[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return True


@njit(error_model="numpy")
def measure(kind: int, X: np.ndarray, i: int, xk: np.ndarray, zq: np.ndarray, Rq: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Residual ``r (m,)``, Jacobian ``H (m, 3 + len(xk))`` (observer's columns, then the target's) and noise
    ``R (m, m)`` of a detection of ``kind`` by the robot at rows ``i:i+3`` of ``X`` of a target at ``xk``
    (:mod:`swarmloc.sensors.models`: predictions, residuals wrapped, a relative pose's noise made Cartesian)."""
    x0, y0, th = X[i], X[i + 1], X[i + 2]
    if kind == ABSOLUTE:
        H = np.eye(3)
        r = np.array([zq[0] - x0, zq[1] - y0, wrap(zq[2] - th)])
        return r, H, Rq[:3, :3].copy()
    dx, dy = xk[0] - x0, xk[1] - y0
    c, s = math.cos(th), math.sin(th)
    bx, by = c * dx + s * dy, -s * dx + c * dy
    w = 3 + xk.shape[0]
    if kind == POSE:
        H = np.zeros((3, w))
        H[0, 0], H[0, 1], H[0, 2], H[1, 0], H[1, 1], H[1, 2], H[2, 2] = -c, -s, by, s, -c, -bx, -1.0
        H[0, 3], H[0, 4], H[1, 3], H[1, 4], H[2, 5] = c, s, -s, c, 1.0
        r = np.array([zq[0] - bx, zq[1] - by, wrap(zq[2] - wrap(xk[2] - th))])
        cz, sz = math.cos(zq[2]), math.sin(zq[2])
        B = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
        return r, H, B @ Rq[:3, :3].copy() @ B.T
    q = dx * dx + dy * dy
    rng = math.sqrt(q)
    full = np.zeros((2, w))
    full[0, 0], full[0, 1], full[1, 0], full[1, 1], full[1, 2] = -dx / rng, -dy / rng, dy / q, -dx / q, -1.0
    full[:, 3:5] = -full[:, 0:2]
    res = np.array([zq[0] - rng, wrap(zq[1] - wrap(math.atan2(by, bx)))])
    if kind == RANGE_BEARING:
        return res, full, Rq[:2, :2].copy()
    j = 0 if kind == RANGE else 1
    r1 = np.array([zq[0] - rng]) if j == 0 else np.array([wrap(zq[0] - wrap(math.atan2(by, bx)))])
    return r1, full[j : j + 1].copy(), Rq[:1, :1].copy()


@njit(error_model="numpy")
def _sinc(t: float) -> float:
    """``sin(t) / t`` with the Taylor branch of :func:`swarmloc.lie.SE2.exp` below 0.05 (the same coefficients)."""
    if abs(t) < 0.05:
        t2 = t * t
        return (((t2 / 362880.0 - 1.0 / 5040.0) * t2 + 1.0 / 120.0) * t2 - 1.0 / 6.0) * t2 + 1.0
    return math.sin(t) / t


@njit(error_model="numpy")
def _one_minus_cos_over_t(t: float) -> float:
    """``(1 - cos t) / t`` with the Taylor branch of :func:`swarmloc.lie.SE2.exp` below 0.05."""
    if abs(t) < 0.05:
        t2 = t * t
        return t * ((((t2 / 3628800.0 - 1.0 / 40320.0) * t2 + 1.0 / 720.0) * t2 - 1.0 / 24.0) * t2 + 0.5)
    return t * (2.0 * math.sin(t / 2) ** 2 / (t * t))


@njit(error_model="numpy")
def left_correct(X: np.ndarray, delta: np.ndarray) -> None:
    """Every robot's pose ``X[3k:3k+3]`` corrected by its world-frame ``delta[3k:3k+3]``, written into ``delta``:
    the Cartesian pose of ``exp(hat(delta_k)) g(x_k)`` (:func:`swarmloc.kernels.invariant.left_correct`)."""
    for i in range(0, X.shape[0], 3):
        d0, d1, d2 = delta[i], delta[i + 1], delta[i + 2]
        c, s = math.cos(d2), math.sin(d2)
        A, B = _sinc(d2), _one_minus_cos_over_t(d2)
        x, y, ct, st = X[i], X[i + 1], math.cos(X[i + 2]), math.sin(X[i + 2])
        delta[i] = c * x - s * y + (A * d0 - B * d1)
        delta[i + 1] = s * x + c * y + (B * d0 + A * d1)
        delta[i + 2] = wrap(math.atan2(s * ct + c * st, c * ct - s * st))


@njit(error_model="numpy")
def to_world(H: np.ndarray, c: int, x: float, y: float) -> None:
    """The Cartesian Jacobian block ``H[:, c:c+3]`` of a pose at ``(x, y)`` made one of its world-frame error, in
    place: ``H N`` with ``N = [[1, 0, -y], [0, 1, x], [0, 0, 1]]`` (:func:`swarmloc.kernels.invariant.world_basis`)."""
    for k in range(H.shape[0]):
        H[k, c + 2] += -y * H[k, c] + x * H[k, c + 1]


@njit(error_model="numpy")
def world_noise(x: float, y: float, q: np.ndarray) -> np.ndarray:
    """A step's Cartesian process noise (upper triangle ``q00, q01, q02, q11, q12, q22``) at the new pose ``(x, y)``
    as the world-frame error's, ``N^-1 Q N^-T`` (:func:`swarmloc.kernels.invariant.cartesian_to_world_cov`; the
    products of :class:`swarmloc.estimators.InvariantEKF`'s prediction)."""
    q00, q01, q02, q11, q12, q22 = q[0], q[1], q[2], q[3], q[4], q[5]
    a02, a12 = q02 + y * q22, q12 - x * q22
    return np.array([q00 + 2 * y * q02 + y * y * q22, q01 - x * q02 + y * a12, a02,
                     q11 - 2 * x * q12 + x * x * q22, a12, q22])  # fmt: skip


@njit(error_model="numpy")
def innovation(P: np.ndarray, H: np.ndarray, cols: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(U, S)`` of a Kalman update on the columns ``cols`` of ``P (N, N)``: ``U = P[:, cols] H^T`` ``(N, m)`` and
    ``S = H U[cols] + R`` ``(m, m)``, written as loops (small matrices: a matrix product's call costs more than its
    work)."""
    N, m, c = P.shape[0], H.shape[0], cols.shape[0]
    U = np.zeros((N, m))
    for a in range(N):
        for k in range(m):
            acc = 0.0
            for b in range(c):
                acc += P[a, cols[b]] * H[k, b]
            U[a, k] = acc
    S = R.copy()
    for k in range(m):
        for ll in range(m):
            acc = 0.0
            for b in range(c):
                acc += H[k, b] * U[cols[b], ll]
            S[k, ll] += acc
    return U, S


@njit(error_model="numpy")
def kalman(X: np.ndarray, P: np.ndarray, r: np.ndarray, H: np.ndarray, cols: np.ndarray, R: np.ndarray,
            invariant: bool = False) -> tuple[np.ndarray, np.ndarray, float, bool]:  # fmt: skip
    """:func:`swarmloc.kernels.cartesian.kalman_update_blocks` (every robot's heading wrapped): ``U = P[:, cols]
    H^T``, ``S = H U[cols] + R`` (:func:`innovation`), ``K = U S^-1``, ``P+ = P - K U^T - (U - K S) K^T``
    symmetrized, written as loops (the matrices are 3n x m, m <= 3: no temporaries of 3n x 3n but ``P+`` itself).
    ``invariant``: ``P`` is of world-frame errors and each robot's pose is corrected on the group,
    ``exp(hat(K r)) g`` (:func:`left_correct`), not by ``x + K r``."""
    N, m = P.shape[0], H.shape[0]
    U, S = innovation(P, H, cols, R)
    S_inv, regular = inverse(S)
    if not regular:
        return X, P, math.nan, False
    nis = 0.0
    for k in range(m):
        for ll in range(m):
            nis += r[k] * S_inv[k, ll] * r[ll]
    K = np.zeros((N, m))
    W = U.copy()  # U - K S
    xn = np.empty(N)
    for a in range(N):
        step = 0.0
        for k in range(m):
            acc = 0.0
            for ll in range(m):
                acc += U[a, ll] * S_inv[ll, k]
            K[a, k] = acc
            step += acc * r[k]
        xn[a] = step if invariant else X[a] + step
        for k in range(m):
            for ll in range(m):
                W[a, k] -= K[a, ll] * S[ll, k]
    if invariant:
        left_correct(X, xn)
    else:
        for a in range(2, N, 3):
            xn[a] = wrap(xn[a])
    Pn = np.empty((N, N))
    ok = math.isfinite(nis)
    for a in range(N):
        ok = ok and math.isfinite(xn[a])
        for b in range(a, N):
            ab, ba = P[a, b], P[b, a]
            for k in range(m):
                ab -= K[a, k] * U[b, k] + W[a, k] * K[b, k]
                ba -= K[b, k] * U[a, k] + W[b, k] * K[a, k]
            val = 0.5 * (ab + ba)
            Pn[a, b] = val
            Pn[b, a] = val
            ok = ok and math.isfinite(val)
    return xn, Pn, nis, ok


@njit(error_model="numpy")
def screen_started(kind: int, i: int, j: int, t: float, t0: np.ndarray, relative: bool, lm_on: bool
                   ) -> tuple[int, int]:  # fmt: skip
    """``(outcome, reason)`` decided before any state is read (0, 0: go on), as the distributed nodes decide it
    (:meth:`~swarmloc.node.base.Node._classify`; a teammate answers only from its start ``t0[j]`` on)."""
    if kind == ABSOLUTE:
        return 0, 0
    if j <= NO_LANDMARK:
        if not lm_on:
            return REJECTED, R_LANDMARKS_OFF
        return (UNKNOWN, R_NO_LANDMARK) if j == NO_LANDMARK else (0, 0)
    if j == UNUSABLE:  # worded from the detection by the caller (relative off, no target id, a landmark's pose)
        return REJECTED, R_UNUSABLE
    if not relative:
        return REJECTED, R_OFF
    if j == UNKNOWN_ROBOT:
        return UNKNOWN, R_TEAM
    if j == i:
        return REJECTED, R_SELF
    return (UNKNOWN, R_NOT_STARTED) if not t >= t0[j] else (0, 0)


@njit(error_model="numpy")
def _screen(kind: int, i: int, j: int, relative: bool, lm_on: bool) -> tuple[int, int]:
    """``(outcome, reason)`` decided before any state is read (0, 0: go on), the node's ``_classify`` as codes."""
    if kind == ABSOLUTE:
        return 0, 0
    if j <= NO_LANDMARK:  # a landmark's (a pose of a landmark has the code UNUSABLE)
        if not lm_on:
            return REJECTED, R_LANDMARKS_OFF
        return (UNKNOWN, R_NO_LANDMARK) if j == NO_LANDMARK else (0, 0)
    if j == UNKNOWN_ROBOT:
        return (UNKNOWN, R_TEAM) if relative else (REJECTED, R_OFF)
    if j < 0:
        return REJECTED, R_UNUSABLE
    if not relative:
        return REJECTED, R_OFF
    return (REJECTED, R_SELF) if j == i else (0, 0)


@cache
def predict_kernel(noise: UnicycleNoise) -> Any:
    """The engine's scalar prediction for ``noise`` (:func:`swarmloc.engine.scalar.predict_source`) compiled:
    ``predict(x0, x1, x2, p00, p01, p02, p11, p12, p22, v, w, dt) -> (x (3), P upper triangle (6))``."""
    ns: dict[str, Any] = {"math": math, "np": np}
    exec(predict_source(noise), ns)  # noqa: S102 - our own generated code
    return njit(error_model="numpy")(ns["predict"])


@cache
def _kernels(noise: UnicycleNoise, invariant: bool = False, distributed: bool = False) -> Any:
    """Compile the replay loop with the noise model's prediction (once per process, noise model and form).
    ``invariant``: world-frame errors (``iekf``, ``diekf``). ``distributed`` (with ``invariant``: ``diekf``'s nodes):
    each robot starts at its own first input and answers from then on (:func:`screen_started`), and a detected
    robot moves to the detection's stamp only when it takes the update (its node answers a query from a prediction
    it does not store; it moves when the broadcast updates it)."""
    return _loop(*steps(noise, invariant, distributed), distributed)


@cache
def steps(noise: UnicycleNoise, invariant: bool = False, distributed: bool = False) -> tuple[Any, Any, Any]:
    """The compiled steps of the replay loop (:func:`_kernels`): ``advance(X, pend, has, tc, v, w, k, t)`` (robot
    ``k`` to ``t``, its prediction pending), ``marginal(X, P, pend, has, tc, v, w, k, t, out_x, out_P, o)`` (robot
    ``k``'s Cartesian belief at ``t`` into record ``o``, nothing stored) and ``fuse(X, P, pend, has, tc, v, w, t, q,
    i, j, kind, z, R, lxy, lcov, thr, gate) -> (outcome, reason)`` (detection ``q`` of observer ``i``, target ``j``:
    a robot's index, or a landmark's code). They index robots by their rows of the arrays passed, so a cluster's
    views of them run the same steps (:mod:`swarmloc.engine.joint_clusters`)."""
    predict = predict_kernel(noise)

    @njit(error_model="numpy")
    def advance(X, pend, has, tc, v, w, k, t):  # noqa: ANN001, ANN202
        dt = t - tc[k]
        if not dt > 0:
            return
        i = 3 * k
        r = predict(X[i], X[i + 1], X[i + 2], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, v[k], w[k], dt)
        q = np.array([r[3], r[4], r[5], r[6], r[7], r[8]])
        if invariant:  # the error transition is the identity: no shear, the noise in world-frame errors
            dx, dy, q = 0.0, 0.0, world_noise(r[0], r[1], q)
        else:
            dx, dy = r[0] - X[i], r[1] - X[i + 1]
        X[i], X[i + 1], X[i + 2] = r[0], r[1], r[2]
        _compose(pend, has, k, dx, dy, q)
        tc[k] = t

    @njit(error_model="numpy")
    def marginal(X, P, pend, has, tc, v, w, k, t, out_x, out_P, o):  # noqa: ANN001, ANN202
        i = 3 * k
        x, pd, hs, clock = X[i : i + 3].copy(), pend[k : k + 1].copy(), has[k : k + 1].copy(), tc[k : k + 1].copy()
        advance(x, pd, hs, clock, v[k : k + 1], w[k : k + 1], 0, t)
        M = P[i : i + 3, i : i + 3].copy()
        flush(M, pd, hs)
        out_x[o] = x
        if invariant:  # recorded Cartesian: N M N^T
            N = np.array([[1.0, 0.0, -x[1]], [0.0, 1.0, x[0]], [0.0, 0.0, 1.0]])
            M = N @ M @ N.T
        out_P[o] = M

    @njit(error_model="numpy")
    def fuse(X, P, pend, has, tc, v, w, t, q, i, j, kind, z, R, lxy, lcov, thr, gate):  # noqa: ANN001, ANN202
        if not (distributed and j >= 0):
            return update(X, P, pend, has, tc, v, w, t, q, i, j, kind, z, R, lxy, lcov, thr, gate)
        flush(P, pend, has)  # (world-frame noise: additive) the target's step to t is then all it has pending
        k = 3 * j
        xj, tj, Pjj = X[k : k + 3].copy(), tc[j], P[k : k + 3, k : k + 3].copy()
        st, why = update(X, P, pend, has, tc, v, w, t, q, i, j, kind, z, R, lxy, lcov, thr, gate)
        if st != FUSED:  # not taken: the target stays where it was
            X[k : k + 3], tc[j], P[k : k + 3, k : k + 3], has[j] = xj, tj, Pjj, False
        return st, why

    @njit(error_model="numpy")
    def update(X, P, pend, has, tc, v, w, t, q, i, j, kind, z, R, lxy, lcov, thr, gate):  # noqa: ANN001, ANN202
        if j >= 0:  # a robot: predicted to the stamp (and kept there) before anything is read of it
            advance(X, pend, has, tc, v, w, j, t)
        xk = X[3 * j : 3 * j + 3].copy() if j >= 0 else (lxy[NO_LANDMARK - 1 - j].copy() if kind != ABSOLUTE
                                                         else np.zeros(0))  # fmt: skip
        if kind >= RANGE_BEARING and math.hypot(xk[0] - X[3 * i], xk[1] - X[3 * i + 1]) < MIN_RANGE:
            return REJECTED, R_DEGENERATE
        r, H, Rm = measure(kind, X, 3 * i, xk, z[q], R[q])
        own = np.arange(3 * i, 3 * i + 3)
        if j >= 0:
            cols = np.concatenate((own, np.arange(3 * j, 3 * j + 3)))
            if invariant:
                to_world(H, 3, xk[0], xk[1])
        else:
            cols = own
            if kind != ABSOLUTE:  # a map landmark: its covariance enters the noise
                Hk = H[:, 3:5].copy()
                Rm = Rm + Hk @ lcov[NO_LANDMARK - 1 - j] @ Hk.T
            H = H[:, :3].copy()
        if invariant:
            to_world(H, 0, X[3 * i], X[3 * i + 1])
        flush(P, pend, has)
        xn, Pn, nis, ok = kalman(X, P, r, H, cols, Rm, invariant)
        if gate:
            if not math.isfinite(nis):
                return REJECTED, R_NONFINITE
            if nis > thr[kind]:
                return GATED, 0
        if not (ok and usable(Pn)):
            return REJECTED, R_NUMERICAL
        X[:] = xn
        P[:, :] = Pn
        return FUSED, 0

    return advance, marginal, fuse


def _loop(advance: Any, marginal: Any, fuse: Any, distributed: bool) -> Any:
    """The compiled loop over the stamps of a timeline, around the compiled steps of :func:`_kernels`."""

    @njit(error_model="numpy")
    def replay(state, t0, stamps, d0, det, status, reason, gate, thr, relative, lm_on, lxy, lcov, cmd, rec, out):  # noqa: ANN001, ANN202
        X, P, pend, has, tc, v, w = state
        obs, tgt, kind, z, R = det
        c0, crow, cv, cw = cmd
        out_robot, out_stamp, out_x, out_P = out
        n = tc.shape[0]
        o = 0
        for s in range(stamps.shape[0]):
            t = stamps[s]
            for q in range(d0[s], d0[s + 1]):
                i = obs[q]
                advance(X, pend, has, tc, v, w, i, t)  # the observer moves to its group's stamp
                if distributed:
                    st, why = screen_started(kind[q], i, tgt[q], t, t0, relative, lm_on)
                else:
                    st, why = _screen(kind[q], i, tgt[q], relative, lm_on)
                if st == 0:
                    st, why = fuse(X, P, pend, has, tc, v, w, t, q, i, tgt[q], kind[q], z, R, lxy, lcov, thr, gate)
                status[q], reason[q] = st, why
            for c in range(c0[s], c0[s + 1]):  # then the commands: a robot moves to t (after the updates: they
                advance(X, pend, has, tc, v, w, crow[c], t)  # move every correlated heading) and starts its command
                v[crow[c]] = cv[c]
                w[crow[c]] = cw[c]
            if rec[s]:
                for k in range(n):
                    if t >= t0[k]:
                        marginal(X, P, pend, has, tc, v, w, k, t, out_x, out_P, o)
                        out_robot[o] = k
                        out_stamp[o] = s
                        o += 1
        return o

    return replay


def replay_joint(
    tl: Timeline,
    x: np.ndarray,
    P: np.ndarray,
    t0: float | np.ndarray,
    noise: UnicycleNoise,
    *,
    gate: float | None = None,
    use_relative: bool = True,
    use_landmarks: bool = True,
    landmarks: tuple[np.ndarray, np.ndarray] | None = None,
    invariant: bool = False,
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The centralized EKF over ``tl`` (robots as rows, the engine's codes) from Cartesian beliefs ``x (n, 3)``,
    ``P (n, 3, 3)`` (uncorrelated) at ``t0`` [s]: one float, every robot's clock (the centralized nodes), or each
    robot's start ``(n,)`` (``inf``: never starts), with ``invariant`` only: ``diekf``'s nodes (:func:`_kernels`,
    ``distributed``).

    ``gate``: the nodes' gate probability (None: none); ``landmarks``: the map as :func:`swarmloc.engine.core.
    landmark_table` gives it, ``(xy (L, 2), cov (L, 2, 2))``; ``invariant``: the invariant EKF (world-frame errors,
    :class:`~swarmloc.estimators.InvariantEKF`; with per-robot starts the distributed one,
    :class:`~swarmloc.estimators.DistributedInvariantEKF`, whose replicas together are its joint state).
    Returns ``(status, reason, records)``: each detection's outcome and reason code (rows of ``tl.det``) and the
    records ``(robot row, stamp index, x (K, 3), P (K, 3, 3))`` (Cartesian), every started robot at every recorded
    stamp, in stamp then row order.
    """
    n = x.shape[0]
    distributed = np.ndim(t0) == 1
    if distributed and not invariant:
        raise ValueError("replay_joint: per-robot starts are diekf's (invariant=True); cekf starts at one t0")
    p = prepare(tl, x, P, t0, gate, landmarks, invariant)
    J = np.zeros((3 * n, 3 * n))
    for k in range(n):
        J[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = p.blocks[k]
    _kernels(noise, bool(invariant), bool(distributed))(
        (p.X, J, *p.robots), p.starts, *p.head, bool(use_relative), bool(use_landmarks), *p.tail, tl.record, p.out
    )
    return p.status.astype(np.int8), p.reason.astype(np.int8), p.out


class Prepared(NamedTuple):
    """A replay's inputs as the compiled loops take them (:func:`prepare`)."""

    X: np.ndarray
    """Every robot's pose, ``(3n,)``."""
    blocks: np.ndarray
    """Every robot's covariance ``(n, 3, 3)`` (world-frame errors for the invariant filters)."""
    starts: np.ndarray
    """Each robot's start ``(n,)``."""
    robots: tuple
    """The rest of the state: pending predictions ``(n, 8)`` and their flags, clocks, commands ``v``, ``w``."""
    head: tuple
    """``(stamps, d0, detections, status, reason, gate on, thresholds)``: the loop's arguments before the switches."""
    tail: tuple
    """``(landmarks' xy, their covariances, commands)``: its arguments after them."""
    out: tuple
    """The records' arrays, sized for every started robot at every recorded stamp."""
    status: np.ndarray
    reason: np.ndarray


def prepare(tl: Timeline, x: np.ndarray, P: np.ndarray, t0: float | np.ndarray, gate: float | None,
            landmarks: tuple[np.ndarray, np.ndarray] | None, invariant: bool) -> Prepared:  # fmt: skip
    """What :func:`replay_joint`'s loop takes but the joint covariance (:class:`Prepared`): the beliefs ``x (n, 3)``,
    ``P (n, 3, 3)`` (Cartesian; made world-frame with ``invariant``), the starts ``t0``, the gate and the map."""
    n = x.shape[0]
    starts = np.broadcast_to(np.asarray(t0, dtype=float), (n,)).copy()
    x = np.ascontiguousarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    if invariant:  # world-frame error covariances: N^-1 P N^-T
        P = cartesian_to_world_cov(x, P)
    g = Gate(gate)
    thr = np.array([g.threshold(MODELS[name].size) for name in sorted(KIND_ORDER, key=KIND_ORDER.get)])
    lxy, lcov = landmarks if landmarks is not None else (np.zeros((1, 2)), np.zeros((1, 2, 2)))
    m = len(tl.det)
    status, reason = np.zeros(m, dtype=np.int64), np.zeros(m, dtype=np.int64)
    k = int(sum(np.count_nonzero(tl.stamps[tl.record] >= s) for s in starts.tolist()))
    out = (np.zeros(k, dtype=np.int64), np.zeros(k, dtype=np.int64), np.zeros((k, 3)), np.zeros((k, 3, 3)))
    d = tl.det
    det = (d.observer, d.target, d.kind, np.ascontiguousarray(d.z), np.ascontiguousarray(d.R))
    robots = (np.zeros((n, 8)), np.zeros(n, dtype=np.bool_), np.where(np.isfinite(starts), starts, 0.0), np.zeros(n),
              np.zeros(n))  # fmt: skip
    head = (tl.stamps, tl.d0, det, status, reason, g.p is not None, thr)
    tail = (np.ascontiguousarray(lxy, dtype=float), np.ascontiguousarray(lcov, dtype=float),
            (tl.c0, tl.robot, tl.v, tl.w))  # fmt: skip
    return Prepared(x.reshape(3 * n).copy(), P, starts, robots, head, tail, out, status, reason)
