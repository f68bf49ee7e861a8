"""The truth-free consistency score (:mod:`swarmloc.evaluation.heldout`) run on an MRCLAM recording: a truth-free
start from the robots' landmark snapshots, and the runs that hold each fold of the landmarks out.

The start (:func:`fused_from_snapshots`) filters each robot's landmark snapshots up to the start as absolute pose
fixes, from its first one, with restarts where the gate locks a robot out of its own fixes (:func:`fuse_fixes`);
the first-snapshot start (:func:`initial_from_snapshots`, an option: ``start=`` of :func:`truth_free_score`)
dead-reckons each robot from its first snapshot alone.

Used by ``swarmloc evaluate mrclam`` on a recording without ground truth (:func:`truth_free_score`, the recommended
estimator only) and by the leave-one-dataset-out study (the repository's ``swarmloc_studies.lodo``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from swarmloc.config import DEFAULTS, Config
from swarmloc.datasets.mrclam import MRCLAMData, mrclam_events
from swarmloc.estimators import make_team, node_options
from swarmloc.evaluation.heldout import (
    landmark_folds,
    nis_summary,
    reading_times,
    tracks_nis,
    without_landmarks,
)
from swarmloc.events import Detection, Event, Kind, Odometry
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.runner import RunResult, TruthFn, run
from swarmloc.sensors.decorrelate import PRIOR_BEARING_STD, PRIOR_RANGE_STD, DetectionSet, snapshot_poses

__all__ = [
    "FIX_COUNTS",
    "HeldOutRun",
    "NoStart",
    "SCORED_SPAN",
    "fuse_fixes",
    "fused_from_snapshots",
    "heldout_runs",
    "initial_from_snapshots",
    "landmark_readings",
    "snapshot_belief",
    "truth_free_score",
]


class NoStart(ValueError):
    """The recording gives no truth-free start (a robot never reads two landmarks at once, or the start is after
    the span): the data's fault, not the configuration's, which raises a plain ValueError."""


SCORED_SPAN = 300.0
"""[s] The longest span :func:`truth_free_score` scores, from the truth-free start: its runs (3 with landmarks) then
cost at most about what the estimator's own run of 900 s does, whatever the recording's length (the
leave-one-dataset-out study scores 200-300 s too)."""


FIX_COUNTS = ("fused", "gated", "rejected", "unknown", "restarts", "restart_fixes")
"""The counts of :func:`fuse_fixes`: a fix ``fused`` by the filter in force, ``gated``, ``rejected`` or
``unknown`` by the node, or taken by a restart (``restart_fixes``); ``restarts``."""


def initial_from_snapshots(
    data: MRCLAMData, ds: DetectionSet, config: Config = DEFAULTS
) -> tuple[float, dict[int, GroupGaussian]]:
    """Truth-free initial beliefs: each robot's first landmark snapshot pose (fit covariance at the a-priori std),
    dead-reckoned to ``t0``, the latest first snapshot; returns ``(t0, beliefs)``. Raises ValueError when a robot
    of ``data`` never sees two landmarks at once. :func:`fused_from_snapshots` also fuses the snapshots up to ``t0``."""
    poses = snapshot_poses(ds, PRIOR_RANGE_STD, PRIOR_BEARING_STD)
    first = {r: snapshot_belief(poses, i) for r, i in _first_snapshots(data, poses).items()}
    t0 = max(v[0] for v in first.values())
    events = mrclam_events(data, landmarks=False, robot_measurements=False)
    out: dict[int, GroupGaussian] = {}
    for r, (ts, belief) in first.items():
        if t0 - ts <= 0:
            out[r] = belief
            continue
        mine = [e for e in events if isinstance(e, Odometry) and e.robot == r and ts <= e.stamp <= t0]  # all odometry
        res = run(make_team("dr", {r: belief}, **node_options("dr", config, None, ts)), mine, record_times=[t0])
        tr = res.tracks[r]
        out[r] = GroupGaussian(SE2, SE2.from_xytheta(tr.mean[-1]), tr.cov[-1], validate=False)
    return t0, out


def _first_snapshots(data: MRCLAMData, poses: Mapping[str, np.ndarray]) -> dict[int, int]:
    """Each robot's first snapshot in ``poses`` (robot -> index) from the recording's start; raises :class:`NoStart`
    when a robot of ``data`` has none."""
    first = {}
    for r in data.robots:
        sel = np.flatnonzero((poses["observer"] == r) & (poses["t"] >= data.t_start))
        if sel.size == 0:
            raise NoStart(f"{data.name}: robot {r} never reads two landmarks at once; no truth-free start")
        first[r] = int(sel[0])
    return first


def _fix_belief(pose: np.ndarray, cov: np.ndarray, scale: float = 1.0) -> GroupGaussian:
    """The belief a pose fit ``(x, y, theta)`` with covariance ``cov`` of those gives (times ``scale``)."""
    # the fit's covariance is of (x, y, theta); at a small angle it is that of the left perturbation: rotate it into
    # the body frame for the right-perturbation convention of the nodes
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return GroupGaussian(SE2, SE2.from_xytheta(pose), scale * (rot @ cov @ rot.T) + 1e-8 * np.eye(3), validate=False)


def snapshot_belief(poses: Mapping[str, np.ndarray], i: int) -> tuple[float, GroupGaussian]:
    """``(t, belief)`` of snapshot ``i`` of ``poses`` (as
    :func:`~swarmloc.sensors.snapshots.snapshot_poses` returns them): the fitted pose with the fit's covariance
    plus ``1e-8`` on the diagonal, at the snapshot's time ``t`` [s] (:func:`_fix_belief`)."""
    return float(poses["t"][i]), _fix_belief(poses["pose"][i], poses["cov"][i])


