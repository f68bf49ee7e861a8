r"""Closed forms of the increment mean (5.3) and covariance (5.4) for a constant body twist.

Notation: twist ``h = (v, 0, omega)`` (forward speed [m/s], yaw rate [rad/s]), duration ``t`` [s], diagonal
diffusion per second ``Q = diag(q_v, q_lat, q_w)`` (``q_lat = 0`` for a differential drive, whose
``Q = H H^T = D diag(r^2/2, 0, 2 r^2/l^2)``), turn angle ``theta = omega t``, radius ``a = v/omega``.

With ``c = cos(omega tau)``, ``s = sin(omega tau)``:
``Ad(mu(tau)^-1) = [[c, s, a (1 - c)], [-s, c, a s], [0, 0, 1]]``, and integrating ``Ad Q Ad^T`` over ``[0, t]``:

Straight line (``omega = 0``, thesis 5.5, 5.6, which is right)::

    mu    = [[1, 0, v t], [0, 1, 0], [0, 0, 1]]
    Sigma = [[q_v t, 0, 0], [0, q_lat t + q_w v^2 t^3/3, q_w v t^2/2], [0, q_w v t^2/2, q_w t]]

Circular arc (``omega != 0``, thesis 5.7 for the mean; corrected 5.9 for the covariance)::

    S11 = q_v (t/2 + sin 2theta/(4 omega)) + q_lat (t/2 - sin 2theta/(4 omega))
          + q_w a^2 (3t/2 - 2 sin theta/omega + sin 2theta/(4 omega))
    S12 = (q_lat - q_v) sin^2 theta/(2 omega) + q_w a^2 (1 - cos theta)^2/(2 omega)
    S13 = q_w a (t - sin theta/omega)
    S22 = q_v (t/2 - sin 2theta/(4 omega)) + q_lat (t/2 + sin 2theta/(4 omega))
          + q_w a^2 (t/2 - sin 2theta/(4 omega))
    S23 = q_w a (1 - cos theta)/omega
    S33 = q_w t

In the thesis' notation (differential drive, ``q_v = D r^2/2``, ``q_lat = 0``, ``q_w = 2 D r^2/l^2``,
``c = D r^2/(l^2 alpha_dot)``, ``theta = alpha_dot t``) the corrected eq. (5.9) reads::

    sigma_11 = c/8 [(4a^2 + l^2)(2 theta + sin 2theta) + 16 a^2 (theta - 2 sin theta)]    (printed: sin 2theta)
    sigma_12 = -c/2 [4a^2 (cos theta - 1) + l^2 (1 + cos theta)] sin^2(theta/2)
                                                          (printed: 4a^2(-1 + cos 2theta) + l^2)
    sigma_13 = 2 c a (theta - sin theta)                                                   (printed: sin 2theta)
    sigma_22 = c/8 (4a^2 + l^2)(2 theta - sin 2theta)                                      (missing in print)
    sigma_23 = 2 c a (1 - cos theta)                                                       (as printed)
    sigma_33 = 2 c theta = q_w t                                                           (printed: 2 c alpha_dot)

(derived with sympy and checked against quadrature of (5.4) to 1e-13 in ``tests/test_motion.py``).

:func:`constant_twist_cov` is the general, cancellation-free form for any twist ``(v1, v2, omega)`` and any
symmetric ``Q``: ``Ad(mu(tau)^-1) = sum_i phi_i(tau) E_i`` with ``phi = (1, c, s, s/omega, (1 - c)/omega)``, so
``Sigma = sum_ij G_ij E_i Q E_j^T`` with the Gram matrix ``G_ij = int phi_i phi_j`` of
:func:`swarmloc.motion._stable.gram` (Taylor branches for ``|omega t| < 1``; reduces continuously to the straight
line at ``omega = 0``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from swarmloc.lie import SE2
from swarmloc.motion import _stable
from swarmloc.motion._stable import horner

T = Any
"""A float or an array (numpy or jax.numpy) of them."""

Floats = np.ndarray | float
"""A float or a numpy array of them; a function's arguments broadcast together."""


def _arr(*xs: object) -> list[np.ndarray]:
    return list(np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in xs)))


