"""A plain event file for your own robots: odometry, detections, landmarks and initial beliefs in CSV or JSON Lines.

Format (version 1). One record per line (a CSV cell may not span lines; a line holds at most 65536 characters);
lines starting with ``#`` and blank lines are comments. The format follows the file's extension: ``.csv`` or
``.jsonl``. A CSV file's first other line is the header row naming the columns, in any order; columns a file does
not use may be left out, unknown columns are an error; a row may stop after its last non-empty cell. A JSON Lines
file holds one JSON object per line with the same field names (a missing field or ``null`` is an empty cell;
numbers are JSON numbers, ``z``/``std``/``cov`` JSON arrays or, for one number, a number).
Words (``type``, ``target_type``, ``kind``) are case-insensitive. Units: metres, radians, seconds; poses
``(x, y, theta)`` in the world frame, relative quantities in the observer's body frame (x forward, y left).

Numbers in a CSV cell are plain decimals: optional sign, ASCII digits with an optional point, optional exponent
(``1``, ``-0.5``, ``2.5e-3``; blanks around a cell are ignored). ``1_0``, ``0x1``, ``infinity`` or non-ASCII
digits are bad values; ``inf`` and ``nan`` are bad values in every column (CSV and JSON).

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

Bounds (:mod:`swarmloc.datasets.bounds`; physically generous, a value beyond one is a bad value): times
``|t|, |t0| <= 1e10`` s; ids up to ``2**31 - 1``; ``|v| <= 1e3`` m/s, ``|w| <= 1e3`` rad/s; positions
(``x``, ``y`` of a pose, a fix or a landmark) and ranges within ``1e6`` m; headings within ``1e4`` rad; standard
deviations in ``[1e-12, 1e6]`` (a covariance's diagonal in their squares).

Records (every other cell empty):

* ``odometry``: ``t, robot, t0, v, w``; becomes ``Odometry(robot, t0, t, v, w)``. A robot's intervals
  ``[t0, t]`` may not overlap (1e-9 s of rounding is allowed; gaps are fine): of two that do, the one that starts
  later (at equal starts, the later line) is a bad line. They may not start before the robot's initial stamp:
  the ``t`` of its ``initial`` record, or, for a robot without one, the ``starts`` passed to
  :func:`load_events` (e.g. the start of its ground truth).
* ``detection``: ``t, robot, kind, z``; ``target, target_type`` (not for ``absolute``); ``std`` or ``cov``, or
  neither: then the reader's ``defaults`` for the kind apply. For a run (``swarmloc evaluate events``, the
  ``events:`` source) the observer and a robot target must be in the team, the robots with odometry in the file:
  a detection of robot 7 in a file whose robots with odometry are 0 and 1 is a bad line. ``z`` per kind:
  ``pose`` the target's relative pose ``x y theta`` in the observer's frame (its noise: the exponential
  coordinates of ``m_true^-1 m_measured``);
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

(on one line). :func:`load_events` reads the file as a stream and checks every record; it reports the bad lines
with the file name, the line number and the problem: the first 20 in full, then how many more and which lines,
in memory that does not grow with their number. :func:`~swarmloc.datasets.eventwrite.write_events` writes the
format so that it reads back exactly (floats as the shortest text that reads back to the same number). Events are
sorted by their natural stamp: odometry by ``t0`` (a commanded velocity is known when it starts), detections by
``t``; ties: detections before odometry, then by robot id, then file order.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeGuard

import numpy as np

from swarmloc.arrays import readonly
from swarmloc.datasets._eventfields import Bad, Record, check_point, check_pose, check_std, noise
from swarmloc.datasets.bounds import (
    MAX_LINE_CHARS,
    MAX_POSITION,
    MAX_SPEED,
    MAX_STAMP,
    MAX_YAW_RATE,
    BadLines,
    shorten,
)
from swarmloc.datasets.tum import read_tum
from swarmloc.events import Detection, Kind, MeasurementKind, Odometry
from swarmloc.gaussian import GroupGaussian, check_covariance
from swarmloc.lie import SE2
from swarmloc.sensors.models import MODELS

__all__ = [
    "COLUMNS",
    "EventFile",
    "EventFileError",
    "KIND_SIZES",
    "ODOMETRY_TOL",
    "load_events",
    "load_truth_dir",
    "file_format",
]

COLUMNS: tuple[str, ...] = ("type", "t", "robot", "t0", "v", "w", "target", "target_type", "kind", "z", "std", "cov")
"""The columns of the CSV format, in the order :func:`~swarmloc.datasets.eventwrite.write_events` writes them."""

KIND_SIZES: dict[str, int] = {k: MODELS[k].size for k in (Kind.POSE, Kind.RANGE_BEARING, Kind.RANGE, Kind.BEARING,
                                                            Kind.ABSOLUTE)}  # fmt: skip
"""Length of ``z`` per detection kind (the planar kinds' :data:`~swarmloc.sensors.models.MODELS`)."""


def _planar_kind(word: str) -> TypeGuard[MeasurementKind]:
    """True when ``word`` names a planar detection kind (one of :data:`KIND_SIZES`)."""
    return word in KIND_SIZES


RECORD_TYPES: tuple[str, ...] = ("odometry", "detection", "landmark", "initial")

ODOMETRY_TOL = 1e-9
"""[s] Rounding allowed when odometry intervals meet each other or the robot's initial stamp."""

_ALLOWED: dict[str, frozenset[str]] = {
    "odometry": frozenset({"t", "robot", "t0", "v", "w"}),
    "detection": frozenset({"t", "robot", "target", "target_type", "kind", "z", "std", "cov"}),
    "landmark": frozenset({"target", "target_type", "z", "std", "cov"}),  # cov: to say "use std"
    "initial": frozenset({"t", "robot", "z", "std", "cov"}),
}
_BEARING_TOL = 1e-9
_STAMP = (MAX_STAMP, "s")
_HINT = "skip them with strict=False, on the command line with --skip-bad-lines"

EventList = list[Odometry | Detection]
Span = tuple[tuple[float, int], tuple[float, int]]
"""``((t_start, line), (t_end, line))``: the earliest stamp and the latest end [s], and the lines that hold them."""


class EventFileError(ValueError):
    """A problem with an event file. ``problems`` holds the bad lines' messages (the first 20, then one line for
    the others; empty for file-level errors); ``n_bad`` counts them all."""

    def __init__(self, message: str, problems: Sequence[str] = (), n_bad: int | None = None) -> None:
        super().__init__(message)
        self.problems = list(problems)
        self.n_bad = len(self.problems) if n_bad is None else n_bad


@dataclass
class EventFile:
    """A loaded event file.

    ``events``: odometry and detections sorted by stamp (see the module doc). ``landmarks``: ``id -> (x, y, sx,
    sy)`` [m]. ``initial``: ``robot -> (pose (3,), cov (3, 3))``, pose ``(x, y, theta)`` and covariance of the
    exponential coordinates (right perturbation); ``initial_times``: ``robot -> t`` for initial records with a
    time. ``robots``: sorted ids of every robot named (odometry, observer, initial, robot target). ``problems``:
    the skipped bad lines (``strict=False``): the first 20 messages, then one line for the others; ``n_bad``: how
    many in all. ``span``: where the events start and end (:data:`Span`), None without events.
    """

    path: Path
    events: EventList
    landmarks: dict[int, tuple[float, float, float, float]] = field(default_factory=dict)
    initial: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    initial_times: dict[int, float] = field(default_factory=dict)
    robots: list[int] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    n_bad: int = 0
    span: Span | None = None

    def initial_beliefs(self) -> dict[int, GroupGaussian]:
        """The ``initial`` records as SE(2) :class:`~swarmloc.gaussian.GroupGaussian` beliefs."""
        return {r: GroupGaussian(SE2, SE2.from_xytheta(p), c) for r, (p, c) in self.initial.items()}


# ----------------------------------------------------------------------------------------------------------------
# reading: one record -> typed values


def _check_fields(rec: Record, rtype: str) -> None:
    extra = [k for k in COLUMNS if k != "type" and k not in _ALLOWED[rtype] and rec.has(k)]
    if extra:
        names = ", ".join(f"'{k}'" for k in extra)
        raise Bad(f"{names} do{'es' if len(extra) == 1 else ''} not apply to {rtype} records (leave empty)")


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


class _Reader:
    """One pass of :func:`load_events`: the records accepted so far (with their lines) and the bad lines."""

    def __init__(self, label: str, dflt: dict[str, np.ndarray]) -> None:
        self.dflt = dflt
        self.keyed: list[tuple[tuple[float, int, int, int], int, Odometry | Detection]] = []  # (key, line, event)
        self.landmarks: dict[int, tuple[float, float, float, float]] = {}
        self.lm_line: dict[int, int] = {}
        self.initial: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.init_t: dict[int, float] = {}
        self.init_line: dict[int, int] = {}
        self.bad = BadLines(label)

    def record(self, rec: Record, line: int, seq: int) -> None:
        """Check one record and keep what it says; raise :class:`Bad` naming the problem."""
        rtype = rec.word("type")
        if rtype not in _ALLOWED:
            raise Bad(f"unknown record type {rtype!r}; expected one of {', '.join(RECORD_TYPES)}")
        _check_fields(rec, rtype)
        if rtype == "odometry":
            t1, r, t0 = rec.number("t", _STAMP), rec.ident("robot"), rec.number("t0", _STAMP)
            v, w = rec.number("v", (MAX_SPEED, "m/s")), rec.number("w", (MAX_YAW_RATE, "rad/s"))
            if t1 < t0:
                raise Bad(f"odometry must have t >= t0, got t = {t1!r} < t0 = {t0!r}")
            self.keyed.append(((t0, 1, r, seq), line, Odometry(robot=r, t0=t0, t1=t1, v=v, w=w)))
        elif rtype == "detection":
            self.keyed.append(self._detection(rec, line, seq))
        elif rtype == "landmark":
            self._landmark(rec, line)
        else:
            self._initial(rec, line)

    def _detection(self, rec: Record, line: int, seq: int) -> tuple[tuple[float, int, int, int], int, Detection]:
        t, obs = rec.number("t", _STAMP), rec.ident("robot")
        kind = rec.word("kind")
        if not _planar_kind(kind):
            raise Bad(f"unknown detection kind {kind!r}; expected one of {', '.join(KIND_SIZES)}")
        m, model = KIND_SIZES[kind], MODELS[kind]
        target: int | None = None
        is_robot = True
        if kind == Kind.ABSOLUTE:
            if rec.has("target") or rec.has("target_type"):
                raise Bad("an absolute detection (the observer's own pose) has no 'target' or 'target_type'")
        else:
            target = rec.ident("target")
            ttype = rec.word("target_type")
            if ttype not in ("robot", "landmark"):
                raise Bad(f"'target_type' must be 'robot' or 'landmark', got {rec.raw['target_type']!r}")
            is_robot = ttype == "robot"
            if not is_robot and kind == Kind.POSE:
                raise Bad("a landmark is a point: it has no relative pose (use range_bearing, range or bearing)")
            if is_robot and target == obs:
                raise Bad(f"robot {obs} cannot detect itself (target equals robot)")
        z = rec.sized("z", m, f"a {kind} detection must have {m} number{'s' if m > 1 else ''}")
        if model.targets != "point":  # a pose (x, y, theta)
            check_pose(z)
        if model.ranged and not 0 < z[0] <= MAX_POSITION:
            raise Bad(f"range must be positive and at most {MAX_POSITION:g} m, got {z[0]!r}")
        if model.bearing_last and abs(z[-1]) > math.pi + _BEARING_TOL:
            raise Bad(f"bearing must be in [-pi, pi] rad (degrees given?), got {z[-1]!r}")
        cov = noise(rec, m, f"a {kind} detection", self.dflt.get(kind))
        d = Detection(
            observer=obs, t=t, kind=kind, z=readonly(z), cov=readonly(cov), target=target, target_is_robot=is_robot
        )
        return (t, 0, obs, seq), line, d

    def _landmark(self, rec: Record, line: int) -> None:
        lid = rec.ident("target")
        if rec.has("target_type") and rec.word("target_type") != "landmark":
            raise Bad(f"'target_type' of a landmark record must be 'landmark' or empty, got {rec.raw['target_type']!r}")
        z = rec.sized("z", 2, "a landmark must be 'x y' (2 numbers)")
        check_point(z)
        if rec.has("cov"):
            raise Bad("a landmark record takes 'std' (sx sy), not 'cov'")
        if rec.has("std"):
            std = rec.sized("std", 2, "a landmark must be 'sx sy' (2 numbers)")
            check_std(std)
        elif "landmark" in self.dflt:
            std = self.dflt["landmark"]
        else:
            raise Bad("a landmark has no 'std' and no default applies (pass defaults={'landmark': [sx, sy]})")
        val = (float(z[0]), float(z[1]), float(std[0]), float(std[1]))
        if lid in self.landmarks and self.landmarks[lid] != val:
            raise Bad(f"landmark {lid} already defined on line {self.lm_line[lid]} with different values")
        self.landmarks.setdefault(lid, val)
        self.lm_line.setdefault(lid, line)

    def _initial(self, rec: Record, line: int) -> None:
        r = rec.ident("robot")
        t = rec.number("t", _STAMP) if rec.has("t") else None
        z = rec.sized("z", 3, "an initial belief must be 'x y theta' (3 numbers)")
        check_pose(z)
        cov = noise(rec, 3, "an initial belief", self.dflt.get("initial"))
        if r in self.initial:
            z0, c0 = self.initial[r]
            if not (np.array_equal(z0, z) and np.array_equal(c0, cov) and self.init_t.get(r) == t):
                first = self.init_line[r]
                raise Bad(f"initial belief of robot {r} already given on line {first} with different values")
            return
        self.initial[r] = (readonly(z), readonly(cov))
        if t is not None:
            self.init_t[r] = t
        self.init_line[r] = line

    def check_odometry(self, starts: Mapping[int, tuple[float, str]]) -> None:
        """Make bad lines of the odometry records that start before their robot's initial stamp or overlap another
        of the same robot (the one that starts later is bad; see the module doc), and drop them."""
        per: dict[int, list[tuple[float, float, int, int]]] = {}
        for i, (_, line, e) in enumerate(self.keyed):
            if isinstance(e, Odometry):
                per.setdefault(e.robot, []).append((e.t0, e.t1, line, i))
        drop: set[int] = set()
        for r, items in per.items():
            start = self._start(r, starts)
            last: tuple[float, float, int] | None = None  # the kept interval that ends last
            for t0, t1, line, i in sorted(items, key=lambda x: (x[0], x[2])):
                if start is not None and t0 < start[0] - ODOMETRY_TOL:
                    problem = f"odometry of robot {r} starts at t0 = {t0!r} s, before its initial stamp {start[0]!r} s"
                    problem += f" ({start[1]})"
                elif last is not None and min(t1, last[1]) - t0 > ODOMETRY_TOL:
                    problem = (
                        f"odometry of robot {r} over [{t0!r}, {t1!r}] s overlaps its odometry on line {last[2]} over "
                        f"[{last[0]!r}, {last[1]!r}] s (a robot's odometry intervals may not overlap)"
                    )
                else:
                    if last is None or t1 > last[1]:
                        last = (t0, t1, line)
                    continue
                self.bad.add(line, problem)
                drop.add(i)
        if drop:
            self.keyed = [k for i, k in enumerate(self.keyed) if i not in drop]

    def check_team(self, team: Iterable[int] | str) -> None:
        """Make bad lines of the detections by or of a robot outside the team, and drop them: the robots of
        ``team``, or with ``"odometry"`` those with odometry (the robots a run estimates). Such a detection could
        only end ``unknown``."""
        if isinstance(team, str):
            if team != "odometry":
                raise ValueError(f"load_events: team must be robot ids or 'odometry', got {team!r}")
            members = sorted({e.robot for _, _, e in self.keyed if isinstance(e, Odometry)})
            how = "the robots with odometry in the file"
        else:
            members, how = sorted(set(team)), "the team given"
        known = set(members)
        drop: set[int] = set()
        for i, (_, line, e) in enumerate(self.keyed):
            if not isinstance(e, Detection):
                continue
            if e.observer not in known:
                problem = f"a detection by robot {e.observer}, which is not in the team"
            elif e.target_is_robot and e.target is not None and e.target not in known:
                problem = f"a detection of robot {e.target}, which is not in the team"
            else:
                continue
            self.bad.add(line, f"{problem} (robots {members}: {how})")
            drop.add(i)
        if drop:
            self.keyed = [k for i, k in enumerate(self.keyed) if i not in drop]

    def _start(self, robot: int, starts: Mapping[int, tuple[float, str]]) -> tuple[float, str] | None:
        """``(initial stamp [s], where it comes from)`` of ``robot``, or None when it has none."""
        if robot in self.initial:
            t = self.init_t.get(robot)
            return None if t is None else (t, f"the t of its initial record on line {self.init_line[robot]}")
        return starts.get(robot)

    def result(self, path: Path) -> EventFile:
        """The :class:`EventFile` of what was accepted."""
        self.keyed.sort(key=lambda k: k[0])
        events = [e for _, _, e in self.keyed]
        robots = set(self.initial)
        span: Span | None = None
        for key, line, e in self.keyed:
            if isinstance(e, Odometry):
                robots.add(e.robot)
                end = e.t1
            else:
                robots.add(e.observer)
                if e.target is not None and e.target_is_robot:
                    robots.add(e.target)
                end = e.t
            if span is None:
                span = ((key[0], line), (end, line))
            elif end > span[1][0]:
                span = (span[0], (end, line))
        return EventFile(path, events, self.landmarks, self.initial, self.init_t, sorted(robots),
                         self.bad.messages(), self.bad.n, span)  # fmt: skip


# ----------------------------------------------------------------------------------------------------------------
# reading: lines -> records

_TOO_LONG = f"line longer than {MAX_LINE_CHARS} characters (not a record)"


def _lines(path: Path) -> Iterator[tuple[int, str | None]]:
    """``(line number, text)`` of every line that is neither blank nor a ``#`` comment; text None for a line longer
    than ``MAX_LINE_CHARS`` (its text is skipped, never held)."""
    with open(path, encoding="utf-8-sig") as fh:  # -sig: a byte-order mark (as Excel writes) is skipped
        lineno = 0
        while raw := fh.readline(MAX_LINE_CHARS + 1):
            lineno += 1
            if len(raw) > MAX_LINE_CHARS and not raw.endswith("\n"):
                comment = raw.lstrip().startswith("#")
                while raw and not raw.endswith("\n"):
                    raw = fh.readline(MAX_LINE_CHARS + 1)
                if not comment:
                    yield lineno, None
                continue
            text = raw.rstrip("\r\n")
            s = text.strip()
            if s and not s.startswith("#"):
                yield lineno, text


Fields = Mapping[str, object] | str
"""A record's fields, or the problem of its line."""
Row = tuple[int, str, Fields]
"""``(line number, text, fields or problem)``."""


def _csv_rows(path: Path, label: str) -> Iterator[Row]:
    """One :data:`Row` per data line; the header is checked here."""
    lines = _lines(path)
    first = next(lines, None)
    if first is None:
        raise EventFileError(f"{label}: empty file: expected a header row ({','.join(COLUMNS)})")
    hline, htext = first
    if htext is None:
        raise EventFileError(f"{label} line {hline}: bad header row: {_TOO_LONG}")
    try:
        header = [h.strip().lower() for h in next(csv.reader([htext], strict=True))]
    except csv.Error as exc:
        raise EventFileError(f"{label} line {hline}: bad header row ({exc}), got {shorten(htext)!r}") from None
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
            f"got {shorten(htext)!r}"
        )

    def fields(text: str) -> Fields:
        try:
            cells = next(csv.reader([text], strict=True))
        except csv.Error as exc:
            return f"not a CSV row ({exc})"
        if len(cells) > len(header):
            return f"expected at most {len(header)} cells (as in the header row), got {len(cells)}"
        return dict(zip(header, cells, strict=False))  # trailing empty cells may be left out

    yield from _rows(lines, fields)


