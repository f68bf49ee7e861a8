"""A team's events checked as the nodes check them, for the engine's replays (:class:`Checked`).

Malformed, duplicate and unusable input is rejected and counted with the nodes' reasons
(:func:`~swarmloc.node.inputs.validate_detection`, :func:`~swarmloc.node.inputs.odometry_problem`, the odometry
timeline's overlap rule, the stop past an interval's end); what is kept is filed by stamp for
:mod:`swarmloc.engine.replay`. Detections are screened in bulk first (:func:`~swarmloc.node.inputs.clearly_valid`),
and a robot's odometry that no sequential check could refuse is checked as arrays.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from operator import attrgetter
from typing import Any

import numpy as np

from swarmloc.engine.codes import NO_TARGET, UNKNOWN_ROBOT, UNUSABLE
from swarmloc.events import Detection, Kind, Odometry
from swarmloc.node import detection_key, odometry_problem, validate_detection
from swarmloc.node.inputs import CONTIGUOUS, OdometryTimeline, brief, clearly_valid, command_value, finite_number
from swarmloc.node.keys import SubKey

__all__ = ["Checked", "Commands", "Groups"]

Groups = dict[float, dict[int, dict[SubKey, tuple[Detection, int]]]]
"""Checked detections: stamp -> observer row -> detection key -> ``(detection, target code)``."""
Commands = dict[float, dict[int, tuple[Any, Any]]]
"""Checked odometry: start time -> robot row -> ``(v [m/s], w [rad/s])`` (an SE(3) team: tuples of 3, or a stop's
``(0.0, 0.0)``)."""
_T0_T1_V_W = tuple(map(attrgetter, ("t0", "t1", "v", "w")))
"""An odometry record's ``t0``, ``t1``, ``v`` and ``w``, one getter each."""


def _stamp(e: Any) -> float | None:
    s = e.stamp
    return float(s) if finite_number(s) else None


