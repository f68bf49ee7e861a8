"""Bayesian fusion on SE(n) in exponential coordinates (thesis ch. 4, corrected and generalized).

Measurement model (DESIGN.md): robot ``i`` measures neighbour ``k`` as ``g_i^-1 g_k = m_ik exp(n)``,
``n ~ N(0, Sigma_ik)``; the neighbour's own belief is ``g_k = mu_k exp(y_k)``, ``y_k ~ N(0, Sigma_k)``.

Derivation used here (each step is checked against importance sampling in the tests):

1. ``g_i m_ik = g_k exp(-n)``: the convolution of the neighbour's belief with the noise, to second order
   Gaussian with mean ``mu_k`` and covariance ``Sigma_c = Sigma_k + Sigma_ik + F(Sigma_k, Sigma_ik)``
   (the neighbour's covariance enters untransformed; the thesis' printed eq. 4.16 transforms it twice).
2. Hence ``g_i = mu_k exp(z) m_ik^-1 = (mu_k m_ik^-1) exp(Ad(m_ik) z)``: a Gaussian "pseudo-measurement" of
   ``g_i`` itself with mean ``nu_k = mu_k m_ik^-1`` and covariance ``W_k = Ad(m_ik) Sigma_c Ad(m_ik)^T``
   (these are the thesis' ``Ad(m_ik)`` factors of step 5 in eq. 4.19).
3. The posterior of ``g_i`` is proportional to the prior times all pseudo-measurement densities. Writing
   ``g_i = mu_i exp(y)`` and ``x_k = log(nu_k^-1 mu_i)`` (the thesis' ``q_k = m_ik mu_k^-1 mu_i``), second-order
   BCH gives ``log(nu_k^-1 g_i) ~ x_k + Gamma_k y`` with ``Gamma_k = I + ad(x_k)/2``. Completing the square:

       S = Sigma_i^-1 + sum_k Gamma_k^T W_k^-1 Gamma_k
       xbar = S^-1 sum_k Gamma_k^T W_k^-1 x_k          (= S^-1 sum_k Gamma_k^T W_k^-1 Gamma_k x_k, as ad(x)x = 0)
       posterior mean = mu_i exp(-xbar)
       posterior cov  = Gamma(xbar) S^-1 Gamma(xbar)^T,  Gamma(xbar) = I + ad(xbar)/2

   (``Gamma``, not its inverse, and a minus sign: the covariance is re-centred at the new mean.)

The first-order variant drops ``F`` in step 1 and uses ``Gamma = I`` everywhere (an EKF-like update on the
group). ``iterations > 1`` re-linearizes about the current estimate (Gauss-Newton on the same cost).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from swarmloc.gaussian import GroupGaussian, check_covariance, convolution_F
from swarmloc.lie import SE2, wrap_angle
from swarmloc.lie.base import SEGroup

_T = np.swapaxes


def _bvec(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...ij,...j->...i", M, v)


def _gamma(group: type[SEGroup], x: np.ndarray, order: int) -> np.ndarray:
    eye = np.broadcast_to(np.eye(group.dim), (*x.shape[:-1], group.dim, group.dim))
    if order == 1:
        return eye
    return eye + 0.5 * group.ad(x, validate=False)


def relative_to_pseudo(
    group: type[SEGroup],
    mu_k: np.ndarray,
    cov_k: np.ndarray,
    m_ik: np.ndarray,
    cov_ik: np.ndarray,
    order: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """Turn a relative measurement of a neighbour into a Gaussian on the observer's own pose (steps 1-2).

    Returns ``(nu, W)``: ``g_i ~ nu exp(N(0, W))``. Batched, no validation.
    """
    cov_c = cov_k + cov_ik
    if order == 2:
        cov_c = cov_c + convolution_F(group, cov_k, cov_ik)
    Ad = group.Ad(m_ik, validate=False)
    W = Ad @ cov_c @ _T(Ad, -1, -2)
    nu = mu_k @ group.inverse(m_ik, validate=False)
    return nu, 0.5 * (W + _T(W, -1, -2))


def fuse_pseudo(
    group: type[SEGroup],
    mu: np.ndarray,
    cov: np.ndarray,
    nus: np.ndarray,
    Ws: np.ndarray,
    order: int = 2,
    iterations: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Fuse a prior ``(mu, cov)`` with ``K`` Gaussian observations ``(nus[..., k], Ws[..., k])`` of the same pose.

    Shapes: ``mu (..., n+1, n+1)``, ``cov (..., d, d)``, ``nus (..., K, n+1, n+1)``, ``Ws (..., K, d, d)``.
    Step 3 of the module docstring; batched over leading axes, no validation.
    """
    W_inv = np.linalg.inv(Ws)
    mu0 = mu
    cov_inv = np.linalg.inv(cov)
    cur = mu
    for it in range(max(1, iterations)):
        # residuals of all observations (k) and, after the first pass, of the prior, at the current estimate
        x = group.log(group.inverse(nus, validate=False) @ cur[..., None, :, :], validate=False)  # (..., K, d)
        Gm = _gamma(group, x, order)
        GtW = _T(Gm, -1, -2) @ W_inv
        S = np.sum(GtW @ Gm, axis=-3)
        b = np.sum(_bvec(GtW, x), axis=-2)
        if it == 0:
            S = S + cov_inv
        else:
            x0 = group.log(group.inverse(mu0, validate=False) @ cur, validate=False)
            G0 = _gamma(group, x0, order)
            G0tP = _T(G0, -1, -2) @ cov_inv
            S = S + G0tP @ G0
            b = b + _bvec(G0tP, x0)
        xbar = np.linalg.solve(S, b[..., None])[..., 0]
        cur = cur @ group.exp(-xbar, validate=False)
    Gb = _gamma(group, xbar, order)
    post = Gb @ np.linalg.inv(S) @ _T(Gb, -1, -2)
    return cur, 0.5 * (post + _T(post, -1, -2))