def fuse_fixes(
    robot: int,
    belief: GroupGaussian,
    t_start: float,
    t_end: float,
    events: Sequence[Odometry | Detection],
    config: Config = DEFAULTS,
    restart: int | None = 3,
    inflate: float = 1.0,
) -> tuple[GroupGaussian, dict[str, int]]:
    """Robot ``robot``'s ``diekf`` (no landmarks, ``config``'s gate) from ``belief`` at ``t_start`` [s] over its
    ``events`` (its odometry and its absolute pose fixes, ``Kind.ABSOLUTE`` detections, in stamp order) to
    ``t_end``: its belief at ``t_end`` and its counts (every fix once: ``fused`` by the filter in force, ``gated``,
    ``restart_fixes``, or the node's ``rejected`` / ``unknown``; ``restarts``).

    A gate locks a filter out of its own fixes once its belief is off beyond its covariance. ``restart`` (k; None:
    never) re-acquires it as a tracker replaces a confirmed track that keeps missing its gate with a tentative track
    its measurements confirm (M-of-N confirmation and deletion: Blackman & Popoli 1999, *Design and Analysis of
    Modern Tracking Systems*, sec. 9.3; Bar-Shalom, Willett & Tian 2011, *Tracking and Data Fusion*, ch. 3): after k
    fixes in a row gated, a tentative filter started from the first of them (its mean, its covariance times
    ``inflate``, at least 1) on the same odometry must fuse the other k - 1 through the same gate; then it replaces
    the robot's filter (a restart, its k fixes counted ``restart_fixes``), else the run's first fix is counted
    ``gated`` (an outlier, not a lost track) and the run goes on from the next. Raises ValueError for ``restart`` < 1
    or ``inflate`` < 1, RuntimeError for a fix that moves none of the node's counters or more than one."""
    if restart is not None and restart < 1:
        raise ValueError(f"fuse_fixes: restart must be at least 1 fix (or None), got {restart}")
    if not inflate >= 1.0:
        raise ValueError(f"fuse_fixes: inflate must be at least 1, got {inflate}")

    def node_from(b: GroupGaussian, t: float) -> Any:
        return make_team("diekf", {robot: b}, **node_options("diekf", config, None, t))[0]

    def outcome(node: Any, d: Detection) -> str:
        before = node.stats()
        node.step([d])
        after = node.stats()
        moved = [k for k in ("fused", "gated", "rejected", "unknown") if after[k] > before[k]]
        if len(moved) != 1:
            raise RuntimeError(f"fuse_fixes: the fix at {d.stamp} s moved the counters {moved}, not one of them")
        return moved[0]

    node = node_from(belief, t_start)
    counts = dict.fromkeys(FIX_COUNTS, 0)
    lost: list[tuple[int, Detection]] = []  # the fixes gated in a row, with their indices in events
    for i, e in enumerate(events):
        if isinstance(e, Odometry):
            node.step(e)
            continue
        got = outcome(node, e)
        if got != "gated":
            counts[got] += 1
            if got == "fused":
                counts["gated"] += len(lost)
                lost = []
            continue
        lost.append((i, e))
        while restart is not None and len(lost) >= restart:
            j, seed = lost[0]
            tentative = node_from(_fix_belief(seed.z, seed.cov, inflate), seed.stamp)
            held = [x for x in events[:j] if isinstance(x, Odometry)]
            if held:  # the command in force at the seed's stamp, from there on
                tentative.step(Odometry(robot, seed.stamp, max(held[-1].t1, seed.stamp), held[-1].v, held[-1].w))
            if _confirms(tentative, events[j + 1 : i + 1], outcome):
                node = tentative
                counts["restarts"] += 1
                counts["restart_fixes"] += len(lost)
                lost = []
            else:
                counts["gated"] += 1
                lost = lost[1:]
    counts["gated"] += len(lost)
    return node.belief(t_end), counts


