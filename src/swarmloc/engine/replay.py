"""Replay a team's events through the batched engine: :func:`run_engine`, comparable to :func:`swarmloc.runner.run`.

The events are checked as the nodes check them (malformed, duplicate and unusable input is rejected and counted
the same way), put on one timeline of stamps, and each stamp is one :meth:`Engine.step`: the detection groups
stamped ``t`` then the commands starting at ``t``; beliefs are recorded at the record times after every input
stamped at or before them (what :meth:`~swarmloc.node.base.Node.belief_at` answers).

**Compiled replay.** With ``backend="numba"`` a planar ``dekf`` team (the in-place kernels' case: fewer than
:data:`~swarmloc.engine.numba_ops.PARALLEL_MIN` rows a stamp) is not stepped stamp by stamp from Python: every stamp
is packed into one :class:`~swarmloc.engine.detections.Timeline` and run in one compiled loop
(:meth:`Engine.replay_timeline`), which does what :meth:`Engine.step` does per stamp and records the beliefs in
place; a stamp with a detection the loop does not take (range-only, bearing-only) is stepped, and the loop goes on
after it. The input checks are the nodes' either way (:class:`swarmloc.engine.checks.Checked`: detections screened
in bulk, a robot's odometry that no sequential check could refuse checked as arrays).

**The centralized EKFs, the invariant ones and recursive decentralized localization.** ``estimator="cekf"``,
``"iekf"``, ``"diekf"`` and ``"rdl"`` (``backend="numba"``, planar teams) keep other state than the
:class:`Engine`'s per-robot rows (a joint state; a filter and a factor per pair): the same checked timeline runs
through :func:`swarmloc.engine.joint.replay_joint` or :func:`swarmloc.engine.pairs.replay_rdl`, every detection kind
in one compiled call, as the ``cekf`` or ``iekf`` node, the ``diekf`` nodes exchanging their broadcasts (whose
replicas are the invariant EKF's joint state; with ``cluster = K``, each cluster's, through
:func:`swarmloc.engine.joint_clusters.replay_clusters`) or the ``rdl`` nodes compute it; reasons are worded as those
nodes word them. numba is their one compiled backend: another backend is refused with the ones that replay them.

An SE(3) team (initial beliefs on SE(3), e.g. ``sim:3d``) runs on the engine's SE(3) path: body-twist odometry
(:func:`swarmloc.events.twist_odometry`), ``"pose3"`` detections, the source's twist noise (``Source.noise``), tracks
recorded as ``(x, y, z, qx, qy, qz, qw)`` with ``(6, 6)`` covariances, as :func:`swarmloc.runner.run` records them.
"""

from __future__ import annotations

import math
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import numpy as np

from swarmloc.config import Config
from swarmloc.datasets.source import Source
from swarmloc.datasets.tum import pose7
from swarmloc.engine.checks import Checked
from swarmloc.engine.codes import (
    NO_LANDMARK,
    R_DEGENERATE,
    R_NO_LANDMARK,
    R_NONFINITE,
    R_NOT_STARTED,
    R_NUMERICAL,
    R_TEAM,
    R_UNUSABLE,
    REASONS,
    UNKNOWN_ROBOT,
    UNUSABLE,
)
from swarmloc.engine.core import Engine, Records, landmark_table, map_code
from swarmloc.engine.detections import Detections, Timeline
from swarmloc.engine.outcomes import tally
from swarmloc.engine.replay_io import Replayed
from swarmloc.estimators import node_options
from swarmloc.estimators.adaptive_noise import in_force
from swarmloc.events import Detection, Kind
from swarmloc.kernels import cartesian as C
from swarmloc.lie import SE2, SE3
from swarmloc.node.base import refusal
from swarmloc.node.keys import SubKey
from swarmloc.runner import RobotTrack, RunResult, truth_table
from swarmloc.runner.result import RUN_COUNTERS
from swarmloc.sensors.models3 import ALL_MODELS
from swarmloc.sim.simulator import SimResult
from swarmloc.sim.source import sim_source

