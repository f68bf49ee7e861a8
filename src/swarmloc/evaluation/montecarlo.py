"""Sampling references for the closed forms: group means, Monte Carlo convolution, importance-sampled fusion.

These are deliberately plain (no BCH, no linearization): they only sample, multiply matrices and take logs (with
the exponential map's density correction, :func:`log_abs_det_jacobian`), so they serve as independent checks of
:mod:`swarmloc.gaussian` and :mod:`swarmloc.fusion`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from swarmloc.gaussian import GroupGaussian
from swarmloc.lie.base import SEGroup


def group_mean(
    group: type[SEGroup],
    samples: np.ndarray,
    weights: np.ndarray | None = None,
    init: np.ndarray | None = None,
    iters: int = 50,
    tol: float = 1e-12,
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean ``mu`` with ``sum w log(mu^-1 g) = 0`` (thesis eq. 3.20) and covariance about it (3.21).

    ``samples (N, n+1, n+1)``, ``weights (N,)`` (normalized here). Fixed-point iteration from ``init``
    (default: the sample of largest weight).
    """
    N = samples.shape[0]
    w = np.full(N, 1.0 / N) if weights is None else np.asarray(weights, float) / np.sum(weights)
    mu = samples[int(np.argmax(w))] if init is None else np.asarray(init, float)
    for _ in range(iters):
        y = group.log(group.inverse(mu, validate=False) @ samples, validate=False)
        step = w @ y
        mu = mu @ group.exp(step, validate=False)
        if np.linalg.norm(step) < tol:
            break
    y = group.log(group.inverse(mu, validate=False) @ samples, validate=False)
    cov = (y * w[:, None]).T @ y
    return mu, cov


def convolution_mc(a: GroupGaussian, b: GroupGaussian, n: int, rng: np.random.Generator) -> np.ndarray:
    """Second moment ``E[y y^T]`` of ``y = log((mu_a mu_b)^-1 g_a g_b)`` from ``n`` samples (definition 3.21)."""
    G = a.group
    y = G.log(G.inverse(a.mean @ b.mean, validate=False) @ a.sample(n, rng) @ b.sample(n, rng), validate=False)
    return y.T @ y / n


def log_abs_det_jacobian(group: type[SEGroup], x: np.ndarray) -> np.ndarray:
    """``log|det Jl(x)|`` (= ``log|det Jr(x)|`` on SE(n)): the density correction of the exponential map.

    In closed form: ``Jl`` is block triangular, its diagonal ``V(alpha)`` (2x2) and 1 on SE(2), SO(3)'s left
    Jacobian twice on SE(3); each of those blocks has determinant ``2 (1 - cos t) / t^2 = sinc(t / 2)^2`` for the
    rotation angle ``t = |w|`` (``np.sinc`` is ``sin(pi u) / (pi u)``), so ``log|det Jl| = 2 (n - 1)
    log|sinc(t / 2)|`` (checked in the tests against ``slogdet`` of
    :meth:`~swarmloc.lie.base.SEGroup.left_jacobian` and against central differences of ``expm``)."""
    t = np.linalg.norm(np.asarray(x, dtype=float)[..., group.n :], axis=-1)
    return 2.0 * (group.n - 1) * np.log(np.abs(np.sinc(t / (2.0 * np.pi))))


def _gauss_logpdf(y: np.ndarray, cov: np.ndarray) -> np.ndarray:
    L = np.linalg.cholesky(cov)
    z = np.linalg.solve(L, y.T).T
    return -0.5 * np.sum(z * z, axis=-1) - np.log(np.diag(L)).sum() - 0.5 * y.shape[-1] * np.log(2 * np.pi)


