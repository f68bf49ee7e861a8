"""The array namespace ``xp`` of :mod:`swarmloc.engine.formulas` inside numba-compiled code, on scalars.

The formulas call ``xp.where``, ``xp.cos``, ``xp.logical_and``, ...: with ``xp = jax.numpy`` elementwise on arrays,
with this module on the floats, ints and bools of one robot or detection in a numba loop. ``where(c, a, b)`` takes
two computed values, as ``jax.numpy.where`` does (no branch skipped: the formulas compute only finite-cost
scalars), and returns a scalar, not the 0-d array of ``numpy.where``.
"""

from __future__ import annotations

import builtins
import math
from typing import Any

import numpy as np
from numba import njit

__all__ = ["abs", "arctan2", "cos", "hypot", "isfinite", "log", "logical_and", "logical_not", "logical_or",
           "maximum", "minimum", "mod", "sin", "sqrt", "where"]  # fmt: skip

cos, sin, sqrt, arctan2, hypot, log = math.cos, math.sin, math.sqrt, math.atan2, math.hypot, math.log
isfinite = math.isfinite
abs = builtins.abs  # noqa: A001 - numpy's name
mod = np.mod  # numpy's floor modulo (the numpy and jax forms' angle wrap, to the bit)
logical_and, logical_or, logical_not = np.logical_and, np.logical_or, np.logical_not


@njit(error_model="numpy")
def where(c: Any, a: Any, b: Any) -> Any:  # noqa: D103 - the module docstring
    return a if c else b


@njit(error_model="numpy")
def maximum(a: Any, b: Any) -> Any:  # noqa: D103
    return a if a >= b else b


@njit(error_model="numpy")
def minimum(a: Any, b: Any) -> Any:  # noqa: D103
    return a if a <= b else b