Row = tuple[float, np.ndarray, np.ndarray, np.ndarray]
"""One record of a robot: ``(t, (x, y, theta), covariance, truth)``."""
TruthRows = dict[int, tuple[np.ndarray, list[bool]]]
"""Robot -> its truth at every record time and whether a record there is kept (:func:`_truth_rows`)."""


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
    """Run ``estimator`` on a source's events with the batched :class:`Engine` (``"cekf"``, ``"iekf"``, ``"diekf"``,
    ``"rdl"``: the compiled replays of :mod:`swarmloc.engine.joint` and :mod:`swarmloc.engine.pairs`,
    ``backend="numba"`` only: another backend is a ``ValueError`` that names it); returns a
    :class:`~swarmloc.runner.RunResult` like :func:`swarmloc.runner.run` with the nodes of
    :func:`~swarmloc.estimators.make_team`.

    ``source_or_sim``: a :class:`~swarmloc.datasets.source.Source` or a simulation (turned into one by
    :func:`~swarmloc.sim.source.sim_source` with ``config``); ``record_times`` default ``Source.record_times()``;
    ``options``: the nodes' options, default :func:`~swarmloc.estimators.node_options` of the source's
    configuration (overridden by the given ones).
    """
    src = source_or_sim if isinstance(source_or_sim, Source) else sim_source(source_or_sim, "sim", config)
    opts = _options(src, estimator, options)
    if estimator in _COMPILED_ONLY:
        return _run_compiled(src, estimator, backend, record_times, opts)
    initial = [src.initial[r] for r in src.robots]
    checked, rt = _check(src, opts, record_times)
    eng = Engine(estimator, np.stack([b.mean for b in initial]), np.stack([b.cov for b in initial]),
                 t0=checked.start_times(), backend=backend, fast=fast, **opts)  # fmt: skip
    rows, truth_missing, wall = _replay(eng, src, checked, rt)

    reasons = Counter(checked.reasons)
    reasons.update(eng.reasons)
    _name_unknown(reasons, checked, eng.use_relative, eng.t0)
    return _result(f"{estimator}/engine", src, rows, checked, eng.counts, reasons, wall, truth_missing,
                   eng.group is SE3)  # fmt: skip


def _options(src: Source, estimator: str, options: dict[str, Any]) -> dict[str, Any]:
    """The nodes' options of ``estimator`` for ``src`` (:func:`~swarmloc.estimators.node_options`, overridden by
    ``options``) that the engine keeps."""
    own_noise = {} if src.noise is None else {"noise": src.noise}  # an SE(3) team's twist noise
    opts = {**node_options(estimator, src.config, src.landmarks), **own_noise, **options}
    for clock_only in ("tolerance", "jump_inputs"):  # the engine replays a checked log: no clock contract to keep
        opts.pop(clock_only, None)
    opts.pop("quarantine", None)  # nor a teammate that could lie (swarmloc.node.trust)
    opts.pop("association_gate", None)
    if opts.pop("association", "tags") != "tags":
        raise ValueError("the engine fuses tagged detections only: run an association policy with the nodes")
    if "adaptive" in opts:  # the median scale without a landmark to fuse is the fixed noise the replay keeps
        opts["adaptive"] = in_force(opts["adaptive"], opts.get("landmarks"), opts.get("use_landmarks", True))
    for option, why in _NODES_ONLY.items():
        if opts.pop(option, False):
            raise ValueError(f"the engine's diekf {why}: run [filter] diekf_{option} with the nodes, or set it to "
                             f"false for the engine")  # fmt: skip
    return opts


_NODES_ONLY = {"odocal": "takes the odometry as given", "fault": "has no odometry-fault test",
               "reform": "clusters stay fixed", "adaptive": "keeps its noise fixed"}  # fmt: skip
"""``diekf``'s options that only its nodes run (a true value refused) -> what the engine's replay does instead; the
default one (``adaptive``) last, so that an option set on purpose is the one named."""


