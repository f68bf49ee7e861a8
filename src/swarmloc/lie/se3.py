"""SE(3): spatial rigid motions, exponential coordinates ``x = (v1, v2, v3, w1, w2, w3)`` (translation first).

``hat(x) = [[w^, v], [0, 0]]``; ``Ad(g) = [[R, t^ R], [0, R]]``; ``ad(x) = [[w^, v^], [0, w^]]``
(the thesis' eq. 3.15 prints a block layout that does not match this ordering).
``Jl(x) = [[J(w), Q(v, w)], [0, J(w)]]`` with ``J`` the SO(3) left Jacobian and ``Q`` the coupling block
(Barfoot, *State Estimation for Robotics*, eq. 7.86); ``Jl^-1 = [[J^-1, -J^-1 Q J^-1], [0, J^-1]]``.
"""

from __future__ import annotations

import numpy as np

from swarmloc.arrays import FloatArray
from swarmloc.lie import _series as S
from swarmloc.lie.base import SEGroup


def skew(w: FloatArray) -> FloatArray:
    """``(..., 3) -> (..., 3, 3)`` cross-product matrix."""
    w = np.asarray(w, dtype=float)
    W = np.zeros((*w.shape[:-1], 3, 3))
    W[..., 0, 1], W[..., 0, 2] = -w[..., 2], w[..., 1]
    W[..., 1, 0], W[..., 1, 2] = w[..., 2], -w[..., 0]
    W[..., 2, 0], W[..., 2, 1] = -w[..., 1], w[..., 0]
    return W


def unskew(W: FloatArray) -> FloatArray:
    """Antisymmetric part of ``(..., 3, 3)`` as a vector."""
    return 0.5 * np.stack([W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]], -1)


def so3_exp(w: FloatArray) -> FloatArray:
    """Rodrigues' formula, batched."""
    th = np.linalg.norm(w, axis=-1)
    W = skew(w)
    return np.eye(3) + S.sinc(th)[..., None, None] * W + S.one_minus_cos_over_t2(th)[..., None, None] * (W @ W)


def so3_log(R: FloatArray) -> FloatArray:
    """Principal log of rotation matrices, accurate near 0 and near pi.

    ``theta = atan2(|vee(R - R^T)|/2, (tr R - 1)/2)``; away from pi the axis comes from the antisymmetric part,
    near pi (cos theta < -0.5) from the symmetric part ``(R + R^T)/2 - cos(theta) I = (1 - cos theta) n n^T``
    with the sign taken from the antisymmetric part.
    """
    R = np.asarray(R, dtype=float)
    axis_s = unskew(R)  # sin(theta) n
    s = np.linalg.norm(axis_s, axis=-1)
    c = np.clip(0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0), -1.0, 1.0)
    th = np.arctan2(s, c)
    w_small = S.t_over_sin(th)[..., None] * axis_s
    # near pi
    B = 0.5 * (R + np.swapaxes(R, -1, -2)) - c[..., None, None] * np.eye(3)
    diag = np.diagonal(B, axis1=-2, axis2=-1)
    k = np.argmax(diag, axis=-1)
    col = np.take_along_axis(B, k[..., None, None], axis=-1)[..., 0]
    denom = np.sqrt(np.maximum(np.take_along_axis(diag, k[..., None], -1)[..., 0] * (1.0 - c), 1e-300))
    n = col / denom[..., None]
    sign = np.where(np.einsum("...i,...i->...", n, axis_s) < 0, -1.0, 1.0)
    w_big = (sign * th)[..., None] * n
    return np.where((c < -0.5)[..., None], w_big, w_small)


def so3_left_jacobian(w: FloatArray) -> FloatArray:
    th = np.linalg.norm(w, axis=-1)
    W = skew(w)
    return (
        np.eye(3)
        + S.one_minus_cos_over_t2(th)[..., None, None] * W
        + S.t_minus_sin_over_t3(th)[..., None, None] * (W @ W)
    )


def so3_left_jacobian_inv(w: FloatArray) -> FloatArray:
    th = np.linalg.norm(w, axis=-1)
    W = skew(w)
    return np.eye(3) - 0.5 * W + S.jinv_coeff(th)[..., None, None] * (W @ W)


def _q_block(v: FloatArray, w: FloatArray) -> FloatArray:
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    P, V = skew(w), skew(v)
    PV, VP = P @ V, V @ P
    PVP = PV @ P
    return (
        0.5 * V
        + S.t_minus_sin_over_t3(th) * (PV + VP + PVP)
        + S.q2_coeff(th) * (P @ PV + VP @ P - 3 * PVP)
        + S.q3_coeff(th) * (PVP @ P + P @ PVP)
    )


def _upper_blocks(D: FloatArray, C: FloatArray) -> FloatArray:
    """``[[D, C], [0, D]]`` from ``(..., 3, 3)`` blocks, ``(..., 6, 6)`` (the layout of ``Ad``, ``ad``, ``Jl``)."""
    out = np.zeros((*np.shape(D)[:-2], 6, 6))
    out[..., :3, :3] = D
    out[..., 3:, 3:] = D
    out[..., :3, 3:] = C
    return out


class SE3(SEGroup):
    """The spatial special Euclidean group (batched numpy functions)."""

    n = 3
    dim = 6
    name = "SE(3)"

    rotation_hat = staticmethod(skew)
    rotation_vee = staticmethod(unskew)

    @classmethod
    def exp(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """Exponential map ``(..., 6) -> (..., 4, 4)``."""
        x = cls._tangent_arg(x, validate, "exp")
        v, w = x[..., :3], x[..., 3:]
        g = np.zeros((*x.shape[:-1], 4, 4))
        g[..., :3, :3] = so3_exp(w)
        g[..., :3, 3] = np.einsum("...ij,...j->...i", so3_left_jacobian(w), v)
        g[..., 3, 3] = 1.0
        return g

    @classmethod
    def log(cls, g: FloatArray, validate: bool = True) -> FloatArray:
        """Principal logarithm ``(..., 4, 4) -> (..., 6)``, rotation angle in [0, pi]."""
        g = cls._element_arg(g, validate, "log")
        w = so3_log(g[..., :3, :3])
        v = np.einsum("...ij,...j->...i", so3_left_jacobian_inv(w), g[..., :3, 3])
        return np.concatenate([v, w], axis=-1)

    @classmethod
    def Ad(cls, g: FloatArray, validate: bool = True) -> FloatArray:
        """``[[R, t^ R], [0, R]]``, shape ``(..., 6, 6)``."""
        g = cls._element_arg(g, validate, "Ad")
        R = g[..., :3, :3]
        return _upper_blocks(R, skew(g[..., :3, 3]) @ R)

    @classmethod
    def ad(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """``[[w^, v^], [0, w^]]``, shape ``(..., 6, 6)``."""
        x = cls._tangent_arg(x, validate, "ad")
        return _upper_blocks(skew(x[..., 3:]), skew(x[..., :3]))

    @classmethod
    def left_jacobian(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """Left Jacobian ``sum_k ad(x)^k / (k+1)!`` in closed form."""
        x = cls._tangent_arg(x, validate, "left_jacobian")
        v, w = x[..., :3], x[..., 3:]
        return _upper_blocks(so3_left_jacobian(w), _q_block(v, w))

    @classmethod
    def left_jacobian_inv(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """Inverse of the left Jacobian."""
        x = cls._tangent_arg(x, validate, "left_jacobian_inv")
        v, w = x[..., :3], x[..., 3:]
        Ji = so3_left_jacobian_inv(w)
        return _upper_blocks(Ji, -Ji @ _q_block(v, w) @ Ji)
