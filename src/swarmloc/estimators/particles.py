"""The particle-set math of :mod:`swarmloc.estimators.mcl`, pure functions on arrays: systematic resampling, the
weighted Gaussian fit in exponential coordinates, the ensemble transform that moves a weighted set onto a Gaussian
posterior (Tippett et al. 2003), and the split of a landmark's likelihood between a tempered reweighting and that
Gaussian step (Frei & Kuensch 2013; the module docstring of :mod:`~swarmloc.estimators.mcl` says when each runs).
Particles are Cartesian poses ``(x, y, theta)`` [m, m, rad] in rows; weights sum to 1."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from swarmloc.gaussian import mahalanobis2, symmetric
from swarmloc.kernels import group as K
from swarmloc.lie import SE2, between_xyt, exp_xyt, log_xyt, wrap_angle
from swarmloc.node import usable_covariance

COV_FLOOR = 1e-10
"""Added to the diagonal of a fitted covariance (exponential coordinates) so that it stays positive definite."""
MEAN_ITERATIONS = 3
TEMPER_STEPS = 12
"""Bisection steps for the split's exponent (resolution ``2^-12``)."""


def systematic_resample(weights: np.ndarray, u: float) -> np.ndarray:
    """Indices of low-variance (systematic) resampling: one offset ``u`` in [0, 1), positions ``(u + k) / N``."""
    n = weights.size
    c = np.cumsum(weights)
    c /= c[-1]
    idx = np.searchsorted(c, (u + np.arange(n)) / n, side="right")
    return np.minimum(idx, n - 1)


def sqrt_cov3(S11: float, S12: float, S13: float, S22: float, S23: float, S33: float) -> np.ndarray:
    """Lower-triangular ``L`` with ``L L^T = S`` for a positive semi-definite 3x3 ``S`` (pivots clamped at 0)."""
    l11 = math.sqrt(max(S11, 0.0))
    l21 = S12 / l11 if l11 > 0 else 0.0
    l31 = S13 / l11 if l11 > 0 else 0.0
    l22 = math.sqrt(max(S22 - l21 * l21, 0.0))
    l32 = (S23 - l31 * l21) / l22 if l22 > 0 else 0.0
    l33 = math.sqrt(max(S33 - l31 * l31 - l32 * l32, 0.0))
    return np.array([[l11, 0.0, 0.0], [l21, l22, 0.0], [l31, l32, l33]])


def quadratic(r: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``r^T S^-1 r`` and ``log det S`` for residuals ``(N, m)`` and covariances ``(N, m, m)`` (closed forms for
    ``m <= 2``: the batched LAPACK calls cost more than the arithmetic for a few hundred particles)."""
    m = r.shape[-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        if m == 1:
            v = S[:, 0, 0]
            return r[:, 0] ** 2 / v, np.log(v)
        if m == 2:
            a, b, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
            det = a * d - b * b
            x, y = r[:, 0], r[:, 1]
            return (d * x * x - 2 * b * x * y + a * y * y) / det, np.log(det)
    return mahalanobis2(r, S), np.linalg.slogdet(S)[1]


def logsumexp(a: np.ndarray) -> float:
    m = float(np.max(a))
    if not math.isfinite(m):
        return m
    return m + math.log(float(np.sum(np.exp(a - m))))


def ensemble_transform(
    p: np.ndarray, mean: np.ndarray, cov: np.ndarray, mean2: np.ndarray, cov2: np.ndarray
) -> np.ndarray | None:
    """Particles ``p`` ``(N, 3)`` whose fitted Gaussian is ``(mean, cov)`` (SE(2) matrix, exponential-coordinate
    covariance) moved onto ``(mean2, cov2)``: ``g_n <- mean2 exp(A log(mean^-1 g_n))``, ``A = L2 L^-1`` (Cholesky
    factors), the deterministic ensemble transform (module docstring). None when ``(mean2, cov2)`` is not usable."""
    if not (np.isfinite(mean2).all() and usable_covariance(cov2)):
        return None
    m0, m1 = SE2.to_xytheta(mean), SE2.to_xytheta(mean2)
    A = np.linalg.cholesky(cov2) @ np.linalg.inv(np.linalg.cholesky(cov))
    ex, ey, ea = exp_xyt(log_xyt(between_xyt(m0, p)) @ A.T).T
    c, s = math.cos(m1[2]), math.sin(m1[2])
    return np.stack([m1[0] + c * ex - s * ey, m1[1] + s * ex + c * ey, wrap_angle(m1[2] + ea)], axis=-1)


def split_exponent(lw: np.ndarray, q: np.ndarray, ess: float) -> float:
    """The largest ``gamma`` in [0, 1) (bisection, :data:`TEMPER_STEPS` steps) such that log weights ``lw`` plus
    ``-gamma q / 2`` (the likelihood to the power ``gamma``; ``q``: ``nis`` plus relative log-determinant) keep an
    effective sample size of at least ``ess``; 0 when even the weights ``lw`` have less."""
    lo, hi = 0.0, 1.0
    for _ in range(TEMPER_STEPS):
        mid = 0.5 * (lo + hi)
        a = lw - 0.5 * mid * q
        wn = np.exp(a - logsumexp(a))
        if 1.0 / float(wn @ wn) >= ess:
            lo = mid
        else:
            hi = mid
    return lo


def landmark_split(
    p: np.ndarray, lw: np.ndarray, q: np.ndarray, d: Any, landmark: tuple[np.ndarray, np.ndarray], ess: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """A range/bearing detection ``d`` of a landmark ``(position, covariance)`` split between the particles ``p``
    (log weights ``lw``) and their fitted Gaussian (module docstring): particles and normalized log weights after
    the reweighting by the likelihood to the power ``gamma`` (:func:`split_exponent`; ``q``: ``nis`` plus relative
    log-determinant per particle) and the iterated EKF update on the group by the rest (noise and landmark
    covariances over ``1 - gamma``) with the ensemble transform; None when that update is not usable."""
    gamma = split_exponent(lw, q, ess)
    lg = lw - 0.5 * gamma * q
    lg = lg - logsumexp(lg)
    mean, cov = fit_gaussian(p, np.exp(lg))
    with np.errstate(all="ignore"):
        R, share = np.asarray(d.cov, dtype=float), 1.0 - gamma
        meas = K.PointMeasurement(d.kind, d.z, R / share, landmark[0], landmark[1] / share, False)
        m2, c2, ok = K.point_update(mean, cov, meas)
    moved = ensemble_transform(p, mean, cov, m2, c2) if bool(ok) else None
    return None if moved is None else (moved, lg)


def fit_gaussian(particles: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted SE(2) Gaussian of a particle set: mean ``(3, 3)`` and exponential-coordinate covariance ``(3, 3)``
    (right perturbation; see the module docstring)."""
    w = weights
    th = particles[:, 2]
    mu = np.array([w @ particles[:, 0], w @ particles[:, 1], math.atan2(w @ np.sin(th), w @ np.cos(th))])
    for _ in range(MEAN_ITERATIONS):  # Gauss-Newton steps of the weighted Karcher mean: mu <- mu exp(mean y)
        step = SE2.to_xytheta(SE2.from_xytheta(mu) @ SE2.exp(w @ log_xyt(between_xyt(mu, particles)), validate=False))
        mu = step
    y = log_xyt(between_xyt(mu, particles))
    cov = (y * w[:, None]).T @ y
    cov = symmetric(cov) + COV_FLOOR * np.eye(3)
    return SE2.from_xytheta(mu), cov
