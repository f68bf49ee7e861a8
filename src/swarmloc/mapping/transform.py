"""A line seen from a robot, carried into the world frame with the robot's belief (and its uncertainty).

The robot's belief is a Gaussian on SE(2) in exponential coordinates, right perturbation (``swarmloc.gaussian``):
``g = mu exp(xi^)``, ``xi ~ N(0, Sigma)``. A line ``(rho, alpha)`` in the robot frame is the y axis of the frame
``h = (rho cos alpha, rho sin alpha, alpha)`` at its foot point; its own uncertainty is the perturbation
``h exp(eta^)``, ``eta = (d rho, 0, d alpha)`` (first order: sliding along the line changes nothing, so the
tangential entry is 0). The world line is the y axis of ``g h exp(eta^) = mu exp(xi^) h exp(eta^)``, a product of
two independent Gaussians on SE(2): the frame ``f = mu h exp(zeta^)`` has ``zeta`` of covariance

* ``order=1``: ``A + B`` with ``A = Ad(h^-1) Sigma Ad(h^-1)^T``, ``B = cov(eta)``: the usual first-order
  propagation (equal to ``J_pose Sigma J_pose^T + J_line C J_line^T`` on ``(x, y, theta)``, tested);
* ``order=2``: ``A + B + F(A, B)``, the second-order convolution used by the estimators
  (:func:`swarmloc.gaussian.convolve_moments`, thesis eqs. 3.22-3.28). It adds the heading-times-lever-arm terms
  that the first order drops; with a heading std of 0.2-0.3 rad and a lever arm of metres the first order
  underestimates the variance of ``rho`` (see the tests and docs/maps.md).

From ``zeta`` to the world line (first order, exact in ``alpha``): with ``o`` the frame's origin and ``beta`` its
heading, ``rho_w = n(beta + z3) . (o + R_beta (z1, z2)) = rho_0 + z1 + s z3 + O(2)``, ``s = o . t(beta)``,
``alpha_w = beta + z3``; so ``C_w = L cov(zeta) L^T``, ``L = [[sign, 0, sign s], [0, 0, 1]]`` (``sign = -1``
when ``rho_0 < 0`` is flipped to keep ``rho >= 0``).
"""

from __future__ import annotations

import numpy as np

from swarmloc.gaussian import convolve_moments, symmetric
from swarmloc.lie import SE2, wrap_angle

__all__ = ["line_to_world"]


def line_to_world(
    rho: np.ndarray | float,
    alpha: np.ndarray | float,
    cov: np.ndarray,
    pose_mean: np.ndarray,
    pose_cov: np.ndarray,
    order: int = 2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World ``(rho, alpha, cov)`` of robot-frame lines ``(rho, alpha)`` [m, rad] with covariance ``cov``
    ``(..., 2, 2)``, seen from a robot whose belief has mean ``pose_mean`` ``(..., 3, 3)`` (an SE(2) matrix) and
    exponential-coordinate covariance ``pose_cov`` ``(..., 3, 3)`` (right perturbation). Batched; ``order`` 1 or 2
    (module docstring)."""
    if order not in (1, 2):
        raise ValueError(f"line_to_world: order must be 1 or 2, got {order!r}")
    rho = np.asarray(rho, dtype=float)
    alpha = np.asarray(alpha, dtype=float)
    C = np.asarray(cov, dtype=float)
    h = SE2.from_xytheta(rho * np.cos(alpha), rho * np.sin(alpha), alpha)
    B = np.zeros((*C.shape[:-2], 3, 3))
    B[..., 0, 0], B[..., 0, 2], B[..., 2, 0], B[..., 2, 2] = C[..., 0, 0], C[..., 0, 1], C[..., 1, 0], C[..., 1, 1]
    f, Z = convolve_moments(SE2, np.asarray(pose_mean, dtype=float), np.asarray(pose_cov, dtype=float), h, B, order)
    xyt = SE2.to_xytheta(f)
    beta = xyt[..., 2]
    o = xyt[..., :2]
    rho0 = o[..., 0] * np.cos(beta) + o[..., 1] * np.sin(beta)
    s = -o[..., 0] * np.sin(beta) + o[..., 1] * np.cos(beta)
    sign = np.where(rho0 < 0, -1.0, 1.0)
    alpha_w = wrap_angle(np.where(sign < 0, beta + np.pi, beta))
    if order == 1:
        L = np.zeros((*rho0.shape, 2, 3))
        L[..., 0, 0], L[..., 0, 2], L[..., 1, 2] = sign, sign * s, 1.0
        Cw = L @ Z @ np.swapaxes(L, -1, -2)
        return np.abs(rho0), alpha_w, symmetric(Cw)
    # order 2: moments of the exact map zeta -> (rho, alpha) under zeta ~ N(0, Z), by Gauss-Hermite quadrature
    nodes, weights = _quadrature()
    val, vec = np.linalg.eigh(Z)
    root = vec * np.sqrt(np.clip(val, 0.0, None))[..., None, :]  # Z = root root^T (Z may be singular)
    z = np.einsum("...ij,qj->...qi", root, nodes)  # (..., Q, 3)
    z1, z2, z3 = z[..., 0], z[..., 1], z[..., 2]
    r = (rho0[..., None] * np.cos(z3) + s[..., None] * np.sin(z3) + np.sinc(z3 / np.pi) * z1
         + 0.5 * z3 * np.sinc(z3 / (2 * np.pi)) ** 2 * z2) * sign[..., None]  # fmt: skip
    rm = r @ weights
    d = np.stack([r - rm[..., None], z3], axis=-1)  # (..., Q, 2)
    Cw = np.einsum("...qi,q,...qj->...ij", d, weights, d)
    return rm, alpha_w, symmetric(Cw)


_GH: tuple[np.ndarray, np.ndarray] | None = None


def _quadrature(k: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Nodes ``(k^3, 3)`` and weights ``(k^3,)`` of the ``k``-point Gauss-Hermite rule for ``N(0, I_3)``."""
    global _GH
    if _GH is None:
        x, w = np.polynomial.hermite_e.hermegauss(k)
        w = w / w.sum()
        X = np.stack(np.meshgrid(x, x, x, indexing="ij"), -1).reshape(-1, 3)
        W = np.einsum("i,j,k->ijk", w, w, w).ravel()
        _GH = (X, W)
    return _GH
