"""Kernels on the group: beliefs as Gaussians in exponential coordinates (right perturbation, ``g = mu exp(y)``).

Pure, batched over leading axes, no validation (the callers validate). The derivations are in
:mod:`swarmloc.fusion` (relative-pose fusion) and the docstrings below (range/bearing updates); every kernel is
checked against Monte Carlo or importance sampling in ``tests/``.

* :func:`predict`: second-order convolution with the odometry increment (thesis 4.13-4.15, 3.22-3.28);
* :func:`relative_to_pseudo`, :func:`fuse_pseudo`: relative-pose measurements of uncertain neighbours (and absolute
  fixes) as pseudo-observations of the observer's own pose, fused all at once (thesis ch. 4, corrected);
* :func:`point_update`: range/bearing (a :class:`PointMeasurement`) of an uncertain robot or a landmark, iterated
  update on SE(2);
* :func:`pseudo_nis`, :func:`point_nis`: normalized innovations squared for gating.

Shapes: SE(2) means ``(..., 3, 3)``, covariances ``(..., 3, 3)``; SE(3) where stated ``(..., 4, 4)``/``(..., 6, 6)``.
"""

from __future__ import annotations

from typing import NamedTuple, cast

import numpy as np

from swarmloc.arrays import BoolArray, FloatArray
from swarmloc.gaussian import bvec, convolution_F, convolution_F_tensor, mahalanobis2, symmetric
from swarmloc.lie import SE2, wrap_angle
from swarmloc.lie.base import SEGroup
from swarmloc.sensors.models import MIN_RANGE, MODELS

_T = np.swapaxes

FUSE_ITERATIONS = 2
"""Default Gauss-Newton passes of a pose fusion (:func:`fuse_pseudo`): 1 is the thesis' closed form, 2
re-linearizes once. The default of every layer that passes it on (fusion functions, nodes, engine, config)."""

POINT_ITERATIONS = 3
"""Default passes of a range/bearing update on the group (:func:`point_update`), likewise every layer's."""


def gamma(group: type[SEGroup], x: FloatArray, order: int) -> FloatArray:
    """``I + ad(x)/2`` (second order) or ``I`` (first order): the BCH factor of the fusion (see fusion.py)."""
    eye = np.broadcast_to(np.eye(group.dim), (*x.shape[:-1], group.dim, group.dim))
    if order == 1:
        return eye
    return eye + 0.5 * group.ad(x, validate=False)


# ------------------------------------------------------------------------------------------------ prediction
def predict(
    group: type[SEGroup], mu: FloatArray, cov: FloatArray, inc_mean: FloatArray, inc_cov: FloatArray, order: int = 2
) -> tuple[FloatArray, FloatArray]:
    """Belief ``(mu, cov)`` convolved with an independent increment ``(inc_mean, inc_cov)``: the law of ``g h``.

    Mean ``mu inc_mean``; covariance ``A + B + F(A, B)`` with ``A = Ad(inc_mean^-1) cov Ad(inc_mean^-1)^T``,
    ``B = inc_cov`` (thesis 3.22-3.28, eq. 3.26 corrected in :mod:`swarmloc.gaussian`); ``order=1`` drops ``F``.
    One unbatched SE(2) belief takes a scalar path (same arithmetic, fewer array calls).
    """
    if group is SE2 and inc_mean.shape == (3, 3) and cov.shape == (3, 3):
        c, s, x, y = inc_mean[0, 0], inc_mean[1, 0], inc_mean[0, 2], inc_mean[1, 2]
        Ad = np.array([[c, s, s * x - c * y], [-s, c, c * x + s * y], [0.0, 0.0, 1.0]])  # Ad(inc^-1)
        A = Ad @ cov @ Ad.T
        C = A + inc_cov
        if order == 2:
            C = C + (np.multiply.outer(A.ravel(), inc_cov.ravel()).ravel() @ convolution_F_tensor(SE2)).reshape(3, 3)
        return mu @ inc_mean, symmetric(C)
    Ad = group.Ad(group.inverse(inc_mean, validate=False), validate=False)
    A = Ad @ cov @ _T(Ad, -1, -2)
    C = A + inc_cov
    if order == 2:
        C = C + convolution_F(group, A, inc_cov)
    return mu @ inc_mean, symmetric(C)