def _sym(*entries: np.ndarray) -> np.ndarray:
    """Symmetric 3x3 from the upper triangle ``(S11, S12, S13, S22, S23, S33)``."""
    S11, S12, S13, S22, S23, S33 = _arr(*entries)
    row0 = np.stack([S11, S12, S13], axis=-1)
    row1 = np.stack([S12, S22, S23], axis=-1)
    row2 = np.stack([S13, S23, S33], axis=-1)
    return np.stack([row0, row1, row2], axis=-2)


# ------------------------------------------------------------------ straight line (5.5, 5.6)
def straight_line_mean(v: Floats, t: Floats) -> np.ndarray:
    """Eq. (5.5): ``[[1, 0, v t], [0, 1, 0], [0, 0, 1]]``, ``(..., 3, 3)``."""
    v, t = _arr(v, t)
    g = np.zeros((*v.shape, 3, 3))
    g[..., 0, 0] = g[..., 1, 1] = g[..., 2, 2] = 1.0
    g[..., 0, 2] = v * t
    return g


def straight_line_cov(v: Floats, t: Floats, q_v: Floats, q_w: Floats, q_lat: Floats = 0.0) -> np.ndarray:
    """Eq. (5.6) generalized: covariance of a straight run at speed ``v`` for ``t`` s, ``Q = diag(q_v, q_lat, q_w)``."""
    v, t, q_v, q_w, q_lat = _arr(v, t, q_v, q_w, q_lat)
    z = np.zeros(v.shape)
    return _sym(q_v * t, z, z, q_lat * t + q_w * v * v * t**3 / 3, q_w * v * t * t / 2, q_w * t)


def thesis_straight_cov(D: float, r: float, l: float, w: Floats, t: Floats) -> np.ndarray:
    """Eq. (5.6) in the thesis' notation: both wheels at ``w`` [rad/s] (``v = r w``)."""
    w = np.asarray(w, dtype=float)
    return straight_line_cov(r * w, t, D * r * r / 2, 2 * D * r * r / (l * l))


# ------------------------------------------------------------------ circular arc (5.7, 5.8, corrected 5.9)
def circular_mean(v: Floats, omega: Floats, t: Floats) -> np.ndarray:
    """Eq. (5.7): arc of radius ``a = v/omega`` turned by ``theta = omega t`` (``omega != 0``), ``(..., 3, 3)``."""
    v, omega, t = _arr(v, omega, t)
    th = omega * t
    a = v / omega
    c, s = np.cos(th), np.sin(th)
    g = np.zeros((*th.shape, 3, 3))
    g[..., 0, 0], g[..., 0, 1], g[..., 0, 2] = c, -s, a * s
    g[..., 1, 0], g[..., 1, 1], g[..., 1, 2] = s, c, a * (1 - c)
    g[..., 2, 2] = 1.0
    return g


def circular_cov(v: Floats, omega: Floats, t: Floats, q_v: Floats, q_w: Floats, q_lat: Floats = 0.0) -> np.ndarray:
    """Corrected eq. (5.9) for twist ``(v, 0, omega)``, ``omega != 0``, ``Q = diag(q_v, q_lat, q_w)`` (module doc).

    Direct trigonometric form: loses accuracy to cancellation as ``omega t -> 0``; use
    :func:`constant_twist_cov` (or :func:`unicycle_cov`) where ``omega`` may be small.
    """
    v, omega, t, q_v, q_w, q_lat = _arr(v, omega, t, q_v, q_w, q_lat)
    th = omega * t
    a = v / omega
    s1, c1, s2 = np.sin(th), np.cos(th), np.sin(2 * th)
    Ip = t / 2 + s2 / (4 * omega)  # int cos^2
    Im = t / 2 - s2 / (4 * omega)  # int sin^2
    S11 = q_v * Ip + q_lat * Im + q_w * a * a * (1.5 * t - 2 * s1 / omega + s2 / (4 * omega))
    S12 = (q_lat - q_v) * s1 * s1 / (2 * omega) + q_w * a * a * (1 - c1) ** 2 / (2 * omega)
    S13 = q_w * a * (t - s1 / omega)
    S22 = q_v * Im + q_lat * Ip + q_w * a * a * Im
    S23 = q_w * a * (1 - c1) / omega
    S33 = q_w * t
    return _sym(S11, S12, S13, S22, S23, S33)


