"""SE(2): planar rigid motions, exponential coordinates ``x = (v1, v2, alpha)``.

``hat(x) = [[0, -alpha, v1], [alpha, 0, v2], [0, 0, 0]]``.
``exp(x) = [[R(alpha), V(alpha) v], [0, 1]]`` with ``V = [[sin a / a, -(1 - cos a)/a], [(1 - cos a)/a, sin a / a]]``
(thesis eq. 3.7, whose rotation matrix is printed without its minus sign).
``Ad(g) = [[R, M t], [0, 1]]``, ``ad(x) = [[-alpha M, M v], [0, 0]]`` with ``M = [[0, 1], [-1, 0]]`` (eq. 3.14).
Since ``ad(x)^3 = -alpha^2 ad(x)``, every analytic function of ``ad(x)`` is ``I + c1 ad + c2 ad^2``; this gives
``Jl = I + (1 - cos a)/a^2 ad + (a - sin a)/a^3 ad^2`` and ``Jl^-1 = I - ad/2 + (1 - (a/2) cot(a/2))/a^2 ad^2``.
"""

from __future__ import annotations

import math
from typing import overload

import numpy as np
from numpy.typing import ArrayLike

from swarmloc.arrays import FloatArray
from swarmloc.lie import _series as S
from swarmloc.lie.base import SEGroup

_TAU = 2 * math.pi


@overload
def wrap_angle(a: float) -> float: ...
@overload
def wrap_angle(a: FloatArray) -> FloatArray: ...
def wrap_angle(a: FloatArray | float) -> FloatArray | float:
    """Wrap angles [rad] to (-pi, pi] (the convention of every angle swarmloc returns): ``pi - mod(pi - a, 2 pi)``.

    The one wrapping function of the library (the engine's compiled kernels write the same formula in their
    backend's form). A float (a Python or NumPy scalar) is wrapped with the float ``%``, which gives the bits
    ``np.mod`` gives, 20 times faster, and stays a float; anything else as an array."""
    if isinstance(a, float):
        return math.pi - (math.pi - a) % _TAU
    return np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2 * np.pi)


