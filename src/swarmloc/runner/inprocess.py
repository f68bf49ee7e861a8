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
from swarmloc.datasets.tum import pose7
from swarmloc.events import Detection, Event, Odometry, Truth
from swarmloc.lie import SE2
from swarmloc.messages import BeliefQuery, Message, RdlStateQuery
from swarmloc.node import Node
from swarmloc.node.inputs import brief, finite_number
from swarmloc.node.protocol import not_found
from swarmloc.runner.result import RUN_COUNTERS, RobotTrack, RunResult

Progress = Callable[[int, int], None]
"""``progress(done, total)``, called every few thousand events (e.g. to drive a progress bar)."""

SETTLE_ROUNDS = 1000
"""How many times one exchange's message (same type, sender, receiver, stamp and sub-key) may be delivered while
the messages one input caused are routed, before the run stops with an error: an exchange that does not settle (a
choice that depends on its own outcome) would otherwise route messages for ever, its history growing. An input
revises each answer about once (:meth:`_Driver.pump`): the most measured is 2 (MRCLAM dataset 6 whole under every
association policy, and the runner's test of late inputs at shared stamps)."""


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
            w, d = (rows[0][1].size, rows[0][2].shape[-1]) if rows else (3, 3)  # SE(3): 7 and 6
            out[r] = RobotTrack(
                np.array([x[0] for x in rows]),
                np.array([x[1] for x in rows]).reshape(-1, w),
                np.array([x[2] for x in rows]).reshape(-1, d, d),
                np.array([x[3] if x[3].size == w else np.full(w, np.nan) for x in rows]).reshape(-1, w),
            )  # truth unknown (NaN, 3 wide) on an SE(3) team: NaN 7 wide
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
    events = list(events)
    drv = _Driver(team)
    for n in team:
        n.plan(events)  # a recording: known in advance (Node.plan)
    drv.start_nodes(events)
    if record_times is not None:
        drv.plan_records(np.asarray(record_times, dtype=float), truth)
    t_wall = time.perf_counter()
    drv.feed(events, record_truth=record_times is None, progress=progress)
    drv.finish()
    wall = time.perf_counter() - t_wall
    if progress is not None:
        progress(len(events), len(events))
    return drv.result(name or team[0].name, wall, len(events))


