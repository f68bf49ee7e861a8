"""The fixed-lag smoothers' delayed output, as tracks, and scored beside their causal belief at the same instants.

A smoother node with ``lagged_log`` set (option ``delayed=True``, :attr:`swarmloc.estimators.fls.WindowSolver.
lagged_log`) files every pose leaving its window, ``stamp -> (x (3,), P (3, 3))`` Cartesian. :func:`delayed_output`
turns those into tracks at their own stamps (a pose per detection instant, ``lag`` s late; the last ``lag`` s of a
run never leave the window), scored against the truth at those stamps; :func:`delayed_tracks` pairs them with the
run's recorded (causal) beliefs at the same stamps, so that :func:`~swarmloc.evaluation.metrics.evaluate` scores
both on the same instants.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from swarmloc.kernels import cartesian as C
from swarmloc.lie import SE2
from swarmloc.runner import RobotTrack, RunResult, TruthFn, truth_table

__all__ = ["delayed_output", "delayed_tracks", "lagged_track"]


def lagged_track(log: Mapping[float, tuple[np.ndarray, np.ndarray]], robot: int, truth: TruthFn | None) -> RobotTrack:
    """One robot's delayed output ``stamp -> (x (3,), P (3, 3) Cartesian)`` as a track in stamp order: means
    ``(x, y, theta)``, exponential-coordinate covariances (as every track), truth at the stamps; with ``truth``,
    the stamps without finite truth are left out."""
    ts = np.array(sorted(log), dtype=float)
    x = np.array([log[t][0] for t in ts], dtype=float).reshape(-1, 3)
    P = np.array([log[t][1] for t in ts], dtype=float).reshape(-1, 3, 3)
    tr = truth_table(truth, robot, ts)
    if truth is not None:
        ok = np.isfinite(tr).all(axis=1)
        ts, x, P, tr = ts[ok], x[ok], P[ok], tr[ok]
    return RobotTrack(ts, *_track_arrays(x, P), tr)


def _track_arrays(x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cartesian ``x (k, 3)``, ``P (k, 3, 3)`` as a track's means ``(x, y, theta)`` and exponential-coordinate
    covariances."""
    g, cov = C.to_group(x, P) if len(x) else (np.zeros((0, 3, 3)), P)
    return SE2.to_xytheta(g).reshape(-1, 3), cov


def delayed_output(nodes: Iterable[Any], truth: TruthFn | None, name: str, wall_time: float = 0.0) -> RunResult:
    """The delayed output of a team of smoother nodes run with ``delayed=True``: a :class:`RunResult` named
    ``"<name>_delayed"`` with one :func:`lagged_track` per robot."""
    tracks = {n.robot: lagged_track(n.lagged_log, n.robot, truth) for n in nodes}
    return RunResult(f"{name}_delayed", tracks, wall_time)


def delayed_tracks(nodes: Iterable[Any], result: RunResult) -> tuple[RunResult, RunResult]:
    """``(causal, delayed)``: per robot, the recorded beliefs of ``result`` at the stamps of its node's
    ``lagged_log`` that were recorded and have finite truth, and the delayed output at those stamps (means
    ``(x, y, theta)``, exponential-coordinate covariances, as every track). Record the run at the detection
    stamps for the two to meet."""
    causal: dict[int, RobotTrack] = {}
    delayed: dict[int, RobotTrack] = {}
    for n in nodes:
        tr = result.tracks[n.robot]
        at = {float(t): k for k, t in enumerate(tr.times)}
        rows = [(at[float(ts)], xp) for ts, xp in sorted(n.lagged_log.items()) if float(ts) in at]
        rows = [(k, xp) for k, xp in rows if np.isfinite(tr.truth[k]).all()]
        idx = np.array([k for k, _ in rows], dtype=int)
        causal[n.robot] = tr.rows(idx)
        x = np.array([xp[0] for _, xp in rows], dtype=float).reshape(-1, 3)
        P = np.array([xp[1] for _, xp in rows], dtype=float).reshape(-1, 3, 3)
        delayed[n.robot] = RobotTrack(tr.times[idx], *_track_arrays(x, P), tr.truth[idx])
    name = result.estimator
    return RunResult(name, causal, result.wall_time), RunResult(f"{name}_delayed", delayed, result.wall_time)
