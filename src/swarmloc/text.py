"""Short, bounded text of numbers for the ``repr`` of the public types (beliefs, events, nodes, results).

A ``repr`` is read by a person at a prompt or in a log line: every number with 4 significant digits, and never
more than a handful of them, whatever the size of the array behind it (a batch of 10,000 beliefs prints as one).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

__all__ = ["MAX_NUMBERS", "ids", "number", "numbers", "stamp"]

MAX_NUMBERS = 9
"""Most numbers :func:`numbers` writes; the rest is counted (``..., 3 more``)."""


def number(x: object) -> str:
    """One number with 4 significant digits (``0.3``, ``1.235e+04``, ``-0``, ``nan``); anything else as ``repr``."""
    try:
        return f"{float(x):.4g}"  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return repr(x)


def stamp(t: object) -> str:
    """A time [s] to the millisecond and below where it has it (``0.3``, ``1248272272.841``: a Unix-epoch stamp
    keeps its fraction, which 4 significant digits would drop)."""
    try:
        return f"{float(t):.13g}"  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return repr(t)


def numbers(values: Iterable[object] | np.ndarray, limit: int = MAX_NUMBERS) -> str:
    """``[a, b, c]`` of the first ``limit`` values (flattened), then how many more there are."""
    flat = np.asarray(values, dtype=float).ravel()
    shown = ", ".join(number(x) for x in flat[:limit].tolist())
    more = flat.size - min(flat.size, limit)
    return f"[{shown}{f', ... {more} more' if more else ''}]"


def ids(values: Iterable[int], limit: int = MAX_NUMBERS) -> str:
    """``[0, 1, 2]`` of the first ``limit`` integer ids, then how many more there are."""
    items = list(values)
    shown = ", ".join(str(int(i)) for i in items[:limit])
    more = len(items) - min(len(items), limit)
    return f"[{shown}{f', ... {more} more' if more else ''}]"
