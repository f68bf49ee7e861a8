"""Array types for annotations (:mod:`numpy.typing`): the project's one name for an array of floats; and
:func:`readonly`, the one way an array is frozen before it goes into an event or a shared record."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
"""An array of 64-bit floats, any shape (poses, tangent vectors, covariances: float64 throughout)."""

BoolArray = NDArray[np.bool_]
"""An array of booleans, any shape (masks: which elements of a batch are valid)."""

IntArray = NDArray[np.int64]
"""An array of 64-bit integers, any shape (indices and codes: rows, stamps, kinds)."""


def readonly(a: object) -> FloatArray:
    """A read-only float64 copy of ``a`` (what events and shared records hold: nobody can change them later)."""
    out = np.array(a, dtype=float)
    out.setflags(write=False)
    return out


__all__ = ["BoolArray", "FloatArray", "IntArray", "readonly"]