def _result(name: str, src: Source, rows: dict[Any, list[Row]], checked: Checked, counts: Counter[str],
            reasons: Counter[str], wall: float, truth_missing: int, se3: bool = False) -> RunResult:  # fmt: skip
    """The :class:`~swarmloc.runner.RunResult` of a replay: each robot's records as a track, the input checks'
    counts with the fusions' ``counts``, ``reasons`` as the nodes word them."""
    tracks = {}
    w, d = (7, 6) if se3 else (3, 3)  # (x, y, z, quaternion) and 6 dof, or (x, y, theta) and 3
    for r in src.robots:
        rs = rows[r]
        tracks[r] = RobotTrack(
            np.array([x[0] for x in rs]),
            np.array([x[1] for x in rs]).reshape(-1, w),
            np.array([x[2] for x in rs]).reshape(-1, d, d),
            np.array([x[3] if x[3].size == w else np.full(w, np.nan) for x in rs]).reshape(-1, w),
        )
    stats: Counter[str] = Counter(checked.counts)
    for k in ("fused", "gated", "rejected", "unknown"):
        stats[k] += counts[k]
    stats["recorded"] = sum(len(v) for v in rows.values())
    if truth_missing:
        stats["truth_missing"] = truth_missing
    for k in RUN_COUNTERS:
        stats.setdefault(k, 0)
    timing = {"predict_s": 0.0, "predict_n": 0, "fuse_s": 0.0, "fuse_n": 0}
    return RunResult(name, tracks, wall, dict(stats), len(src.events), reasons, timing)


_COMPILED_ONLY = ("cekf", "iekf", "rdl", "diekf")
"""Estimators the engine runs only as a compiled replay of their own state (numba): ``cekf``'s and ``iekf``'s joint
state, ``diekf``'s too (the nodes' replicas together are the invariant EKF's joint state,
:mod:`swarmloc.engine.joint`), ``rdl``'s filters and factors (:mod:`swarmloc.engine.pairs`)."""
_COMPILED_OPTIONS = frozenset({"noise", "gate", "landmarks", "use_relative", "use_landmarks", "horizon", "cluster"})
"""The nodes' options those replays take (``horizon`` plays no role: input comes in order; ``cluster``: ``diekf``'s
only)."""
_CENTRAL = ("cekf", "iekf")
"""Compiled replays of a centralized node: it starts at the team's first input and words its own refusals."""


def _run_compiled(src: Source, estimator: str, backend: str, record_times: Any, opts: dict[str, Any]) -> RunResult:
    """``cekf``, ``iekf``, ``rdl`` or ``diekf`` through their compiled replay (planar teams) with the nodes' options
    ``opts`` (:func:`_options`): the same input checks and timeline as the other estimators, the whole replay in one
    numba call (:func:`_replayer`)."""
    if backend != "numba":
        raise ValueError(f"run_engine: {estimator!r} runs on the engine's compiled replay only, which backend='numba'"
                         f" runs (the one backend that replays it), not backend={backend!r}")  # fmt: skip
    if src.noise is not None or any(np.shape(b.mean) != (3, 3) for b in src.initial.values()):
        raise ValueError(f"run_engine: {estimator!r} on the engine takes planar (SE(2)) teams; run the nodes")
    extra = sorted(set(opts) - _COMPILED_OPTIONS)
    if extra:
        raise TypeError(f"run_engine: {estimator!r} on the engine takes no option {extra}")
    cluster = opts.pop("cluster", 0)
    if cluster and estimator != "diekf":
        raise ValueError(f"run_engine: {estimator!r} has no clusters (cluster = 0; diekf's nodes take one)")
    checked, rt = _check(src, opts, record_times)
    starts = checked.start_times()
    # a centralized node starts at the team's first input, the others each at its own
    t0: Any = float(starts.min(initial=math.inf)) if estimator in _CENTRAL else starts  # the replays take either
    records = _record_index(rt)
    tl = _timeline(checked, records)
    x, P = C.from_group(np.stack([src.initial[r].mean for r in src.robots]),
                        np.stack([src.initial[r].cov for r in src.robots]))  # fmt: skip
    use_relative, use_landmarks = bool(opts.get("use_relative", True)), bool(opts.get("use_landmarks", True))
    wall = time.perf_counter()
    status, reason, (o_robot, o_stamp, o_x, o_P) = _replayer(estimator, cluster)(
        tl, x, P, t0, opts["noise"], gate=opts.get("gate"), use_relative=use_relative, use_landmarks=use_landmarks,
        landmarks=landmark_table(opts.get("landmarks"))[1])  # fmt: skip
    wall = time.perf_counter() - wall
    counts: Counter[str] = Counter()
    reasons: Counter[str] = Counter(checked.reasons)
    if estimator in _CENTRAL:  # the centralized node's own words for what it refuses before reading a state
        dynamic = np.isin(reason, (R_DEGENERATE, R_NONFINITE, R_NUMERICAL))
        tally(counts, reasons, status, np.where(dynamic, reason, 0).astype(np.int8))
        reasons.update(_joint_reasons(checked, t0, use_relative, use_landmarks))
    else:
        tally(counts, reasons, status, reason)
        _name_unknown(reasons, checked, use_relative, t0)
        _name_unusable(reasons, checked, t0, use_relative, use_landmarks)
        _name_not_started(reasons, checked, t0, src.robots)
    rows, truth_missing = _file_all(src, tl, records, _truth_rows(src, rt), o_robot, o_stamp, o_x, o_P)
    return _result(f"{estimator}/engine", src, rows, checked, counts, reasons, wall, truth_missing)