class _Driver:
    """The state of one run: who owns which robot, the records waiting to be final, the runner's own counters."""

    def __init__(self, team: list[Node]) -> None:
        self.team = team
        self.owner: dict[int, Node] = {}
        for n in team:
            for r in n.robots:
                if r in self.owner:
                    raise ValueError(f"run: robot {r} is owned by two nodes ({self.owner[r].name} and {n.name})")
                self.owner[r] = n
        self.stats: Counter[str] = Counter()
        self.reasons: Counter[str] = Counter()
        self.rec = _Records()
        self.order = itertools.count()

    def start_nodes(self, events: list[Event]) -> None:
        """Start every node not started yet at the earliest stamp of the events it will receive."""
        first: dict[int, float] = {}
        for e in events:
            r = e.robot if isinstance(e, Odometry | Truth) else e.observer if isinstance(e, Detection) else None
            n = self.owner.get(r)
            s = e.stamp if n is not None else math.nan
            if n is not None and finite_number(s) and s < first.get(id(n), math.inf):
                first[id(n)] = s
        for n in self.team:
            if not n.started and id(n) in first:
                n.start(first[id(n)])

    def plan_records(self, rt: np.ndarray, truth: TruthFn | None) -> None:
        for r in sorted(self.owner):
            tr = truth_table(truth, r, rt)
            for t, row in zip(rt.tolist(), tr, strict=True):
                if truth is not None and not np.isfinite(row).all():
                    self.stats["truth_missing"] += 1
                    continue
                self.rec.add(self.owner[r], t, r, row)

    def resolve(self, node: Node, stamp: float) -> None:
        """Record the beliefs no input can change once this one, stamped ``stamp``, is taken: up to a horizon before
        the node's present or ``stamp``, but never past a horizon before ``present + tolerance`` (a node refuses an
        input stamped later: one stamped 1e12 s or inf would otherwise record every belief before the inputs that
        follow it)."""
        h = self.rec.heap.get(id(node))
        if h:
            upto = _final(node.present, stamp, node.tolerance, node.horizon)
            if h[0][0] <= upto:
                self.rec.resolve(node, upto)

    def deliver(self, node: Node, item: Odometry | list[Detection], stamp: float) -> None:
        """Resolve the records this input could no longer change, then step the node and route its messages."""
        if finite_number(stamp):
            self.resolve(node, stamp)
        out = node.step(item)
        if out:
            self.pump(out)

    def pump(self, msgs: list[Message]) -> None:
        """Deliver messages until none are left, lowest key first (an answer at key ``q`` depends only on inputs
        before ``q``, so in this order no answer is revised twice for the same cause); among messages with one key
        the highest revision first, so that an older one arrives stale instead of causing a second replay.

        A message superseded before its delivery by a newer one of the same exchange (same type, sender, receiver,
        stamp and sub-key: a revised answer, a re-sent or retracted update) is not delivered (counted
        ``messages_superseded``): its receiver would take the newer one in its place anyway (answers by revision,
        updates replacing the one filed under their key), and delivering it made every node replay, re-send and
        revise once more for it. A late input at a stamp where all robots detect each other made such rounds grow
        without bound: ``diekf`` on 5 robots sharing stamps replayed 229,687 history entries in 9 s of data (36 s of
        wall time) where the newest messages alone need 4,543 (2.6 s), with the same beliefs.

        Raises RuntimeError once one exchange's message is delivered more than :data:`SETTLE_ROUNDS` times."""
        heap: list[tuple] = []
        latest: dict[tuple, int] = {}
        rounds: Counter[tuple] = Counter()

        def push(ms: list[Message]) -> None:
            for m in ms:
                n = next(self.order)
                latest[(type(m), m.sender, m.receiver, m.stamp, m.sub)] = n
                heapq.heappush(heap, (m.stamp, m.observer, m.sub, -getattr(m, "seq", 0), n, m))

        push(msgs)
        while heap:
            _, _, _, _, n, m = heapq.heappop(heap)
            if latest.get(k := (type(m), m.sender, m.receiver, m.stamp, m.sub)) != n:
                self.stats["messages_superseded"] += 1
                continue
            del latest[k]
            rounds[k] += 1
            if rounds[k] > SETTLE_ROUNDS:
                raise RuntimeError(
                    f"run: the exchange of {m.sender} -> {m.receiver} at stamp {m.stamp!r} ({type(m).__name__}, "
                    f"sub-key {m.sub!r}) does not settle: delivered {SETTLE_ROUNDS} times for one input"
                )
            self.stats["messages"] += 1
            node = self.owner.get(m.receiver)
            if node is None:
                if isinstance(m, BeliefQuery | RdlStateQuery):
                    push([not_found(m, f"robot {m.receiver} is not in the team")])
                else:
                    self.stats["messages_undeliverable"] += 1
                continue
            if not isinstance(m, BeliefQuery | RdlStateQuery) and finite_number(m.stamp):
                self.rec.resolve(node, _final(node.present, m.stamp, node.tolerance, node.horizon))
            push(node.step(m))

    def feed(self, events: list[Event], record_truth: bool, progress: Progress | None) -> None:
        """Hand every event to the node owning its robot; consecutive detections of one observer at one instant go
        together. Odometry, the bulk of a log, goes straight to the node's fast path when it takes it."""
        total, i = len(events), 0
        while i < total:
            e = events[i]
            if progress is not None and i % 4096 == 0:
                progress(i, total)
            i += 1
            if type(e) is Odometry:
                self._odometry(e)
            elif isinstance(e, Detection):
                group = [e]
                while i < total and isinstance(d := events[i], Detection) and d.observer == e.observer and d.t == e.t:
                    group.append(d)
                    i += 1
                self._detections(group)
            elif isinstance(e, Truth):
                node = self.owner.get(e.robot)
                if node is None:
                    self.stats["truth_unknown_robot"] += 1
                elif record_truth:
                    self.rec.add(node, float(e.t), e.robot, np.asarray(e.pose, dtype=float))
            else:
                self.stats["unknown_event"] += 1

    def _odometry(self, e: Odometry) -> None:
        node = self.owner.get(e.robot)
        if node is None:
            self.stats["unknown_robot"] += 1
            self.stats["odometry"] += 1
            return
        t0 = e.t0
        if type(t0) is float:
            h = self.rec.heap.get(id(node))  # resolve(), inlined: this runs once per odometry record
            if h:
                clock = node._clock
                upto = _final(clock.present, t0, clock.tolerance, clock.horizon)
                if h[0][0] <= upto:
                    self.rec.resolve(node, upto)
            if node._intake.odometry_fast(e):
                return
        self.deliver(node, e, t0)

    def _detections(self, group: list[Detection]) -> None:
        e = group[0]
        node = self.owner.get(e.observer)
        if node is None:
            self.stats["unknown_robot"] += len(group)
            self.stats["detections"] += len(group)
            self.stats["unknown"] += len(group)
            self.reasons[f"unknown: observer {brief(e.observer)} is not in the team"] += len(group)
            return
        self.deliver(node, group, e.t)

    def finish(self) -> None:
        for n in self.team:
            self.pump(n.expire())
        for n in self.team:
            self.rec.resolve(n, math.inf)

    def result(self, name: str, wall: float, n_events: int) -> RunResult:
        merged: Counter[str] = Counter()
        reasons: Counter[str] = Counter()
        timing = {"predict_s": 0.0, "predict_n": 0, "fuse_s": 0.0, "fuse_n": 0}
        for n in self.team:
            merged.update(n.stats())
            reasons.update(n.reasons)
            for k in timing:
                timing[k] += n.timing[k]
        merged.update(self.stats)
        reasons.update(self.reasons)
        merged["recorded"] = sum(len(v) for v in self.rec.rows.values())
        if self.rec.too_old:
            merged["record_too_old"] = self.rec.too_old
        for k in RUN_COUNTERS:
            merged.setdefault(k, 0)
        return RunResult(name, self.rec.tracks(), wall, dict(merged), n_events, reasons, timing)