def thesis_circular_cov(D: float, r: float, l: float, a: Floats, alpha_dot: Floats, t: Floats) -> np.ndarray:
    """Corrected eq. (5.9) written exactly in the thesis' notation (radius ``a``, yaw rate ``alpha_dot``)."""
    a, ad, t = _arr(a, alpha_dot, t)
    c = D * r * r / (l * l * ad)
    th = ad * t
    s11 = c / 8 * ((4 * a * a + l * l) * (2 * th + np.sin(2 * th)) + 16 * a * a * (th - 2 * np.sin(th)))
    s12 = -c / 2 * (4 * a * a * (np.cos(th) - 1) + l * l * (1 + np.cos(th))) * np.sin(th / 2) ** 2
    s13 = 2 * c * a * (th - np.sin(th))
    s22 = c / 8 * (4 * a * a + l * l) * (2 * th - np.sin(2 * th))
    s23 = 2 * c * a * (1 - np.cos(th))
    s33 = 2 * c * th
    return _sym(s11, s12, s13, s22, s23, s33)


# ------------------------------------------------------------------ general constant twist
_E_FIXED = np.zeros((3, 3, 3))
_E_FIXED[0, 2, 2] = 1.0  # E_0: the constant part (bottom-right 1)
_E_FIXED[1, 0, 0] = _E_FIXED[1, 1, 1] = 1.0  # E_c
_E_FIXED[2, 0, 1], _E_FIXED[2, 1, 0] = 1.0, -1.0  # E_s


def constant_twist_cov(h: np.ndarray, Q: np.ndarray, t: Floats) -> np.ndarray:
    """Exact (5.4) for any constant twist ``h = (v1, v2, omega)`` ``(..., 3)``, symmetric ``Q`` ``(..., 3, 3)``.

    Stable for all ``omega`` including 0 (see module doc). Returns ``(..., 3, 3)``.
    """
    h = np.asarray(h, dtype=float)
    Q = np.asarray(Q, dtype=float)
    t = np.asarray(t, dtype=float)
    shape = np.broadcast_shapes(h.shape[:-1], Q.shape[:-2], t.shape)
    h = np.broadcast_to(h, (*shape, 3))
    Q = np.broadcast_to(Q, (*shape, 3, 3))
    t = np.broadcast_to(t, shape)
    v1, v2 = h[..., 0], h[..., 1]
    E = np.zeros((*shape, 5, 3, 3))
    E[..., :3, :, :] = _E_FIXED
    E[..., 3, 0, 2], E[..., 3, 1, 2] = -v2, v1  # E_S: coefficient of sin(w tau)/w
    E[..., 4, 0, 2], E[..., 4, 1, 2] = v1, v2  # E_C: coefficient of (1 - cos(w tau))/w
    G = _stable.gram(h[..., 2] * t, t)
    EQ = E @ Q[..., None, :, :]
    return np.einsum("...ij,...iab,...jcb->...ac", G, EQ, E)


def unicycle_cov(v: Floats, omega: Floats, t: Floats, q_v: Floats, q_w: Floats, q_lat: Floats = 0.0) -> np.ndarray:
    """(5.4) for twist ``(v, 0, omega)`` and ``Q = diag(q_v, q_lat, q_w)``, stable for all ``omega`` (batched).

    Same as :func:`circular_cov` (and :func:`straight_line_cov` at ``omega = 0``) but cancellation-free: the entries
    of :func:`unicycle_terms` with the series terms of :func:`series_terms`.
    """
    v, omega, t, q_v, q_w, q_lat = _arr(v, omega, t, q_v, q_w, q_lat)
    x = omega * t
    _, *terms = series_terms(np, x)
    return _sym(*unicycle_terms(x, t, v, q_v, q_w, q_lat, *terms)[2:])


