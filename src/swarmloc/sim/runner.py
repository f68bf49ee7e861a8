"""The runner: drives any estimator over any time-ordered event source and records beliefs against truth.

Timing is causal. Each robot's filter has its own time and its last odometry command ``(v, w)``.

* ``Odometry(t0, t1, v, w)``: the filter is predicted from its time to ``t1`` with ``(v, w)`` (a gap before
  ``t0`` is bridged with the previous command; a part already extrapolated is not predicted twice).
* Detections of one observer at one instant are handed to ``update`` together, after the observer has been
  brought to that instant with its last command (zero-order hold). A neighbour asked for its belief through the
  channel answers with its belief predicted to that instant (``Estimator.predicted_belief``) without moving its
  own filter; recording on a time grid does the same, so results do not depend on when one looks.
* ``Truth`` events (simulation) or a grid of record times with a truth function (datasets) trigger recording.

Bad events (NaN odometry, unknown robot ids) are counted in ``RunResult.stats`` and skipped; they never stop
the run.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from swarmloc.estimators.base import CallbackChannel, Estimator
from swarmloc.events import Detection, Event, Odometry, Truth
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2

TruthFn = Callable[[int, np.ndarray], np.ndarray]
"""``truth(robot, times) -> (len(times), 3)`` world poses."""


@dataclass
class RobotTrack:
    """Recorded beliefs of one robot: times ``(T,)``, means ``(T, 3)`` as (x, y, theta), exponential-coordinate
    covariances ``(T, 3, 3)`` (right perturbation) and truth ``(T, 3)``."""

    times: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    truth: np.ndarray


@dataclass
class RunResult:
    estimator: str
    tracks: dict[int, RobotTrack]
    wall_time: float
    stats: dict[str, int] = field(default_factory=dict)
    n_events: int = 0


class _Recorder:
    def __init__(self) -> None:
        self.rows: dict[int, list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]] = {}

    def add(self, robot: int, t: float, b: GroupGaussian, truth: np.ndarray) -> None:
        self.rows.setdefault(robot, []).append((t, SE2.to_xytheta(b.mean), np.array(b.cov), np.asarray(truth, float)))

    def tracks(self) -> dict[int, RobotTrack]:
        out = {}
        for r, rows in sorted(self.rows.items()):
            out[r] = RobotTrack(
                np.array([x[0] for x in rows]),
                np.array([x[1] for x in rows]),
                np.array([x[2] for x in rows]),
                np.array([x[3] for x in rows]),
            )
        return out


def run(
    estimator: Estimator,
    events: Iterable[Event],
    record_times: Sequence[float] | np.ndarray | None = None,
    truth: TruthFn | None = None,
    progress: bool = False,
    description: str | None = None,
) -> RunResult:
    """Drive ``estimator`` over ``events`` (sorted by time) and record its beliefs.

    With ``record_times`` and ``truth`` (datasets) every robot is recorded at those times against
    ``truth(robot, times)``; otherwise at each ``Truth`` event (simulation).
    """
    events = list(events)
    robots = set(estimator.robots)
    clock = {r: -math.inf for r in robots}
    cmd = {r: (0.0, 0.0) for r in robots}
    stats = {"odometry": 0, "detections": 0, "bad_odometry": 0, "unknown_robot": 0, "recorded": 0, "extrapolated": 0}
    rec = _Recorder()

    def advance(r: int, t: float) -> None:
        if clock[r] == -math.inf:
            clock[r] = t
            return
        if t > clock[r]:
            v, w = cmd[r]
            estimator.predict(r, clock[r], t, v, w)
            stats["extrapolated"] += 1
            clock[r] = t

    def peek(r: int, t: float) -> GroupGaussian:
        """Belief of ``r`` at ``t`` without moving its filter (falls back to advancing it)."""
        if clock[r] != -math.inf and t > clock[r]:
            v, w = cmd[r]
            try:
                return estimator.predicted_belief(r, t - clock[r], v, w)
            except NotImplementedError:
                advance(r, t)
        return estimator.belief(r)

    def answer(k: int, t: float) -> GroupGaussian | None:
        if k not in robots:
            return None
        if clock[k] != -math.inf and t > clock[k] and type(estimator).shared_belief is Estimator.shared_belief:
            return peek(k, t)
        advance(k, t)
        return estimator.shared_belief(k)

    def call(k: int, t: float, request: str, payload: dict) -> object:
        handler = getattr(estimator, "handle", None)
        if k not in robots or handler is None:
            return None
        advance(k, t)
        return handler(k, request, payload)

    channel = CallbackChannel(answer, call)

    rt = np.asarray(record_times, dtype=float) if record_times is not None else None
    rec_i = 0
    pending: list[Detection] = []

    def flush() -> None:
        if not pending:
            return
        d0 = pending[0]
        advance(d0.observer, d0.t)
        estimator.update(d0.observer, d0.t, list(pending), channel)
        pending.clear()

    # truth at every record time, one vectorized call per robot (falls back to one call per time when some
    # times lie outside a robot's ground truth)
    truth_table: dict[int, np.ndarray] = {}
    if rt is not None and truth is not None:
        for r in robots:
            try:
                truth_table[r] = np.asarray(truth(r, rt), dtype=float)
            except ValueError:
                pass

    def truth_at(r: int, i: int) -> np.ndarray | None:
        if truth is None:
            return np.full(3, np.nan)
        if r in truth_table:
            return truth_table[r][i]
        try:
            return np.asarray(truth(r, rt[i : i + 1]), dtype=float)[0]
        except ValueError:
            return None  # no truth at this time for this robot

    def record_grid(i: int) -> None:
        t_rec = float(rt[i])
        for r in sorted(robots):
            tr = truth_at(r, i)
            if tr is not None:
                rec.add(r, t_rec, peek(r, t_rec), tr)
                stats["recorded"] += 1

    bar = None
    if progress:
        from rich.progress import Progress

        bar = Progress(transient=True)
        task = bar.add_task(description or f"{estimator.name}", total=len(events))
        bar.start()
    t_wall = time.perf_counter()
    try:
        for n, e in enumerate(events):
            if bar is not None and n % 2000 == 0:
                bar.update(task, completed=n)
            if pending and not (isinstance(e, Detection) and e.observer == pending[0].observer and e.t == pending[0].t):
                flush()
            if rt is not None:
                while rec_i < rt.size and rt[rec_i] < e.t:
                    record_grid(rec_i)
                    rec_i += 1
            if isinstance(e, Odometry):
                r = e.robot
                if r not in robots:
                    stats["unknown_robot"] += 1
                    continue
                if not all(map(math.isfinite, (e.v, e.w, e.t0, e.t1))) or e.t1 < e.t0:
                    stats["bad_odometry"] += 1
                    continue
                if clock[r] == -math.inf:
                    clock[r] = e.t0
                if clock[r] < e.t0:
                    advance(r, e.t0)
                start = max(clock[r], e.t0)
                if e.t1 > start:
                    estimator.predict(r, start, e.t1, e.v, e.w)
                    clock[r] = e.t1
                cmd[r] = (e.v, e.w)
                stats["odometry"] += 1
            elif isinstance(e, Detection):
                if e.observer not in robots:
                    stats["unknown_robot"] += 1
                    continue
                pending.append(e)
                stats["detections"] += 1
            elif isinstance(e, Truth):
                if rt is None and e.robot in robots:
                    advance(e.robot, e.t)
                    rec.add(e.robot, e.t, estimator.belief(e.robot), e.pose)
                    stats["recorded"] += 1
        flush()
        if rt is not None:
            while rec_i < rt.size:
                record_grid(rec_i)
                rec_i += 1
    finally:
        if bar is not None:
            bar.stop()
    wall = time.perf_counter() - t_wall
    stats.update({f"est_{k}": v for k, v in estimator.stats.items()})
    stats["channel_requests"] = channel.requests
    return RunResult(estimator.name, rec.tracks(), wall, stats, len(events))
