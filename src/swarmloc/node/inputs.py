"""A node's input contract: what a detection and an odometry record must be, and each robot's odometry timeline.

* A **detection** has a known kind, a finite value ``z`` of that kind's size that the kind allows (a positive
  range), a finite stamp, a symmetric positive-definite covariance of matching size and an integer target id
  (:func:`validate_detection`).
* An **odometry** record ``(robot, t0, t1, v, w)`` has finite numbers and ``t0 <= t1``; one robot's intervals
  ``[t0, t1]`` do not overlap (up to :data:`CONTIGUOUS` s of rounding): :class:`OdometryTimeline` keeps them and
  says where a new one would overlap and which one is in force at a point of the history. Past the end ``t1``
  of an interval, until the robot's next one starts (a gap) or when none follows, a node assumes the robot
  **stopped**: its command becomes ``(0, 0)`` at ``t1`` and the motion model's zero-speed diffusion keeps its
  covariance growing (counted once per interval: ``odometry_stops``).
"""

from __future__ import annotations

import logging
import math
from bisect import bisect_left
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from swarmloc.events import Detection, Kind, Odometry
from swarmloc.gaussian import check_covariance
from swarmloc.messages import Message
from swarmloc.node.accounting import Accounting
from swarmloc.node.clock import FUTURE, Clock
from swarmloc.node.history import PRUNE_EVERY, History
from swarmloc.node.keys import P_GROUP, P_ODOMETRY, Entry, Group, Key, Position, detection_key
from swarmloc.node.protocol import Served, not_found, quarantine_reason
from swarmloc.node.trust import Trust
from swarmloc.sensors.models import MODELS
from swarmloc.sensors.models3 import MODELS3

if TYPE_CHECKING:
    from collections import Counter

log = logging.getLogger("swarmloc.node")

__all__ = [
    "CONTIGUOUS",
    "Intake",
    "Landmarks",
    "OdometryTimeline",
    "brief",
    "clearly_valid",
    "finite_number",
    "landmark_state",
    "odometry_problem",
    "validate_detection",
]


CONTIGUOUS = 1e-9
"""[s] Odometry intervals that overlap by less than this are contiguous (rounding of stamps)."""

Landmarks = Mapping[int, tuple[float, ...]]
"""Landmark id -> (x, y, std_x, std_y) in metres; a 3-D landmark (3-D teams): (x, y, z, std_x, std_y, std_z)."""

_VALID_COVS: dict[tuple[int, bytes], bool] = {}
"""Detection covariances already found valid, by ``(dimension, bytes)`` (sensors repeat one covariance)."""


def _clearly_valid(cov: np.ndarray) -> bool:
    """True when ``cov`` is ``1 x 1`` or ``2 x 2``, finite, exactly symmetric and positive definite with a margin
    (``det > 1e-9 trace^2``, so eigenvalues well above rounding): :func:`check_covariance` would accept it. False
    means "not sure": the full check decides."""
    if cov.shape == (1, 1):
        a = float(cov[0, 0])
        return math.isfinite(a) and a > 0
    if cov.shape != (2, 2):
        return False
    a, b, c, d = cov.ravel().tolist()
    if not (b == c and math.isfinite(a) and math.isfinite(b) and math.isfinite(d) and a > 0 and d > 0):
        return False
    return bool(a * d - b * b > 1e-9 * (a + d) * (a + d))  # not ** 2: a Python float's power raises on overflow


_NUMBER = frozenset({float, np.float64})  # not int: one too large for a float is checked one by one
_INTEGER = frozenset({int, np.int64})
_ID = 2**63  # ids are integers of 64 bits (:func:`_integer`)


def finite_number(x: object) -> bool:
    """True when ``x`` is a plain real number (int, float, numpy's floating) and finite (an int too large for a
    float is not: ``math.isfinite`` would raise on it)."""
    if not isinstance(x, int | float | np.floating):
        return False
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def _integer(x: object) -> bool:
    """An id: an int (not a bool) of 64 bits (as messages carry ids)."""
    return isinstance(x, int | np.integer) and not isinstance(x, bool) and bool(-_ID <= x < _ID)