def _confirms(node: Any, events: Sequence[Odometry | Detection], outcome: Callable[[Any, Detection], str]) -> bool:
    """Whether ``node`` fuses every fix of ``events`` (stepped in order, up to the first it does not fuse)."""
    for e in events:
        if isinstance(e, Odometry):
            node.step(e)
        elif outcome(node, e) != "fused":
            return False
    return True


def fused_from_snapshots(
    data: MRCLAMData, ds: DetectionSet, config: Config = DEFAULTS, restart: int | None = 3, inflate: float = 1.0
) -> tuple[float, dict[int, GroupGaussian], dict[int, dict[str, int]]]:
    """The truth-free start: at ``t0``, the latest of the robots' first landmark snapshots (as
    :func:`initial_from_snapshots`'), each robot's :func:`fuse_fixes` from its first snapshot, its later ones up to
    ``t0`` its absolute pose fixes (the fit's covariance at the a-priori std), gated at chi-square 0.99; returns
    ``(t0, beliefs, counts per robot)`` (``fixes`` and :func:`fuse_fixes`' counts). ``restart``, ``inflate``:
    :func:`fuse_fixes`' (None: a robot its gate locked out of its fixes stays out). Raises ValueError as
    :func:`initial_from_snapshots` does."""
    poses = snapshot_poses(ds, PRIOR_RANGE_STD, PRIOR_BEARING_STD)
    first = _first_snapshots(data, poses)
    t0 = max(float(poses["t"][i]) for i in first.values())
    odometry = [e for e in mrclam_events(data, landmarks=False, robot_measurements=False) if isinstance(e, Odometry)]
    # one robot and its own fixes: the team's options (association of robot detections, clusters) do not apply
    gated = config.with_filter(gate=0.99, association="tags", diekf_cluster=0, diekf_reform=0.0)
    beliefs: dict[int, GroupGaussian] = {}
    counts: dict[int, dict[str, int]] = {}
    for r in data.robots:
        sel = np.flatnonzero((poses["observer"] == r) & (poses["t"] > poses["t"][first[r]]) & (poses["t"] <= t0))
        ts, seed = snapshot_belief(poses, first[r])
        fixes = [Detection(r, float(poses["t"][j]), Kind.ABSOLUTE, np.asarray(poses["pose"][j], float),
                           np.asarray(poses["cov"][j], float) + 1e-8 * np.eye(3), target=None)
                 for j in sel]  # fmt: skip
        if ts >= t0:  # the robot whose first snapshot defines t0
            beliefs[r], counts[r] = seed, {"fixes": 0, **dict.fromkeys(FIX_COUNTS, 0)}
            continue
        mine: list[Odometry | Detection] = [e for e in odometry if e.robot == r and ts <= e.stamp <= t0]
        mine = sorted([*mine, *fixes], key=lambda e: e.stamp)
        beliefs[r], n = fuse_fixes(r, seed, ts, t0, mine, gated, restart, inflate)
        counts[r] = {"fixes": len(fixes), **n}
    return t0, beliefs, counts


def landmark_readings(data: MRCLAMData, t0: float, t1: float) -> list[Detection]:
    """Every landmark reading of ``data`` in ``(t0, t1]`` [s] (the ones a score can use, whether or not the run
    fuses landmarks)."""
    events = mrclam_events(data, landmarks=True, robot_measurements=False)
    return [e for e in events if isinstance(e, Detection) and not e.target_is_robot and t0 < e.t <= t1]


