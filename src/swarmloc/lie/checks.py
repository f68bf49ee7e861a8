"""Input validation shared by the Lie-group classes.

Every public group function validates its arguments and raises :class:`ValueError` that names the function,
the argument and the problem (and, for batches, the first offending index). Hot paths inside swarmloc call
the same functions with ``validate=False``.
"""

from __future__ import annotations

import numpy as np

from swarmloc.arrays import BoolArray, FloatArray

ORTHO_TOL = 1e-6
"""Largest allowed entry of ``|R^T R - I|`` for a rotation block to count as orthonormal."""


def first_bad(mask: BoolArray) -> tuple[int, ...]:
    idx = np.argwhere(mask)
    return tuple(int(i) for i in idx[0]) if idx.size else ()


def as_tangent(x: object, dim: int, where: str, name: str = "x") -> FloatArray:
    """Return ``x`` as a float array of shape ``(..., dim)`` or raise ValueError."""
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: argument '{name}' is not a numeric array ({exc})") from None
    if arr.ndim < 1 or arr.shape[-1] != dim:
        raise ValueError(
            f"{where}: argument '{name}' must have shape (..., {dim}) (exponential coordinates), got shape {arr.shape}"
        )
    finite = np.isfinite(arr)
    if not finite.all():
        raise ValueError(f"{where}: argument '{name}' contains NaN or inf (first at index {first_bad(~finite)})")
    return arr


def as_square(x: object, dim: int, where: str, name: str) -> FloatArray:
    """Return ``x`` as a finite float array of shape ``(..., dim, dim)`` or raise ValueError."""
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: argument '{name}' is not a numeric array ({exc})") from None
    if arr.ndim < 2 or arr.shape[-2:] != (dim, dim):
        raise ValueError(f"{where}: argument '{name}' must have shape (..., {dim}, {dim}), got {arr.shape}")
    finite = np.isfinite(arr)
    if not finite.all():
        raise ValueError(f"{where}: argument '{name}' contains NaN or inf (first at index {first_bad(~finite)})")
    return arr


def as_element(g: object, n: int, where: str, name: str = "g") -> FloatArray:
    """Return ``g`` as an array of SE(n) matrices ``(..., n+1, n+1)`` or raise ValueError.

    Checks shape, finiteness, the bottom row ``[0, ..., 0, 1]``, orthonormality of the rotation block
    (``max |R^T R - I| <= ORTHO_TOL``) and ``det R > 0``.
    """
    arr = as_square(g, n + 1, where, name)
    bottom = arr[..., n, :]
    want = np.zeros(n + 1)
    want[n] = 1.0
    bad_row = np.abs(bottom - want).max(axis=-1) > 1e-9
    if bad_row.any():
        i = first_bad(bad_row)
        raise ValueError(
            f"{where}: argument '{name}' is not in SE({n}): bottom row must be {want.tolist()}, "
            f"got {arr[i][n].tolist()}" + (f" at batch index {i}" if i else "")
        )
    R = arr[..., :n, :n]
    err = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(n)).max(axis=(-1, -2))
    bad = err > ORTHO_TOL
    if bad.any():
        i = first_bad(bad)
        raise ValueError(
            f"{where}: argument '{name}' is not in SE({n}): its rotation block is not orthonormal "
            f"(max |R^T R - I| = {err[i]:.3g} > {ORTHO_TOL:g})" + (f" at batch index {i}" if i else "")
        )
    det = np.linalg.det(R)
    if (det <= 0).any():
        i = first_bad(det <= 0)
        raise ValueError(
            f"{where}: argument '{name}' is not in SE({n}): its rotation block has det {det[i]:.3g} "
            "(a reflection, not a rotation)" + (f" at batch index {i}" if i else "")
        )
    return arr
