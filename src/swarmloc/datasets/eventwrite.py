"""Writer of swarmloc event files (:mod:`swarmloc.datasets.eventfile` reads them and says the format):
:func:`write_events` writes what :func:`~swarmloc.datasets.eventfile.load_events` reads back exactly."""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from swarmloc.datasets.eventfile import COLUMNS, file_format
from swarmloc.events import Detection, Odometry

__all__ = ["write_events"]


def _num(x: float) -> str:
    """Shortest text that reads back to exactly the same float (Python's ``repr``)."""
    return repr(float(x))


def _noise_fields(cov: np.ndarray) -> dict[str, list[float]]:
    """``{"std": [...]}`` when ``cov`` is diagonal and each variance is exactly a std squared, else ``{"cov": ...}``."""
    c = np.asarray(cov, dtype=float)
    d = np.diag(c)
    std = np.sqrt(d)
    if np.count_nonzero(c - np.diag(d)) == 0 and np.array_equal(std * std, d) and (d > 0).all():
        return {"std": [float(s) for s in std]}
    return {"cov": [float(x) for x in c.ravel()]}


def _records(
    events: Iterable[Odometry | Detection],
    landmarks: Mapping[int, Sequence[float]] | None,
    initial: Mapping[int, tuple[object, object]] | None,
    initial_times: Mapping[int, float] | None,
) -> Iterator[dict[str, object]]:
    """Records as ``{field: int | float | str | list[float]}`` in file order: landmarks, initial, events."""
    for lid, lm in sorted((landmarks or {}).items()):
        x, y, sx, sy = (float(v) for v in lm)
        yield {"type": "landmark", "target": int(lid), "target_type": "landmark", "z": [x, y], "std": [sx, sy]}
    for r, (pose, cov) in sorted((initial or {}).items()):
        rec: dict[str, object] = {"type": "initial"}
        if initial_times and r in initial_times:
            rec["t"] = float(initial_times[r])
        rec["robot"] = int(r)
        rec["z"] = [float(v) for v in np.asarray(pose, dtype=float).ravel()]
        rec.update(_noise_fields(np.asarray(cov, dtype=float)))
        yield rec
    for e in events:
        if isinstance(e, Odometry):
            yield {"type": "odometry", "t": float(e.t1), "robot": int(e.robot), "t0": float(e.t0),
                   "v": float(e.v), "w": float(e.w)}  # fmt: skip
        elif isinstance(e, Detection):
            rec = {"type": "detection", "t": float(e.t), "robot": int(e.observer)}
            if e.target is not None:
                rec["target"] = int(e.target)
                rec["target_type"] = "robot" if e.target_is_robot else "landmark"
            rec["kind"] = e.kind
            rec["z"] = [float(v) for v in np.asarray(e.z, dtype=float).ravel()]
            rec.update(_noise_fields(e.cov))
            yield rec
        else:
            raise ValueError(
                f"write_events: only Odometry and Detection events can be written, got {type(e).__name__} "
                "(write ground truth with swarmloc.datasets.tum.write_tum)"
            )


def _cell(v: object) -> str:
    if isinstance(v, list):
        return " ".join(_num(x) for x in v)
    if isinstance(v, float):
        return _num(v)
    return str(v)


def write_events(
    path: str | os.PathLike[str],
    events: Iterable[Odometry | Detection],
    landmarks: Mapping[int, Sequence[float]] | None = None,
    initial: Mapping[int, tuple[object, object]] | None = None,
    initial_times: Mapping[int, float] | None = None,
) -> Path:
    """Write an event file (``.csv`` or ``.jsonl`` by extension) that :func:`load_events` reads back exactly.

    ``landmarks``: ``id -> (x, y, sx, sy)``; ``initial``: ``robot -> (pose (3,), cov (3, 3))``; ``initial_times``:
    ``robot -> t`` (optional). A diagonal noise covariance is written as ``std`` when that is exact, else as
    ``cov``. Floats are written as the shortest text that reads back to the same number. Returns the path.
    """
    p = Path(path)
    fmt = file_format(p)
    recs = list(_records(events, landmarks, initial, initial_times))
    buf = io.StringIO()
    buf.write("# swarmloc event file, format 1 (see swarmloc.datasets.eventfile)\n")
    if fmt == "csv":
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(COLUMNS)
        for rec in recs:
            w.writerow([_cell(rec[c]) if c in rec else "" for c in COLUMNS])
    else:
        for rec in recs:
            buf.write(json.dumps(rec, allow_nan=False) + "\n")
    p.write_text(buf.getvalue(), encoding="utf-8")
    return p
