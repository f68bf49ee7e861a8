"""Scalar coefficient functions of the angle with Taylor branches near zero.

Each function takes an array of angles ``theta`` (any shape) and returns the coefficient elementwise. Below
``small`` the Taylor polynomial is used, where the closed form loses digits to cancellation.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from swarmloc.arrays import FloatArray

_SMALL = 0.05


def _branch(
    theta: FloatArray, exact: Callable[[FloatArray], FloatArray], taylor: Sequence[float], small: float
) -> FloatArray:
    theta = np.asarray(theta, dtype=float)
    near = np.abs(theta) < small
    safe = np.where(near, 1.0, theta)
    t2 = theta * theta
    poly = np.zeros_like(theta)
    for c in reversed(taylor):  # Horner in theta^2
        poly = poly * t2 + c
    return np.where(near, poly, exact(safe))


def sinc(theta: FloatArray) -> FloatArray:
    """sin(t)/t."""
    return _branch(theta, lambda t: np.sin(t) / t, [1.0, -1 / 6, 1 / 120, -1 / 5040, 1 / 362880], _SMALL)


def one_minus_cos_over_t(theta: FloatArray) -> FloatArray:
    """(1 - cos t)/t, odd in t."""
    return theta * one_minus_cos_over_t2(theta)


def one_minus_cos_over_t2(theta: FloatArray) -> FloatArray:
    """(1 - cos t)/t^2 = 2 sin^2(t/2)/t^2."""
    return _branch(
        theta,
        lambda t: 2.0 * np.sin(t / 2) ** 2 / (t * t),
        [1 / 2, -1 / 24, 1 / 720, -1 / 40320, 1 / 3628800],
        _SMALL,
    )


def t_minus_sin_over_t3(theta: FloatArray) -> FloatArray:
    """(t - sin t)/t^3."""
    return _branch(
        theta,
        lambda t: (t - np.sin(t)) / t**3,
        [1 / 6, -1 / 120, 1 / 5040, -1 / 362880, 1 / 39916800],
        _SMALL,
    )


def half_cot_half(theta: FloatArray) -> FloatArray:
    """(t/2) cot(t/2), which is 0 at t = pi and singular at t = 2 pi."""
    return _branch(
        theta,
        lambda t: (t / 2) / np.tan(t / 2),
        [1.0, -1 / 12, -1 / 720, -1 / 30240, -1 / 1209600],
        _SMALL,
    )


def jinv_coeff(theta: FloatArray) -> FloatArray:
    """(1 - (t/2) cot(t/2))/t^2, the quadratic coefficient of the inverse Jacobians."""
    return _branch(
        theta,
        lambda t: (1.0 - (t / 2) / np.tan(t / 2)) / (t * t),
        [1 / 12, 1 / 720, 1 / 30240, 1 / 1209600, 1 / 47900160],
        _SMALL,
    )


def t_over_sin(theta: FloatArray) -> FloatArray:
    """t / sin t."""
    return _branch(theta, lambda t: t / np.sin(t), [1.0, 1 / 6, 7 / 360, 31 / 15120, 127 / 604800], _SMALL)


def q2_coeff(theta: FloatArray) -> FloatArray:
    """(t^2 + 2 cos t - 2)/(2 t^4), from the SE(3) left-Jacobian block Q."""
    return _branch(
        theta,
        lambda t: (t * t + 2 * np.cos(t) - 2) / (2 * t**4),
        [1 / 24, -1 / 720, 1 / 40320, -1 / 3628800],
        0.1,
    )


def q3_coeff(theta: FloatArray) -> FloatArray:
    """(2 t - 3 sin t + t cos t)/(2 t^5), from the SE(3) left-Jacobian block Q."""
    return _branch(
        theta,
        lambda t: (2 * t - 3 * np.sin(t) + t * np.cos(t)) / (2 * t**5),
        [1 / 120, -1 / 2520, 1 / 120960, -1 / 9979200],
        0.1,
    )


# ------------------------------------------------------------------------------------------------ scalar fast paths
# The same branches and coefficients for one Python float (used by SE2 on unbatched input).
_SINC = (1.0, -1 / 6, 1 / 120, -1 / 5040, 1 / 362880)
_OMC2 = (1 / 2, -1 / 24, 1 / 720, -1 / 40320, 1 / 3628800)
_HCH = (1.0, -1 / 12, -1 / 720, -1 / 30240, -1 / 1209600)


def _poly(coeffs: Sequence[float], t2: float) -> float:
    acc = 0.0
    for c in reversed(coeffs):
        acc = acc * t2 + c
    return acc


def sinc_scalar(t: float) -> float:
    """:func:`sinc` of one float."""
    return _poly(_SINC, t * t) if abs(t) < _SMALL else math.sin(t) / t


def one_minus_cos_over_t_scalar(t: float) -> float:
    """:func:`one_minus_cos_over_t` of one float."""
    if abs(t) < _SMALL:
        return t * _poly(_OMC2, t * t)
    return t * (2.0 * math.sin(t / 2) ** 2 / (t * t))


def half_cot_half_scalar(t: float) -> float:
    """:func:`half_cot_half` of one float."""
    return _poly(_HCH, t * t) if abs(t) < _SMALL else (t / 2) / math.tan(t / 2)