def _json_fields(text: str) -> Fields:
    """The fields of one JSON Lines record, or its problem."""
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        return f"not valid JSON ({exc.msg} at column {exc.colno})"
    except RecursionError:
        return "not valid JSON (nested too deeply)"
    if not isinstance(obj, dict):
        return f"expected a JSON object, got a {type(obj).__name__}"
    unknown = [k for k in obj if k not in COLUMNS]
    if unknown:
        return "unknown field(s) " + ", ".join(repr(shorten(k, 40)) for k in unknown[:5])
    return obj


def _rows(lines: Iterator[tuple[int, str | None]], fields: Callable[[str], Fields]) -> Iterator[Row]:
    """One :data:`Row` per line of ``lines`` (:func:`_lines`): its ``fields`` (or their problem), or the problem of a
    line too long."""
    for lineno, text in lines:
        yield (lineno, "", _TOO_LONG) if text is None else (lineno, text, fields(text))


def file_format(path: Path) -> str:
    """``"csv"`` or ``"jsonl"`` by the file's extension (anything else raises :class:`EventFileError`)."""
    ext = path.suffix.lower()
    if ext not in (".csv", ".jsonl"):
        raise EventFileError(f"{path.name}: unknown event file extension {path.suffix!r}; use .csv or .jsonl")
    return ext[1:]