def validate_detection(d: Detection) -> str | None:
    """Why a detection is unusable, or None when its kind, value, stamp, covariance and target are well formed."""
    try:
        z = np.asarray(d.z, dtype=float)
        cov = np.asarray(d.cov, dtype=float)
    except (TypeError, ValueError) as exc:
        return f"z or cov is not numeric: {exc}"
    model = (MODELS.get(d.kind) or MODELS3.get(d.kind)) if isinstance(d.kind, str) else None
    if model is None:
        return f"unknown measurement kind {brief(d.kind)}"
    want = model.size
    if z.shape != (want,):
        return f"z has shape {z.shape}, expected ({want},) for kind {brief(d.kind)}"
    if not np.isfinite(z).all():
        return "z contains NaN or inf"
    if not finite_number(d.t):
        return f"time stamp {brief(d.t)} is not a finite number"
    seen = (want, cov.tobytes()) if cov.shape == (want, want) else None
    if seen is None or not (_clearly_valid(cov) or seen in _VALID_COVS):
        try:
            check_covariance(cov, want, "detection", "cov")
        except ValueError as exc:
            return str(exc)
        if seen is not None:
            if len(_VALID_COVS) >= 4096:
                _VALID_COVS.clear()
            _VALID_COVS[seen] = True
    why = model.problem(z)
    if why is not None:
        return why
    if d.target is not None and not _integer(d.target):
        return f"target id must be an integer of 64 bits, got {brief(d.target)}"
    if not _integer(d.observer):
        return f"observer id must be an integer of 64 bits, got {brief(d.observer)}"
    return None


_KIND_TYPES = (str, Kind)
"""A kind's exact types the fast screen takes: a name, or a :class:`~swarmloc.events.Kind` member."""


def clearly_valid(ds: Sequence[Detection]) -> np.ndarray:
    """``(len(ds),)`` bool: True where :func:`validate_detection` certainly finds detection ``ds[k]`` well formed,
    decided on arrays per kind: a planar kind, ``z`` and ``cov`` numeric numpy arrays of the kind's sizes, finite,
    a positive range, a finite float stamp, 64-bit int ids, the covariance checked as :func:`_clearly_valid`
    checks it. False means "not sure": call :func:`validate_detection`, which says why. For checking many
    detections at once (a replay's): one odd detection leaves the others' screen as it is."""
    ok = np.zeros(len(ds), dtype=bool)
    by_kind: dict[str, list[int]] = {}
    for k, d in enumerate(ds):
        model = MODELS.get(d.kind) if type(d.kind) in _KIND_TYPES else None
        if model is None:
            continue
        m, z, cov = model.size, d.z, d.cov
        if (type(z) is np.ndarray and type(cov) is np.ndarray and z.shape == (m,) and cov.shape == (m, m)
                and z.dtype.kind in "fi" and cov.dtype.kind in "fi" and type(d.t) in _NUMBER
                and type(d.observer) in _INTEGER and -_ID <= d.observer < _ID
                and (d.target is None or (type(d.target) in _INTEGER and -_ID <= d.target < _ID))):  # fmt: skip
            by_kind.setdefault(d.kind, []).append(k)
    for kind, rows in by_kind.items():
        z = np.array([ds[k].z for k in rows], dtype=float)
        cov = np.array([ds[k].cov for k in rows], dtype=float)
        t = np.array([ds[k].t for k in rows], dtype=float)
        good = np.isfinite(z).all(axis=1) & np.isfinite(t) & _clearly_valid_batch(cov)
        if MODELS[kind].ranged:
            good &= z[:, 0] > 0
        ok[rows] = good
    return ok


def _clearly_valid_batch(cov: np.ndarray) -> np.ndarray:
    """:func:`_clearly_valid` over ``cov (k, m, m)`` (``m`` 1 or 2; False for other sizes)."""
    if cov.shape[1:] == (1, 1):
        a = cov[:, 0, 0]
        ok: np.ndarray = np.isfinite(a) & (a > 0)
        return ok
    if cov.shape[1:] != (2, 2):
        return np.zeros(cov.shape[0], dtype=bool)
    a, b, c, d = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 0], cov[:, 1, 1]
    finite = np.isfinite(a) & np.isfinite(b) & np.isfinite(d)
    with np.errstate(invalid="ignore", over="ignore"):
        ok = finite & (b == c) & (a > 0) & (d > 0) & (a * d - b * b > 1e-9 * (a + d) * (a + d))
    return ok


