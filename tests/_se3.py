"""Helpers of the SE(3) Jacobian tests: the Cartesian pose perturbation and central finite differences."""

from __future__ import annotations

import numpy as np

from swarmloc.lie.se3 import so3_exp

EPS = 1e-6
"""Step of the central differences."""


def perturb(g: np.ndarray, e: np.ndarray) -> np.ndarray:
    """The pose ``g`` (4x4) with Cartesian error ``e = (dp, dtheta)``: ``p + dp``, ``R exp(dtheta^)``."""
    out = g.copy()
    out[:3, 3] += e[:3]
    out[:3, :3] = g[:3, :3] @ so3_exp(e[3:])
    return out


def fd(f, n: int = 6) -> np.ndarray:
    """Central finite-difference Jacobian of ``f`` at 0 over ``n`` inputs (step :data:`EPS`)."""
    cols = []
    for c in range(n):
        e = np.zeros(n)
        e[c] = EPS
        cols.append((f(e) - f(-e)) / (2 * EPS))
    return np.stack(cols, axis=-1)
