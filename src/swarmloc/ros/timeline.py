"""One robot's ROS inputs as swarmloc events, in one place for the live node and the replay of a recording.

The robot's start ``t0`` is the stamp of its first odometry message (its belief there is ``initial_state``, or
the last ``/initialpose`` that came before it); each later odometry message closes an interval
(:mod:`swarmloc.ros.convert`). An ``/initialpose`` after the start is an absolute fix of the robot's pose, fused
(and gated) like any measurement: the team's correlations stay consistent, which a hard reset of one robot's
belief would break. Detections stamped before ``t0`` are refused (``before_start``); those that arrive before the
first odometry wait for it (at most :data:`MAX_EARLY`). The odometry samples are kept (a bounded window) for the
``map -> odom`` transform and the output's twist. Every message ends counted: turned into events, or refused
with its reason.
"""

from __future__ import annotations

import bisect
import math
from collections import Counter, deque
from collections.abc import Mapping
from typing import Any

import numpy as np

from swarmloc.events import Detection, Event, Odometry
from swarmloc.ros.convert import OdomSample, Refused, detections_in, initialpose_in, interpolate_pose, odometry_in

MAX_EARLY = 1000
"""Detection messages kept while the first odometry has not come (older ones refused ``early_overflow``)."""
MAX_SAMPLES = 20_000
"""Odometry samples kept for the transform and the twist (about 200 s at 100 Hz)."""


class InputTimeline:
    """Robot ``robot``'s inputs (module docstring). ``mounts``: sensor frame -> ``(x, y, yaw)`` on ``base_frame``;
    ``robots``: the team (detections of other robots are refused ``unknown_robot``)."""

    def __init__(
        self,
        robot: int,
        *,
        base_frame: str = "base_link",
        world_frame: str = "map",
        mounts: Mapping[str, tuple[float, float, float]] | None = None,
        robots: frozenset[int] | None = None,
    ) -> None:
        self.robot = int(robot)
        self.base_frame, self.world_frame = base_frame, world_frame
        self.mounts = dict(mounts or {})
        self.robots = robots
        self.t0: float | None = None
        self.initial: tuple[np.ndarray, np.ndarray] | None = None
        """``(x, y, yaw)`` and its world-frame covariance from an ``/initialpose`` before the start (None: none)."""
        self.samples: deque[OdomSample] = deque(maxlen=MAX_SAMPLES)
        self._times: deque[float] = deque(maxlen=MAX_SAMPLES)
        self._early: deque[Any] = deque()
        self.counts: Counter[str] = Counter()
        """Messages received per input (``odometry``, ``detections``, ``initialpose``) and events made (``events``)."""
        self.reasons: Counter[str] = Counter()
        """Inputs refused, by reason."""

    # ---------------------------------------------------------------------------------------------- inputs
    def odometry(self, msg: Any) -> list[Event]:
        """The events of one odometry message: none for the first (it sets ``t0``), else the interval it closes;
        then the detections that waited for the start."""
        self.counts["odometry"] += 1
        try:
            s = odometry_in(msg)
        except Refused as exc:
            self.reasons[f"odometry_{exc.reason}"] += 1
            return []
        if self.t0 is None:
            self.t0 = s.t
            self._keep(s)
            out: list[Event] = []
            while self._early:
                out += self.detections(self._early.popleft(), again=True)
            return out
        prev = self.samples[-1]
        if s.t <= prev.t:
            self.reasons["odometry_not_after_previous"] += 1
            return []
        self._keep(s)
        self.counts["events"] += 1
        return [Odometry(self.robot, prev.t, s.t, s.v, s.w)]

    def detections(self, msg: Any, again: bool = False) -> list[Event]:
        """The detections of one ``Detection3DArray`` (refused ones counted by reason)."""
        if not again:
            self.counts["detections"] += 1
        if self.t0 is None:
            if len(self._early) >= MAX_EARLY:
                self._early.popleft()
                self.reasons["early_overflow"] += 1
            self._early.append(msg)
            return []
        t, dets, refused = detections_in(msg, self.robot, self.mounts, self.base_frame, self.robots)
        self.reasons.update(refused)
        if dets and t < self.t0:
            self.reasons["before_start"] += len(dets)
            return []
        self.counts["events"] += len(dets)
        return list(dets)

    def initialpose(self, msg: Any) -> list[Event]:
        """An ``/initialpose`` as an absolute fix of the robot (a message stamped 0, as some tools send it, is taken
        at the latest odometry's stamp: a function of the inputs, the same live and replayed)."""
        self.counts["initialpose"] += 1
        try:
            now = self.samples[-1].t if self.samples else 0.0
            d = initialpose_in(msg, self.robot, self.world_frame, now)
        except Refused as exc:
            self.reasons[f"initialpose_{exc.reason}"] += 1
            return []
        if self.t0 is None:
            self.initial = (np.asarray(d.z, dtype=float), np.asarray(d.cov, dtype=float))
            self.counts["initialpose_initial"] += 1
            return []
        if d.t < self.t0:
            self.reasons["initialpose_before_start"] += 1
            return []
        self.counts["events"] += 1
        return [d]

    def _keep(self, s: OdomSample) -> None:
        self.samples.append(s)
        self._times.append(s.t)

    # ---------------------------------------------------------------------------------------------- outputs
    def odom_at(self, t: float) -> tuple[np.ndarray | None, OdomSample | None]:
        """The odometry pose at ``t`` (interpolated; None outside the samples kept) and the sample whose interval
        holds ``t`` (its twist is in force then; None before the second sample or after the last)."""
        k = bisect.bisect_left(self._times, t)
        if k < len(self.samples) and self.samples[k].t == t:
            return np.asarray(self.samples[k].pose, dtype=float), (self.samples[k] if k > 0 else None)
        if k == 0 or k >= len(self.samples):
            return None, None
        a, b = self.samples[k - 1], self.samples[k]
        return interpolate_pose(t, a, b), b


