"""Mean and covariance of the SE(2) body-twist SDE over a constant-twist interval (thesis eqs. 5.3, 5.4, 5.11, 5.12).

For ``(g^-1 dg)^v = h dt + H dw`` started at the identity with constant ``h``, to first order in the noise
(right perturbation ``g(t) = mu(t) exp(y)``)::

    mu(t)    = exp(t h^)                                                       (5.3)
    Sigma(t) = int_0^t Ad(mu(tau)^-1) Q Ad(mu(tau)^-1)^T dtau,  Q = H H^T      (5.4)

All functions are batched: ``h`` ``(..., 3)``, ``t`` ``(...)``, ``Q`` ``(..., 3, 3)`` broadcast against each other.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy.integrate import quad_vec

from swarmloc.lie import SE2
from swarmloc.motion.closed_form import constant_twist_cov

CovMethod = Literal["gauss", "simpson38", "quad", "closed"]

_GL_NODES = 12
_GL_X, _GL_W = np.polynomial.legendre.leggauss(_GL_NODES)
_GL_MAX_PHASE = 1.0  # largest |omega| * panel length per Gauss-Legendre panel [rad]


def _broadcast(h: np.ndarray, t: np.ndarray | float, Q: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    h = np.asarray(h, dtype=float)
    t = np.asarray(t, dtype=float)
    shape = (
        np.broadcast_shapes(h.shape[:-1], t.shape)
        if Q is None
        else np.broadcast_shapes(h.shape[:-1], t.shape, np.shape(Q)[:-2])
    )
    h = np.broadcast_to(h, (*shape, 3))
    t = np.broadcast_to(t, shape)
    if Q is None:
        return h, t
    return h, t, np.broadcast_to(np.asarray(Q, dtype=float), (*shape, 3, 3))


def increment_mean(h: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    """Exact mean increment ``mu(t) = exp(t h^)`` (5.3), ``(..., 3, 3)``."""
    h, t = _broadcast(h, t)
    return SE2.exp(t[..., None] * h, validate=False)


def increment_mean_second_order(h: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    """Second-order mean ``I + X + X^2/2`` with ``X = t h^`` (thesis eq. 5.11), ``(..., 3, 3)``.

    The result is *not* exactly in SE(2): its rotation block is ``[[1 - a^2/2, -a], [a, 1 - a^2/2]]``
    (``a = omega t``), orthonormal only to ``O(a^3)``; the error to :func:`increment_mean` is ``O(|t h|^3)``.
    Provided to reproduce the thesis; use :func:`increment_mean` in estimators.
    """
    h, t = _broadcast(h, t)
    X = SE2.hat(t[..., None] * h, validate=False)
    return np.eye(3) + X + 0.5 * (X @ X)


def _integrand(h: np.ndarray, Q: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``Ad(exp(-tau h)) Q Ad(exp(-tau h))^T`` for ``tau`` ``(..., k)`` -> ``(..., k, 3, 3)``."""
    Ad = SE2.Ad(SE2.exp(-tau[..., None] * h[..., None, :], validate=False), validate=False)
    return Ad @ Q[..., None, :, :] @ np.swapaxes(Ad, -1, -2)


def increment_cov(h: np.ndarray, Q: np.ndarray, t: np.ndarray | float, method: CovMethod = "gauss") -> np.ndarray:
    """Covariance (5.4) of the increment over ``[0, t]`` for constant twist ``h`` and diffusion ``Q`` per second.

    ``method``:

    * ``"gauss"`` (default): composite 12-node Gauss-Legendre with panels of turn angle <= 1 rad; the integrand is
      a trigonometric polynomial of frequency <= 2 omega, so the quadrature error is ~1e-16 relative;
    * ``"simpson38"``: thesis eq. (5.12), ``t/8 [f(0) + 3 f(t/3) + 3 f(2t/3) + f(t)]``; exact for straight motion,
      error ``O((omega t)^4)`` relative otherwise;
    * ``"quad"``: ``scipy.integrate.quad_vec`` (reference, slow);
    * ``"closed"``: the closed form :func:`swarmloc.motion.closed_form.constant_twist_cov`.

    Returns ``(..., 3, 3)``.
    """
    h, t, Q = _broadcast(h, t, Q)
    if method == "closed":
        return constant_twist_cov(h, Q, t)
    if method == "simpson38":
        u = np.array([0.0, 1 / 3, 2 / 3, 1.0])
        w = np.array([1.0, 3.0, 3.0, 1.0]) / 8
        f = _integrand(h, Q, t[..., None] * u)
        return t[..., None, None] * np.einsum("k,...kij->...ij", w, f)
    if method == "gauss":
        phase = float(np.max(np.abs(h[..., 2] * t), initial=0.0))
        n_pan = max(1, int(np.ceil(phase / _GL_MAX_PHASE)))
        edges = np.arange(n_pan) / n_pan
        u = (edges[:, None] + (0.5 * (_GL_X + 1.0)) / n_pan).ravel()
        w = np.tile(0.5 * _GL_W / n_pan, n_pan)
        f = _integrand(h, Q, t[..., None] * u)
        return t[..., None, None] * np.einsum("k,...kij->...ij", w, f)
    if method == "quad":

        def integrand(u: float) -> np.ndarray:
            return _integrand(h, Q, (t * u)[..., None])[..., 0, :, :]

        val, _ = quad_vec(integrand, 0.0, 1.0, epsabs=1e-15, epsrel=1e-13, limit=2000)
        return t[..., None, None] * val
    raise ValueError(f"increment_cov: unknown method {method!r} (use 'gauss', 'simpson38', 'quad' or 'closed')")
