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

from swarmloc.gaussian import GroupGaussian, check_covariance
from swarmloc.kernels import group as K


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
    iterations: int = K.FUSE_ITERATIONS,
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
        by the single step when uncertainties are large (see tests/test_fusion.py and docs/verification.md).

    With no measurements the prior is returned unchanged. The kernels are
    :func:`swarmloc.kernels.group.relative_to_pseudo` and :func:`swarmloc.kernels.group.fuse_pseudo`.
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
    nus, Ws = K.relative_to_pseudo(
        G,
        np.stack([nb.mean for nb, _ in pairs], axis=-3),
        np.stack([nb.cov for nb, _ in pairs], axis=-3),
        np.stack([m.mean for _, m in pairs], axis=-3),
        np.stack([m.cov for _, m in pairs], axis=-3),
        order,
    )
    mu, cov = K.fuse_pseudo(G, prior.mean, prior.cov, nus, Ws, order, int(iterations))
    return GroupGaussian(G, mu, check_covariance(cov, G.dim, where, "posterior covariance"), validate=False)


def fuse_absolute(
    prior: GroupGaussian, observations: Sequence[GroupGaussian], order: int = 2, iterations: int = K.FUSE_ITERATIONS
) -> GroupGaussian:
    """Fuse direct Gaussian observations of the same pose (e.g. GPS-like fixes) with the prior."""
    if not isinstance(prior, GroupGaussian):
        raise ValueError(f"fuse_absolute: argument 'prior' must be a GroupGaussian, got {type(prior).__name__}")
    if not observations:
        return prior
    for i, o in enumerate(observations):
        if not isinstance(o, GroupGaussian) or o.group is not prior.group:
            raise ValueError(f"fuse_absolute: observations[{i}] must be a GroupGaussian on {prior.group.__name__}")
    nus = np.stack([o.mean for o in observations], axis=-3)
    Ws = np.stack([o.cov for o in observations], axis=-3)
    mu, cov = K.fuse_pseudo(prior.group, prior.mean, prior.cov, nus, Ws, order, iterations)
    return GroupGaussian(prior.group, mu, cov, validate=False)


def fuse_point_measurement(
    mu: np.ndarray,
    cov: np.ndarray,
    kind: str,
    z: np.ndarray,
    R: np.ndarray,
    target_mean: np.ndarray,
    target_cov: np.ndarray,
    iterations: int = K.POINT_ITERATIONS,
    order: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """Update an SE(2) belief ``(mu (3, 3), cov)`` with a range/bearing measurement of an uncertain target.

    ``target_mean`` is a robot's pose ``(3, 3)`` (with exponential-coordinate covariance ``(3, 3)``) or a world
    point ``(2,)`` (Cartesian covariance ``(2, 2)``). See :func:`swarmloc.kernels.group.point_update` for the
    iterated update on the group; raises ValueError when the target is at the observer's position.
    """
    meas = point_measurement(kind, z, R, target_mean, target_cov)
    m, c, ok = K.point_update(np.asarray(mu, float), np.asarray(cov, float), meas, iterations, order)
    if not np.all(ok):
        raise ValueError("fuse_point_measurement: degenerate geometry (the target is at the observer's position)")
    return m, c


def point_innovation(mu: np.ndarray, cov: np.ndarray, meas: K.PointMeasurement) -> float:
    """Normalized innovation squared ``r^T (H Sigma H^T + C + R)^-1 r`` of a range/bearing measurement ``meas``
    (:func:`point_measurement`) for the SE(2) belief ``(mu (3, 3), cov)`` (gating)."""
    return float(K.point_nis(np.asarray(mu, float), np.asarray(cov, float), meas))


def point_measurement(
    kind: str, z: np.ndarray, R: np.ndarray, target_mean: np.ndarray, target_cov: np.ndarray
) -> K.PointMeasurement:
    """The kernels' measurement (floats) of :func:`fuse_point_measurement`'s arguments; the target is a robot when
    its mean is a pose ``(3, 3)``."""
    tm = np.asarray(target_mean, dtype=float)
    return K.PointMeasurement(kind, np.asarray(z, float), np.asarray(R, float), tm, np.asarray(target_cov, float),
                              tm.shape[-2:] == (3, 3))  # fmt: skip


__all__ = ["fuse_absolute", "fuse_point_measurement", "fuse_relative", "point_innovation", "point_measurement"]