def _replayer(estimator: str, cluster: int) -> Callable[..., Replayed]:
    """``estimator``'s compiled replay as ``replay(timeline, x, P, t0, noise, **switches)``: ``rdl``'s
    (:func:`swarmloc.engine.pairs.replay_rdl`), ``diekf``'s in clusters of ``cluster`` robots
    (:func:`swarmloc.engine.joint_clusters.replay_clusters`), else the joint state's
    (:func:`swarmloc.engine.joint.replay_joint`, invariant but for ``cekf``). Imported here: numba is optional."""
    if estimator == "rdl":
        from swarmloc.engine.pairs import replay_rdl

        return replay_rdl
    if cluster:
        from swarmloc.engine.joint_clusters import replay_clusters

        return partial(replay_clusters, cluster=cluster)
    from swarmloc.engine.joint import replay_joint

    return partial(replay_joint, invariant=estimator != "cekf")


def _check(src: Source, opts: dict[str, Any], record_times: Any) -> tuple[Checked, np.ndarray]:
    """``src``'s events checked as the nodes check them (robots as rows, landmarks by the map of ``opts``), with
    the stops the replay to the last input or record time implies; and the record times (default the source's)."""
    col = {r: i for i, r in enumerate(src.robots)}
    checked = Checked(col, partial(map_code, landmark_table(opts.get("landmarks"))[0]))
    checked.add_all(src.events)
    rt = src.record_times() if record_times is None else np.asarray(record_times, dtype=float)
    checked.stops(max([checked.last_command(), *checked.groups, *rt.tolist()], default=-math.inf))
    return checked, rt


def _record_index(rt: np.ndarray) -> dict[float, tuple[int, ...]]:
    """Record time -> the indices of ``rt`` at that time (tuples of ints: the garbage collector untracks them)."""
    records: dict[float, tuple[int, ...]] = {}
    for k, t in enumerate(rt.tolist()):
        records[t] = (*records.get(t, ()), k)
    return records


def _file_all(src: Source, tl: Timeline, records: dict[float, tuple[int, ...]], truth_rows: TruthRows,
              robot: np.ndarray, stamp: np.ndarray, x: np.ndarray, P: np.ndarray,
              ) -> tuple[dict[Any, list[Row]], int]:  # fmt: skip
    """A compiled replay's records (robot rows, stamp indices of ``tl``, Cartesian ``x (K, 3)``, ``P (K, 3, 3)``)
    filed by robot as beliefs on the group (:func:`_file`); returns them and the records left out for missing
    truth."""
    mean, cov = C.to_group(x, P)
    xyt = SE2.to_xytheta(mean)
    rows: dict[Any, list[Row]] = {r: [] for r in src.robots}
    truth_missing = 0
    for j, (i, s) in enumerate(zip(robot.tolist(), stamp.tolist(), strict=True)):
        t = float(tl.stamps[s])
        truth_missing += _file(rows, truth_rows, src.robots[i], t, records[t], xyt[j], cov[j])
    return rows, truth_missing