def brief(x: object) -> str:
    """``repr(x)`` for a message, at most 40 characters (an int of 5000 digits has no repr at all)."""
    try:
        text = repr(x)
    except ValueError:
        return f"<{type(x).__name__} too large to show>"
    return text if len(text) <= 40 else text[:37] + "..."


def _components(x: object) -> tuple[Any, ...]:
    """A command's numbers: ``(x,)`` for a planar speed, the 3 components of a 3-D velocity (a tuple)."""
    if isinstance(x, tuple):
        if len(x) != 3:
            raise TypeError("a 3-D velocity has 3 components")
        return x
    return (x,)


def command_value(x: float | tuple[float, ...]) -> float | tuple[float, ...]:
    """A command's value as filed: a float (planar), or a tuple of 3 floats (a 3-D velocity)."""
    return tuple(float(c) for c in x) if isinstance(x, tuple) else float(x)


def odometry_problem(e: Odometry) -> str | None:
    """Why an odometry record is malformed (non-numeric or non-finite numbers, ``t1 < t0``), or None."""
    try:
        finite = all(math.isfinite(x) for x in (e.t0, e.t1, *_components(e.v), *_components(e.w)))
    except (TypeError, OverflowError):  # not a number; an int too large for a float
        finite = False
    if not finite:
        return "non-finite or non-numeric time or speed"
    if e.t1 < e.t0:
        return "t1 before t0"
    return None


def landmark_state(landmarks: Landmarks | None, lid: int | None) -> tuple[np.ndarray, np.ndarray] | None:
    """Position ``(2,)`` and covariance ``(2, 2)`` of a known landmark (a 3-D one: ``(3,)`` and ``(3, 3)``), or
    None."""
    if landmarks is None or lid is None or lid not in landmarks:
        return None
    row = landmarks[lid]
    d = len(row) // 2
    std = np.asarray(row[d:], dtype=float)
    return np.asarray(row[:d], dtype=float), np.diag(std * std)


class OdometryTimeline:
    """Each robot's odometry intervals ``[t0, t1]``, sorted by ``t0``, non-overlapping."""

    def __init__(self) -> None:
        self._t0: dict[int, list[float]] = {}
        self._t1: dict[int, list[float]] = {}

    def clear(self) -> None:
        self._t0.clear()
        self._t1.clear()

    def overlap(self, robot: int, t0: float, t1: float) -> str | None:
        """Why ``[t0, t1]`` cannot join ``robot``'s intervals (it overlaps one), or None."""
        starts, ends = self._t0.get(robot), self._t1.get(robot)
        if not starts or ends is None:
            return None
        i = bisect_left(starts, t0)
        for j in (i - 1, i):
            if 0 <= j < len(starts) and t0 < ends[j] - CONTIGUOUS and starts[j] < t1 - CONTIGUOUS:
                return f"overlaps the odometry interval [{starts[j]:.9g}, {ends[j]:.9g}] s filed before"
            if 0 <= j < len(starts) and starts[j] == t0:
                return f"overlaps the odometry interval [{starts[j]:.9g}, {ends[j]:.9g}] s filed before"
        return None

    def add(self, robot: int, t0: float, t1: float) -> None:
        starts = self._t0.setdefault(robot, [])
        ends = self._t1.setdefault(robot, [])
        if not starts or t0 > starts[-1]:  # in order: the common case
            starts.append(t0)
            ends.append(t1)
            return
        i = bisect_left(starts, t0)
        starts.insert(i, t0)
        ends.insert(i, t1)

    def extend(self, robot: int, t0: list[float], t1: list[float]) -> None:
        """File ``robot``'s intervals ``[t0[k], t1[k]]``, sorted and non-overlapping, all after its last one (the
        caller has checked them)."""
        starts = self._t0.setdefault(robot, [])
        if starts and t0 and t0[0] <= starts[-1]:
            raise ValueError("OdometryTimeline.extend: intervals must come after the robot's last one")
        starts.extend(t0)
        self._t1.setdefault(robot, []).extend(t1)

    def intervals(self) -> dict[int, tuple[list[float], list[float]]]:
        """Every robot's intervals as ``(starts, ends)`` (sorted, read-only views of the timeline)."""
        return {r: (self._t0[r], self._t1[r]) for r in self._t0}

    def last(self, robot: int) -> tuple[float, float] | None:
        """``robot``'s latest interval ``(t0, t1)``, or None."""
        starts = self._t0.get(robot)
        return (starts[-1], self._t1[robot][-1]) if starts else None

    def in_force(self, robot: int, after: Position) -> tuple[float, float] | None:
        """The interval ``(t0, t1)`` of ``robot`` whose command is in force in a state after the history entries
        keyed before ``after``: the latest with key ``(t0, P_ODOMETRY, robot, ())`` before ``after``; None if none."""
        starts = self._t0.get(robot)
        if not starts:
            return None
        if after > (starts[-1], 2, robot, ()):  # the common case: after the latest interval
            return starts[-1], self._t1[robot][-1]
        i = bisect_left(starts, after[0])
        if i < len(starts) and starts[i] == after[0] and (2, robot, ()) < after[1:]:
            i += 1
        return (starts[i - 1], self._t1[robot][i - 1]) if i > 0 else None

    def prune(self, cutoff: float) -> None:
        """Forget intervals that started before ``cutoff``, but the one in force at ``cutoff``."""
        for robot, starts in self._t0.items():
            n = bisect_left(starts, cutoff) - 1
            if n > 0:
                del starts[:n]
                del self._t1[robot][:n]


