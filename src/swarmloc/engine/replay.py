"""Replay a team's events through the batched engine: :func:`run_engine`, comparable to :func:`swarmloc.runner.run`.

The events are checked as the nodes check them (malformed, duplicate and unusable input is rejected and counted
the same way), put on one timeline of stamps, and each stamp is one :meth:`Engine.step`: the detection groups
stamped ``t`` then the commands starting at ``t``; beliefs are recorded at the record times after every input
stamped at or before them (what :meth:`~swarmloc.node.base.Node.belief_at` answers).

An SE(3) team (initial beliefs on SE(3), e.g. ``sim:3d``) runs on the engine's SE(3) path: body-twist odometry
(:func:`swarmloc.events.twist_odometry`), ``"pose3"`` detections, the source's twist noise (``Source.noise``), tracks
recorded as ``(x, y, z, qx, qy, qz, qw)`` with ``(6, 6)`` covariances, as :func:`swarmloc.runner.run` records them.
"""

from __future__ import annotations

import math
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from swarmloc.config import Config
from swarmloc.datasets.source import Source
from swarmloc.datasets.tum import pose7
from swarmloc.engine.codes import NO_TARGET, UNKNOWN_ROBOT, UNUSABLE
from swarmloc.engine.core import Engine
from swarmloc.engine.detections import Detections
from swarmloc.estimators import node_options
from swarmloc.events import Detection, Odometry
from swarmloc.lie import SE2, SE3
from swarmloc.node import detection_key, odometry_problem, validate_detection
from swarmloc.node.inputs import CONTIGUOUS, OdometryTimeline, command_value
from swarmloc.runner import RobotTrack, RunResult, truth_table
from swarmloc.sensors.models import KIND_ORDER
from swarmloc.sensors.models3 import KIND_ORDER3
from swarmloc.sim.simulator import SimResult
from swarmloc.sim.source import sim_source


def _stamp(e: Any) -> float | None:
    s = e.stamp
    return float(s) if isinstance(s, int | float | np.floating) and math.isfinite(s) else None


Groups = dict[float, dict[int, dict[tuple, tuple[Detection, int]]]]
"""Checked detections: stamp -> observer row -> detection key -> ``(detection, target code)``."""
Commands = dict[float, dict[int, tuple[Any, Any]]]
"""Checked odometry: start time -> robot row -> ``(v [m/s], w [rad/s])`` (an SE(3) team: tuples of 3, or a stop's
``(0.0, 0.0)``)."""
Row = tuple[float, np.ndarray, np.ndarray, np.ndarray]
"""One record of a robot: ``(t, (x, y, theta), covariance, truth)``."""


def run_engine(
    source_or_sim: Source | SimResult,
    estimator: str = "expfusion",
    *,
    backend: str = "numpy",
    fast: bool = True,
    record_times: Sequence[float] | np.ndarray | None = None,
    config: Config | None = None,
    **options: Any,
) -> RunResult:
    """Run ``estimator`` on a source's events with the batched :class:`Engine`; returns a
    :class:`~swarmloc.runner.RunResult` like :func:`swarmloc.runner.run` with the nodes of
    :func:`~swarmloc.estimators.make_team`.

    ``source_or_sim``: a :class:`~swarmloc.datasets.source.Source` or a simulation (turned into one by
    :func:`~swarmloc.sim.source.sim_source` with ``config``); ``record_times`` default ``Source.record_times()``;
    ``options``: the nodes' options, default :func:`~swarmloc.estimators.node_options` of the source's
    configuration (overridden by the given ones).
    """
    src = source_or_sim if isinstance(source_or_sim, Source) else sim_source(source_or_sim, "sim", config)
    own_noise = {} if src.noise is None else {"noise": src.noise}  # an SE(3) team's twist noise
    opts = {**node_options(estimator, src.config, src.landmarks), **own_noise, **options}
    for clock_only in ("tolerance", "jump_inputs"):  # the engine replays a checked log: no clock contract to keep
        opts.pop(clock_only, None)
    opts.pop("association_gate", None)
    if opts.pop("association", "tags") != "tags":
        raise ValueError("the engine fuses tagged detections only: run an association policy with the nodes")
    robots = src.robots
    col = {r: i for i, r in enumerate(robots)}
    initial = [src.initial[r] for r in robots]
    eng = Engine(estimator, np.stack([b.mean for b in initial]), np.stack([b.cov for b in initial]),
                 t0=_start_times(src.events, col), backend=backend, fast=fast, **opts)  # fmt: skip
    checked = _Checked(col, eng.landmark_code)
    for e in src.events:
        checked.add(e)
    rt = src.record_times() if record_times is None else np.asarray(record_times, dtype=float)
    checked.stops(max([*checked.odo, *checked.groups, *rt.tolist()], default=-math.inf))
    rows, truth_missing, wall = _replay(eng, src, checked, rt)

    tracks = {}
    w, d = (7, 6) if eng.group is SE3 else (3, 3)  # (x, y, z, quaternion) and 6 dof, or (x, y, theta) and 3
    for r in robots:
        rs = rows[r]
        tracks[r] = RobotTrack(
            np.array([x[0] for x in rs]),
            np.array([x[1] for x in rs]).reshape(-1, w),
            np.array([x[2] for x in rs]).reshape(-1, d, d),
            np.array([x[3] if x[3].size == w else np.full(w, np.nan) for x in rs]).reshape(-1, w),
        )
    stats: Counter[str] = Counter(checked.counts)
    for k in ("fused", "gated", "rejected", "unknown"):
        stats[k] += eng.counts[k]
    stats["recorded"] = sum(len(v) for v in rows.values())
    if truth_missing:
        stats["truth_missing"] = truth_missing
    for k in ("detections", "fused", "gated", "rejected", "unknown", "pending", "odometry", "messages"):
        stats.setdefault(k, 0)
    reasons = Counter(checked.reasons)
    reasons.update(eng.reasons)
    timing = {"predict_s": 0.0, "predict_n": 0, "fuse_s": 0.0, "fuse_n": 0}
    return RunResult(f"{estimator}/engine", tracks, wall, dict(stats), len(src.events), reasons, timing)


