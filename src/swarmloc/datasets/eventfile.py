"""A plain event file for your own robots: odometry, detections, landmarks and initial beliefs in CSV or JSON Lines.

Format (version 1). One record per line (a CSV cell may not span lines); lines starting with ``#`` and blank lines
are comments. The format follows the file's extension: ``.csv`` or ``.jsonl``. A CSV file's first other line is
the header row naming the columns, in any order; columns a file does not use may be left out, unknown columns are
an error; a row may stop after its last non-empty cell. A JSON Lines file holds one JSON object per line with the
same field names (a missing field or ``null`` is an empty cell; numbers are JSON numbers, ``z``/``std``/``cov``
JSON arrays or, for one number, a number).
Words (``type``, ``target_type``, ``kind``) are case-insensitive. Units: metres, radians, seconds; poses
``(x, y, theta)`` in the world frame, relative quantities in the observer's body frame (x forward, y left).

Columns::

    type         odometry | detection | landmark | initial
    t            time [s]: end of an odometry interval, time of a detection or of an initial belief
    robot        robot id (integer >= 0): the odometry's robot, the detection's observer, the initial belief's
    t0           start of an odometry interval [s], t0 <= t
    v, w         odometry: body-frame forward speed [m/s] and yaw rate [rad/s], held over [t0, t]
    target       id (integer >= 0) of the detected robot or landmark; a landmark record's own id
    target_type  robot | landmark
    kind         pose | range_bearing | range | bearing | absolute
    z            measured value: numbers separated by spaces ("1.2 0.3"; a JSON array in .jsonl)
    std          noise standard deviations, one per number of z (a diagonal covariance)
    cov          full noise covariance, row-major: m*m numbers for a z of m numbers

Records (every other cell empty):

* ``odometry``: ``t, robot, t0, v, w``; becomes ``Odometry(robot, t0, t, v, w)``.
* ``detection``: ``t, robot, kind, z``; ``target, target_type`` (not for ``absolute``); ``std`` or ``cov``, or
  neither: then the reader's ``defaults`` for the kind apply. ``z`` per kind: ``pose`` the target's relative pose
  ``x y theta`` in the observer's frame (its noise: the exponential coordinates of ``m_true^-1 m_measured``);
  ``range_bearing`` ``range bearing``; ``range``; ``bearing`` (in ``[-pi, pi]``); ``absolute`` the observer's own
  world pose ``x y theta`` (a GPS-like fix). A landmark is a point: a ``pose`` detection of one is an error.
* ``landmark``: ``target`` (its id), ``z = "x y"``, ``std = "sx sy"`` (or ``defaults["landmark"]``);
  ``target_type`` may be ``landmark`` or empty.
* ``initial``: ``robot``, ``z = "x y theta"``, ``std`` or ``cov`` (or ``defaults["initial"]``), ``t`` optional:
  the initial belief, Gaussian in the exponential coordinates of SE(2), right perturbation (as
  :class:`~swarmloc.gaussian.GroupGaussian`).

A landmark or a robot's initial belief may be repeated only with identical values.

Example (``events.csv``)::

    type,t,robot,t0,v,w,target,target_type,kind,z,std,cov
    landmark,,,,,,7,landmark,,4.0 2.5,0.01 0.01,
    initial,0.0,1,,,,,,,0 0 0,0.01 0.01 0.01,
    odometry,0.1,1,0.0,0.5,0.02,,,,,,
    detection,0.1,1,,,,7,landmark,range_bearing,4.2 0.55,0.1 0.035,
    detection,0.1,1,,,,2,robot,pose,1.5 -0.2 0.1,,0.0025 0 0 0 0.0025 0 0 0 0.0003

The same range-bearing detection in ``events.jsonl``::

    {"type": "detection", "t": 0.1, "robot": 1, "target": 7, "target_type": "landmark", "kind": "range_bearing",
     "z": [4.2, 0.55], "std": [0.1, 0.035]}

(on one line). :func:`load_events` checks every record and reports every bad line with the file name, the line
number and the problem; :func:`write_events` writes the format so that it reads back exactly (floats as the
shortest text that reads back to the same number). Events are sorted by their natural stamp: odometry by ``t0``
(a commanded velocity is known when it starts), detections by ``t``; ties: detections before odometry, then by
robot id, then file order.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from swarmloc.datasets.tum import read_tum
from swarmloc.events import Detection, Odometry
from swarmloc.gaussian import GroupGaussian, check_covariance
from swarmloc.lie import SE2

__all__ = [
    "COLUMNS",
    "EventFile",
    "EventFileError",
    "KIND_SIZES",
    "load_events",
    "load_truth_dir",
    "write_events",
]

COLUMNS: tuple[str, ...] = ("type", "t", "robot", "t0", "v", "w", "target", "target_type", "kind", "z", "std", "cov")
"""The columns of the CSV format, in the order :func:`write_events` writes them."""

KIND_SIZES: dict[str, int] = {"pose": 3, "range_bearing": 2, "range": 1, "bearing": 1, "absolute": 3}
"""Length of ``z`` per detection kind."""

RECORD_TYPES: tuple[str, ...] = ("odometry", "detection", "landmark", "initial")

_ALLOWED: dict[str, frozenset[str]] = {
    "odometry": frozenset({"t", "robot", "t0", "v", "w"}),
    "detection": frozenset({"t", "robot", "target", "target_type", "kind", "z", "std", "cov"}),
    "landmark": frozenset({"target", "target_type", "z", "std", "cov"}),  # cov: to say "use std"
    "initial": frozenset({"t", "robot", "z", "std", "cov"}),
}
_MAX_LISTED = 20
_MAX_NUMBERS = 50
_BEARING_TOL = 1e-9

EventList = list[Odometry | Detection]


class EventFileError(ValueError):
    """A problem with an event file. ``problems`` holds one message per bad line (empty for file-level errors)."""

    def __init__(self, message: str, problems: Sequence[str] = ()) -> None:
        super().__init__(message)
        self.problems = list(problems)


@dataclass
class EventFile:
    """A loaded event file.

    ``events``: odometry and detections sorted by stamp (see the module doc). ``landmarks``: ``id -> (x, y, sx,
    sy)`` [m]. ``initial``: ``robot -> (pose (3,), cov (3, 3))``, pose ``(x, y, theta)`` and covariance of the
    exponential coordinates (right perturbation); ``initial_times``: ``robot -> t`` for initial records with a
    time. ``robots``: sorted ids of every robot named (odometry, observer, initial, robot target). ``problems``:
    one message per skipped bad line (``strict=False``).
    """

    path: Path
    events: EventList
    landmarks: dict[int, tuple[float, float, float, float]] = field(default_factory=dict)
    initial: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    initial_times: dict[int, float] = field(default_factory=dict)
    robots: list[int] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    def initial_beliefs(self) -> dict[int, GroupGaussian]:
        """The ``initial`` records as SE(2) :class:`~swarmloc.gaussian.GroupGaussian` beliefs."""
        return {r: GroupGaussian(SE2, SE2.from_xytheta(p), c) for r, (p, c) in self.initial.items()}


# ----------------------------------------------------------------------------------------------------------------
# reading: one record -> typed values


class _Bad(Exception):
    """A problem with one record (becomes one message naming the line)."""


def _shorten(text: str, n: int = 80) -> str:
    return text if len(text) <= n else text[: n - 3] + "..."


def _empty(v: object) -> bool:
    return v is None or (isinstance(v, str) and not v.strip())


class _Record:
    """Accessors over one record's raw fields (CSV: strings; JSON: JSON values) with uniform error messages."""

    def __init__(self, raw: Mapping[str, object], text: bool) -> None:
        self.raw = raw
        self.text = text

    def has(self, key: str) -> bool:
        return not _empty(self.raw.get(key))

    def _get(self, key: str) -> object:
        v = self.raw.get(key)
        if _empty(v):
            raise _Bad(f"'{key}' is required")
        return v.strip() if isinstance(v, str) else v

    def word(self, key: str) -> str:
        v = self._get(key)
        if not isinstance(v, str):
            raise _Bad(f"'{key}' must be a string, got {v!r}")
        return v.strip().lower()

    def number(self, key: str) -> float:
        v = self._get(key)
        if isinstance(v, str) and self.text:
            try:
                x = float(v)
            except ValueError:
                raise _Bad(f"'{key}' must be a number, got {v!r}") from None
        elif isinstance(v, int | float) and not isinstance(v, bool):
            x = float(v) if isinstance(v, float) or abs(v) < 2**1000 else math.inf
        else:
            raise _Bad(f"'{key}' must be a number, got {v!r}")
        if not math.isfinite(x):
            raise _Bad(f"'{key}' must be finite, got {v!r}")
        return x

    def ident(self, key: str) -> int:
        """A non-negative integer id (``3``; ``3.0`` is accepted, as spreadsheets and pandas write it)."""
        v = self._get(key)
        n: int | None = None
        if isinstance(v, str) and self.text:
            try:
                n = int(v)
            except ValueError:
                try:
                    x = float(v)
                except ValueError:
                    x = math.nan
                n = int(x) if math.isfinite(x) and x == int(x) else None
        elif isinstance(v, int) and not isinstance(v, bool):
            n = v
        elif isinstance(v, float) and math.isfinite(v) and v == int(v):
            n = int(v)
        if n is None or n < 0:
            raise _Bad(f"'{key}' must be a non-negative integer id, got {v!r}")
        return n

    def vector(self, key: str) -> np.ndarray:
        v = self._get(key)
        if isinstance(v, str) and self.text:
            parts = v.split()
            try:
                vals = [float(s) for s in parts]
            except ValueError:
                raise _Bad(f"'{key}' must be numbers separated by spaces, got {v!r}") from None
        elif isinstance(v, list) and all(isinstance(x, int | float) and not isinstance(x, bool) for x in v):
            vals = [float(x) if isinstance(x, float) or abs(x) < 2**1000 else math.inf for x in v]
        elif isinstance(v, int | float) and not isinstance(v, bool) and not self.text:
            vals = [float(v) if isinstance(v, float) or abs(v) < 2**1000 else math.inf]
        else:
            raise _Bad(f"'{key}' must be {'numbers separated by spaces' if self.text else 'an array of numbers'}")
        arr = np.array(vals, dtype=float)
        if not np.isfinite(arr).all():
            raise _Bad(f"'{key}' must be finite, got {v!r}")
        return arr