# ------------------------------------------------------------------------------------------------ relative pose
def relative_to_pseudo(
    group: type[SEGroup],
    mu_k: FloatArray,
    cov_k: FloatArray,
    m_ik: FloatArray,
    cov_ik: FloatArray,
    order: int = 2,
) -> tuple[FloatArray, FloatArray]:
    """Turn a relative measurement of a neighbour into a Gaussian on the observer's own pose (fusion.py, steps 1-2).

    ``mu_k, cov_k``: the neighbour's belief; ``m_ik, cov_ik``: the measured pose of ``k`` in ``i``'s frame and the
    covariance of its noise ``g_i^-1 g_k = m_ik exp(n)``. Returns ``(nu, W)``: ``g_i ~ nu exp(N(0, W))``.
    """
    cov_c = cov_k + cov_ik
    if order == 2:
        cov_c = cov_c + convolution_F(group, cov_k, cov_ik)
    Ad = group.Ad(m_ik, validate=False)
    W = Ad @ cov_c @ _T(Ad, -1, -2)
    nu = mu_k @ group.inverse(m_ik, validate=False)
    return nu, symmetric(W)


def fuse_pseudo(
    group: type[SEGroup],
    mu: FloatArray,
    cov: FloatArray,
    nus: FloatArray,
    Ws: FloatArray,
    order: int = 2,
    iterations: int = FUSE_ITERATIONS,
) -> tuple[FloatArray, FloatArray]:
    """Fuse a prior ``(mu, cov)`` with ``K`` Gaussian observations ``(nus[..., k, :, :], Ws[..., k, :, :])`` of the
    same pose, all at once (fusion.py, step 3). ``iterations > 1`` re-linearizes about the current estimate
    (Gauss-Newton on the same cost). Shapes: ``mu (..., n+1, n+1)``, ``cov (..., d, d)``, ``nus (..., K, n+1, n+1)``,
    ``Ws (..., K, d, d)``.
    """
    W_inv = np.linalg.inv(Ws)
    cov_inv = np.linalg.inv(cov)
    cur = mu
    for it in range(max(1, iterations)):
        # residuals of all observations (k) and, after the first pass, of the prior, at the current estimate
        x = group.log(group.inverse(nus, validate=False) @ cur[..., None, :, :], validate=False)  # (..., K, d)
        Gm = gamma(group, x, order)
        GtW = _T(Gm, -1, -2) @ W_inv
        S = np.sum(GtW @ Gm, axis=-3)
        b = np.sum(bvec(GtW, x), axis=-2)
        if it == 0:
            S = S + cov_inv
        else:
            x0 = group.log(group.inverse(mu, validate=False) @ cur, validate=False)
            G0 = gamma(group, x0, order)
            G0tP = _T(G0, -1, -2) @ cov_inv
            S = S + G0tP @ G0
            b = b + bvec(G0tP, x0)
        xbar = np.linalg.solve(S, b[..., None])[..., 0]
        cur = cur @ group.exp(-xbar, validate=False)
    Gb = gamma(group, xbar, order)
    return cur, symmetric(Gb @ np.linalg.inv(S) @ _T(Gb, -1, -2))