def _joint_reasons(checked: Checked, t0: float, use_relative: bool, use_landmarks: bool) -> Counter[str]:
    """The outcomes of the centralized node decided before it reads a state, in its words
    (:meth:`~swarmloc.node.base.Node._classify`, :meth:`~swarmloc.estimators.CentralizedEKF._robot_target`)."""
    out: Counter[str] = Counter()
    for t, by_observer in checked.groups.items():
        for group in by_observer.values():
            for d, code in group.values() if t >= t0 else ():
                why = _static_reason(d, code, use_relative, use_landmarks)
                if why is not None:
                    out[why] += 1
    return out


def _static_reason(d: Detection, code: int, use_relative: bool, use_landmarks: bool) -> str | None:
    """``"<outcome>: <reason>"`` of a detection the centralized node refuses before it reads a state, or None."""
    why = refusal(d, d.observer, use_relative, use_landmarks)
    if why is not None:
        return f"{why[0]}: {why[1]}"
    if d.kind == Kind.ABSOLUTE:
        return None
    if d.target_is_robot:
        return f"unknown: robot {d.target} is not in the team" if code == UNKNOWN_ROBOT else None
    return f"unknown: landmark {d.target} is not in the map" if code == NO_LANDMARK else None


def _rename(reasons: Counter[str], checked: Checked, t0: np.ndarray, generic: str,
            words: Callable[[float, int, Detection, int], str | None]) -> None:  # fmt: skip
    """Replace the count under the engine's ``generic`` text by the nodes' own texts ``words(t, row, d, code)`` (None:
    not such a detection) of the detections of started observers, where those account for all of it."""
    if generic not in reasons:
        return
    named: Counter[str] = Counter()
    for t, by_observer in checked.groups.items():
        for row, group in by_observer.items():
            if t >= t0[row]:
                for d, code in group.values():
                    text = words(t, row, d, code)
                    if text is not None:
                        named[text] += 1
    if named and sum(named.values()) == reasons[generic]:
        del reasons[generic]
        reasons.update(named)


def _name_unusable(reasons: Counter[str], checked: Checked, t0: np.ndarray, use_relative: bool, use_landmarks: bool
                   ) -> None:  # fmt: skip
    """The distributed replays count a detection no filter can use (code ``UNUSABLE``) under one text; the nodes say
    why (:meth:`~swarmloc.node.base.Node._classify`: relative measurements off, no target id, the pose of a
    landmark). Each such detection of a started observer is worded as the nodes word it."""
    generic = f"rejected: {REASONS[R_UNUSABLE]}"

    def words(t: float, row: int, d: Detection, code: int) -> str | None:
        return (_static_reason(d, code, use_relative, use_landmarks) or generic) if code == UNUSABLE else None

    _rename(reasons, checked, t0, generic, words)


def _name_not_started(reasons: Counter[str], checked: Checked, t0: np.ndarray, robots: Sequence[Any]) -> None:
    """The distributed replays count a detection of a teammate before its start under one text; the runner answers
    each query with the teammate's clock's words (:class:`~swarmloc.node.clock.Clock`: ``unknown: robot 2: stamp
    0.2 is before the node's start time 4.0``). Each such detection (of a started observer) is worded so."""

    def words(t: float, row: int, d: Detection, code: int) -> str | None:
        if 0 <= code != row and not t >= t0[code]:
            return f"unknown: robot {robots[code]}: stamp {t} is before the node's start time {t0[code]}"
        return None

    _rename(reasons, checked, t0, f"unknown: {REASONS[R_NOT_STARTED]}", words)