def _noise(rec: _Record, m: int, what: str, default: np.ndarray | None) -> np.ndarray:
    """The ``(m, m)`` noise covariance from ``std`` or ``cov`` (exactly one), else from ``default``."""
    has_std, has_cov = rec.has("std"), rec.has("cov")
    if has_std and has_cov:
        raise _Bad("give either 'std' or 'cov', not both")
    if has_std:
        std = rec.vector("std")
        if std.size != m:
            raise _Bad(f"'std' of {what} must have {m} number{'s' if m > 1 else ''}, got {std.size}")
        if (std <= 0).any():
            raise _Bad(f"'std' must be positive, got {std.tolist()}")
        return np.diag(std * std)
    if has_cov:
        c = rec.vector("cov")
        if c.size != m * m:
            raise _Bad(f"'cov' of {what} must have {m}*{m} = {m * m} numbers (row-major), got {c.size}")
        try:
            return check_covariance(c.reshape(m, m), m, "cov").copy()
        except ValueError as exc:
            raise _Bad(str(exc).replace("cov: argument 'cov'", "'cov'")) from None
    if default is None:
        raise _Bad(f"{what} has neither 'std' nor 'cov' and no default applies (pass defaults={{...}})")
    return default.copy()


def _check_fields(rec: _Record, rtype: str) -> None:
    extra = [k for k in COLUMNS if k != "type" and k not in _ALLOWED[rtype] and rec.has(k)]
    if extra:
        names = ", ".join(f"'{k}'" for k in extra)
        raise _Bad(f"{names} do{'es' if len(extra) == 1 else ''} not apply to {rtype} records (leave empty)")


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _normalize_defaults(defaults: Mapping[str, object] | None) -> dict[str, np.ndarray]:
    """``kind -> (m, m)`` covariance from a std vector ``(m,)`` or a covariance ``(m, m)`` per key; for
    ``"landmark"`` the std vector itself (landmarks are stored as ``(x, y, sx, sy)``)."""
    sizes = {**KIND_SIZES, "landmark": 2, "initial": 3}
    out: dict[str, np.ndarray] = {}
    for key, val in (defaults or {}).items():
        if key not in sizes:
            raise ValueError(f"load_events: unknown key {key!r} in 'defaults'; known keys: {', '.join(sizes)}")
        m = sizes[key]
        a = np.asarray(val, dtype=float)
        if a.shape == (m,):
            if not (np.isfinite(a).all() and (a > 0).all()):
                raise ValueError(f"load_events: defaults[{key!r}] std must be finite and positive, got {a.tolist()}")
            out[key] = a.copy() if key == "landmark" else np.diag(a * a)
        elif a.shape == (m, m) and key != "landmark":
            out[key] = check_covariance(a, m, "load_events", f"defaults[{key!r}]").copy()
        else:
            want = f"a std vector of {m}" if key == "landmark" else f"a std vector of {m} or a {m}x{m} covariance"
            raise ValueError(f"load_events: defaults[{key!r}] must be {want}, got shape {a.shape}")
    return out