class HeldOutRun(NamedTuple):
    """One run of :func:`heldout_runs`: its result, the readings it scores (its fold's, never fused in it) and its
    nodes (a smoother's delayed output is theirs: :func:`~swarmloc.evaluation.delayed.delayed_output`)."""

    run: RunResult
    readings: list[Detection]
    nodes: list[Any]


def heldout_runs(
    name: str,
    initial: Mapping[int, GroupGaussian],
    events: Sequence[Event],
    readings: Sequence[Detection],
    landmarks: Mapping[int, Sequence[float]],
    t0: float,
    configs: Mapping[frozenset[int], Config],
    truth: TruthFn | None = None,
) -> list[HeldOutRun]:
    """Estimator ``name`` once per fold of ``configs`` (landmark ids -> the run's configuration) from ``initial`` at
    ``t0``, on ``events`` less that fold's landmark readings (:func:`~swarmloc.evaluation.heldout.without_landmarks`),
    beliefs recorded just before each of that fold's ``readings``; one :class:`HeldOutRun` per fold."""
    out = []
    for fold, config in configs.items():
        mine = [d for d in readings if d.target in fold]
        nodes = make_team(name, initial, **node_options(name, config, landmarks, t0))
        rec = reading_times(mine) if mine else np.array([t0])
        res = run(nodes, without_landmarks(events, fold), record_times=rec, truth=truth, name=name)
        out.append(HeldOutRun(res, mine, nodes))
    return out


def truth_free_score(
    data: MRCLAMData,
    ds: DetectionSet,
    events: Sequence[Event],
    name: str,
    config: Config,
    std: tuple[float, float],
    landmarks: bool,
    t_end: float,
    holdout: int = 3,
    longest: float = SCORED_SPAN,
    start: tuple[float, Mapping[int, GroupGaussian]] | None = None,
    keep_runs: bool = False,
) -> dict[str, Any]:
    """The held-out landmark NIS score of estimator ``name`` on ``data`` up to ``t_end`` [s], at most ``longest`` s:
    the runs start from :func:`fused_from_snapshots` (at ``t0``) on ``events`` (those of the evaluation: its camera
    model), with ``config``; with ``landmarks`` one run per each of ``holdout`` landmark folds scores that fold's
    readings, without landmarks one run scores every reading. ``std`` (range [m], bearing [rad]): the readings' noise
    in the NIS (the camera model's). Returns :func:`~swarmloc.evaluation.heldout.nis_summary` with ``folds`` (0:
    landmarks off), ``t0_s`` (after the recording's start), ``duration_s`` (scored) and ``wall_s`` (every run of the
    score). ``start``: ``(t0, beliefs)`` of :func:`fused_from_snapshots` when the caller has them already, or
    another start's (:func:`initial_from_snapshots`'). ``keep_runs``: also ``runs``, the runs scored, each with the
    readings it scores (:class:`HeldOutRun`; a diagnosis reads their innovations). Raises :class:`NoStart`
    where there is no truth-free start before ``t_end``."""
    wall = time.perf_counter()
    t0, initial = fused_from_snapshots(data, ds, config)[:2] if start is None else start
    if t0 >= t_end:
        raise NoStart(f"the truth-free start (every robot's first landmark snapshot) is {t0 - data.t_start:.1f} s "
                      f"in, after the span's end")  # fmt: skip
    t_end = min(t_end, t0 + longest)
    span = [e for e in events if t0 <= e.stamp <= t_end]
    readings = landmark_readings(data, t0, t_end)
    folds = landmark_folds(data.landmarks, holdout) if landmarks else [frozenset(data.landmarks)]
    scored = heldout_runs(name, initial, span, readings, data.landmarks, t0, dict.fromkeys(folds, config))
    nis = np.concatenate([np.empty(0)] + [tracks_nis(h.run.tracks, h.readings, data.landmarks, std) for h in scored])
    kept = {"runs": scored} if keep_runs else {}
    return {**nis_summary(nis), "folds": len(folds) if landmarks else 0, "t0_s": t0 - data.t_start,
            "duration_s": t_end - t0, "wall_s": time.perf_counter() - wall, **kept}  # fmt: skip