def _start_times(events: Sequence[Any], col: dict[Any, int]) -> np.ndarray:
    """Each robot's first stamp (odometry or detection it made), ``inf`` for a robot without input."""
    t0 = np.full(len(col), math.inf)
    for e in events:
        r = e.robot if isinstance(e, Odometry) else e.observer if isinstance(e, Detection) else None
        s = _stamp(e)
        if r in col and s is not None:
            t0[col[r]] = min(t0[col[r]], s)
    return t0


class _Checked:
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
        ``t1`` (to ``last`` [s]); counted once per interval (``odometry_stops``)."""
        for row, (starts, ends) in self.timeline.intervals().items():
            for t1, nxt in zip(ends, [*starts[1:], math.inf], strict=True):
                if nxt > t1 + CONTIGUOUS and last > t1 + CONTIGUOUS and row not in self.odo.get(t1, {}):
                    self.odo[t1][row] = (0.0, 0.0)
                    self.counts["odometry_stops"] += 1

    def _detection(self, e: Detection) -> None:
        self.counts["detections"] += 1
        if e.observer not in self.col:
            self.counts["unknown_robot"] += 1
            self.reject("unknown", f"observer {e.observer!r} is not in the team")
            return
        why = validate_detection(e)
        if why is not None:
            self.reject("rejected", why)
            return
        code = NO_TARGET if e.kind == "absolute" else self.col.get(e.target, UNKNOWN_ROBOT)
        if e.kind != "absolute" and not e.target_is_robot:  # a landmark (the pose of one: in the group, not fused)
            code = UNUSABLE if e.kind == "pose" else self.landmark_code(e.target)
        elif e.kind != "absolute" and e.target is None:
            code = UNUSABLE
        group = self.groups[float(e.t)][self.col[e.observer]]
        key = detection_key(e)
        if key in group:
            self.reject("rejected", "duplicate detection")
            return
        group[key] = (e, code)


def _replay(eng: Engine, src: Source, checked: _Checked, rt: np.ndarray) -> tuple[dict[Any, list[Row]], int, float]:
    """Every stamp through ``eng`` (its groups, then its commands), beliefs recorded at the record times ``rt``
    after every input stamped at or before them; returns each robot's records, the records without truth and the
    wall time [s] of the loop over stamps."""
    robots = src.robots
    truth_rows = {r: truth_table(src.truth, r, rt) for r in robots}
    records: dict[float, list[int]] = defaultdict(list)
    for k, t in enumerate(rt.tolist()):
        records[t].append(k)
    rows: dict[Any, list[Row]] = {r: [] for r in robots}
    odo, groups = checked.odo, checked.groups
    se3 = eng.group is SE3
    truth_missing = 0
    stamps = sorted(set(odo) | set(groups) | set(records))
    wall = time.perf_counter()
    for t in stamps:
        det = _detections(groups[t], 6 if se3 else 3) if t in groups else None
        cmd = None
        if t in odo:
            idx = np.fromiter(odo[t], dtype=np.int64)
            if se3:  # body twists (k, 6); a stop (0, 0) on every axis
                vw = np.array([np.broadcast_to(v, 3).tolist() + np.broadcast_to(w, 3).tolist()
                               for v, w in odo[t].values()], dtype=float)  # fmt: skip
                cmd = (idx, vw[:, :3], vw[:, 3:])
            else:
                vw = np.array(list(odo[t].values()), dtype=float).reshape(-1, 2)
                cmd = (idx, vw[:, 0], vw[:, 1])
        eng.step(t, det, cmd)
        if t not in records:
            continue
        live = np.flatnonzero(t >= eng.t0)
        mean, cov = eng.belief(t, live)
        xyt = pose7(mean) if se3 else SE2.to_xytheta(mean)
        for j, i in enumerate(live.tolist()):
            r = robots[i]
            for k in records[t]:
                tr = truth_rows[r][k]
                if src.truth is not None and not np.isfinite(tr).all():
                    truth_missing += 1
                    continue
                rows[r].append((t, xyt[j], cov[j], tr))
    return rows, truth_missing, time.perf_counter() - wall


def _detections(by_observer: dict[int, dict[tuple, tuple[Detection, int]]], width: int = 3) -> Detections:
    """One stamp's checked detections as arrays (robots as rows), ``z`` ``width`` wide (6: an SE(3) team's)."""
    obs, tgt, kind, zs, Rs = [], [], [], [], []
    for o, group in by_observer.items():
        for d, code in group.values():
            m = len(d.z)
            if m > width:  # a 3-D detection in a planar team: no planar filter takes it
                raise ValueError(f"run_engine: a {d.kind!r} detection in an SE(2) team; run the nodes")
            z = np.zeros(width)
            z[:m] = d.z
            R = np.zeros((width, width))
            R[:m, :m] = d.cov
            obs.append(o)
            tgt.append(code)
            kind.append(KIND_ORDER[d.kind] if d.kind in KIND_ORDER else KIND_ORDER3[d.kind])
            zs.append(z)
            Rs.append(R)
    return Detections(
        np.array(obs, dtype=np.int64), np.array(tgt, dtype=np.int64), np.array(kind, dtype=np.int64),
        np.array(zs), np.array(Rs),
    )  # fmt: skip