# ----------------------------------------------------------------------------------------------------------------
# reading: lines -> records


def _lines(path: Path) -> Iterator[tuple[int, str]]:
    """``(line number, text)`` of every line that is neither blank nor a ``#`` comment."""
    with open(path, encoding="utf-8-sig") as fh:  # -sig: a byte-order mark (as Excel writes) is skipped
        for lineno, raw in enumerate(fh, start=1):
            text = raw.rstrip("\r\n")
            s = text.strip()
            if s and not s.startswith("#"):
                yield lineno, text


def _csv_rows(path: Path, label: str) -> Iterator[tuple[int, str, Mapping[str, object] | str]]:
    """``(line number, text, fields or problem)`` per data line; the header is checked here."""
    lines = _lines(path)
    first = next(lines, None)
    if first is None:
        raise EventFileError(f"{label}: empty file: expected a header row ({','.join(COLUMNS)})")
    hline, htext = first
    try:
        header = [h.strip().lower() for h in next(csv.reader([htext], strict=True))]
    except csv.Error as exc:
        raise EventFileError(f"{label} line {hline}: bad header row ({exc}), got {_shorten(htext)!r}") from None
    unknown = [h for h in header if h not in COLUMNS]
    dup = sorted({h for h in header if header.count(h) > 1})
    if unknown or dup or "type" not in header:
        what = []
        if unknown:
            what.append("unknown column(s) " + ", ".join(repr(h) for h in unknown))
        if dup:
            what.append("repeated column(s) " + ", ".join(repr(h) for h in dup))
        if "type" not in header:
            what.append("no 'type' column")
        raise EventFileError(
            f"{label} line {hline}: bad header row: {'; '.join(what)}; known columns: {','.join(COLUMNS)}, "
            f"got {_shorten(htext)!r}"
        )
    for lineno, text in lines:
        try:
            cells = next(csv.reader([text], strict=True))
        except csv.Error as exc:
            yield lineno, text, f"not a CSV row ({exc})"
            continue
        if len(cells) > len(header):
            yield lineno, text, f"expected at most {len(header)} cells (as in the header row), got {len(cells)}"
        else:  # trailing empty cells may be left out
            yield lineno, text, dict(zip(header, cells, strict=False))