def _final(present: float, stamp: float, tolerance: float, horizon: float) -> float:
    """[s] The time up to which a node's beliefs are final once an input stamped ``stamp`` is taken: a horizon
    before the later of its present and ``stamp``, ``stamp`` counted at most ``tolerance`` past the present (the
    node refuses a later one, so it moves nothing)."""
    if stamp > present:  # (not a NaN)
        ahead = present + tolerance
        return (stamp if stamp < ahead else ahead) - horizon
    return present - horizon


def _xytheta(g: np.ndarray) -> np.ndarray:
    """:meth:`SE2.to_xytheta` of one pose, in floats (the same numbers, a quarter of the time); an SE(3) pose
    ``(4, 4)`` as ``(x, y, z, qx, qy, qz, qw)`` (:func:`swarmloc.datasets.tum.pose7`)."""
    if g.shape == (4, 4):
        return pose7(g)
    if g.shape != (3, 3):
        return SE2.to_xytheta(g)
    th = float(np.arctan2(g[1, 0], g[0, 0]))  # numpy's arctan2, not math.atan2: they may differ in the last bit
    return np.array([g[0, 2], g[1, 2], th + 2 * np.pi if th <= -np.pi else th])


def truth_table(truth: TruthFn | None, robot: int, times: np.ndarray) -> np.ndarray:
    """Truth at every record time, one vectorized call (falls back to one call per time: NaN where missing)."""
    if truth is None:
        return np.full((times.size, 3), np.nan)
    try:
        return np.asarray(truth(robot, times), dtype=float).reshape(times.size, -1)
    except ValueError:
        rows: list[np.ndarray | None] = []
        for k in range(times.size):
            try:
                rows.append(np.asarray(truth(robot, times[k : k + 1]), dtype=float).reshape(-1))
            except ValueError:
                rows.append(None)
        w = next((row.size for row in rows if row is not None), 3)  # 3 (x, y, theta) or 7 (SE(3), pose7)
        out = np.full((times.size, w), np.nan)
        for k, row in enumerate(rows):
            if row is not None and row.size == w:
                out[k] = row
        return out
