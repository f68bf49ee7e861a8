"""Planar poses as rows ``(x [m], y [m], theta [rad])``: the SE(2) product, inverse, relative pose, exp and log
without building matrices (batched numpy: any leading shape ``(..., 3)``, broadcast between arguments).

Conventions: a pose ``a`` places frame ``a`` in a parent frame, so a point ``p`` of frame ``a`` is
``R(theta_a) p + (x_a, y_a)`` in the parent. ``compose_xyt(a, b)`` is the product ``a b`` (``b`` given in ``a``'s
frame, the result in ``a``'s parent); ``between_xyt(a, b)`` is ``a^-1 b`` (``b``'s pose in ``a``'s frame, both given
in one frame). Exponential coordinates ``(v_x [m], v_y [m], alpha [rad])`` are those of :class:`~swarmloc.lie.SE2`
(``exp(y) = [[R(alpha), V(alpha) v], [0, 1]]``), computed with the same coefficient functions and Taylor branches:
:func:`exp_xyt` gives ``SE2.exp``'s translation bit for bit. Every returned angle is wrapped to (-pi, pi] by
:func:`~swarmloc.lie.wrap_angle` (``SE2``'s ``to_xytheta``/``log`` take theirs from ``arctan2`` of the matrix, which
can differ from it in the last bit).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from swarmloc.arrays import FloatArray
from swarmloc.lie import _series as S
from swarmloc.lie.se2 import wrap_angle

__all__ = ["between_xyt", "compose_xyt", "exp_xyt", "invert_xyt", "log_xyt"]


def compose_xyt(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """The product ``a b`` of planar poses ``(..., 3)`` (``b`` in ``a``'s frame; broadcast)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    b0, b1 = b[..., 0], b[..., 1]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 0] + c * b0 - s * b1
    out[..., 1] = a[..., 1] + s * b0 + c * b1
    out[..., 2] = wrap_angle(a[..., 2] + b[..., 2])
    return out


def invert_xyt(a: ArrayLike) -> FloatArray:
    """The inverse ``a^-1`` of planar poses ``(..., 3)``: ``(-R^T t, -theta)``."""
    a = np.asarray(a, float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    out = np.empty(a.shape)
    out[..., 0] = -c * a[..., 0] - s * a[..., 1]
    out[..., 1] = s * a[..., 0] - c * a[..., 1]
    out[..., 2] = wrap_angle(-a[..., 2])
    return out


def between_xyt(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """The relative pose ``a^-1 b`` ``(..., 3)``: ``b`` in ``a``'s frame, both given in one frame (broadcast)."""
    return compose_xyt(invert_xyt(a), b)


def log_xyt(q: ArrayLike) -> FloatArray:
    """Exponential coordinates ``(..., 3)`` of planar poses ``(..., 3)``: ``SE2.log`` without the matrices, the angle
    ``alpha`` the pose's own, wrapped to (-pi, pi]."""
    q = np.asarray(q, float)
    a = wrap_angle(q[..., 2])
    k = S.half_cot_half(a)
    h = 0.5 * a
    t1, t2 = q[..., 0], q[..., 1]
    out = np.empty(q.shape)
    out[..., 0] = k * t1 + h * t2
    out[..., 1] = -h * t1 + k * t2
    out[..., 2] = a
    return out


def exp_xyt(y: ArrayLike) -> FloatArray:
    """Planar poses ``(..., 3)`` of exponential coordinates ``(..., 3)``: ``SE2.exp`` without the matrices."""
    y = np.asarray(y, float)
    a = y[..., 2]
    A = S.sinc(a)
    B = S.one_minus_cos_over_t(a)
    out = np.empty(y.shape)
    out[..., 0] = A * y[..., 0] - B * y[..., 1]
    out[..., 1] = B * y[..., 0] + A * y[..., 1]
    out[..., 2] = wrap_angle(a)
    return out
