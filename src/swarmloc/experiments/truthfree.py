"""The truth-free consistency score (:mod:`swarmloc.evaluation.heldout`) run on an MRCLAM recording: a truth-free
start from the robots' landmark snapshots, and the runs that hold each fold of the landmarks out.

Used by ``swarmloc evaluate mrclam`` on a recording without ground truth (:func:`truth_free_score`, the recommended
estimator only) and by the leave-one-dataset-out study (the repository's ``swarmloc_studies.lodo``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

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
from swarmloc.events import Detection, Event, Odometry
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.runner import RunResult, TruthFn, run
from swarmloc.sensors.decorrelate import PRIOR_BEARING_STD, PRIOR_RANGE_STD, DetectionSet, snapshot_poses

__all__ = [
    "SCORED_SPAN",
    "heldout_runs",
    "initial_from_snapshots",
    "landmark_readings",
    "snapshot_belief",
    "truth_free_score",
]

SCORED_SPAN = 300.0
"""[s] The longest span :func:`truth_free_score` scores, from the truth-free start: its runs (3 with landmarks) then
cost at most about what the estimator's own run of 900 s does, whatever the recording's length (the
leave-one-dataset-out study scores 200-300 s too)."""


def initial_from_snapshots(
    data: MRCLAMData, ds: DetectionSet, config: Config = DEFAULTS
) -> tuple[float, dict[int, GroupGaussian]]:
    """Truth-free initial beliefs: each robot's first landmark snapshot pose (fit covariance at the a-priori std),
    dead-reckoned to ``t0``, the latest first snapshot; returns ``(t0, beliefs)``. Raises ValueError when a robot
    of ``data`` never sees two landmarks at once."""
    poses = snapshot_poses(ds, PRIOR_RANGE_STD, PRIOR_BEARING_STD)
    first: dict[int, tuple[float, GroupGaussian]] = {}
    for r in data.robots:
        sel = np.flatnonzero((poses["observer"] == r) & (poses["t"] >= data.t_start))
        if sel.size == 0:
            raise ValueError(f"{data.name}: robot {r} never reads two landmarks at once; no truth-free start")
        first[r] = snapshot_belief(poses, int(sel[0]))
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


def snapshot_belief(poses: Mapping[str, np.ndarray], i: int) -> tuple[float, GroupGaussian]:
    """``(t, belief)`` of snapshot ``i`` of ``poses`` (as
    :func:`~swarmloc.sensors.snapshots.snapshot_poses` returns them): the fitted pose with the fit's covariance
    plus ``1e-8`` on the diagonal, at the snapshot's time ``t`` [s]. The fit's covariance is of ``(x, y, theta)``;
    at a small angle it is that of the left perturbation, so it is rotated into the body frame for the
    right-perturbation convention of the nodes."""
    pose, cov = poses["pose"][i], poses["cov"][i]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    belief = GroupGaussian(SE2, SE2.from_xytheta(pose), rot @ cov @ rot.T + 1e-8 * np.eye(3), validate=False)
    return float(poses["t"][i]), belief


def landmark_readings(data: MRCLAMData, t0: float, t1: float) -> list[Detection]:
    """Every landmark reading of ``data`` in ``(t0, t1]`` [s] (the ones a score can use, whether or not the run
    fuses landmarks)."""
    events = mrclam_events(data, landmarks=True, robot_measurements=False)
    return [e for e in events if isinstance(e, Detection) and not e.target_is_robot and t0 < e.t <= t1]


def heldout_runs(
    name: str,
    initial: Mapping[int, GroupGaussian],
    events: Sequence[Event],
    readings: Sequence[Detection],
    landmarks: Mapping[int, Sequence[float]],
    t0: float,
    configs: Mapping[frozenset[int], Config],
    truth: TruthFn | None = None,
) -> list[tuple[RunResult, list[Detection]]]:
    """Estimator ``name`` once per fold of ``configs`` (landmark ids -> the run's configuration) from ``initial`` at
    ``t0``, on ``events`` less that fold's landmark readings (:func:`~swarmloc.evaluation.heldout.without_landmarks`),
    beliefs recorded just before each of that fold's ``readings``; returns ``(run, the fold's readings)`` pairs."""
    out = []
    for fold, config in configs.items():
        mine = [d for d in readings if d.target in fold]
        nodes = make_team(name, initial, **node_options(name, config, landmarks, t0))
        rec = reading_times(mine) if mine else np.array([t0])
        out.append((run(nodes, without_landmarks(events, fold), record_times=rec, truth=truth, name=name), mine))
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
) -> dict[str, Any]:
    """The held-out landmark NIS score of estimator ``name`` on ``data`` up to ``t_end`` [s], at most ``longest`` s:
    the runs start from :func:`initial_from_snapshots` (at ``t0``) on ``events`` (those of the evaluation: its camera
    model), with ``config``; with ``landmarks`` one run per each of ``holdout`` landmark folds scores that fold's
    readings, without landmarks one run scores every reading. ``std`` (range [m], bearing [rad]): the readings' noise
    in the NIS (the camera model's). Returns :func:`~swarmloc.evaluation.heldout.nis_summary` with ``folds`` (0:
    landmarks off), ``t0_s`` (after the recording's start), ``duration_s`` (scored) and ``wall_s`` (every run of the
    score). ``start``: :func:`initial_from_snapshots`' ``(t0, beliefs)`` when the caller has them already. Raises
    ValueError where there is no truth-free start before ``t_end``."""
    wall = time.perf_counter()
    t0, initial = initial_from_snapshots(data, ds, config) if start is None else start
    if t0 >= t_end:
        raise ValueError(f"the truth-free start (every robot's first landmark snapshot) is {t0 - data.t_start:.1f} s "
                         f"in, after the span's end")  # fmt: skip
    t_end = min(t_end, t0 + longest)
    span = [e for e in events if t0 <= e.stamp <= t_end]
    readings = landmark_readings(data, t0, t_end)
    folds = landmark_folds(data.landmarks, holdout) if landmarks else [frozenset(data.landmarks)]
    scored = heldout_runs(name, initial, span, readings, data.landmarks, t0, dict.fromkeys(folds, config))
    nis = np.concatenate([np.empty(0)] + [tracks_nis(r.tracks, d, data.landmarks, std) for r, d in scored])
    return {**nis_summary(nis), "folds": len(folds) if landmarks else 0, "t0_s": t0 - data.t_start,
            "duration_s": t_end - t0, "wall_s": time.perf_counter() - wall}  # fmt: skip
