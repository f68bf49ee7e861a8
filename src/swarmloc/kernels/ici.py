"""Inverse covariance intersection (Noack, Sijs, Reinhardt & Hanebeck, "Decentralized data fusion with inverse
covariance intersection", Automatica 79, 2017) of a belief with a Gaussian observation of the same pose.

Covariance intersection bounds the fused error whatever the correlation of the two estimates. In a team the
correlation has one origin, information both already hold (earlier exchanges and the detections they fused); for
that case ICI gives a bound that is still consistent and at least as tight: with the belief ``N(a, P)``, the
observation ``N(b, B)`` and a weight ``w`` in ``(0, 1)``, the unknown common information is bounded by
``Gamma = w P + (1 - w) B``, counted once, and

    ``Y = P^-1 + B^-1 - Gamma^-1``,   ``x = Y^-1 ((P^-1 - w Gamma^-1) a + (B^-1 - (1 - w) Gamma^-1) b)``.

(``Gamma^-1 <= w P^-1 + (1 - w) B^-1``, the inverse being matrix convex, so ``Y`` holds at least CI's information
with the weight ``1 - w`` on the belief.) ``w`` minimizes ``log det Y^-1`` (grid and parabola, as
:mod:`swarmloc.kernels.ci`). On the group the fusion is linearized at the belief's mean ``mu`` (right perturbation,
``a = 0``): an observation ``g ~ nu exp(N(0, W))`` is ``b = log(mu^-1 nu)`` with ``B = Jr(b)^-1 W Jr(b)^-T``; the
result is ``(mu exp(x), Y^-1)``.
"""

from __future__ import annotations

import numpy as np

from swarmloc.arrays import FloatArray
from swarmloc.gaussian import symmetric
from swarmloc.kernels.ci import W_BOUNDS, minimize_on_grid
from swarmloc.lie.base import SEGroup


def _information(Y0: FloatArray, P: FloatArray, B: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """ICI's fused information ``Y (..., d, d)`` and ``Gamma^-1`` for weights ``w (...)`` (broadcast over the
    leading axes of ``P`` and ``B``), given the information of both as if independent, ``Y0 = P^-1 + B^-1``."""
    wc = np.asarray(w, dtype=float)[..., None, None]
    Gi: FloatArray = np.asarray(np.linalg.inv(wc * P + (1.0 - wc) * B), dtype=float)
    Y: FloatArray = np.asarray(Y0 - Gi, dtype=float)
    return Y, Gi


def inverse_ci(
    group: type[SEGroup], mu: FloatArray, P: FloatArray, nu: FloatArray, W: FloatArray
) -> tuple[FloatArray, FloatArray, float]:
    """A belief ``(mu, P)`` (group element, exponential-coordinate covariance) fused with an observation ``g ~ nu
    exp(N(0, W))`` of the same pose by inverse covariance intersection (module docstring): the fused mean and
    covariance and the weight ``w`` of the belief."""
    b = group.log(group.inverse(mu, validate=False) @ nu, validate=False)
    Ji = group.right_jacobian_inv(b, validate=False)
    B = Ji @ W @ Ji.T
    B = symmetric(B)
    Bi = np.linalg.inv(B)
    Y0 = np.linalg.inv(P) + Bi  # once, not at each of the weight search's evaluations

    def cost(w: FloatArray) -> FloatArray:
        sign, logdet = np.linalg.slogdet(_information(Y0, P, B, w)[0])
        out: FloatArray = np.where(sign > 0, -logdet, np.inf)
        return out

    w = float(minimize_on_grid(cost, (), W_BOUNDS))
    Y, Gi = _information(Y0, P, B, np.array(w))
    cov = np.linalg.inv(Y)
    x = cov @ ((Bi - (1.0 - w) * Gi) @ b)
    return mu @ group.exp(x, validate=False), symmetric(cov), w