def series_terms(xp: Any, x: T) -> tuple[T, ...]:
    """``(sin x, s2, A, B, E, s1, h2, h4)`` for ``x = omega t``: the sine and the series terms :func:`unicycle_terms`
    takes (:func:`swarmloc.motion._stable.scalar_terms`' for arrays) on the array namespace ``xp`` (numpy, jax.numpy
    or the engine's traced scalars): the Taylor branch below ``SERIES_BELOW`` with all its terms, each selected by
    ``xp.where`` from both branches computed at a safe argument."""
    near = xp.abs(x) < _stable.SERIES_BELOW
    zero = x == 0.0
    x2 = x * x
    safe = xp.where(near, 1.0, x)
    s3 = safe * safe * safe
    A = xp.where(near, horner(_stable.SERIES["A"], x2), (2 * safe - xp.sin(2 * safe)) / (4 * s3))
    B = xp.where(near, horner(_stable.SERIES["B"], x2), (safe - xp.sin(safe)) / s3)
    E = xp.where(near, horner(_stable.SERIES["E"], x2),
                 (1.5 * safe - 2 * xp.sin(safe) + xp.sin(2 * safe) / 4) / (s3 * safe * safe))  # fmt: skip
    nz = xp.where(zero, 1.0, x)
    sin_x = xp.sin(x)  # also sin(nz) where it is used (nz == x there): one sine, not two
    s2 = xp.where(zero, 1.0, xp.sin(2 * nz) / (2 * nz))
    s1 = xp.where(zero, 1.0, sin_x / nz)
    h = xp.where(zero, 1.0, xp.sin(nz / 2) / (nz / 2))
    h2 = h * h
    return sin_x, s2, A, B, E, s1, h2, h2 * h2


def unicycle_increment_terms(
    v: float, omega: float, t: float, q_v: float, q_w: float, q_lat: float = 0.0
) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """Scalar fast path in floats: ``(cos, sin, tx, ty, S11, S12, S13, S22, S23, S33)``: the increment
    ``exp(t (v, 0, omega)) = [[cos, -sin, tx], [sin, cos, ty], [0, 0, 1]]`` and the upper triangle of its
    covariance (5.4), as :func:`unicycle_cov` (pure-Python arithmetic)."""
    x = omega * t
    return (math.cos(x), math.sin(x), *unicycle_terms(x, t, v, q_v, q_w, q_lat, *_stable.scalar_terms(x)))


def unicycle_terms(
    x: T, t: T, v: T, q_v: T, q_w: T, q_lat: T, s2: T, A: T, B: T, E: T, s1: T, h2: T, h4: T
) -> tuple[T, T, T, T, T, T, T, T]:
    """``(tx, ty, S11, S12, S13, S22, S23, S33)`` of :func:`unicycle_increment_terms` from ``x = omega t`` and its
    series terms ``(s2, A, B, E, s1, h2, h4)`` (:func:`swarmloc.motion._stable.scalar_terms`), written with
    arithmetic operators only: floats, or numpy / jax.numpy arrays (the batched engine's kernels)."""
    t2 = t * t
    t3 = t2 * t
    vv = v * v
    Gcc = t * (1 + s2) / 2
    Gss = t * x * x * A
    Gcs = t * x * s1 * s1 / 2
    qwvv = q_w * vv
    S11 = q_v * Gcc + q_lat * Gss + qwvv * t3 * x * x * E
    S12 = (q_lat - q_v) * Gcs + qwvv * t3 * x * h4 / 8
    S13 = q_w * v * t2 * x * B
    S22 = q_v * Gss + q_lat * Gcc + qwvv * t3 * A
    S23 = q_w * v * t2 * h2 / 2
    S33 = q_w * t
    vt = v * t
    return vt * s1, vt * x * h2 / 2, S11, S12, S13, S22, S23, S33


def unicycle_increment_scalar(
    v: float, omega: float, t: float, q_v: float, q_w: float, q_lat: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Scalar fast path: ``(exp(t (v, 0, omega)), Sigma)`` as two ``(3, 3)`` arrays, pure-Python arithmetic."""
    cx, sx, tx, ty, S11, S12, S13, S22, S23, S33 = unicycle_increment_terms(v, omega, t, q_v, q_w, q_lat)
    mean = np.array([[cx, -sx, tx], [sx, cx, ty], [0.0, 0.0, 1.0]])
    cov = np.array([[S11, S12, S13], [S12, S22, S23], [S13, S23, S33]])
    return mean, cov


def increment_mean_closed(v: Floats, omega: Floats, t: Floats) -> np.ndarray:
    """``exp(t (v, 0, omega))``: (5.5) for ``omega = 0``, (5.7) otherwise, stable in between."""
    v, omega, t = _arr(v, omega, t)
    return SE2.exp(np.stack([v * t, np.zeros(v.shape), omega * t], axis=-1), validate=False)
