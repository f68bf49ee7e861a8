"""Replay a team's events through the batched engine: :func:`run_engine`, comparable to :func:`swarmloc.runner.run`.

The events are checked as the nodes check them (malformed, duplicate and unusable input is rejected and counted
the same way), put on one timeline of stamps, and each stamp is one :meth:`Engine.step`: the detection groups
stamped ``t`` then the commands starting at ``t``; beliefs are recorded at the record times after every input
stamped at or before them (what :meth:`~swarmloc.node.base.Node.belief_at` answers).
"""

from __future__ import annotations

import math
import time
from collections import Counter, defaultdict
from collections.abc import Sequence
from typing import Any

import numpy as np

from swarmloc.config import Config
from swarmloc.datasets.source import Source
from swarmloc.engine.core import NO_TARGET, UNKNOWN_ROBOT, UNUSABLE, Detections, Engine
from swarmloc.estimators import node_options
from swarmloc.events import Detection, Odometry
from swarmloc.lie import SE2
from swarmloc.node import detection_key, validate_detection
from swarmloc.runner import RobotTrack, RunResult, truth_table
from swarmloc.sensors.models import KIND_ORDER
from swarmloc.sim.simulator import SimResult
from swarmloc.sim.source import sim_source


def _stamp(e: Any) -> float | None:
    s = e.stamp
    return float(s) if isinstance(s, int | float | np.floating) and math.isfinite(s) else None


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

    ``source_or_sim``: a :class:`~swarmloc.experiments.sources.Source` or a simulation (turned into one by
    :func:`~swarmloc.experiments.sources.sim_source` with ``config``); ``record_times`` default
    ``Source.record_times()``; ``options``: the nodes' options, default
    :func:`~swarmloc.experiments.evaluate.node_options` of the source's configuration (overridden by the given ones).
    """
    src = source_or_sim if isinstance(source_or_sim, Source) else sim_source(source_or_sim, "sim", config)
    opts = {**node_options(estimator, src.config, src.landmarks), **options}
    for clock_only in ("tolerance", "jump_inputs"):  # the engine replays a checked log: no clock contract to keep
        opts.pop(clock_only, None)
    robots = src.robots
    col = {r: i for i, r in enumerate(robots)}
    n = len(robots)
    counts: Counter[str] = Counter()
    reasons: Counter[str] = Counter()

    def reject(what: str, why: str, k: int = 1) -> None:
        counts[what] += k
        reasons[f"{what}: {why}"] += k

    t0 = np.full(n, math.inf)
    for e in src.events:
        r = e.robot if isinstance(e, Odometry) else e.observer if isinstance(e, Detection) else None
        s = _stamp(e)
        if r in col and s is not None:
            t0[col[r]] = min(t0[col[r]], s)

    odo: dict[float, dict[int, tuple[float, float]]] = defaultdict(dict)
    groups: dict[float, dict[int, dict[tuple, tuple[Detection, int]]]] = defaultdict(lambda: defaultdict(dict))
    lm = src.landmarks
    for e in src.events:
        if isinstance(e, Odometry):
            counts["odometry"] += 1
            if e.robot not in col:
                counts["unknown_robot"] += 1
                continue
            try:
                finite = all(math.isfinite(a) for a in (e.t0, e.t1, e.v, e.w))
            except TypeError:
                finite = False
            if not finite:
                reject("odometry_rejected", "non-finite or non-numeric time or speed")
            elif e.t1 < e.t0:
                reject("odometry_rejected", "t1 before t0")
            else:
                slot = odo[float(e.t0)]
                old = slot.get(col[e.robot])
                if old is not None:
                    same = old == (float(e.v), float(e.w))
                    reject("odometry_rejected", "duplicate" if same else "a different command at the same t0")
                else:
                    slot[col[e.robot]] = (float(e.v), float(e.w))
                    counts["odometry_used"] += 1
        elif isinstance(e, Detection):
            counts["detections"] += 1
            if e.observer not in col:
                counts["unknown_robot"] += 1
                reject("unknown", f"observer {e.observer!r} is not in the team")
                continue
            why = validate_detection(e)
            if why is not None:
                reject("rejected", why)
                continue
            code = NO_TARGET if e.kind == "absolute" else col.get(e.target, UNKNOWN_ROBOT)
            if e.kind != "absolute" and not e.target_is_robot:  # in the group (the observer moves to t), not fused
                if lm:
                    raise ValueError("run_engine: landmark detections are not supported; run the nodes")
                code = UNUSABLE if e.kind == "pose" else UNKNOWN_ROBOT
            elif e.kind != "absolute" and e.target is None:
                code = UNUSABLE
            group = groups[float(e.t)][col[e.observer]]
            key = detection_key(e)
            if key in group:
                reject("rejected", "duplicate detection")
                continue
            group[key] = (e, code)

    rt = src.record_times() if record_times is None else np.asarray(record_times, dtype=float)
    truth_rows = {r: truth_table(src.truth, r, rt) for r in robots}
    initial = [src.initial[r] for r in robots]
    eng = Engine(
        estimator,
        np.stack([b.mean for b in initial]),
        np.stack([b.cov for b in initial]),
        t0=t0,
        backend=backend,
        fast=fast,
        **opts,
    )
    records: dict[float, list[int]] = defaultdict(list)
    for k, t in enumerate(rt.tolist()):
        records[t].append(k)
    rows: dict[int, list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]] = {r: [] for r in robots}
    stamps = sorted(set(odo) | set(groups) | set(records))
    truth_missing = 0

    wall = time.perf_counter()
    for t in stamps:
        det = _detections(groups[t]) if t in groups else None
        cmd = None
        if t in odo:
            idx = np.fromiter(odo[t], dtype=np.int64)
            vw = np.array(list(odo[t].values()), dtype=float).reshape(-1, 2)
            cmd = (idx, vw[:, 0], vw[:, 1])
        eng.step(t, det, cmd)
        if t in records:
            live = np.flatnonzero(t >= eng.t0)
            mean, cov = eng.belief(t, live)
            xyt = SE2.to_xytheta(mean)
            for j, i in enumerate(live.tolist()):
                r = robots[i]
                for k in records[t]:
                    tr = truth_rows[r][k]
                    if src.truth is not None and not np.isfinite(tr).all():
                        truth_missing += 1
                        continue
                    rows[r].append((t, xyt[j], cov[j], tr))
    wall = time.perf_counter() - wall

    tracks = {}
    for r in robots:
        rs = rows[r]
        tracks[r] = RobotTrack(
            np.array([x[0] for x in rs]),
            np.array([x[1] for x in rs]).reshape(-1, 3),
            np.array([x[2] for x in rs]).reshape(-1, 3, 3),
            np.array([x[3] for x in rs]).reshape(-1, 3),
        )
    stats: Counter[str] = Counter(counts)
    for k in ("fused", "gated", "rejected", "unknown"):
        stats[k] += eng.counts[k]
    stats["recorded"] = sum(len(v) for v in rows.values())
    if truth_missing:
        stats["truth_missing"] = truth_missing
    for k in ("detections", "fused", "gated", "rejected", "unknown", "pending", "odometry", "messages"):
        stats.setdefault(k, 0)
    reasons.update(eng.reasons)
    timing = {"predict_s": 0.0, "predict_n": 0, "fuse_s": 0.0, "fuse_n": 0}
    return RunResult(f"{estimator}/engine", tracks, wall, dict(stats), len(src.events), reasons, timing)


def _detections(by_observer: dict[int, dict[tuple, tuple[Detection, int]]]) -> Detections:
    """One stamp's checked detections as arrays (robots as rows)."""
    obs, tgt, kind, zs, Rs = [], [], [], [], []
    for o, group in by_observer.items():
        for d, code in group.values():
            m = len(d.z)
            z = np.zeros(3)
            z[:m] = d.z
            R = np.zeros((3, 3))
            R[:m, :m] = d.cov
            obs.append(o)
            tgt.append(code)
            kind.append(KIND_ORDER[d.kind])
            zs.append(z)
            Rs.append(R)
    return Detections(
        np.array(obs, dtype=np.int64), np.array(tgt, dtype=np.int64), np.array(kind, dtype=np.int64),
        np.array(zs), np.array(Rs),
    )  # fmt: skip
