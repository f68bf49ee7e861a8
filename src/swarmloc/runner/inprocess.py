"""The in-process driver: routes events and messages between nodes, and records beliefs against truth.

:func:`run` is a short loop. Each event goes to the node owning its robot (odometry by robot, detections by
observer; consecutive detections of one observer at one instant go together); the messages a node returns go
to the nodes they are addressed to until none are left (a query to a robot outside the team is answered "not
found"). Nodes do the rest: time, replay, accounting (:mod:`swarmloc.node`).

Recording: at every ``Truth`` event (simulation) or at every ``record_times`` entry with a ``truth(robot, times)``
function (datasets), the owning node's :meth:`~swarmloc.node.base.Node.belief_at` is taken once the belief
at that time is final: once the node's present is a horizon past it (any later input that old would be
rejected) or at the end of the run. So the record is the same whatever order the events came in, within the
horizon.

Start times: a node that has no ``t0`` starts at the earliest stamp of the events it will receive.
"""

from __future__ import annotations

import heapq
import itertools
import math
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence

import numpy as np

from swarmloc.datasets.source import TruthFn
from swarmloc.events import Detection, Event, Odometry, Truth
from swarmloc.lie import SE2
from swarmloc.messages import BeliefAnswer, BeliefQuery, Message, RdlState, RdlStateQuery
from swarmloc.node import Node
from swarmloc.runner.result import RobotTrack, RunResult

Progress = Callable[[int, int], None]
"""``progress(done, total)``, called every few thousand events (e.g. to drive a progress bar)."""


class _Records:
    """Pending records per node (a heap by time), resolved once final."""

    def __init__(self) -> None:
        self.heap: dict[int, list[tuple[float, int, int, np.ndarray]]] = {}
        self.rows: dict[int, list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]] = {}
        self.n = 0
        self.too_old = 0

    def add(self, node: Node, t: float, robot: int, truth: np.ndarray) -> None:
        self.n += 1
        heapq.heappush(self.heap.setdefault(id(node), []), (t, self.n, robot, truth))

    def resolve(self, node: Node, upto: float) -> int:
        h = self.heap.get(id(node))
        done = 0
        while h and h[0][0] <= upto:
            t, _, robot, truth = heapq.heappop(h)
            try:
                b = node.belief_at(t, robot)
            except ValueError:  # asked for after the node's history moved past it (a very late Truth event)
                self.too_old += 1
                continue
            self.rows.setdefault(robot, []).append((t, _xytheta(b.mean), np.array(b.cov), truth))
            done += 1
        return done

    def tracks(self) -> dict[int, RobotTrack]:
        out = {}
        for r, rows in sorted(self.rows.items()):
            rows.sort(key=lambda x: x[0])
            out[r] = RobotTrack(
                np.array([x[0] for x in rows]),
                np.array([x[1] for x in rows]).reshape(-1, 3),
                np.array([x[2] for x in rows]).reshape(-1, 3, 3),
                np.array([x[3] for x in rows]).reshape(-1, 3),
            )
        return out


