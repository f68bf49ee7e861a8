"""Cancellation-free scalar functions of the turn angle ``x = omega t`` used by the closed-form covariances.

The closed-form increment covariance (see :mod:`swarmloc.motion.closed_form`) needs the Gram integrals
``int_0^t phi_i(tau) phi_j(tau) dtau`` of ``phi = (1, cos(w tau), sin(w tau), sin(w tau)/w, (1 - cos(w tau))/w)``.
Each is ``t^k`` times a dimensionless function of ``x = w t``. Four of them cancel catastrophically for small
``x`` and get a Taylor branch (even power series in ``x``, coefficients exact rationals computed here from the
series of ``sin``):

* ``A(x) = (2x - sin 2x) / (4 x^3)``                     ``A(0) = 1/3``
* ``B(x) = (x - sin x) / x^3``                            ``B(0) = 1/6``
* ``C(x) = (sin x - x/2 - sin(2x)/4) / x^3``             ``C(0) = 1/6``
* ``E(x) = (3x/2 - 2 sin x + sin(2x)/4) / x^5``          ``E(0) = 1/20``

The others are written with ``sinc`` so that they never cancel (``1 - cos x = 2 sin^2(x/2)``,
``1 - cos x - sin^2(x)/2 = 2 sin^4(x/2)``). Below ``|x| < SERIES_BELOW`` the series (``N_TERMS`` terms, truncation
error < 1e-17 there) is used; above it the exact forms lose at most ~1e-14 relative to cancellation.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from fractions import Fraction
from typing import Any

import numpy as np

SERIES_BELOW = 1.0
N_TERMS = 13


def _coeffs(term: Callable[[int], Fraction], n0: int) -> tuple[float, ...]:
    """Coefficients of ``x^(2k)``, k = 0..N_TERMS-1, with ``term(n)`` the coefficient for summation index n0 + k."""
    return tuple(float(term(n0 + k)) for k in range(N_TERMS))


# A: 2x - sin 2x = sum_{n>=1} (-1)^(n+1) (2x)^(2n+1)/(2n+1)!  ->  / 4x^3
_A = _coeffs(lambda n: Fraction((-1) ** (n + 1) * 2 ** (2 * n + 1), 4 * math.factorial(2 * n + 1)), 1)
# B: x - sin x = sum_{n>=1} (-1)^(n+1) x^(2n+1)/(2n+1)!  ->  / x^3
_B = _coeffs(lambda n: Fraction((-1) ** (n + 1), math.factorial(2 * n + 1)), 1)
# C: sin x - x/2 - sin(2x)/4 = sum_{n>=1} (-1)^n (1 - 2^(2n-1)) x^(2n+1)/(2n+1)!  ->  / x^3
_C = _coeffs(lambda n: Fraction((-1) ** n * (1 - 2 ** (2 * n - 1)), math.factorial(2 * n + 1)), 1)
# E: 3x/2 - 2 sin x + sin(2x)/4 = sum_{n>=2} (-1)^n (2^(2n-1) - 2) x^(2n+1)/(2n+1)!  ->  / x^5
_E = _coeffs(lambda n: Fraction((-1) ** n * (2 ** (2 * n - 1) - 2), math.factorial(2 * n + 1)), 2)

SERIES = {"A": _A, "B": _B, "C": _C, "E": _E}


def _exact_A(x: np.ndarray) -> np.ndarray:
    return (2 * x - np.sin(2 * x)) / (4 * x**3)


def _exact_B(x: np.ndarray) -> np.ndarray:
    return (x - np.sin(x)) / x**3


def _exact_C(x: np.ndarray) -> np.ndarray:
    return (np.sin(x) - x / 2 - np.sin(2 * x) / 4) / x**3


def _exact_E(x: np.ndarray) -> np.ndarray:
    return (1.5 * x - 2 * np.sin(x) + np.sin(2 * x) / 4) / x**5


_EXACT = {"A": _exact_A, "B": _exact_B, "C": _exact_C, "E": _exact_E}


def series_fn(name: str, x: np.ndarray) -> np.ndarray:
    """Evaluate one of ``A, B, C, E`` elementwise on an array (Taylor branch below ``SERIES_BELOW``)."""
    x = np.asarray(x, dtype=float)
    near = np.abs(x) < SERIES_BELOW
    x2 = x * x
    poly = np.zeros_like(x)
    for c in reversed(SERIES[name]):
        poly = poly * x2 + c
    safe = np.where(near, 1.0, x)
    return np.where(near, poly, _EXACT[name](safe))


def sinc(x: np.ndarray) -> np.ndarray:
    """Unnormalized ``sin(x)/x`` (numpy's ``sinc`` is ``sin(pi x)/(pi x)``; this is exact at 0)."""
    return np.sinc(np.asarray(x, dtype=float) / np.pi)


def gram(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Gram matrix ``G_ij = int_0^t phi_i phi_j dtau``, shape ``(..., 5, 5)``, for ``x = omega t``.

    ``phi = (1, cos(w tau), sin(w tau), sin(w tau)/w, (1 - cos(w tau))/w)``; as ``w -> 0`` the last two tend to
    ``(tau, 0)`` and the formulas stay exact (no division by ``w``).
    """
    x, t = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(t, dtype=float))
    A = series_fn("A", x)
    B = series_fn("B", x)
    C = series_fn("C", x)
    E = series_fn("E", x)
    s1 = sinc(x)
    s2 = sinc(2 * x)
    h = sinc(x / 2)
    h2 = h * h
    h4 = h2 * h2
    t2 = t * t
    t3 = t2 * t
    G = np.empty((*x.shape, 5, 5))
    entries = {
        (0, 0): t,
        (0, 1): t * s1,
        (0, 2): t * x * h2 / 2,
        (0, 3): t2 * h2 / 2,
        (0, 4): t2 * x * B,
        (1, 1): t * (1 + s2) / 2,
        (1, 2): t * x * s1 * s1 / 2,
        (1, 3): t2 * s1 * s1 / 2,
        (1, 4): t2 * x * C,
        (2, 2): t * x * x * A,
        (2, 3): t2 * x * A,
        (2, 4): t2 * x * x * h4 / 8,
        (3, 3): t3 * A,
        (3, 4): t3 * x * h4 / 8,
        (4, 4): t3 * x * x * E,
    }
    for (i, j), val in entries.items():
        G[..., i, j] = val
        G[..., j, i] = val
    return G


def horner(coeffs: tuple[float, ...], x2: Any) -> Any:
    """``sum_k coeffs[k] x2^k`` by Horner's rule, in plain arithmetic (a float, or an array of any namespace)."""
    acc: Any = 0.0
    for c in reversed(coeffs):
        acc = acc * x2 + c
    return acc


def _truncations() -> tuple[tuple[float, int], ...]:
    """``(max |x|, terms)`` pairs: below ``max |x|`` the first ``terms`` coefficients of every series reach the full
    series to a relative 1e-18 (the first omitted term bounds the error: the series alternate and decrease)."""
    out = []
    for n in (3, 4, 5, 6, 8, 10):
        lim = min((1e-18 * abs(c[0]) / abs(c[n])) ** (1 / (2 * n)) for c in SERIES.values())
        out.append((lim, n))
    return tuple(out)


_TRUNC = _truncations()


def _terms(x2: float) -> int:
    ax = math.sqrt(x2)
    for lim, n in _TRUNC:
        if ax < lim:
            return n
    return N_TERMS


def scalar_terms(x: float) -> tuple[float, float, float, float, float, float, float]:
    """Scalar fast path: ``(s2, A, B, E, s1, h2, h4)`` for a Python float ``x`` (see :func:`gram`).

    The series are cut after as many terms as ``|x|`` needs for full double precision (:func:`_truncations`).
    """
    if abs(x) < SERIES_BELOW:
        x2 = x * x
        n = _terms(x2)
        A = horner(_A[:n], x2)
        B = horner(_B[:n], x2)
        E = horner(_E[:n], x2)
        if x == 0.0:
            return 1.0, A, B, E, 1.0, 1.0, 1.0
        sx, s2x = math.sin(x), math.sin(2 * x)
    else:
        sx, s2x = math.sin(x), math.sin(2 * x)
        x3 = x * x * x
        A = (2 * x - s2x) / (4 * x3)
        B = (x - sx) / x3
        E = (1.5 * x - 2 * sx + s2x / 4) / (x3 * x * x)
    h = math.sin(x / 2) / (x / 2)
    h2 = h * h
    return s2x / (2 * x), A, B, E, sx / x, h2, h2 * h2