class SE2(SEGroup):
    """The planar special Euclidean group (batched numpy functions)."""

    n = 2
    dim = 3
    name = "SE(2)"

    @staticmethod
    def rotation_hat(w: FloatArray) -> FloatArray:
        """``(..., 1) -> (..., 2, 2)``: ``[[0, -w], [w, 0]]``."""
        W = np.zeros((*w.shape[:-1], 2, 2))
        W[..., 0, 1] = -w[..., 0]
        W[..., 1, 0] = w[..., 0]
        return W

    @staticmethod
    def rotation_vee(W: FloatArray) -> FloatArray:
        """``(..., 2, 2) -> (..., 1)``: the angle of the antisymmetric part."""
        return 0.5 * (W[..., 1, 0] - W[..., 0, 1])[..., None]

    @classmethod
    def exp(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """Exponential map ``(..., 3) -> (..., 3, 3)`` in closed form."""
        x = cls._tangent_arg(x, validate, "exp")
        if x.ndim == 1:  # one element: the same formulas in floats
            return _exp_one(*x.tolist())
        a = x[..., 2]
        c, s = np.cos(a), np.sin(a)
        A = S.sinc(a)
        B = S.one_minus_cos_over_t(a)
        g = np.zeros((*x.shape[:-1], 3, 3))
        g[..., 0, 0] = c
        g[..., 0, 1] = -s
        g[..., 1, 0] = s
        g[..., 1, 1] = c
        g[..., 0, 2] = A * x[..., 0] - B * x[..., 1]
        g[..., 1, 2] = B * x[..., 0] + A * x[..., 1]
        g[..., 2, 2] = 1.0
        return g

    @classmethod
    def log(cls, g: FloatArray, validate: bool = True) -> FloatArray:
        """Principal logarithm ``(..., 3, 3) -> (..., 3)``, angle in (-pi, pi]."""
        g = cls._element_arg(g, validate, "log")
        if g.ndim == 2:  # one element: the same formulas in floats
            return _log_one(g)
        a = np.arctan2(g[..., 1, 0], g[..., 0, 0])
        a = np.where(a <= -np.pi, a + 2 * np.pi, a)
        k = S.half_cot_half(a)
        h = 0.5 * a
        t1, t2 = g[..., 0, 2], g[..., 1, 2]
        return np.stack([k * t1 + h * t2, -h * t1 + k * t2, a], axis=-1)

    @classmethod
    def inverse(cls, g: FloatArray, validate: bool = True) -> FloatArray:
        """Group inverse ``[[R^T, -R^T t], [0, 1]]`` (exact, batched)."""
        g = cls._element_arg(g, validate, "inverse")
        if g.ndim == 2:
            c, s, tx, ty = g[0, 0], g[1, 0], g[0, 2], g[1, 2]
            r01, r11 = g[0, 1], g[1, 1]
            return np.array([[c, s, -(c * tx + s * ty)], [r01, r11, -(r01 * tx + r11 * ty)], [0.0, 0.0, 1.0]])
        return super().inverse(g, validate=False)

    @classmethod
    def Ad(cls, g: FloatArray, validate: bool = True) -> FloatArray:
        """Adjoint matrix ``[[R, M t], [0, 1]]``, shape ``(..., 3, 3)``."""
        g = cls._element_arg(g, validate, "Ad")
        if g.ndim == 2:
            return np.array([[g[0, 0], g[0, 1], g[1, 2]], [g[1, 0], g[1, 1], -g[0, 2]], [0.0, 0.0, 1.0]])
        A = np.zeros(g.shape)
        A[..., :2, :2] = g[..., :2, :2]
        A[..., 0, 2] = g[..., 1, 2]
        A[..., 1, 2] = -g[..., 0, 2]
        A[..., 2, 2] = 1.0
        return A

    @classmethod
    def ad(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """Small adjoint ``[[-alpha M, M v], [0, 0]]``, shape ``(..., 3, 3)``."""
        x = cls._tangent_arg(x, validate, "ad")
        return cls.hat(np.stack([x[..., 1], -x[..., 0], x[..., 2]], axis=-1), validate=False)  # hat(M v, alpha)

    @classmethod
    def _poly_ad(cls, x: FloatArray, c1: FloatArray, c2: FloatArray) -> FloatArray:
        adx = cls.ad(x, validate=False)
        return np.eye(3) + c1[..., None, None] * adx + c2[..., None, None] * (adx @ adx)

    @classmethod
    def left_jacobian(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """Left Jacobian ``sum_k ad(x)^k / (k+1)!``."""
        x = cls._tangent_arg(x, validate, "left_jacobian")
        a = x[..., 2]
        return cls._poly_ad(x, S.one_minus_cos_over_t2(a), S.t_minus_sin_over_t3(a))

    @classmethod
    def left_jacobian_inv(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """Inverse of the left Jacobian (singular only at ``|alpha| = 2 pi``)."""
        x = cls._tangent_arg(x, validate, "left_jacobian_inv")
        a = x[..., 2]
        return cls._poly_ad(x, np.full(a.shape, -0.5), S.jinv_coeff(a))

    # ----------------------------------------------------------------- planar conveniences
    @staticmethod
    def from_xytheta(x: ArrayLike, y: ArrayLike | None = None, theta: ArrayLike | None = None) -> FloatArray:
        """Pose matrix from ``(x, y, theta)`` (either one array ``(..., 3)`` or three arrays)."""
        if y is None:
            p = np.asarray(x, dtype=float)
            x, y, theta = p[..., 0], p[..., 1], p[..., 2]
        X, Y, T = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float), np.asarray(theta, float))
        g = np.zeros((*X.shape, 3, 3))
        c, s = np.cos(T), np.sin(T)
        g[..., 0, 0], g[..., 0, 1], g[..., 0, 2] = c, -s, X
        g[..., 1, 0], g[..., 1, 1], g[..., 1, 2] = s, c, Y
        g[..., 2, 2] = 1.0
        return g

    @staticmethod
    def rotation(theta: FloatArray) -> FloatArray:
        """``(...) -> (..., 2, 2)``: the rotation ``R(theta) = [[cos, -sin], [sin, cos]]`` of a heading [rad]."""
        c, s = np.cos(theta), np.sin(theta)
        return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)

    @staticmethod
    def to_xytheta(g: FloatArray) -> FloatArray:
        """``(..., 3, 3) -> (..., 3)`` Cartesian ``(x, y, theta)``, theta in (-pi, pi]."""
        g = np.asarray(g, dtype=float)
        th = np.arctan2(g[..., 1, 0], g[..., 0, 0])
        th = np.where(th <= -np.pi, th + 2 * np.pi, th)
        return np.stack([g[..., 0, 2], g[..., 1, 2], th], axis=-1)


def _exp_one(x0: float, x1: float, a: float) -> FloatArray:
    """:meth:`SE2.exp` of one tangent vector ``(x0, x1, a)``, in floats."""
    c, s = math.cos(a), math.sin(a)
    A, B = S.sinc_scalar(a), S.one_minus_cos_over_t_scalar(a)
    return np.array([[c, -s, A * x0 - B * x1], [s, c, B * x0 + A * x1], [0.0, 0.0, 1.0]])


def _log_one(g: FloatArray) -> FloatArray:
    """:meth:`SE2.log` of one element ``(3, 3)``, in floats."""
    a = math.atan2(g[1, 0], g[0, 0])
    a = a + 2 * math.pi if a <= -math.pi else a
    k, h = S.half_cot_half_scalar(a), 0.5 * a
    t1, t2 = g[0, 2], g[1, 2]
    return np.array([k * t1 + h * t2, -h * t1 + k * t2, a])