def _name_unknown(reasons: Counter[str], checked: Checked, use_relative: bool, t0: np.ndarray) -> None:
    """The engine counts a detection of a robot outside the team, or of a landmark not in the map, under one text
    (``unknown: no answer: the robot is not in the team``, ``unknown: the landmark is not in the map``); the nodes
    name it (``unknown: robot 4: robot 4 is not in the team``, the answer the runner gives a query to it;
    ``unknown: landmark 7 is not in the map``). Where every such detection ended there (each observer started, and
    for robots relative measurements on: the screening refused none before), the count is split by id under the
    nodes' text."""
    robot, landmark = "unknown: robot {0}: robot {0} is not in the team", "unknown: landmark {0} is not in the map"
    for generic, code, text, on in (
        (f"unknown: {REASONS[R_TEAM]}", UNKNOWN_ROBOT, robot, use_relative),
        (f"unknown: {REASONS[R_NO_LANDMARK]}", NO_LANDMARK, landmark, True),
    ):
        if on:

            def words(t: float, row: int, d: Detection, c: int, code: int = code, text: str = text) -> str | None:
                return text.format(d.target) if c == code and (code != NO_LANDMARK or not d.target_is_robot) else None

            _rename(reasons, checked, t0, generic, words)


def _replay(eng: Engine, src: Source, checked: Checked, rt: np.ndarray) -> tuple[dict[Any, list[Row]], int, float]:
    """Every stamp through ``eng`` (its groups, then its commands), beliefs recorded at the record times ``rt``
    after every input stamped at or before them; returns each robot's records, the records without truth and the
    wall time [s] of the loop over stamps."""
    robots = src.robots
    truth_rows = _truth_rows(src, rt)
    records = _record_index(rt)
    se3 = eng.group is SE3
    most = max([eng.n, *(sum(map(len, g.values())) for g in checked.groups.values())])  # rows of a stamp, at most
    if not se3 and eng.compiled_replay(most):
        wall = time.perf_counter()
        compiled, missed = _replay_compiled(eng, src, checked, records, truth_rows)
        return compiled, missed, time.perf_counter() - wall
    rows: dict[Any, list[Row]] = {r: [] for r in robots}
    odo, groups = checked.by_stamp(), checked.groups
    truth_missing = 0
    stamps = sorted(set(odo) | set(groups) | set(records))
    wall = time.perf_counter()
    for t in stamps:
        det = _detections(list(groups[t].items()), 6 if se3 else 3) if t in groups else None
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
            truth_missing += _file(rows, truth_rows, robots[i], t, records[t], xyt[j], cov[j])
    return rows, truth_missing, time.perf_counter() - wall


def _truth_rows(src: Source, rt: np.ndarray) -> TruthRows:
    """Robot -> its truth at every record time ``rt`` and whether a record there is kept (its truth is finite, or
    the source has no truth: NaN rows)."""
    out: TruthRows = {}
    for r in src.robots:
        table = truth_table(src.truth, r, rt)
        keep = np.isfinite(table).all(axis=1) if src.truth is not None else np.ones(rt.shape[0], dtype=bool)
        out[r] = (table, keep.tolist())
    return out


def _file(rows: dict[Any, list[Row]], truth_rows: TruthRows, r: Any, t: float, keys: tuple[int, ...], xyt: np.ndarray,
          cov: np.ndarray) -> int:  # fmt: skip
    """File robot ``r``'s belief at ``t`` once per record index in ``keys`` with its truth row (:func:`_truth_rows`);
    returns the records left out because the source's truth is missing there."""
    table, keep = truth_rows[r]
    missing = 0
    for k in keys:
        if not keep[k]:
            missing += 1
            continue
        rows[r].append((t, xyt, cov, table[k]))
    return missing


