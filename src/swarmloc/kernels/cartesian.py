"""Kernels of the EKF family in Cartesian coordinates ``x = (x [m], y [m], theta [rad])`` (world frame).

Prediction: the mean moves along the exact arc of the odometry ``(v, w)`` held over ``dt`` (the same mean as the
exponential-coordinate prediction, so comparisons isolate the filters, not the integrators; the thesis' eq. 5.13
is its Euler approximation), the covariance by the linearization

    P <- Phi P Phi^T + B Sigma_inc B^T,   Phi = [[1, 0, -dy], [0, 1, dx], [0, 0, 1]],   B = diag(R(theta+), 1),

where ``(dx, dy)`` is the world-frame displacement and ``Sigma_inc`` the increment covariance of eq. (5.4) in the
robot's frame at the end of the interval (thesis eqs. 2.4-2.5, 5.15-5.16).

Update: :func:`kalman_update` is the one Kalman update of swarmloc (Joseph form), used by the distributed EKF,
the centralized EKF and recursive decentralized fusion, on a robot's own 3-vector, a pair's 6-vector or a team's
3n-vector alike.

All functions are batched over leading axes; unbatched inputs take the same code.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from swarmloc.arrays import FloatArray, IntArray
from swarmloc.gaussian import symmetric
from swarmloc.lie import SE2, wrap_angle
from swarmloc.motion import UnicycleNoise, odometry_increment, odometry_increment_terms

_TAU = 2 * math.pi

_T = np.swapaxes


def increment(
    x: FloatArray, v: FloatArray | float, w: FloatArray | float, dt: FloatArray | float, noise: UnicycleNoise
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """New mean ``(..., 3)``, ``Phi`` ``(..., 3, 3)`` and additive process covariance ``(..., 3, 3)`` of one step."""
    x = np.asarray(x, dtype=float)
    if x.ndim == 1 and isinstance(v, int | float) and isinstance(w, int | float) and isinstance(dt, int | float):
        # one robot in floats (the same formulas; ~3x faster than the array path)
        x0, y0, th, dx, dy, *q = increment_terms(x, float(v), float(w), float(dt), noise)
        return np.array([x0, y0, th]), np.array([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]]), sym3(q)
    inc_mean, inc_cov = odometry_increment(v, w, dt, noise)
    c, s = np.cos(x[..., 2]), np.sin(x[..., 2])
    ix, iy = inc_mean[..., 0, 2], inc_mean[..., 1, 2]
    dx, dy = c * ix - s * iy, s * ix + c * iy
    th = wrap_angle(x[..., 2] + np.arctan2(inc_mean[..., 1, 0], inc_mean[..., 0, 0]))
    new = np.stack([x[..., 0] + dx, x[..., 1] + dy, th], axis=-1)
    shape = new.shape[:-1]
    Phi = np.broadcast_to(np.eye(3), (*shape, 3, 3)).copy()
    Phi[..., 0, 2], Phi[..., 1, 2] = -dy, dx
    B = np.broadcast_to(np.eye(3), (*shape, 3, 3)).copy()
    B[..., :2, :2] = SE2.rotation(th)
    return new, Phi, B @ inc_cov @ _T(B, -1, -2)


def increment_terms(
    x: FloatArray, v: float, w: float, dt: float, noise: UnicycleNoise
) -> tuple[float, float, float, float, float, float, float, float, float, float, float]:
    """One robot's step in floats: new ``(x, y, theta)``, ``(dx, dy)`` and the process covariance's upper triangle
    ``(q00, q01, q02, q11, q12, q22)`` (module docstring)."""
    x0, y0, th0 = x.tolist()
    return increment_terms_xy(x0, y0, th0, v, w, dt, noise)


def increment_terms_xy(
    x0: float, y0: float, th0: float, v: float, w: float, dt: float, noise: UnicycleNoise
) -> tuple[float, float, float, float, float, float, float, float, float, float, float]:
    """:func:`increment_terms` of the pose ``(x0 [m], y0 [m], th0 [rad])`` given as floats."""
    # memoized (increment_cached): the same numbers as odometry_increment_terms, its (cos, sin) kept as the angle
    hit = increment_cached(increment_cache(noise), v, w, dt, noise)
    alpha, tx, ty = hit[0], hit[1], hit[2]
    ct, st = math.cos(th0), math.sin(th0)
    dx, dy = ct * tx - st * ty, st * tx + ct * ty
    th = wrap_angle(th0 + alpha)
    return (x0 + dx, y0 + dy, th, dx, dy, *world_cov(math.cos(th), math.sin(th), hit[3:]))


def sym3(p: Sequence[float]) -> FloatArray:
    """The symmetric ``(3, 3)`` matrix of the upper triangle ``p = (p00, p01, p02, p11, p12, p22)``."""
    p00, p01, p02, p11, p12, p22 = p
    return np.array([[p00, p01, p02], [p01, p11, p12], [p02, p12, p22]])


def predict_one(
    x: FloatArray, P: FloatArray, v: float, w: float, dt: float, noise: UnicycleNoise
) -> tuple[FloatArray, FloatArray, float, float]:
    """:func:`predict` for one robot in floats: ``(x, P, dx, dy)``, where ``Phi = [[1, 0, -dy], [0, 1, dx],
    [0, 0, 1]]`` (``Phi P Phi^T`` expanded: ``Phi`` differs from the identity in two entries)."""
    x0, y0, th, dx, dy, *q = increment_terms(x, v, w, dt, noise)
    p00, p01, p02, _, p11, p12, _, _, p22 = P.ravel().tolist()
    return np.array([x0, y0, th]), sym3(shifted_cov((p00, p01, p02, p11, p12, p22), dx, dy, q)), dx, dy


def shifted_cov(p: Sequence[Any], dx: Any, dy: Any, q: Sequence[Any]) -> tuple[Any, ...]:
    """Upper triangle ``(00, 01, 02, 11, 12, 22)`` of ``Phi P Phi^T + Q`` with ``Phi = [[1, 0, -dy], [0, 1, dx],
    [0, 0, 1]]`` (the prediction's Jacobian after a move by ``(dx, dy)`` [m]), from the upper triangles ``p`` of ``P``
    and ``q`` of ``Q``: expanded, in plain arithmetic (floats, arrays, or the engine's traced entries)."""
    p00, p01, p02, p11, p12, p22 = p
    q00, q01, q02, q11, q12, q22 = q
    a02 = p02 - dy * p22
    a12 = p12 + dx * p22
    n00 = p00 - 2 * dy * p02 + dy * dy * p22 + q00
    n01 = p01 - dy * p12 + dx * a02 + q01
    n11 = p11 + 2 * dx * p12 + dx * dx * p22 + q11
    return n00, n01, a02 + q02, n11, a12 + q12, p22 + q22


def world_cov(c: Any, s: Any, S: Sequence[Any]) -> tuple[Any, ...]:
    """Upper triangle ``(00, 01, 02, 11, 12, 22)`` of ``B S B^T``, ``B = diag(R(theta), 1)`` (``c, s`` the cosine and
    sine of the heading ``theta`` after the step): an increment's covariance, upper triangle ``S = (S11, S12, S13,
    S22, S23, S33)`` in the robot's frame, in the world frame; plain arithmetic as :func:`shifted_cov`."""
    S11, S12, S13, S22, S23, S33 = S
    cc, ss, cs = c * c, s * s, c * s
    return (
        cc * S11 - 2 * cs * S12 + ss * S22, cs * (S11 - S22) + (cc - ss) * S12, c * S13 - s * S23,
        ss * S11 + 2 * cs * S12 + cc * S22, s * S13 + c * S23, S33,
    )  # fmt: skip


INCREMENT_CACHE_SIZE = 1 << 16
"""Increments kept per noise model by :func:`increment_cached` (the cache is emptied when it is full)."""

Increments = dict[tuple[float, float, float], tuple[float, ...]]
"""An increment cache: ``(v, w, dt) -> (alpha, tx, ty, S11, S12, S13, S22, S23, S33)`` (:func:`increment_cache`)."""

_CACHES: dict[int, tuple[UnicycleNoise, Increments]] = {}


def increment_cache(noise: UnicycleNoise) -> Increments:
    """The increment cache of ``noise``: ``(v, w, dt) -> (alpha, tx, ty, S11, S12, S13, S22, S23, S33)``."""
    hit = _CACHES.get(id(noise))
    if hit is None or hit[0] is not noise:
        if len(_CACHES) > 64:
            _CACHES.clear()
        hit = _CACHES[id(noise)] = (noise, {})
    return hit[1]


def increment_cached(cache: Increments, v: float, w: float, dt: float, noise: UnicycleNoise) -> tuple[float, ...]:
    """``(alpha, tx, ty, S11, S12, S13, S22, S23, S33)`` of one odometry increment: its rotation angle [rad],
    translation [m] and covariance (:func:`swarmloc.motion.odometry_increment_terms`), memoized in ``cache``
    (:func:`increment_cache`): logged odometry repeats the same command over the same period again and again."""
    key = (v, w, dt)
    hit = cache.get(key)
    if hit is None:
        c, s, *rest = odometry_increment_terms(v, w, dt, noise)
        if len(cache) >= INCREMENT_CACHE_SIZE:
            cache.clear()
        hit = cache[key] = (math.atan2(s, c), *rest)
    return hit


def predict_run(
    x: tuple[float, float, float],
    p: tuple[float, float, float, float, float, float],
    t: float,
    cmd: tuple[float, float],
    shear: tuple[float, float],
    cmds: list[tuple[float, float, float]],
    noise: UnicycleNoise,
) -> tuple[tuple[float, float, float], tuple[float, ...], float, tuple[float, float], tuple[float, float]]:
    """One robot's predictions over a run of odometry commands, in floats (preintegration of the odometry).

    ``x = (x, y, theta)`` at time ``t`` [s] with command ``cmd = (v, w)`` in force, ``p`` the upper triangle
    ``(p00, p01, p02, p11, p12, p22)`` of a covariance, ``shear = (a, b)`` the entries ``(0, 2), (1, 2)`` of a
    product of ``Phi``'s; ``cmds = [(t_k, v_k, w_k), ...]``: at each ``t_k`` the robot is predicted to ``t_k``
    (:func:`predict_one`, nothing for ``t_k <= t``) and the command becomes ``(v_k, w_k)``. Returns the new
    ``(x, p, t, cmd, shear)``: the same arithmetic as :func:`predict_one` step by step (``p <- Phi p Phi^T + Q``,
    ``a <- a - dy``, ``b <- b + dx``), so the same bits, with the increments memoized (:func:`increment_cached`) and
    no array per step.
    """
    x0, y0, th = x
    p00, p01, p02, p11, p12, p22 = p
    a, b = shear
    v, w = cmd
    cache = increment_cache(noise)
    ct: float | None = None  # cos and sin of the heading, once the first step needs them
    st = 0.0
    for tk, vk, wk in cmds:
        dt = tk - t
        if dt > 0:
            hit = cache.get((v, w, dt))
            if hit is None:
                hit = increment_cached(cache, v, w, dt, noise)
            alpha, tx, ty, S11, S12, S13, S22, S23, S33 = hit
            if ct is None:
                ct, st = math.cos(th), math.sin(th)
            dx, dy = ct * tx - st * ty, st * tx + ct * ty
            th = wrap_angle(th + alpha)
            ct, st = math.cos(th), math.sin(th)
            cc, ss, cs = ct * ct, st * st, ct * st  # world_cov and shifted_cov inlined (a call costs ~15% here)
            x0, y0 = x0 + dx, y0 + dy
            a02 = p02 - dy * p22
            a12 = p12 + dx * p22
            p00 = p00 - 2 * dy * p02 + dy * dy * p22 + (cc * S11 - 2 * cs * S12 + ss * S22)
            p01 = p01 - dy * p12 + dx * a02 + (cs * (S11 - S22) + (cc - ss) * S12)
            p11 = p11 + 2 * dx * p12 + dx * dx * p22 + (ss * S11 + 2 * cs * S12 + cc * S22)
            p02, p12, p22 = a02 + (ct * S13 - st * S23), a12 + (st * S13 + ct * S23), p22 + S33
            a, b = a - dy, b + dx
            t = tk
        v, w = vk, wk
    return (x0, y0, th), (p00, p01, p02, p11, p12, p22), t, (v, w), (a, b)


def predict(
    x: FloatArray, P: FloatArray, v: FloatArray | float, w: FloatArray | float, dt: FloatArray | float,
    noise: UnicycleNoise,
) -> tuple[FloatArray, FloatArray, FloatArray]:  # fmt: skip
    """EKF prediction of ``(x, P)`` over ``dt`` [s] with odometry ``(v [m/s], w [rad/s])``; returns ``(x, P, Phi)``."""
    xn, Phi, Qd = increment(x, v, w, dt, noise)
    if Phi.ndim == 2:
        return xn, Phi @ P @ Phi.T + Qd, Phi
    return xn, Phi @ P @ _T(Phi, -1, -2) + Qd, Phi


def kalman_update(
    x: FloatArray,
    P: FloatArray,
    r: FloatArray,
    H: FloatArray,
    R: FloatArray,
    angles: tuple[int, ...] = (2,),
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """One Kalman update in Joseph form, batched: ``x (..., n)``, ``P (..., n, n)``, innovation ``r (..., m)``,
    Jacobian ``H (..., m, n)``, noise ``R (..., m, m)`` (everything the innovation does not depend on through
    ``x``: sensor noise plus, for a distributed filter, the neighbour's or landmark's propagated covariance).

    ``K = P H^T S^-1``, ``x+ = x + K r`` (components ``angles`` wrapped to (-pi, pi]),
    ``P+ = (I - K H) P (I - K H)^T + K R K^T``. Returns ``(x+, P+, nis, ok)``: ``nis = r^T S^-1 r`` is the
    normalized innovation squared (for gating) and ``ok`` is False where the update is not finite (a singular
    innovation covariance, an infinite innovation): the caller keeps the prior there.
    """
    if x.ndim == 1 and P.ndim == 2 and r.ndim == 1 and H.ndim == 2 and R.ndim == 2 and all(map(math.isfinite, r)):
        xn, Pn, nis, ok = kalman_one(x, P, r, H, R, angles)  # one state: nis and ok as arrays
        return xn, Pn, np.array(nis), np.array(ok)
    Ht = _T(H, -1, -2)
    PHt = P @ Ht
    S = H @ PHt + R
    try:
        S_inv = np.linalg.inv(S)
    except np.linalg.LinAlgError:
        nan = np.full(np.broadcast_shapes(r.shape[:-1], P.shape[:-2]), np.nan)
        return x, P, nan, np.zeros(nan.shape, dtype=bool)
    nis = np.einsum("...i,...ij,...j->...", r, S_inv, r)
    K = PHt @ S_inv
    xn = x + np.einsum("...ij,...j->...i", K, r)
    with np.errstate(invalid="ignore"):  # a non-finite innovation gives ok = False below
        for j in angles:
            xn[..., j] = wrap_angle(xn[..., j])
    IKH = np.eye(x.shape[-1]) - K @ H
    Pn = IKH @ P @ _T(IKH, -1, -2) + K @ R @ _T(K, -1, -2)
    Pn = symmetric(Pn)
    ok = np.isfinite(nis) & np.isfinite(xn).all(axis=-1) & np.isfinite(Pn).all(axis=(-1, -2))
    return xn, Pn, nis, ok


def matmul(A: FloatArray, B: FloatArray) -> FloatArray:
    """``A @ B``; numba-compiled code runs it as loops (:mod:`swarmloc.engine.joint_math` registers that form: on
    matrices of a few rows a BLAS call costs more than its work)."""
    out: FloatArray = A @ B
    return out


def logdets(a: FloatArray, A: FloatArray, b: FloatArray, B: FloatArray, R: FloatArray) -> FloatArray:
    """``log |det(a_k A + b_k B + R)|`` for each ``k`` of the coefficients ``a, b (k,)``, matrices ``A, B, R (m, m)``:
    ``(k,)``. Numba-compiled code runs it one matrix at a time (:mod:`swarmloc.engine.joint_math` registers that
    form: the batched expression made the replays that inline it compile for seconds longer)."""
    M = a[:, None, None] * A + b[:, None, None] * B + R
    out: FloatArray = np.linalg.slogdet(M)[1]
    return out


def kalman_one(
    x: FloatArray, P: FloatArray, r: FloatArray, H: FloatArray, R: FloatArray, angles: tuple[int, ...]
) -> tuple[FloatArray, FloatArray, float, bool]:
    """:func:`kalman_update` for one state ``x (n,)`` (the same Joseph form with fewer array calls; equal to
    rounding): ``(x+, P+, nis, ok)``, ``(x, P, nan, False)`` for a singular innovation covariance. Numpy code that
    numba compiles: the engine's ``rdl`` replay runs it compiled (:mod:`swarmloc.engine.pairs`), its products
    (:func:`matmul`) as loops."""
    PHt = matmul(P, H.T)
    S = matmul(H, PHt) + R
    if S.shape[0] == 2:  # closed form (LAPACK's call costs more than the arithmetic)
        a, b, c, d = S[0, 0], S[0, 1], S[1, 0], S[1, 1]
        det = a * d - b * c
        if det == 0:
            return x, P, math.nan, False
        S_inv = np.array([[d / det, -b / det], [-c / det, a / det]])
    else:
        try:
            S_inv = np.ascontiguousarray(np.linalg.inv(S))
        except Exception:  # numba matches no narrower class; numpy raises LinAlgError
            return x, P, math.nan, False
    Sr = matmul(S_inv, r)
    nis = float(matmul(r, Sr))
    K = matmul(PHt, S_inv)
    xn = x + matmul(PHt, Sr)
    for j in angles:
        if math.isfinite(xn[j]):
            xn[j] = math.pi - (math.pi - xn[j]) % _TAU  # wrap_angle's float form
    IKH = np.eye(x.shape[0]) - matmul(K, H)
    Pn = matmul(matmul(IKH, P), IKH.T) + matmul(matmul(K, R), K.T)
    Pn = 0.5 * (Pn + Pn.T)  # symmetric
    ok = math.isfinite(nis) and bool(np.isfinite(xn).all()) and bool(np.isfinite(Pn).all())
    return xn, Pn, nis, ok


def kalman_update_blocks(
    x: FloatArray,
    P: FloatArray,
    r: FloatArray,
    H: FloatArray,
    cols: IntArray,
    R: FloatArray,
    angles: Sequence[int] = (2,),
) -> tuple[FloatArray, FloatArray, float, bool]:
    """:func:`kalman_update` (one, unbatched) for a Jacobian that is zero outside the columns ``cols``: ``H (m, k)``
    holds those columns only (e.g. the observer's and the target's 3 columns of a team's ``3n``).

    The Joseph form is expanded around ``U = P H^T`` (``n x m``) and ``S = H U + R``: for ``K = U S^-1``,
    ``(I - K H) P (I - K H)^T + K R K^T = P - K U^T - (U - K S) K^T``, the same matrix for any ``K`` (so the
    Joseph form's robustness to an inexact ``K`` is kept: ``U - K S`` is what rounding left of ``U``), in
    ``O(n^2 m)`` instead of ``O(n^3)``; symmetrized as :func:`kalman_update` does. Returns ``(x+, P+, nis, ok)``,
    ``(x, P, nan, False)`` for a singular innovation covariance. Numpy code that numba compiles: the engine's joint
    replays run it compiled (:func:`swarmloc.engine.joint_math.kalman`), its products (:func:`matmul`) as loops.
    """
    U = matmul(P[:, cols], H.T)
    S = matmul(H, U[cols]) + R
    try:
        S_inv = np.ascontiguousarray(np.linalg.inv(S))
    except Exception:  # numba matches no narrower class; numpy raises LinAlgError
        return x, P, math.nan, False
    nis = float(matmul(matmul(r, S_inv), r))
    K = matmul(U, S_inv)
    xn = x + matmul(K, r)
    for j in angles:
        if math.isfinite(xn[j]):
            xn[j] = math.pi - (math.pi - xn[j]) % _TAU  # wrap_angle's float form
    Pn = joseph_blocks(P, K, U, S)
    ok = math.isfinite(nis) and bool(np.isfinite(xn).all()) and bool(np.isfinite(Pn).all())
    return xn, Pn, nis, ok


def joseph_blocks(P: FloatArray, K: FloatArray, U: FloatArray, S: FloatArray) -> FloatArray:
    """:func:`kalman_update_blocks`' covariance ``P - K U^T - (U - K S) K^T`` symmetrized (``K, U (n, m)``,
    ``S (m, m)``); numba-compiled code runs it as one loop over the upper triangle (:mod:`swarmloc.engine.joint_math`
    registers that form: no ``n x n`` temporaries but the result)."""
    Pn = P - K @ U.T - (U - K @ S) @ K.T
    out: FloatArray = 0.5 * (Pn + Pn.T)  # symmetric
    return out


def rot_block(theta: FloatArray | float) -> FloatArray:
    """``diag(R(theta), 1)`` ``(..., 3, 3)``: maps body-frame ``(v1, v2, alpha)`` to world-frame increments."""
    theta = np.asarray(theta, dtype=float)
    if theta.ndim == 0:
        c1, s1 = math.cos(theta), math.sin(theta)
        return np.array([[c1, -s1, 0.0], [s1, c1, 0.0], [0.0, 0.0, 1.0]])
    B = np.broadcast_to(np.eye(3), (*theta.shape, 3, 3)).copy()
    B[..., :2, :2] = SE2.rotation(theta)
    return B


def to_group(x: FloatArray, P: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Cartesian ``(x, y, theta), P`` (world frame) -> exponential-coordinate mean ``(..., 3, 3)`` and covariance.

    First order: ``g = (x, y, theta)`` and ``y = (R^T dp, dtheta)``, so ``Sigma = T P T^T``, ``T = diag(R^T, 1)``.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        c1, s1 = math.cos(x[2]), math.sin(x[2])
        T = np.array([[c1, s1, 0.0], [-s1, c1, 0.0], [0.0, 0.0, 1.0]])
        g = np.array([[c1, -s1, x[0]], [s1, c1, x[1]], [0.0, 0.0, 1.0]])
        return g, T @ P @ T.T
    T = _T(rot_block(x[..., 2]), -1, -2)
    c, s = np.cos(x[..., 2]), np.sin(x[..., 2])
    g = np.zeros((*x.shape[:-1], 3, 3))
    g[..., 0, 0], g[..., 0, 1], g[..., 0, 2] = c, -s, x[..., 0]
    g[..., 1, 0], g[..., 1, 1], g[..., 1, 2] = s, c, x[..., 1]
    g[..., 2, 2] = 1.0
    return g, T @ P @ _T(T, -1, -2)


def from_group(mean: FloatArray, cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Exponential-coordinate Gaussian -> Cartesian ``(x, y, theta), P`` (first order; inverse of :func:`to_group`)."""
    mean = np.asarray(mean, dtype=float)
    if mean.ndim == 2:
        th1 = math.atan2(mean[1, 0], mean[0, 0])
        th1 = th1 + 2 * math.pi if th1 <= -math.pi else th1
        B = rot_block(th1)
        return np.array([mean[0, 2], mean[1, 2], th1]), B @ cov @ B.T
    th = np.arctan2(mean[..., 1, 0], mean[..., 0, 0])
    th = np.where(th <= -np.pi, th + 2 * np.pi, th)
    x = np.stack([mean[..., 0, 2], mean[..., 1, 2], th], axis=-1)
    B = rot_block(th)
    return x, B @ cov @ _T(B, -1, -2)