def _check_pair(prior: GroupGaussian, item: object, idx: int, where: str) -> tuple[GroupGaussian, GroupGaussian]:
    if not (isinstance(item, tuple | list) and len(item) == 2):
        raise ValueError(f"{where}: measurements[{idx}] must be a (neighbour_belief, measurement) pair, got {item!r}")
    nb, meas = item
    for name, obj in (("neighbour_belief", nb), ("measurement", meas)):
        if not isinstance(obj, GroupGaussian):
            raise ValueError(f"{where}: measurements[{idx}] {name} must be a GroupGaussian, got {type(obj).__name__}")
        if obj.group is not prior.group:
            raise ValueError(
                f"{where}: measurements[{idx}] {name} is on {obj.group.__name__}, prior on {prior.group.__name__}"
            )
        if obj.batch_shape != prior.batch_shape:
            raise ValueError(
                f"{where}: measurements[{idx}] {name} has batch shape {obj.batch_shape}, prior {prior.batch_shape}"
            )
    return nb, meas


def fuse_relative(
    prior: GroupGaussian,
    measurements: Sequence[tuple[GroupGaussian, GroupGaussian]],
    order: int = 2,
    iterations: int = 2,
) -> GroupGaussian:
    """Posterior of robot ``i``'s pose after relative measurements of any number of uncertain neighbours.

    Parameters
    ----------
    prior: robot ``i``'s belief ``(mu_i, Sigma_i)``.
    measurements: pairs ``(neighbour_belief, measurement)``: the neighbour's belief ``(mu_k, Sigma_k)`` and the
        measurement ``(m_ik, Sigma_ik)`` = pose of ``k`` in ``i``'s frame with noise ``g_i^-1 g_k = m_ik exp(n)``.
    order: 2 (thesis, second order) or 1 (first-order variant: no ``F`` term, ``Gamma = I``).
    iterations: 1 is the closed form (thesis 4.16-4.19 as corrected in the module docstring); the default 2
        re-linearizes once about the updated mean (Gauss-Newton), which removes most of the mean error left
        by the single step when uncertainties are large (see tests/test_fusion.py and the README).

    With no measurements the prior is returned unchanged.
    """
    where = "fuse_relative"
    if not isinstance(prior, GroupGaussian):
        raise ValueError(f"{where}: argument 'prior' must be a GroupGaussian, got {type(prior).__name__}")
    if order not in (1, 2):
        raise ValueError(f"{where}: argument 'order' must be 1 or 2, got {order!r}")
    if int(iterations) < 1:
        raise ValueError(f"{where}: argument 'iterations' must be >= 1, got {iterations!r}")
    pairs = [_check_pair(prior, item, i, where) for i, item in enumerate(measurements)]
    if not pairs:
        return prior
    G = prior.group
    nus, Ws = relative_to_pseudo(
        G,
        np.stack([nb.mean for nb, _ in pairs], axis=-3),
        np.stack([nb.cov for nb, _ in pairs], axis=-3),
        np.stack([m.mean for _, m in pairs], axis=-3),
        np.stack([m.cov for _, m in pairs], axis=-3),
        order,
    )
    mu, cov = fuse_pseudo(G, prior.mean, prior.cov, nus, Ws, order, int(iterations))
    return GroupGaussian(G, mu, check_covariance(cov, G.dim, where, "posterior covariance"), validate=False)