def _jsonl_rows(path: Path) -> Iterator[tuple[int, str, Mapping[str, object] | str]]:
    for lineno, text in _lines(path):
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as exc:
            yield lineno, text, f"not valid JSON ({exc.msg} at column {exc.colno})"
            continue
        if not isinstance(obj, dict):
            yield lineno, text, f"expected a JSON object, got a {type(obj).__name__}"
            continue
        unknown = [k for k in obj if k not in COLUMNS]
        if unknown:
            yield lineno, text, "unknown field(s) " + ", ".join(repr(k) for k in unknown)
            continue
        yield lineno, text, obj


def _format(path: Path) -> str:
    ext = path.suffix.lower()
    if ext not in (".csv", ".jsonl"):
        raise EventFileError(f"{path.name}: unknown event file extension {path.suffix!r}; use .csv or .jsonl")
    return ext[1:]


def _summary(label: str, problems: list[str], lines: list[int]) -> str:
    """Every bad line: the first ``_MAX_LISTED`` messages in full, then the others' line numbers."""
    n = len(problems)
    head = f"{label}: {n} bad line{'s' if n != 1 else ''} (pass strict=False to skip bad lines):"
    body = [f"  {p}" for p in problems[:_MAX_LISTED]]
    rest = problems[_MAX_LISTED:]
    if rest:
        more = ", ".join(str(k) for k in lines[_MAX_LISTED : _MAX_LISTED + _MAX_NUMBERS])
        more += ", ..." if len(rest) > _MAX_NUMBERS else ""
        body.append(f"  ... and {len(rest)} more (lines {more})")
    return "\n".join([head, *body])