def importance_posterior(
    prior: GroupGaussian,
    measurements: Sequence[tuple[GroupGaussian, GroupGaussian]],
    n: int,
    rng: np.random.Generator,
    stages: int = 4,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Posterior mean and covariance of ``g_i`` by adaptive importance sampling.

    Model (exactly that of DESIGN.md): ``g_i = mu_i exp(y_i)``, ``g_k = mu_k exp(y_k)`` with Gaussian ``y``, and
    ``g_i^-1 g_k = m_ik exp(n_k)``, ``n_k ~ N(0, Sigma_ik)``. Each draw proposes ``y_i ~ q`` (a Gaussian in
    ``g_i``'s exponential coordinates about ``mu_i``) and, given ``g_i``, ``g_k = g_i m_ik exp(n_k)`` with
    ``n_k`` drawn from the measurement noise, so the noise density cancels and the weight is

        N(y_i; 0, Sigma_i) / q(y_i) * prod_k N(y_k; 0, Sigma_k) / |det J(y_k)|,   y_k = log(mu_k^-1 g_k),

    where ``1/|det J|`` turns the neighbour's exponential-coordinate density into a density on the group (the
    noise's Jacobian cancels the same way). Where the neighbour's belief is tighter than the noise
    (smaller determinant) the roles swap: ``g_k`` is drawn from the belief and weighted by the noise density.
    Stage 1 uses the prior as ``q``; each later stage uses a Gaussian
    with the previous stage's weighted mean and 1.5^2 times its covariance. Nothing here uses the closed-form
    fusion. Returns ``(mean, cov, effective_sample_size of the last stage)``.
    """
    G = prior.group
    d = G.dim

    def add_loglik(gi: np.ndarray, logw: np.ndarray) -> None:
        for nb, meas in measurements:
            if np.linalg.det(meas.cov) <= np.linalg.det(nb.cov):
                # propose g_k from the measurement, weight by the neighbour's density on the group
                nk = rng.multivariate_normal(np.zeros(d), meas.cov, size=n)
                gk = gi @ meas.mean @ G.exp(nk, validate=False)
                y_k = G.log(G.inverse(nb.mean, validate=False) @ gk, validate=False)
                logw += _gauss_logpdf(y_k, nb.cov) - log_abs_det_jacobian(G, y_k)
            else:
                # propose g_k from the neighbour's belief, weight by the noise density on the group
                gk = nb.sample(n, rng)
                nk = G.log(G.inverse(meas.mean, validate=False) @ G.inverse(gi, validate=False) @ gk, validate=False)
                logw += _gauss_logpdf(nk, meas.cov) - log_abs_det_jacobian(G, nk)

    return _adaptive_importance(G, prior, n, rng, stages, add_loglik)


def importance_posterior_point(
    prior: GroupGaussian,
    kind: str,
    z: np.ndarray,
    R: np.ndarray,
    target: GroupGaussian | tuple[np.ndarray, np.ndarray],
    n: int,
    rng: np.random.Generator,
    stages: int = 4,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Posterior of an SE(2) pose after a range/bearing measurement, by adaptive importance sampling.

    ``target`` is a robot's belief (GroupGaussian) or a landmark ``(position (2,), covariance (2, 2))``. Each
    draw samples the observer from the proposal and the target from its own belief; the weight is the prior
    over proposal ratio times ``N(z - h; 0, R)`` with ``h`` computed from the sampled poses directly
    (``R_i^T (p_k - t_i)``, ``atan2``), angles wrapped. No linearization anywhere.
    """
    from swarmloc.lie import SE2
    from swarmloc.sensors.models import model

    point = model(kind)
    Rinv = np.linalg.inv(R)

    def add_loglik(gi: np.ndarray, logw: np.ndarray) -> None:
        if isinstance(target, GroupGaussian):
            pk = target.sample(n, rng)[:, :2, 2]
        else:
            pk = rng.multivariate_normal(target[0], target[1], size=n)
        dp = pk - gi[:, :2, 2]
        q = np.einsum("nji,nj->ni", gi[:, :2, :2], dp)
        rr = np.hypot(q[:, 0], q[:, 1])
        bb = np.arctan2(q[:, 1], q[:, 0])
        res = point.residual(z, np.stack([rr, bb], 1)[:, point.components])
        logw -= 0.5 * np.einsum("ni,ij,nj->n", res, Rinv, res)

    return _adaptive_importance(SE2, prior, n, rng, stages, add_loglik, jitter=1e-12)


def _adaptive_importance(
    G: type[SEGroup],
    prior: GroupGaussian,
    n: int,
    rng: np.random.Generator,
    stages: int,
    add_loglik: Callable[[np.ndarray, np.ndarray], None],
    jitter: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, float]:
    """The sampler both posteriors share: ``stages`` rounds of ``n`` draws ``g_i = mu_i exp(y_i)``, ``y_i ~ q``
    (the prior first, then a Gaussian at the last round's weighted mean with 1.5^2 times its weighted covariance,
    plus ``jitter`` I), log-weighted by ``N(y_i; 0, Sigma_i) / q(y_i)`` plus what ``add_loglik(g_i (n, ...), logw
    (n,))`` adds in place. Returns ``(mean, cov, effective sample size of the last round)``."""
    d = G.dim
    q_mean, q_cov = np.zeros(d), prior.cov
    for stage in range(max(1, stages)):
        y_i = rng.multivariate_normal(q_mean, q_cov, size=n)
        gi = prior.mean @ G.exp(y_i, validate=False)
        logw = _gauss_logpdf(y_i, prior.cov) - _gauss_logpdf(y_i - q_mean, q_cov)
        add_loglik(gi, logw)
        w = np.exp(logw - logw.max())
        w /= w.sum()
        ess = float(1.0 / (w**2).sum())
        mu, cov = group_mean(G, gi, w, init=prior.mean)
        if stage < stages - 1:
            # next proposal, in y_i coordinates about prior.mean
            y_mu = G.log(G.inverse(prior.mean, validate=False) @ mu, validate=False)
            dy = y_i - y_mu
            q_mean, q_cov = y_mu, 1.5**2 * ((dy * w[:, None]).T @ dy)
            if jitter:
                q_cov = q_cov + jitter * np.eye(d)
    return mu, cov, ess