def run(
    nodes: Node | Iterable[Node],
    events: Iterable[Event],
    record_times: Sequence[float] | np.ndarray | None = None,
    truth: TruthFn | None = None,
    progress: Progress | None = None,
    name: str | None = None,
) -> RunResult:
    """Drive ``nodes`` (a team: each robot owned by exactly one node) over ``events`` and record their beliefs.

    With ``record_times`` every robot is recorded at those times, against ``truth(robot, times)`` when given (NaN
    truth otherwise); without, at each ``Truth`` event. Bad events never stop the run: they are rejected by the
    nodes and counted in ``RunResult.stats``/``reasons``; events of robots outside the team are counted
    ``unknown_robot`` (detections also as ``unknown``, so that every detection stays accounted for).
    """
    team = [nodes] if isinstance(nodes, Node) else list(nodes)
    if not team:
        raise ValueError("run: no nodes")
    owner: dict[int, Node] = {}
    for n in team:
        for r in n.robots:
            if r in owner:
                raise ValueError(f"run: robot {r} is owned by two nodes ({owner[r].name} and {n.name})")
            owner[r] = n
    events = list(events)
    first: dict[int, float] = {}
    for e in events:
        r = e.robot if isinstance(e, Odometry | Truth) else e.observer if isinstance(e, Detection) else None
        n = owner.get(r)
        s = e.stamp if n is not None else math.nan
        if n is not None and isinstance(s, int | float) and math.isfinite(s) and s < first.get(id(n), math.inf):
            first[id(n)] = s
    for n in team:
        if not n.started and id(n) in first:
            n.start(first[id(n)])

    stats: Counter[str] = Counter()
    runner_reasons: Counter[str] = Counter()
    rec = _Records()
    if record_times is not None:
        rt = np.asarray(record_times, dtype=float)
        for r in sorted(owner):
            tr = truth_table(truth, r, rt)
            for t, row in zip(rt.tolist(), tr, strict=True):
                if truth is not None and not np.isfinite(row).all():
                    stats["truth_missing"] += 1
                    continue
                rec.add(owner[r], t, r, row)

    def deliver(node: Node, item: object, stamp: object) -> None:
        """Resolve the records this input could no longer change, then step the node and route its messages."""
        h = rec.heap.get(id(node))
        if h and isinstance(stamp, float | int):
            upto = max(node.present, stamp) - node.horizon
            if h[0][0] <= upto:
                rec.resolve(node, upto)
        out = node.step(item)
        if out:
            pump(out)

    order = itertools.count()

    def pump(msgs: list[Message]) -> None:
        """Deliver messages until none are left, lowest key first (an answer at key ``q`` depends only on inputs
        before ``q``, so in this order no answer is revised twice for the same cause); among messages with one key
        the highest revision first, so that an older one arrives stale instead of causing a second replay."""
        heap: list[tuple] = []

        def push(ms: list[Message]) -> None:
            for m in ms:
                heapq.heappush(heap, (m.stamp, m.observer, m.sub, -getattr(m, "seq", 0), next(order), m))

        push(msgs)
        while heap:
            m = heapq.heappop(heap)[-1]
            stats["messages"] += 1
            node = owner.get(m.receiver)
            if node is None:
                if isinstance(m, BeliefQuery | RdlStateQuery):
                    kind = BeliefAnswer if isinstance(m, BeliefQuery) else RdlState
                    reason = f"robot {m.receiver} is not in the team"
                    push([kind(sender=m.receiver, receiver=m.sender, stamp=m.stamp, sub=m.sub, found=False,
                               reason=reason)])  # fmt: skip
                else:
                    stats["messages_undeliverable"] += 1
                continue
            if not isinstance(m, BeliefQuery | RdlStateQuery):
                rec.resolve(node, max(node.present, m.stamp) - node.horizon)
            push(node.step(m))

    # odometry, the bulk of a log, goes straight to the node's fast path (Node._odometry_fast) when it takes it, with
    # the records resolved exactly as deliver() would: (node, its record heap, horizon, fast path) per robot
    odo_route = {r: (n, rec.heap.setdefault(id(n), []), n.horizon, n._odometry_fast) for r, n in owner.items()}
    t_wall = time.perf_counter()
    total = len(events)
    i = 0
    while i < total:
        e = events[i]
        if progress is not None and i % 4096 == 0:
            progress(i, total)
        i += 1
        if type(e) is Odometry:
            route = odo_route.get(e.robot)
            if route is None:
                stats["unknown_robot"] += 1
                stats["odometry"] += 1
                continue
            node, h, horizon, fast = route
            stamp = e.t0
            if type(stamp) is float:
                if h:
                    upto = max(node.present, stamp) - horizon
                    if h[0][0] <= upto:
                        rec.resolve(node, upto)
                if fast(e):
                    continue
                out = node.step(e)
                if out:
                    pump(out)
            else:
                deliver(node, e, stamp)
        elif isinstance(e, Detection):
            group = [e]
            while i < total and isinstance(events[i], Detection) and events[i].observer == e.observer \
                    and events[i].t == e.t:  # fmt: skip
                group.append(events[i])
                i += 1
            node = owner.get(e.observer)
            if node is None:
                stats["unknown_robot"] += len(group)
                stats["detections"] += len(group)
                stats["unknown"] += len(group)
                runner_reasons[f"unknown: observer {e.observer!r} is not in the team"] += len(group)
                continue
            deliver(node, group, e.t)
        elif isinstance(e, Truth):
            node = owner.get(e.robot)
            if node is None:
                stats["truth_unknown_robot"] += 1
            elif record_times is None:
                rec.add(node, float(e.t), e.robot, np.asarray(e.pose, dtype=float))
        else:
            stats["unknown_event"] += 1
    for n in team:
        pump(n.expire())
    for n in team:
        rec.resolve(n, math.inf)
    wall = time.perf_counter() - t_wall
    if progress is not None:
        progress(total, total)

    merged: Counter[str] = Counter()
    reasons: Counter[str] = Counter()
    timing = {"predict_s": 0.0, "predict_n": 0, "fuse_s": 0.0, "fuse_n": 0}
    for n in team:
        merged.update(n.stats())
        reasons.update(n.reasons)
        for k in timing:
            timing[k] += n.timing[k]
    merged.update(stats)
    reasons.update(runner_reasons)
    merged["recorded"] = sum(len(v) for v in rec.rows.values())
    if rec.too_old:
        merged["record_too_old"] = rec.too_old
    for k in ("detections", "fused", "gated", "rejected", "unknown", "pending", "odometry", "messages"):
        merged.setdefault(k, 0)
    return RunResult(name or team[0].name, rec.tracks(), wall, dict(merged), total, reasons, timing)


def _xytheta(g: np.ndarray) -> np.ndarray:
    """:meth:`SE2.to_xytheta` of one pose, in floats (the same numbers, a quarter of the time)."""
    if g.shape != (3, 3):
        return SE2.to_xytheta(g)
    th = float(np.arctan2(g[1, 0], g[0, 0]))  # numpy's arctan2, not math.atan2: they may differ in the last bit
    return np.array([g[0, 2], g[1, 2], th + 2 * np.pi if th <= -np.pi else th])


def truth_table(truth: TruthFn | None, robot: int, times: np.ndarray) -> np.ndarray:
    """Truth at every record time, one vectorized call (falls back to one call per time: NaN where missing)."""
    if truth is None:
        return np.full((times.size, 3), np.nan)
    try:
        return np.asarray(truth(robot, times), dtype=float).reshape(times.size, 3)
    except ValueError:
        out = np.full((times.size, 3), np.nan)
        for k in range(times.size):
            try:
                out[k] = np.asarray(truth(robot, times[k : k + 1]), dtype=float)[0]
            except ValueError:
                pass
        return out