# ----------------------------------------------------------------------------------------------------------------
# public API


def load_events(
    path: str | os.PathLike[str], defaults: Mapping[str, object] | None = None, strict: bool = True
) -> EventFile:
    """Read an event file (``.csv`` or ``.jsonl``; format in the module doc).

    ``defaults``: noise used when a record has neither ``std`` nor ``cov``, per key ``pose``, ``range_bearing``,
    ``range``, ``bearing``, ``absolute``, ``landmark``, ``initial``: a std vector (or, except for ``landmark``,
    a covariance matrix); e.g. :meth:`swarmloc.config.Config.event_defaults`. With ``strict=True`` any bad line
    raises :class:`EventFileError` listing every bad line; with ``strict=False`` bad lines are skipped and listed
    in ``EventFile.problems``. A missing file, a bad header and a file without odometry always raise.
    """
    p = Path(path).expanduser()
    label = p.name
    fmt = _format(p)
    if not p.is_file():
        raise EventFileError(f"event file not found: {p}" if not p.exists() else f"event path {p} is not a file")
    dflt = _normalize_defaults(defaults)

    keyed: list[tuple[tuple[float, int, int, int], Odometry | Detection]] = []
    landmarks: dict[int, tuple[float, float, float, float]] = {}
    lm_line: dict[int, int] = {}
    initial: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    init_t: dict[int, float] = {}
    init_line: dict[int, int] = {}
    robots: set[int] = set()
    problems: list[str] = []
    bad_lines: list[int] = []

    def parse(rec: _Record, lineno: int, seq: int) -> None:
        rtype = rec.word("type")
        if rtype not in _ALLOWED:
            raise _Bad(f"unknown record type {rtype!r}; expected one of {', '.join(RECORD_TYPES)}")
        _check_fields(rec, rtype)
        if rtype == "odometry":
            t1, r, t0, v, w = rec.number("t"), rec.ident("robot"), rec.number("t0"), rec.number("v"), rec.number("w")
            if t1 < t0:
                raise _Bad(f"odometry must have t >= t0, got t = {t1!r} < t0 = {t0!r}")
            keyed.append(((t0, 1, r, seq), Odometry(robot=r, t0=t0, t1=t1, v=v, w=w)))
            robots.add(r)
        elif rtype == "detection":
            _detection(rec, seq)
        elif rtype == "landmark":
            lid = rec.ident("target")
            if rec.has("target_type") and rec.word("target_type") != "landmark":
                raise _Bad(
                    f"'target_type' of a landmark record must be 'landmark' or empty, got {rec.raw['target_type']!r}"
                )
            z = rec.vector("z")
            if z.size != 2:
                raise _Bad(f"'z' of a landmark must be 'x y' (2 numbers), got {z.size}")
            if rec.has("cov"):
                raise _Bad("a landmark record takes 'std' (sx sy), not 'cov'")
            if rec.has("std"):
                std = rec.vector("std")
                if std.size != 2:
                    raise _Bad(f"'std' of a landmark must be 'sx sy' (2 numbers), got {std.size}")
                if (std <= 0).any():
                    raise _Bad(f"'std' must be positive, got {std.tolist()}")
            elif "landmark" in dflt:
                std = dflt["landmark"]
            else:
                raise _Bad("a landmark has no 'std' and no default applies (pass defaults={'landmark': [sx, sy]})")
            val = (float(z[0]), float(z[1]), float(std[0]), float(std[1]))
            if lid in landmarks and landmarks[lid] != val:
                raise _Bad(f"landmark {lid} already defined on line {lm_line[lid]} with different values")
            landmarks.setdefault(lid, val)
            lm_line.setdefault(lid, lineno)
        else:  # initial
            r = rec.ident("robot")
            t = rec.number("t") if rec.has("t") else None
            z = rec.vector("z")
            if z.size != 3:
                raise _Bad(f"'z' of an initial belief must be 'x y theta' (3 numbers), got {z.size}")
            cov = _noise(rec, 3, "an initial belief", dflt.get("initial"))
            if r in initial:
                z0, c0 = initial[r]
                if not (np.array_equal(z0, z) and np.array_equal(c0, cov) and init_t.get(r) == t):
                    raise _Bad(
                        f"initial belief of robot {r} already given on line {init_line[r]} with different values"
                    )
                return
            initial[r] = (_readonly(z), _readonly(cov))
            if t is not None:
                init_t[r] = t
            init_line[r] = lineno
            robots.add(r)

    def _detection(rec: _Record, seq: int) -> None:
        t, obs = rec.number("t"), rec.ident("robot")
        kind = rec.word("kind")
        if kind not in KIND_SIZES:
            raise _Bad(f"unknown detection kind {kind!r}; expected one of {', '.join(KIND_SIZES)}")
        m = KIND_SIZES[kind]
        target: int | None = None
        is_robot = True
        if kind == "absolute":
            if rec.has("target") or rec.has("target_type"):
                raise _Bad("an absolute detection (the observer's own pose) has no 'target' or 'target_type'")
        else:
            target = rec.ident("target")
            ttype = rec.word("target_type")
            if ttype not in ("robot", "landmark"):
                raise _Bad(f"'target_type' must be 'robot' or 'landmark', got {rec.raw['target_type']!r}")
            is_robot = ttype == "robot"
            if not is_robot and kind == "pose":
                raise _Bad("a landmark is a point: it has no relative pose (use range_bearing, range or bearing)")
            if is_robot and target == obs:
                raise _Bad(f"robot {obs} cannot detect itself (target equals robot)")
        z = rec.vector("z")
        if z.size != m:
            raise _Bad(f"'z' of a {kind} detection must have {m} number{'s' if m > 1 else ''}, got {z.size}")
        if kind in ("range_bearing", "range") and z[0] <= 0:
            raise _Bad(f"range must be positive, got {z[0]!r}")
        if kind in ("range_bearing", "bearing"):
            b = z[-1]
            if abs(b) > math.pi + _BEARING_TOL:
                raise _Bad(f"bearing must be in [-pi, pi] rad (degrees given?), got {b!r}")
        cov = _noise(rec, m, f"a {kind} detection", dflt.get(kind))
        d = Detection(
            observer=obs, t=t, kind=kind, z=_readonly(z), cov=_readonly(cov), target=target, target_is_robot=is_robot
        )
        keyed.append(((t, 0, obs, seq), d))
        robots.add(obs)
        if target is not None and is_robot:
            robots.add(target)

    rows = _csv_rows(p, label) if fmt == "csv" else _jsonl_rows(p)
    try:
        for seq, (lineno, text, fields_or_problem) in enumerate(rows):
            try:
                if isinstance(fields_or_problem, str):
                    raise _Bad(fields_or_problem)
                parse(_Record(fields_or_problem, text=fmt == "csv"), lineno, seq)
            except _Bad as exc:
                problems.append(f"{label} line {lineno}: {exc}, got {_shorten(text.strip())!r}")
                bad_lines.append(lineno)
    except UnicodeDecodeError as exc:
        raise EventFileError(f"{label}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise EventFileError(f"{label}: cannot read file ({exc.strerror or exc})") from None

    if problems and strict:
        raise EventFileError(_summary(label, problems, bad_lines), problems)
    if not any(isinstance(e, Odometry) for _, e in keyed):
        extra = f" ({len(problems)} bad lines skipped)" if problems else ""
        raise EventFileError(f"{label}: no odometry records{extra}; an event file needs at least one", problems)
    keyed.sort(key=lambda ke: ke[0])
    return EventFile(
        path=p,
        events=[e for _, e in keyed],
        landmarks=landmarks,
        initial=initial,
        initial_times=init_t,
        robots=sorted(robots),
        problems=problems,
    )


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
    fmt = _format(p)
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


def load_truth_dir(folder: str | os.PathLike[str], robots: Iterable[int]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Ground truth ``robot -> (times (N,) [s], xytheta (N, 3))`` from ``truth_robot<N>.tum`` files in ``folder``.

    Robots without a file are left out. Raises :class:`EventFileError` when ``folder`` is not a folder and
    :class:`~swarmloc.datasets.tum.TUMError` for a bad TUM file.
    """
    d = Path(folder).expanduser()
    if not d.is_dir():
        raise EventFileError(f"truth folder not found: {d}" if not d.exists() else f"truth path {d} is not a folder")
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for r in sorted(set(robots)):
        f = d / f"truth_robot{int(r)}.tum"
        if f.is_file():
            out[int(r)] = read_tum(f)
    return out