class Intake:
    """How a :class:`~swarmloc.node.base.Node` takes its own robots' odometry and detections: checked against the
    input contract and the clock (:mod:`~swarmloc.node.clock`), then filed in the history (a part of the node: its
    methods use the node's clock, history, timeline and accounting)."""

    robots: tuple[int, ...]
    accounting: Accounting
    _clock: Clock
    _history: History
    _timeline: OdometryTimeline
    _pending: dict[Key, Group]
    _since_prune: int
    _trust: Trust
    _served: Served
    name: ClassVar[str]
    lazy_odometry: ClassVar[bool]

    if TYPE_CHECKING:  # the node's (swarmloc.node.base.Node), declared for the type checker

        @property
        def counts(self) -> Counter[str]: ...
        @property
        def horizon(self) -> float: ...
        @property
        def tolerance(self) -> float: ...
        def start(self, t0: float) -> None: ...
        def _adv(self, s: Any, robot: int, t: float, after: Position | None = ...) -> Any: ...
        def _file(self, entries: list[Entry], accept: bool = ...) -> list[Message]: ...
        def _replay(self, pos: int, late: bool, changed: Key | None = ...) -> list[Message]: ...
        def _requests(self, g: Group) -> list[Message]: ...
        def _restamp(self, s: Any, t: float) -> Any: ...
        def _set_command(self, s: Any, robot: int, v: float, w: float) -> Any: ...

    # ------------------------------------------------------------------------------------------------ clock
    def _ensure_started(self, t: float) -> None:
        if self._clock.t0 is None:
            self.start(t)

    def _admit(self, t: float, item: Any) -> list[Message] | None:
        """Check an input of the node's own robots stamped ``t`` against the clock. None: file it (inputs held
        before are then refused: the clock did not jump). Otherwise it is held as a possible clock jump and the
        messages to send are returned (those of the held inputs, filed after a confirmed jump)."""
        verdict = self._clock.side(t)
        if verdict is None:
            if self._clock.held:
                self._refuse_held(self._clock.release())
            return None
        side = verdict[0]
        self._refuse_held(self._clock.hold(t, side, item))
        if self._clock.jumped():
            return self._clock_jump(side)
        return []

    def _refuse_held(self, held: list[tuple[float, str, Any]]) -> None:
        """Count inputs held as a possible clock jump, which it was not, as refused with their reason."""
        for t, side, item in held:
            why = self._clock.future(t) if side == FUTURE else self._clock.too_old(t)
            why = why or f"stamp {t} did not agree with the node's clock when it came"
            if side == FUTURE:
                self.counts["future"] += 1 if isinstance(item, Odometry) else len(item)
            if isinstance(item, Odometry):
                self.accounting.odometry_rejected(why)
            else:
                for d in item:
                    self.accounting.detection_rejected(d.observer, d.t, why)

    def _clock_jump(self, side: str) -> list[Message]:
        """The robot's clock jumped (the held inputs agree): keep the belief at the present, re-stamped at the
        earliest held stamp; forget the history, the answers given, the groups waiting (``unknown``); then file
        the held inputs."""
        held = self._clock.release()
        t_new = min(t for t, _, _ in held)
        old = self._clock.present
        s = self._history.last_state()
        for r in self.robots:
            s = self._adv(s, r, old, (math.inf,))
        for key in sorted(self._pending):
            g = self._pending.pop(key)
            for d in g.detections:
                self.accounting.detection_rejected(d.observer, d.t, "the robot's clock jumped", "unknown")
        self._history.reset(self._restamp(s, t_new), (t_new, -1, -1, ()))
        self._timeline.clear()
        self._served.clear()
        self._clock.restart(t_new)
        self.counts["clock_jumps" if side == FUTURE else "clock_resets"] += 1
        log.warning("%s: robot clock jumped %s from %.9g s to %.9g s: history reset, belief kept", self.name,
                    "forward" if side == FUTURE else "back", old, t_new)  # fmt: skip
        out: list[Message] = []
        for t, _, item in sorted(held, key=lambda h: h[0]):
            if isinstance(item, Odometry):
                out += self._take_odometry(item)
            else:
                out += self._take_detections(int(item[0].observer), t, item)
        return out

    # ------------------------------------------------------------------------------------------------ odometry
    def _odometry_fast(self, e: Odometry) -> bool:
        """Consume ``e`` if it takes the common path: valid, in order (after every entry), contiguous with its
        robot's last interval, inside the clock, nothing to revise and no pruning due; False (nothing changed)
        otherwise, for :meth:`step` to handle it. The in-process runner calls it before :meth:`step`."""
        t0, t1, v, w = e.t0, e.t1, e.v, e.w
        clock = self._clock
        if not (type(t0) is type(t1) is type(v) is type(w) is float) or self._since_prune >= PRUNE_EVERY - 1:
            return False
        robot = e.robot
        start = clock.t0
        if start is None or robot not in self.robots or not (start <= t0 <= t1) or clock.held:
            return False
        present = clock.present
        if not (present - clock.horizon <= t0 <= present + clock.tolerance and t1 <= max(present, t0) + clock.tolerance
                and math.isfinite(v) and math.isfinite(w)):  # fmt: skip
            return False
        last = self._timeline.last(robot)
        if last is not None and not (last[0] < t0 and abs(t0 - last[1]) <= CONTIGUOUS):
            return False
        key: Key = (t0, P_ODOMETRY, robot, ())
        hist = self._history
        latest = self._served.latest_key()
        if (hist.keys and not hist.keys[-1] < key) or (latest is not None and latest > key):
            return False
        counts = self.counts
        counts["odometry"] += 1
        counts["odometry_used"] += 1
        self._timeline.add(robot, t0, t1)
        entry = Entry(key, "odometry", (robot, v, w))
        if not self.lazy_odometry:
            self._cursor = key
            entry.state = self._set_command(self._adv(hist.last_state(), robot, t0), robot, v, w)
        hist.append(entry)
        if t0 > present:
            clock.present = t0
        self._since_prune += 1
        return True

    def _on_odometry(self, e: Odometry) -> list[Message]:
        if self._odometry_fast(e):
            return []
        self.counts["odometry"] += 1
        if e.robot not in self.robots:
            self.accounting.odometry_rejected(f"robot {brief(e.robot)} is not a robot of this node")
            return []
        why = odometry_problem(e)
        if why:
            self.accounting.odometry_rejected(why)
            return []
        self._ensure_started(float(e.t0))
        return self._take_odometry(e)

    def _take_odometry(self, e: Odometry) -> list[Message]:
        """File a well-formed odometry record of this node's robot (counted in): clock, duplicates, overlaps,
        then the command and the stops its gaps need."""
        held = self._admit(float(e.t0), e)
        if held is not None:
            return held
        t0, t1 = float(e.t0), float(e.t1)
        if t1 > max(self._clock.present, t0) + self.tolerance:
            self.counts["future"] += 1
            self.accounting.odometry_rejected(f"interval ends at {t1:.9g} s, {self._clock.future(t1)}")
            return []
        key: Key = (t0, P_ODOMETRY, e.robot, ())
        pos = self._history.find(key)
        if pos is not None:
            _, v, w = self._history.entries[pos].data
            why = "duplicate" if (v, w) == (e.v, e.w) else "a different command at the same t0"
            self.accounting.odometry_rejected(why)
            return []
        overlap = self._timeline.overlap(e.robot, t0, t1)
        if overlap:
            self.accounting.odometry_rejected(overlap)
            return []
        self.counts["odometry_used"] += 1
        self._timeline.add(e.robot, t0, t1)
        return self._file([Entry(key, "odometry", (e.robot, command_value(e.v), command_value(e.w)))])

    # ------------------------------------------------------------------------------------------------ detections
    def _on_detections(self, dets: list[Detection]) -> list[Message]:
        groups: dict[tuple[int, float], list[Detection]] = {}
        for d in dets:
            self.counts["detections"] += 1
            why = validate_detection(d)
            if why is None and d.observer not in self.robots:
                why = f"observer {brief(d.observer)} is not a robot of this node"
            if why is not None:
                self.accounting.detection_rejected(d.observer, d.t, why)
                continue
            groups.setdefault((int(d.observer), float(d.t)), []).append(d)
        out: list[Message] = []
        for (obs, t), ds in groups.items():
            self._ensure_started(t)
            out += self._take_detections(obs, t, ds)
        return out

    def _take_detections(self, observer: int, t: float, ds: list[Detection]) -> list[Message]:
        """File well-formed detections of one observer at one instant (counted in): clock, then the group."""
        held = self._admit(t, ds)
        if held is not None:
            return held
        return self._add_detections(observer, t, ds)

    def _add_detections(self, observer: int, t: float, ds: list[Detection]) -> list[Message]:
        key: Key = (t, P_GROUP, observer, ())
        pending = self._pending.get(key)
        g = pending if pending is not None else Group(observer, t)
        pos = self._history.find(key)
        applied: Group | None = self._history.entries[pos].data if pos is not None else None
        added = []
        for d in ds:
            if (applied is not None and detection_key(d) in applied.keys) or not g.add(d):
                self.accounting.detection_rejected(d.observer, d.t, "duplicate detection")
            else:
                added.append(d)
        if not added:
            return []
        if applied is not None:  # the answers already received serve the new detections too
            g.answers = {**applied.answers, **g.answers}
        queries = [q for q in self._requests(g) if (q.receiver, q.sub) not in g.answers]
        shut = self._trust.quarantined  # nothing is asked of a quarantined teammate: answered here, not found
        for q in queries:
            g.answers[(q.receiver, q.sub)] = not_found(q, quarantine_reason(q.receiver)) if q.receiver in shut else None
        queries = [q for q in queries if q.receiver not in shut]
        if queries or (pending is not None and g.waiting()):
            self._pending[key] = g
            return queries
        self._pending.pop(key, None)
        return self._commit_group(key, g)

    def _commit_group(self, key: Key, g: Group) -> list[Message]:
        """Put a group whose answers are all in (or given up) into the history and apply it."""
        pos = self._history.find(key)
        if pos is not None:  # merge into the applied group
            old: Group = self._history.entries[pos].data
            for d in g.detections:
                old.add(d)
            old.answers.update({k: v for k, v in g.answers.items() if v is not None})
            return self._replay(pos, late=True)
        if key[0] < self._clock.present - self.horizon:  # waited too long: beyond the horizon now
            for d in g.detections:
                self.accounting.detection_rejected(d.observer, d.t, "older than the history horizon")
            return []
        return self._file([Entry(key, "group", g)])