# ----------------------------------------------------------------------------------------------------------------
# public API


def load_events(
    path: str | os.PathLike[str],
    defaults: Mapping[str, object] | None = None,
    strict: bool = True,
    starts: Mapping[int, tuple[float, str]] | None = None,
    team: Iterable[int] | str | None = None,
) -> EventFile:
    """Read an event file (``.csv`` or ``.jsonl``; format in the module doc), as a stream.

    ``defaults``: noise used when a record has neither ``std`` nor ``cov``, per key ``pose``, ``range_bearing``,
    ``range``, ``bearing``, ``absolute``, ``landmark``, ``initial``: a std vector (or, except for ``landmark``,
    a covariance matrix); e.g. :meth:`swarmloc.config.Config.event_defaults`. ``starts``: ``robot -> (t [s],
    where it comes from)``, the initial stamp of a robot without an ``initial`` record (e.g. the start of its
    ground truth): its odometry may not start before. ``team``: the robots of the team (ids), or ``"odometry"``:
    those with odometry in the file (the robots a run estimates); a detection by or of a robot outside it is then a
    bad line (it could only end ``unknown``); None: any robot. With ``strict=True`` any bad line raises
    :class:`EventFileError` saying how many and listing the first 20; with ``strict=False`` bad lines are skipped
    and listed in ``EventFile.problems`` (counted in ``n_bad``). A missing file, a bad header and a file without
    odometry always raise.
    """
    p = Path(path).expanduser()
    label = p.name
    fmt = file_format(p)
    if not p.is_file():
        raise EventFileError(f"event file not found: {p}" if not p.exists() else f"event path {p} is not a file")
    reader = _Reader(label, _normalize_defaults(defaults))
    rows = _csv_rows(p, label) if fmt == "csv" else _rows(_lines(p), _json_fields)
    try:
        for seq, (lineno, text, fields_or_problem) in enumerate(rows):
            try:
                if isinstance(fields_or_problem, str):
                    raise Bad(fields_or_problem)
                reader.record(Record(fields_or_problem, text=fmt == "csv"), lineno, seq)
            except Bad as exc:
                reader.bad.add(lineno, f"{exc}; the line: {shorten(text.strip())!r}" if text else str(exc))
    except UnicodeDecodeError as exc:
        raise EventFileError(f"{label}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise EventFileError(f"{label}: cannot read file ({exc.strerror or exc})") from None
    reader.check_odometry(starts or {})
    if team is not None:
        reader.check_team(team)
    bad = reader.bad
    if bad.n and strict:
        raise EventFileError(bad.summary(_HINT), bad.messages(), bad.n)
    if not any(isinstance(e, Odometry) for _, _, e in reader.keyed):
        extra = f" ({bad.n} bad lines skipped)" if bad.n else ""
        raise EventFileError(f"{label}: no odometry records{extra}; an event file needs at least one", bad.messages(),
                             bad.n)  # fmt: skip
    return reader.result(p)


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
