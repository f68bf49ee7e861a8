"""The fields of one event-file record (:mod:`swarmloc.datasets.eventfile`), read strictly and checked against
:mod:`swarmloc.datasets.bounds`: a problem raises :class:`Bad` with a message naming the column.

A number in a CSV cell is a plain decimal: an optional sign, ASCII digits with an optional point, an optional
exponent (``1``, ``-0.5``, ``.5``, ``2.5e-3``); blanks (spaces, tabs) around a cell are ignored. Python's
``float()`` accepts more (``1_0``, ``infinity``, non-ASCII digits such as ``١``, other Unicode spaces): here
each is a bad value. ``inf`` and ``nan`` are bad values in every column (CSV or JSON).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping

import numpy as np

from swarmloc.datasets.bounds import MAX_ANGLE, MAX_ID, MAX_POSITION, MAX_STD, MIN_STD
from swarmloc.gaussian import check_covariance

__all__ = ["Bad", "Record", "check_point", "check_pose", "check_std", "noise"]

BLANKS = " \t"
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_NONFINITE = frozenset({s + w for s in ("", "+", "-") for w in ("inf", "infinity", "nan")})
_PLAIN = "plain decimal: sign, digits, point, exponent, e.g. -1.5e-3"
_FINITE = "inf and nan are bad values in every column"

Bound = tuple[float, str]
"""``(limit, unit)``: ``|x| <= limit`` in ``unit``."""


class Bad(Exception):
    """A problem with one record (becomes one message naming the line)."""


def empty(v: object) -> bool:
    """A missing cell: None, or a string of blanks."""
    return v is None or (isinstance(v, str) and not v.strip(BLANKS))


def _text_number(key: str, s: str, what: str) -> float:
    if _DECIMAL.fullmatch(s) is None:
        if s.lower() in _NONFINITE:
            raise Bad(f"'{key}' must be finite ({_FINITE}), got {s!r}")
        raise Bad(f"'{key}' must be {what} ({_PLAIN}), got {s!r}")
    x = float(s)
    if not math.isfinite(x):
        raise Bad(f"'{key}' is too large for a float, got {s!r}")
    return x


def _json_number(key: str, v: object) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise Bad(f"'{key}' must be a number, got {v!r}")
    try:
        x = float(v)
    except OverflowError:
        raise Bad(f"'{key}' is too large for a float, got {v!r}") from None
    if not math.isfinite(x):
        raise Bad(f"'{key}' must be finite ({_FINITE}), got {v!r}")
    return x


def within(key: str, x: float, bound: Bound, what: str = "") -> None:
    """Raise :class:`Bad` unless ``|x| <= limit``."""
    limit, unit = bound
    if not abs(x) <= limit:
        raise Bad(f"'{key}'{f' {what}' if what else ''} = {x!r} is beyond +-{limit:g} {unit}")


class Record:
    """Accessors over one record's raw fields (CSV: strings; JSON: JSON values) with uniform error messages."""

    def __init__(self, raw: Mapping[str, object], text: bool) -> None:
        self.raw = raw
        self.text = text

    def has(self, key: str) -> bool:
        return not empty(self.raw.get(key))

    def _get(self, key: str) -> object:
        v = self.raw.get(key)
        if empty(v):
            raise Bad(f"'{key}' is required")
        return v.strip(BLANKS) if isinstance(v, str) else v

    def word(self, key: str) -> str:
        v = self._get(key)
        if not isinstance(v, str):
            raise Bad(f"'{key}' must be a string, got {v!r}")
        return v.lower()

    def number(self, key: str, bound: Bound | None = None) -> float:
        """A finite number, within ``bound`` when given."""
        v = self._get(key)
        x = _text_number(key, v, "a number") if isinstance(v, str) and self.text else _json_number(key, v)
        if bound is not None:
            within(key, x, bound)
        return x

    def ident(self, key: str) -> int:
        """A non-negative integer id up to ``MAX_ID`` (``3``; ``3.0`` is accepted, as spreadsheets write it)."""
        v = self._get(key)
        x = math.nan
        if isinstance(v, str) and self.text:
            x = float(v) if _DECIMAL.fullmatch(v) else math.nan
        elif isinstance(v, int | float) and not isinstance(v, bool):
            x = v if isinstance(v, int) else v if math.isfinite(v) else math.nan
        if not (isinstance(x, int) or (math.isfinite(x) and x == int(x))) or not 0 <= x <= MAX_ID:
            raise Bad(f"'{key}' must be a non-negative integer id (at most {MAX_ID}), got {v!r}")
        return int(x)

    def vector(self, key: str) -> np.ndarray:
        """Finite numbers: separated by blanks in a CSV cell, a JSON array (or one JSON number)."""
        v = self._get(key)
        if isinstance(v, str) and self.text:
            vals = [_text_number(key, s, "numbers separated by spaces") for s in re.split(r"[ \t]+", v)]
        elif isinstance(v, list) and all(isinstance(x, int | float) and not isinstance(x, bool) for x in v):
            vals = [_json_number(key, x) for x in v]
        elif isinstance(v, int | float) and not isinstance(v, bool) and not self.text:
            vals = [_json_number(key, v)]
        else:
            raise Bad(f"'{key}' must be {'numbers separated by spaces' if self.text else 'an array of numbers'}")
        return np.array(vals, dtype=float)

    def sized(self, key: str, n: int, of: str) -> np.ndarray:
        """:meth:`vector` of exactly ``n`` numbers; else :class:`Bad`: ``'<key>' of <of>, got <size>`` (``of``: what
        it belongs to and must hold, ``"a landmark must be 'x y' (2 numbers)"``)."""
        v = self.vector(key)
        if v.size != n:
            raise Bad(f"'{key}' of {of}, got {v.size}")
        return v


