"""The fixed-lag smoothers' delayed output, as tracks, and scored beside their causal belief at the same instants.

A smoother node with ``lagged_log`` set (option ``delayed=True``, :attr:`swarmloc.estimators.fls.WindowSolver.
lagged_log`) files every pose leaving its window, ``stamp -> (x (3,), P (3, 3))`` Cartesian. :func:`delayed_output`
turns those into tracks at their own stamps (a pose per detection instant, ``lag`` s late; the last ``lag`` s of a
run never leave the window), scored against the truth at those stamps; :func:`delayed_tracks` pairs them with the
run's recorded (causal) beliefs at the same stamps, so that :func:`~swarmloc.evaluation.metrics.evaluate` scores
both on the same instants. :func:`carried_output` gives it at any instants instead (the held-out scores' readings):
the pose filed last, predicted through the robot's odometry.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from swarmloc.estimators.adaptive_noise import scaled
from swarmloc.events import Event, Odometry
from swarmloc.kernels import cartesian as C
from swarmloc.lie import SE2
from swarmloc.motion.unicycle import UnicycleNoise
from swarmloc.runner import RobotTrack, RunResult, TruthFn, truth_table

_ZERO33 = np.zeros((3, 3))

__all__ = ["carried", "carried_output", "delayed_output", "delayed_tracks", "lagged_track"]


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


def carried(log: Mapping[float, tuple[np.ndarray, np.ndarray]], odometry: Sequence[Odometry], times: np.ndarray,
            noise: UnicycleNoise, scales: Mapping[float, float] | None = None,
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """One robot's delayed output ``log`` (``stamp -> (x (3,), P (3, 3))`` Cartesian) at ``times`` [s]: at each
    time the pose filed last at or before it, predicted to it through the robot's ``odometry`` (its intervals in
    ``t0`` order, no command outside them) with the motion model's ``noise``
    (:func:`~swarmloc.kernels.cartesian.predict_one`, as a node predicts between its detections), its process
    noise times ``scales[stamp]`` where given (the node's online scale in force at the filed pose's stamp,
    :attr:`~swarmloc.estimators.fls.WindowSolver.lagged_scale`). ``(times, x (k, 3), P (k, 3, 3))`` at the
    times that have one: none before the first filing, nor at or after the last one (still in the window when the
    run ended)."""
    stamps = sorted(log)
    starts = [o.t0 for o in odometry]
    ts: list[float] = []
    xs: list[np.ndarray] = []
    Ps: list[np.ndarray] = []
    base = math.nan
    cur, j = math.nan, 0
    x = P = np.zeros(0)
    lam = 1.0
    for t in np.sort(np.asarray(times, dtype=float)).tolist():
        i = bisect_right(stamps, t) - 1
        if i < 0 or i == len(stamps) - 1:
            continue
        if stamps[i] != base:  # a later filing: start again from it
            base = cur = stamps[i]
            x, P = (np.array(a, dtype=float) for a in log[base])
            lam = 1.0 if scales is None else float(scales.get(base, 1.0))
            j = max(bisect_right(starts, cur) - 1, 0)
        while cur < t:
            while j < len(odometry) and odometry[j].t1 <= cur:
                j += 1
            if j < len(odometry) and odometry[j].t0 <= cur:
                v, w, end = odometry[j].v, odometry[j].w, min(odometry[j].t1, t)
            else:  # no command: standing still until the next interval
                v, w, end = 0.0, 0.0, min(odometry[j].t0, t) if j < len(odometry) else t
            x1, P1, _, _ = C.predict_one(x, P, v, w, end - cur, noise)
            if lam != 1.0:  # the step's process noise (its covariance from zero) scaled, as the node scales it
                P1 = scaled(P1 - C.predict_one(x, _ZERO33, v, w, end - cur, noise)[1], P1, lam)
            x, P, cur = x1, P1, end
        ts.append(t)
        xs.append(x)
        Ps.append(P)
    return (
        np.array(ts, dtype=float),
        np.array(xs, dtype=float).reshape(-1, 3),
        np.array(Ps, dtype=float).reshape(-1, 3, 3),
    )


def carried_output(nodes: Iterable[Any], events: Sequence[Event], times: np.ndarray, truth: TruthFn | None,
                   name: str) -> RunResult:  # fmt: skip
    """The delayed output of a team of smoother nodes run with ``delayed=True`` on ``events``, :func:`carried` to
    ``times`` [s] with each robot's odometry in ``events`` and its node's motion noise (scaled as the node scaled
    it): a :class:`RunResult` named ``"<name>_delayed"``, truth at the times (those without finite truth left out
    when ``truth`` is given)."""
    tracks = {}
    for n in nodes:
        odometry = sorted((e for e in events if isinstance(e, Odometry) and e.robot == n.robot), key=lambda o: o.t0)
        ts, x, P = carried(n.lagged_log, odometry, times, n.noise, n.lagged_scale)
        tr = truth_table(truth, n.robot, ts)
        if truth is not None:
            ok = np.isfinite(tr).all(axis=1)
            ts, x, P, tr = ts[ok], x[ok], P[ok], tr[ok]
        tracks[n.robot] = RobotTrack(ts, *_track_arrays(x, P), tr)
    return RunResult(f"{name}_delayed", tracks, 0.0)