def record_times(t0: float, frequency: float, upto: float) -> np.ndarray:
    """``t0 + k / frequency`` for ``k = 0, 1, ...`` up to ``upto`` [s] (as the network node makes them)."""
    if not math.isfinite(upto) or upto < t0:
        return np.zeros(0)
    k1 = math.floor((upto - t0) * frequency + 1e-9) + 1
    return t0 + np.arange(k1) / frequency


def refused_record(e: Odometry | Detection, reason: str) -> dict[str, Any]:
    """An input event the node's feed refused (``reason``: ``stale`` for a late one...) as JSON-ready fields, enough
    to leave that event out of a replay (:func:`refused_key`): ``kind`` (``odometry`` or ``detection``), ``robot``
    (the robot's own), ``stamp`` [s] (where the event is filed); odometry's lost interval ``t0``, ``t1`` [s] (the
    message's sample was kept: only the interval it closes is lost); a detection's ``what`` (its measurement kind),
    ``target`` and ``target_is_robot``."""
    if isinstance(e, Odometry):
        return {"kind": "odometry", "robot": int(e.robot), "stamp": float(e.stamp), "t0": float(e.t0),
                "t1": float(e.t1), "reason": reason}  # fmt: skip
    return {"kind": "detection", "robot": int(e.observer), "stamp": float(e.stamp), "what": str(e.kind),
            "target": None if e.target is None else int(e.target), "target_is_robot": bool(e.target_is_robot),
            "reason": reason}  # fmt: skip


def refused_key(rec: Mapping[str, Any]) -> tuple[Any, ...]:
    """What names one input event in a :func:`refused_record` (its reason aside): equal for the event the live node
    refused and the one the replay makes of the same message (the same conversion of the same stamps)."""
    if rec["kind"] == "odometry":
        return ("odometry", int(rec["robot"]), float(rec["t0"]), float(rec["t1"]))
    return ("detection", int(rec["robot"]), float(rec["stamp"]), str(rec["what"]), rec["target"],
            bool(rec["target_is_robot"]))  # fmt: skip