class Checked:
    """A source's odometry and detections checked as the nodes check them (malformed, duplicate and unusable input
    rejected and counted), filed by stamp: :attr:`odo` and :attr:`groups` (robots as rows of ``col``, landmarks as
    the codes ``landmark_code`` gives: :meth:`Engine.landmark_code`)."""

    def __init__(self, col: dict[Any, int], landmark_code: Callable[[Any], int]) -> None:
        self.col = col
        self.landmark_code = landmark_code
        self.counts: Counter[str] = Counter()
        self.reasons: Counter[str] = Counter()
        self.odo: Commands = defaultdict(dict)
        self.timeline = OdometryTimeline()
        self.groups: Groups = defaultdict(lambda: defaultdict(dict))
        self.bulk: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        """Odometry filed in bulk (:meth:`add_all`): chunks ``(t0 [s], row, v [m/s], w [rad/s])``."""
        self.bulk_rows: set[int] = set()
        self.first: dict[Any, float] = {}  # robot -> its first finite stamp (filed or not)

    def add_all(self, events: Sequence[Any]) -> None:
        """Every event of ``events``, as :meth:`add` one after the other would file and count them. A robot's
        odometry that is all plain finite numbers, in increasing ``t0`` and without overlaps (the sequential
        checks could not refuse one) is checked as arrays and filed in bulk (:attr:`bulk`); another robot's, one
        record at a time."""
        odometry: dict[Any, list[Odometry]] = defaultdict(list)
        detections: list[Detection] = []
        for e in events:
            if isinstance(e, Odometry):
                odometry[e.robot].append(e)
            elif isinstance(e, Detection):
                detections.append(e)
        for e, sure in zip(detections, clearly_valid(detections).tolist(), strict=True):
            self._first(e.observer, float(e.t) if sure else _stamp(e))
            self._detection(e, sure)
        for robot, mine in odometry.items():
            row = self.col.get(robot)
            if row is None or not self._bulk(row, mine):
                for e in mine:
                    self._first(robot, _stamp(e))
                    self._odometry(e)

    def _first(self, robot: Any, s: float | None) -> None:
        """Robot ``robot``'s first stamp so far, with an input at ``s`` [s] (None: not a finite number)."""
        if s is not None and robot in self.col:
            self.first[robot] = min(self.first.get(robot, math.inf), s)

    def start_times(self) -> np.ndarray:
        """Each robot's first stamp (an odometry record or a detection it made, filed or not), ``inf`` for a robot
        without input: where its belief starts (rows of ``col``)."""
        t0 = np.full(len(self.col), math.inf)
        for r, s in self.first.items():
            t0[self.col[r]] = s
        return t0

    def _bulk(self, row: int, mine: list[Odometry]) -> bool:
        """File robot ``row``'s odometry ``mine`` (arrival order) in bulk where no sequential check could refuse a
        record of it; False (nothing filed) otherwise."""
        if self.timeline.last(row) is not None:
            return False
        columns = []
        for field in _T0_T1_V_W:  # plain numbers (float, int, bool, numpy's) give a float or int array; strings,
            try:  # None, tuples do not
                a = np.array(list(map(field, mine)))
            except (ValueError, TypeError, OverflowError):
                return False
            if a.shape != (len(mine),) or a.dtype.kind not in "fiub":
                return False
            columns.append(a.astype(float))
        t0, t1, v, w = columns
        if not (np.isfinite(t0).all() and np.isfinite(t1).all() and np.isfinite(v).all() and np.isfinite(w).all()):
            return False
        # the sequential overlap check against the interval filed just before (intervals in order, t0 increasing)
        overlap = (t0[1:] < t1[:-1] - CONTIGUOUS) & (t0[:-1] < t1[1:] - CONTIGUOUS)
        if (t1 < t0).any() or (np.diff(t0) <= 0).any() or overlap.any():
            return False
        self.timeline.extend(row, t0.tolist(), t1.tolist())
        self.bulk.append((t0, np.full(t0.shape, row, dtype=np.int64), v, w))
        self.bulk_rows.add(row)
        self.first[mine[0].robot] = min(self.first.get(mine[0].robot, math.inf), float(t0[0]))
        self.counts["odometry"] += len(mine)
        self.counts["odometry_used"] += len(mine)
        return True

    def last_command(self) -> float:
        """The latest command start filed [s] (``-inf`` for none)."""
        return max([*self.odo, *(float(b[0][-1]) for b in self.bulk if b[0].size)], default=-math.inf)

    def commands(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every command filed, ``(t0 [s], row, v, w)`` as arrays (unsorted)."""
        flat = [(t, row, v, w) for t, cmds in self.odo.items() for row, (v, w) in cmds.items()]
        a = np.array(flat, dtype=float).reshape(-1, 4)
        parts = [*self.bulk, (a[:, 0], a[:, 1].astype(np.int64), a[:, 2], a[:, 3])]
        return tuple(np.concatenate([p[k] for p in parts]) for k in range(4))  # type: ignore[return-value]

    def by_stamp(self) -> Commands:
        """:attr:`odo` with the bulk commands filed in it too (start time -> row -> ``(v, w)``)."""
        for t0, rows, v, w in self.bulk:
            for t, row, vk, wk in zip(t0.tolist(), rows.tolist(), v.tolist(), w.tolist(), strict=True):
                self.odo[t][row] = (vk, wk)
        self.bulk.clear()
        return self.odo

    def reject(self, what: str, why: str) -> None:
        self.counts[what] += 1
        self.reasons[f"{what}: {why}"] += 1

    def add(self, e: Any) -> None:
        if isinstance(e, Odometry):
            self._odometry(e)
        elif isinstance(e, Detection):
            self._detection(e)

    def _odometry(self, e: Odometry) -> None:
        self.counts["odometry"] += 1
        if e.robot not in self.col:
            self.counts["unknown_robot"] += 1
            return
        why = odometry_problem(e)  # planar speeds, or an SE(3) team's 3-vectors
        if why is not None:
            self.reject("odometry_rejected", why)
        else:
            row, t0, t1 = self.col[e.robot], float(e.t0), float(e.t1)
            old = self.odo.get(t0, {}).get(row)
            if old is not None:
                same = old == (command_value(e.v), command_value(e.w))
                self.reject("odometry_rejected", "duplicate" if same else "a different command at the same t0")
                return
            why = self.timeline.overlap(row, t0, t1)
            if why:
                self.reject("odometry_rejected", why)
                return
            self.timeline.add(row, t0, t1)
            self.odo[t0][row] = (command_value(e.v), command_value(e.w))
            self.counts["odometry_used"] += 1

    def stops(self, last: float) -> None:
        """The nodes' policy past an interval's end ``t1`` with no odometry from there (:mod:`swarmloc.node.inputs`):
        the robot is stopped, a command ``(0, 0)`` at ``t1``, when a gap follows or when the replay goes on past
        ``t1`` (to ``last`` [s]); counted once per interval (``odometry_stops``). An interval of no length
        (``t0 = t1``) is followed by its stop too: the stop replaces its command at ``t1``, which lasted no time."""
        for row, (starts, ends) in self.timeline.intervals().items():
            if row in self.bulk_rows:  # the same rule on arrays (filed after the bulk: it replaces a command at t1)
                t1a = np.array(ends)
                t0n = np.append(np.array(starts[1:]), math.inf)  # the next interval's start
                at = t1a[(t0n > t1a + CONTIGUOUS) & (last > t1a + CONTIGUOUS)]
                if at.size:
                    zero = np.zeros(at.shape)
                    self.bulk.append((at, np.full(at.shape, row, dtype=np.int64), zero, zero))
                    self.counts["odometry_stops"] += int(at.size)
                continue
            for t1, nxt in zip(ends, [*starts[1:], math.inf], strict=True):
                if nxt > t1 + CONTIGUOUS and last > t1 + CONTIGUOUS:
                    self.odo[t1][row] = (0.0, 0.0)
                    self.counts["odometry_stops"] += 1

    def _detection(self, e: Detection, sure: bool = False) -> None:
        """File ``e`` (``sure``: :func:`~swarmloc.node.inputs.clearly_valid` found it well formed)."""
        self.counts["detections"] += 1
        if e.observer not in self.col:
            self.counts["unknown_robot"] += 1
            self.reject("unknown", f"observer {brief(e.observer)} is not in the team")
            return
        why = None if sure else validate_detection(e)
        if why is not None:
            self.reject("rejected", why)
            return
        code = NO_TARGET if e.kind == Kind.ABSOLUTE else self.col.get(e.target, UNKNOWN_ROBOT)
        if e.kind != Kind.ABSOLUTE and not e.target_is_robot:  # a landmark (the pose of one: in the group, not fused)
            code = UNUSABLE if e.kind == Kind.POSE else self.landmark_code(e.target)
        elif e.kind != Kind.ABSOLUTE and e.target is None:
            code = UNUSABLE
        group = self.groups[float(e.t)][self.col[e.observer]]
        key = detection_key(e)
        if key in group:
            self.reject("rejected", "duplicate detection")
            return
        group[key] = (e, code)