def fuse_absolute(
    prior: GroupGaussian, observations: Sequence[GroupGaussian], order: int = 2, iterations: int = 2
) -> GroupGaussian:
    """Fuse direct Gaussian observations of the same pose (e.g. GPS-like fixes) with the prior."""
    if not observations:
        return prior
    for i, o in enumerate(observations):
        if not isinstance(o, GroupGaussian) or o.group is not prior.group:
            raise ValueError(f"fuse_absolute: observations[{i}] must be a GroupGaussian on {prior.group.__name__}")
    nus = np.stack([o.mean for o in observations], axis=-3)
    Ws = np.stack([o.cov for o in observations], axis=-3)
    mu, cov = fuse_pseudo(prior.group, prior.mean, prior.cov, nus, Ws, order, iterations)
    return GroupGaussian(prior.group, mu, cov, validate=False)


# ---------------------------------------------------------------------------------------------------------------
# Partial measurements (range, bearing, range-bearing) of a robot or a landmark, on SE(2)

_J2 = np.array([[0.0, -1.0], [1.0, 0.0]])


def _dz_dq(kind: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted measurement and its Jacobian w.r.t. the target's position ``q`` in the observer's frame."""
    r2 = float(q @ q)
    r = np.sqrt(r2)
    rng = np.array([r])
    brg = np.array([np.arctan2(q[1], q[0])])
    d_r = np.array([[q[0] / r, q[1] / r]])
    d_b = np.array([[-q[1] / r2, q[0] / r2]])
    if kind == "range_bearing":
        return np.concatenate([rng, brg]), np.vstack([d_r, d_b])
    if kind == "range":
        return rng, d_r
    if kind == "bearing":
        return brg, d_b
    raise ValueError(f"unknown partial measurement kind {kind!r}")


def point_measurement_model(
    kind: str,
    mu_i: np.ndarray,
    target_mean: np.ndarray,
    target_cov: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Range/bearing of a target seen from pose ``mu_i``, linearized on SE(2).

    ``target_mean`` is either a pose (3x3, a robot with exponential-coordinate covariance ``target_cov`` 3x3) or a
    world point (2,) with Cartesian covariance (2x2). The observer is perturbed on the right, ``g_i = mu_i exp(y)``;
    the target's position in the observer's frame is ``q = exp(-y) mu_i^-1 p``, so ``dq/dy = -[I, J q]`` with
    ``J = [[0, -1], [1, 0]]``; a robot target ``g_k = mu_k exp(y_k)`` moves ``q`` by ``R(mu_i^-1 mu_k) v_k``.
    Returns ``(h, H, C)``: prediction, Jacobian w.r.t. ``y`` and the covariance the target's uncertainty adds.
    """
    R_iT = mu_i[:2, :2].T
    if target_mean.shape == (3, 3):
        rel = SE2.inverse(mu_i, validate=False) @ target_mean
        q = rel[:2, 2]
        dq_dt = np.hstack([rel[:2, :2], np.zeros((2, 1))])  # w.r.t. y_k
    else:
        q = R_iT @ (np.asarray(target_mean, float) - mu_i[:2, 2])
        dq_dt = R_iT
    h, dz = _dz_dq(kind, q)
    H = dz @ -np.hstack([np.eye(2), (_J2 @ q)[:, None]])
    Ht = dz @ dq_dt
    return h, H, Ht @ target_cov @ Ht.T


def _wrap_residual(kind: str, r: np.ndarray) -> np.ndarray:
    idx = {"range_bearing": [1], "bearing": [0], "range": []}[kind]
    r = r.copy()
    for j in idx:
        r[j] = wrap_angle(r[j])
    return r


def fuse_point_measurement(
    mu: np.ndarray,
    cov: np.ndarray,
    kind: str,
    z: np.ndarray,
    R: np.ndarray,
    target_mean: np.ndarray,
    target_cov: np.ndarray,
    iterations: int = 3,
    order: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """Update an SE(2) belief with a range/bearing measurement of an uncertain robot or landmark.

    Iterated (Gauss-Newton) update on the group: at the current estimate ``mu_c = mu exp(x0)``-style point,
    minimize ``|x0 + Gamma(x0) d|^2_{Sigma^-1} + |r - H d|^2_{S^-1}`` with ``S = C + R`` (target uncertainty
    ``C`` from :func:`point_measurement_model` plus noise), step ``mu_c <- mu_c exp(d)``. One iteration is the
    EKF update on the group; the posterior covariance is re-centred with ``Gamma(d)`` (second order) as in
    :func:`fuse_pseudo`. ``order=1`` uses ``Gamma = I``.
    """
    cov_inv = np.linalg.inv(cov)
    cur = mu
    d = np.zeros(3)
    info = cov_inv
    for it in range(max(1, iterations)):
        h, H, C = point_measurement_model(kind, cur, target_mean, target_cov)
        Sinv = np.linalg.inv(C + R)
        r = _wrap_residual(kind, np.asarray(z, float) - h)
        if it == 0:
            G0 = np.eye(3)
            x0 = np.zeros(3)
        else:
            x0 = SE2.log(SE2.inverse(mu, validate=False) @ cur, validate=False)
            G0 = _gamma(SE2, x0, order)
        G0tP = G0.T @ cov_inv
        info = G0tP @ G0 + H.T @ Sinv @ H
        d = np.linalg.solve(info, H.T @ Sinv @ r - G0tP @ x0)
        cur = cur @ SE2.exp(d, validate=False)
    Gd = _gamma(SE2, -d, order)  # mu_c exp(d + y) = mu_c exp(d) exp(Jr(d) y), Jr(d) ~ I - ad(d)/2
    post = Gd @ np.linalg.inv(info) @ Gd.T
    return cur, 0.5 * (post + post.T)


def point_innovation(
    mu: np.ndarray,
    cov: np.ndarray,
    kind: str,
    z: np.ndarray,
    R: np.ndarray,
    target_mean: np.ndarray,
    target_cov: np.ndarray,
) -> float:
    """Normalized innovation squared ``r^T (H Sigma H^T + C + R)^-1 r`` of a range/bearing measurement (gating)."""
    h, H, C = point_measurement_model(kind, mu, target_mean, target_cov)
    r = _wrap_residual(kind, np.asarray(z, float) - h)
    return float(r @ np.linalg.solve(H @ cov @ H.T + C + R, r))


def pseudo_innovation(mu: np.ndarray, cov: np.ndarray, nu: np.ndarray, W: np.ndarray) -> float:
    """Normalized innovation squared of a pose pseudo-observation (first order), for gating."""
    x = SE2.log(SE2.inverse(nu, validate=False) @ mu, validate=False)
    return float(x @ np.linalg.solve(cov + W, x))