def _timeline(checked: Checked, records: dict[float, tuple[int, ...]]) -> Timeline:
    """Every stamp's checked detections and commands as one :class:`Timeline` (planar team)."""
    t_cmd, c_row, c_v, c_w = checked.commands()
    t_det = np.array([t for t, by_obs in checked.groups.items() for group in by_obs.values() for _ in group], float)
    det = _detections([g for by_observer in checked.groups.values() for g in by_observer.items()])
    t_rec = np.array(list(records), dtype=float)
    stamps = np.unique(np.concatenate([t_cmd, t_det, t_rec]))
    at_det = np.searchsorted(stamps, t_det)
    at_cmd = np.searchsorted(stamps, t_cmd)
    order = np.argsort(at_cmd, kind="stable")
    bounds = np.arange(stamps.size + 1)
    d0, c0 = np.searchsorted(np.sort(at_det), bounds), np.searchsorted(at_cmd[order], bounds)
    record = np.zeros(stamps.size, dtype=bool)
    record[np.searchsorted(stamps, t_rec)] = True  # every record time is a stamp
    return Timeline(stamps, det.canonical(at_det), d0, c0, c_row[order], c_v[order], c_w[order], record)


def _replay_compiled(
    eng: Engine, src: Source, checked: Checked, records: dict[float, tuple[int, ...]], truth_rows: TruthRows
) -> tuple[dict[Any, list[Row]], int]:
    """:func:`_replay`'s loop as compiled calls over the whole :class:`Timeline` (:meth:`Engine.replay_timeline`),
    a stamp the compiled kernel does not take stepped by :meth:`Engine.step`; the same records."""
    tl = _timeline(checked, records)
    k = int(tl.record.sum()) * eng.n
    out: Records = (np.zeros(k, dtype=np.int64), np.zeros(k, dtype=np.int64), np.zeros((k, 3)), np.zeros((k, 3, 3)),
           np.zeros(1, dtype=np.int64))  # fmt: skip
    s = 0
    while s < len(tl):
        s, _ = eng.replay_timeline(tl, s, out)
        if s == len(tl):
            break
        t = float(tl.stamps[s])
        a, b, c, e = int(tl.d0[s]), int(tl.d0[s + 1]), int(tl.c0[s]), int(tl.c0[s + 1])
        eng.step(t, tl.det.take(np.arange(a, b)), (tl.robot[c:e], tl.v[c:e], tl.w[c:e]), presorted=True)
        if tl.record[s]:
            live = np.flatnonzero(t >= eng.t0)
            x, P = eng.state(t, live)
            n0, n1 = int(out[4][0]), int(out[4][0]) + live.size
            out[0][n0:n1], out[1][n0:n1], out[2][n0:n1], out[3][n0:n1] = live, s, x, P
            out[4][0] = n1
        s += 1
    n = int(out[4][0])
    return _file_all(src, tl, records, truth_rows, out[0][:n], out[1][:n], out[2][:n], out[3][:n])


def _detections(groups: Sequence[tuple[int, dict[SubKey, tuple[Detection, int]]]], width: int = 3) -> Detections:
    """Checked detection groups ``(observer row, group)`` as arrays, in that order (robots as rows), ``z``
    ``width`` wide (6: an SE(3) team's)."""
    obs: list[int] = []
    dets: list[Detection] = []
    codes: list[int] = []  # three flat lists, no tuple per detection (fewer objects for the garbage collector)
    for o, group in groups:
        for d, code in group.values():
            obs.append(o)
            dets.append(d)
            codes.append(code)
    z, R = np.zeros((len(dets), width)), np.zeros((len(dets), width, width))
    sizes: dict[int, list[int]] = defaultdict(list)  # the rows of each size of z, filled in one call each
    for k, d in enumerate(dets):
        m = len(d.z)
        if m > width:  # a 3-D detection in a planar team: no planar filter takes it
            raise ValueError(f"run_engine: a {d.kind!r} detection in an SE(2) team; run the nodes")
        sizes[m].append(k)
    for m, rows in sizes.items():
        z[rows, :m] = np.array([dets[k].z for k in rows], dtype=float).reshape(-1, m)
        R[rows, :m, :m] = np.array([dets[k].cov for k in rows], dtype=float).reshape(-1, m, m)
    kind = [ALL_MODELS[d.kind].order for d in dets]
    return Detections(np.array(obs, dtype=np.int64), np.array(codes, dtype=np.int64), np.array(kind, dtype=np.int64),
                      z, R)  # fmt: skip
