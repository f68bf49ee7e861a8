"""Whitespace-separated numeric tables with ``#`` comments (the MRCLAM files, :mod:`swarmloc.datasets.mrclam`):
read fast with pandas, and when that fails scanned line by line so that the error names the file and the first bad
line; integer columns and time order checked the same way."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd

from swarmloc.datasets.bounds import shorten

__all__ = ["file_label", "find_bad_line", "integer_column", "line_of_row", "read_table", "sort_by_time"]


def file_label(path: Path) -> str:
    """``MRCLAM_Dataset6/Robot1_Odometry.dat``: the name used in messages."""
    return f"{path.parent.name}/{path.name}" if path.parent.name else path.name


def _data_lines(path: Path) -> Iterator[tuple[int, str]]:
    """``(line number, content)`` of every data line of ``path``: what is left of it before a ``#``, stripped, when
    that is not empty."""
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, raw in enumerate(fh, start=1):
            content = raw.split("#", 1)[0].strip()
            if content:
                yield lineno, content


def find_bad_line(path: Path, ncols: int) -> tuple[int, str, str] | None:
    """Scan ``path`` line by line; return ``(line number, stripped content, problem)`` of the first bad data line."""
    for lineno, content in _data_lines(path):
        parts = content.split()
        if len(parts) != ncols:
            return lineno, content, f"expected {ncols} numeric columns"
        for p in parts:
            try:
                x = float(p)
            except ValueError:
                return lineno, content, f"expected {ncols} numeric columns"
            if not math.isfinite(x):
                return lineno, content, f"expected {ncols} finite numeric columns"
    return None


def line_of_row(path: Path, row: int) -> tuple[int, str]:
    """File line number (1-based) and content of data row ``row`` (0-based, headers and blank lines skipped)."""
    return next(itertools.islice(_data_lines(path), row, None), (-1, ""))


def read_table(path: Path, ncols: int, error: type[ValueError] = ValueError) -> np.ndarray:
    """Read a whitespace-separated numeric table with ``#`` comments as a float64 ``(n, ncols)`` array.

    Fast path: ``pandas.read_csv``. When it fails or yields the wrong shape or non-finite values, the file is
    scanned line by line to name the first bad line. Problems raise ``error`` (the caller's ``ValueError``
    subclass) with a one-line message naming the file and line.
    """
    try:
        df = pd.read_csv(path, sep=r"\s+", comment="#", header=None, dtype=np.float64, engine="c")
        arr = df.to_numpy(dtype=np.float64)
        ok = arr.ndim == 2 and arr.shape[1] == ncols and bool(np.isfinite(arr).all())
    except pd.errors.EmptyDataError:
        return np.empty((0, ncols))
    except OSError as exc:
        raise error(f"{file_label(path)}: cannot read file ({exc.strerror or exc})") from None
    except (ValueError, pd.errors.ParserError, UnicodeDecodeError):
        arr, ok = None, False
    if ok:
        return arr
    try:
        bad = find_bad_line(path, ncols)
    except OSError as exc:  # pragma: no cover - file vanished between the two reads
        raise error(f"{file_label(path)}: cannot read file ({exc.strerror or exc})") from None
    if bad is not None:
        lineno, content, problem = bad
        raise error(f"{file_label(path)} line {lineno}: {problem}, got {shorten(content)!r}")
    raise error(f"{file_label(path)}: could not parse as a table of {ncols} numeric columns")  # pragma: no cover


def integer_column(path: Path, arr: np.ndarray, col: int, what: str,
                   error: type[ValueError] = ValueError) -> np.ndarray:  # fmt: skip
    """Column ``col`` of ``arr`` as int64; raise ``error`` naming the line when a value is not an integer."""
    x = arr[:, col]
    bad = np.flatnonzero(x != np.round(x))
    if bad.size:
        lineno, content = line_of_row(path, int(bad[0]))
        raise error(f"{file_label(path)} line {lineno}: {what} must be an integer, got {content!r}")
    return x.astype(np.int64)


def sort_by_time(path: Path, arr: np.ndarray, notes: list[str]) -> np.ndarray:
    """Stable sort of rows by column 0; records a note when the file was not in time order."""
    if arr.shape[0] > 1:
        back = int(np.count_nonzero(np.diff(arr[:, 0]) < 0))
        if back:
            notes.append(f"{file_label(path)}: {back} time step(s) backwards, rows sorted by time")
            arr = arr[np.argsort(arr[:, 0], kind="stable")]
    return arr