def check_pose(z: np.ndarray, key: str = "z") -> None:
    """``x y theta``: ``|x|, |y| <= MAX_POSITION`` m, ``|theta| <= MAX_ANGLE`` rad."""
    check_point(z[:2], key)
    within(key, float(z[2]), (MAX_ANGLE, "rad"), "heading")


def check_point(xy: np.ndarray, key: str = "z") -> None:
    """``x y``: ``|x|, |y| <= MAX_POSITION`` m."""
    for name, x in zip("xy", xy.tolist(), strict=False):
        within(key, x, (MAX_POSITION, "m"), name)


def check_std(std: np.ndarray) -> None:
    """Standard deviations: positive, each in ``[MIN_STD, MAX_STD]``."""
    if (std <= 0).any():
        raise Bad(f"'std' must be positive, got {std.tolist()}")
    if ((std < MIN_STD) | (std > MAX_STD)).any():
        raise Bad(f"'std' must be in [{MIN_STD:g}, {MAX_STD:g}] (m or rad), got {std.tolist()}")


def noise(rec: Record, m: int, what: str, default: np.ndarray | None) -> np.ndarray:
    """The ``(m, m)`` noise covariance from ``std`` or ``cov`` (exactly one), else from ``default``; variances in
    ``[MIN_STD^2, MAX_STD^2]``."""
    has_std, has_cov = rec.has("std"), rec.has("cov")
    if has_std and has_cov:
        raise Bad("give either 'std' or 'cov', not both")
    if has_std:
        std = rec.sized("std", m, f"{what} must have {m} number{'s' if m > 1 else ''}")
        check_std(std)
        return np.diag(std * std)
    if has_cov:
        c = rec.sized("cov", m * m, f"{what} must have {m}*{m} = {m * m} numbers (row-major)")
        try:
            cov = check_covariance(c.reshape(m, m), m, "cov").copy()
        except ValueError as exc:
            raise Bad(str(exc).replace("cov: argument 'cov'", "'cov'")) from None
        d = np.diag(cov)
        if ((d < MIN_STD**2) | (d > MAX_STD**2)).any():
            raise Bad(f"'cov' variances (its diagonal) must be in [{MIN_STD**2:g}, {MAX_STD**2:g}], got {d.tolist()}")
        return cov
    if default is None:
        raise Bad(f"{what} has neither 'std' nor 'cov' and no default applies (pass defaults={{...}})")
    return default.copy()