def absolute_to_pseudo(xytheta: FloatArray, cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """A world-frame pose fix ``(x, y, theta)`` with additive Cartesian covariance -> ``(nu, W)`` on SE(2).

    First order: ``W = T cov T^T`` with ``T = diag(R(theta)^T, 1)`` (the fix's frame).
    """
    xytheta = np.asarray(xytheta, dtype=float)
    T = np.broadcast_to(np.eye(3), (*xytheta.shape[:-1], 3, 3)).copy()
    T[..., :2, :2] = _T(SE2.rotation(xytheta[..., 2]), -1, -2)
    return SE2.from_xytheta(xytheta), symmetric(T @ cov @ _T(T, -1, -2))


def pseudo_nis(group: type[SEGroup], mu: FloatArray, cov: FloatArray, nu: FloatArray, W: FloatArray) -> FloatArray:
    """Normalized innovation squared of a pose pseudo-observation (first order), for gating. Batched."""
    x = group.log(group.inverse(nu, validate=False) @ mu, validate=False)
    return mahalanobis2(x, cov + W)


# ------------------------------------------------------------------------------------------------ range / bearing
_J2 = np.array([[0.0, -1.0], [1.0, 0.0]])
POINT_KINDS = {k: m.components for k, m in MODELS.items() if m.targets == "point"}
"""Partial measurements of a point: which of (range, bearing) each kind observes (its model's ``components``)."""


def point_model(
    kind: str, mu_i: FloatArray, target_mean: FloatArray, target_cov: FloatArray, robot: bool
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Range/bearing of a target seen from pose ``mu_i``, linearized on SE(2). Batched.

    The target is a robot (``robot=True``: pose ``(..., 3, 3)`` with exponential-coordinate covariance
    ``(..., 3, 3)``) or a world point (``(..., 2)`` with Cartesian covariance ``(..., 2, 2)``). The observer is
    perturbed on the right, ``g_i = mu_i exp(y)``; the target's position in the observer's frame is
    ``q = exp(-y) mu_i^-1 p``, so ``dq/dy = -[I, J q]`` with ``J = [[0, -1], [1, 0]]``; a robot target
    ``g_k = mu_k exp(y_k)`` moves ``q`` by ``R(mu_i^-1 mu_k) v_k``.

    Returns ``(h, H, C, rng)``: prediction ``(..., m)``, Jacobian w.r.t. ``y`` ``(..., m, 3)``, the covariance the
    target's uncertainty adds ``(..., m, m)`` and the predicted range ``(...)`` (the model is undefined at 0).
    """
    if mu_i.ndim == 2 and target_mean.ndim == (2 if robot else 1):
        return _point_model_one(kind, mu_i, target_mean, target_cov, robot)
    R_iT = _T(mu_i[..., :2, :2], -1, -2)
    if robot:
        rel = SE2.inverse(mu_i, validate=False) @ target_mean
        q = rel[..., :2, 2]
        dq_dt = np.concatenate([rel[..., :2, :2], np.zeros((*rel.shape[:-2], 2, 1))], axis=-1)
    else:
        q = bvec(R_iT, target_mean - mu_i[..., :2, 2])
        dq_dt = R_iT
    qx, qy = q[..., 0], q[..., 1]
    r2 = qx * qx + qy * qy
    r = np.sqrt(r2)
    sel = POINT_KINDS[kind]
    h = np.stack([(r, np.arctan2(qy, qx))[j] for j in sel], axis=-1)
    rows = {0: (qx / r, qy / r), 1: (-qy / r2, qx / r2)}
    dz = np.stack([np.stack(rows[j], axis=-1) for j in sel], axis=-2)  # (..., m, 2)
    Jq = bvec(_J2, q)
    dq_dy = -np.concatenate([np.broadcast_to(np.eye(2), (*q.shape[:-1], 2, 2)), Jq[..., :, None]], axis=-1)
    H = dz @ dq_dy
    Ht = dz @ dq_dt
    return h, H, Ht @ target_cov @ _T(Ht, -1, -2), r


def _point_model_one(
    kind: str, mu_i: FloatArray, target_mean: FloatArray, target_cov: FloatArray, robot: bool
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """:func:`point_model` for one observer and one target (the same formulas with fewer array calls)."""
    c, s_, tx, ty = mu_i[0, 0], mu_i[1, 0], mu_i[0, 2], mu_i[1, 2]
    if robot:
        px, py = target_mean[0, 2] - tx, target_mean[1, 2] - ty
        qx, qy = c * px + s_ * py, -s_ * px + c * py
        rc, rs = c * target_mean[0, 0] + s_ * target_mean[1, 0], c * target_mean[1, 0] - s_ * target_mean[0, 0]
        dq_dt = np.array([[rc, -rs, 0.0], [rs, rc, 0.0]])  # rotation of mu_i^-1 mu_k, w.r.t. y_k
    else:
        px, py = target_mean[0] - tx, target_mean[1] - ty
        qx, qy = c * px + s_ * py, -s_ * px + c * py
        dq_dt = np.array([[c, s_], [-s_, c]])
    r2 = qx * qx + qy * qy
    r = np.sqrt(r2)
    sel = POINT_KINDS[kind]
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.array([(r, np.arctan2(qy, qx))[j] for j in sel])
        dz = np.array([((qx / r, qy / r), (-qy / r2, qx / r2))[j] for j in sel])
    dq_dy = np.array([[-1.0, 0.0, qy], [0.0, -1.0, -qx]])  # -[I, J q]
    Ht = dz @ dq_dt
    return h, dz @ dq_dy, Ht @ target_cov @ Ht.T, r


def point_residual(kind: str, z: FloatArray, h: FloatArray) -> FloatArray:
    """``z - h`` with the bearing component wrapped to (-pi, pi]."""
    r = np.asarray(z, dtype=float) - h
    for j, comp in enumerate(POINT_KINDS[kind]):
        if comp == 1:
            r[..., j] = wrap_angle(r[..., j])
    return r


class PointMeasurement(NamedTuple):
    """A range/bearing measurement of an uncertain target, as :func:`point_update` and :func:`point_nis` take it.

    ``kind``: a key of :data:`POINT_KINDS`; ``z`` ``(..., m)``: range [m] / bearing [rad]; ``R`` ``(..., m, m)``: its
    noise covariance; the target a robot's pose ``target_mean (..., 3, 3)`` with exponential-coordinate covariance
    ``target_cov (..., 3, 3)`` (``robot``) or a world point ``(..., 2)`` with Cartesian covariance ``(..., 2, 2)``.
    """

    kind: str
    z: FloatArray
    R: FloatArray
    target_mean: FloatArray
    target_cov: FloatArray
    robot: bool


def point_update(
    mu: FloatArray, cov: FloatArray, meas: PointMeasurement, iterations: int = POINT_ITERATIONS, order: int = 2
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Update an SE(2) belief with a range/bearing measurement of an uncertain robot or landmark. Batched.

    Iterated (Gauss-Newton) update on the group: at the current estimate ``mu_c``, minimize
    ``|x0 + Gamma(x0) d|^2_{Sigma^-1} + |r - H d|^2_{S^-1}`` with ``x0 = log(mu^-1 mu_c)`` and ``S = C + R`` (target
    uncertainty ``C`` from :func:`point_model` plus noise), step ``mu_c <- mu_c exp(d)``. One iteration is the
    EKF update on the group; the posterior covariance is re-centred with ``Gamma(-d)`` (second order), since
    ``mu_c exp(d + y) = mu_c exp(d) exp(Jr(d) y)`` and ``Jr(d) ~ I - ad(d)/2``. ``order=1`` uses ``Gamma = I``.

    Returns ``(mean, cov, ok)``; ``ok`` is False where the geometry is degenerate (predicted range below
    :data:`~swarmloc.sensors.models.MIN_RANGE` at any iteration) or the result is not finite: the caller keeps
    the prior there.
    """
    kind, z, R, target_mean, target_cov, robot = meas
    z = np.asarray(z, dtype=float)
    cov_inv = np.linalg.inv(cov)
    cur = mu
    ok = np.ones(np.broadcast_shapes(mu.shape[:-2], z.shape[:-1]), dtype=bool)
    one = mu.ndim == 2 and z.ndim == 1
    for it in range(max(1, iterations)):
        if one:  # the unbatched model guards its own divisions
            h, H, C, rng = _point_model_one(kind, cur, target_mean, target_cov, robot)
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                h, H, C, rng = point_model(kind, cur, target_mean, target_cov, robot)
        ok = ok & (rng >= MIN_RANGE)
        if not ok.any():
            return mu, cov, ok
        if not ok.all():  # keep the degenerate elements finite; they are discarded at the end
            H = np.where(ok[..., None, None], H, 0.0)
            h = np.where(ok[..., None], h, z)
            C = np.where(ok[..., None, None], C, 0.0)
        S_inv = np.linalg.inv(C + R)
        r = point_residual(kind, z, h)
        HtS = _T(H, -1, -2) @ S_inv
        if it == 0:
            info = cov_inv + HtS @ H
            rhs = bvec(HtS, r)
        else:
            x0 = SE2.log(SE2.inverse(mu, validate=False) @ cur, validate=False)
            G0 = gamma(SE2, x0, order)
            G0tP = _T(G0, -1, -2) @ cov_inv
            info = G0tP @ G0 + HtS @ H
            rhs = bvec(HtS, r) - bvec(G0tP, x0)
        d = cast(FloatArray, np.linalg.solve(info, rhs[..., None])[..., 0])  # numpy types it floating[Any]
        cur = cur @ SE2.exp(d, validate=False)
    Gd = gamma(SE2, -d, order)
    post = symmetric(Gd @ np.linalg.inv(info) @ _T(Gd, -1, -2))
    ok = ok & np.isfinite(cur).all(axis=(-1, -2)) & np.isfinite(post).all(axis=(-1, -2))
    return cur, post, ok


def point_nis(mu: FloatArray, cov: FloatArray, meas: PointMeasurement) -> FloatArray:
    """Normalized innovation squared ``r^T (H Sigma H^T + C + R)^-1 r`` of a range/bearing measurement (gating).

    NaN where the geometry is degenerate (predicted range below ``MIN_RANGE``).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        h, H, C, rng = point_model(meas.kind, mu, meas.target_mean, meas.target_cov, meas.robot)
        r = point_residual(meas.kind, meas.z, h)
        S = H @ cov @ _T(H, -1, -2) + C + meas.R
        ok = (rng >= MIN_RANGE) & np.isfinite(S).all(axis=(-1, -2))
        S = np.where(ok[..., None, None], S, np.eye(S.shape[-1]))
        r = np.where(ok[..., None], r, 0.0)
        nis = mahalanobis2(r, S)
    return np.where(ok, nis, np.nan)
