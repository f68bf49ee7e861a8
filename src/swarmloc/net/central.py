"""A centralized estimator (``cekf``, ``iekf``, ``fej``) hosted by the belief server, fed by raw measurements.

Each robot process runs a :class:`Forwarder`: it sends its own odometry and detections, in key order, as numbered
:class:`~swarmloc.net.schema.Raw` forwards on ``robot/<id>/raw`` (signed with its own key: the server refuses a
forward that is not signed by the robot whose key it is on, and counts the refusal with its reason), then repeats
where its stream ends until the server has reported. The server runs a :class:`Fusion` (no I/O): the centralized
node, each robot's stream put back in forward order, and the records.

**Order.** A forward says where its robot's stream then stands: every measurement the robot will forward later is
keyed at or after ``(upto, prio)``. The server fuses a measurement keyed ``k = (t, prio, robot)`` once every other
robot's stream stands past ``k`` (the lowest key among the robots' next measurements and stream positions goes
first): the node's history then receives its inputs in key order, whatever order the forwards of different robots
arrived in, and the run equals the in-process run on the same events (tested to 1e-6; measured: equal, difference 0).

**Loss.** A forward missing from a robot's numbers is asked of its robot again (:class:`~swarmloc.net.schema.RawAck`
on ``server/ack``, after ``repair_wait`` s and again every ``repair_wait`` s: the robot keeps its last :data:`KEEP`
forwards and sends those asked for again); missing ``gap_timeout`` s of wall time, it is counted lost: the later
forward's cumulative counts say exactly how many odometry records and detections it carried (``raw_lost_odometry``,
``raw_lost_detections``; the detections also end ``unknown`` with the reason, so the report still accounts for every
detection). A robot silent for ``lost_timeout`` s while the merge waits on it is declared lost (``robots_lost``):
the others go on without it.

**Records.** The belief of every robot at every record time is taken once final (the node's present a horizon past
it, or the end), as :func:`swarmloc.runner.run` takes it, and returned as a final
:class:`~swarmloc.net.schema.Belief` for the server to store and publish.
"""

from __future__ import annotations

import heapq
import logging
import math
import queue
import threading
import time
from collections import Counter, deque
from collections.abc import Iterable, Sequence
from functools import partial
from typing import Any

import numpy as np

from swarmloc.events import Detection, Event, Kind, Odometry, OwnEvent
from swarmloc.messages import flat
from swarmloc.net.auth import open_envelope
from swarmloc.net.faults import Faults, FaultySender
from swarmloc.net.numbered import Numbered
from swarmloc.net.outbound import Envelopes
from swarmloc.net.schema import (
    MAX_RAW_ITEMS,
    MAX_REPAIR,
    SERVER,
    Belief,
    Progress,
    Raw,
    RawAck,
    RawDetection,
    RawOdometry,
    Rejected,
    Report,
    group_tag,
)
from swarmloc.net.teamlink import Presence, TeamLink
from swarmloc.net.transport import alive_key, block, robot_key, server_key
from swarmloc.node import Node

__all__ = ["Forwarder", "Fusion", "from_wire", "to_wire"]

log = logging.getLogger(__name__)

SPAN = 0.2
"""[s] of data a paced robot's forward spans at most (its measurements reach the server that much late at most)."""
KEEP = 4096
"""Forwards a robot keeps to send again when the server asks (older ones are lost if lost). The server takes a
forward numbered at most this far past the first one it misses from that robot (one further ahead is refused and
counted ``raw_too_far_ahead``: it could never be waited for)."""
AHEAD_ITEMS = 65536
"""Measurements the server holds at most per robot in forwards ahead of a gap (a forward past it is refused and
counted ``raw_ahead_full``; the robot sends it again when the server asks for it)."""
LOST_REASON = "unknown: lost on the network before the server (a raw measurement forward lost)"
Key = tuple[float, int, int]


# ------------------------------------------------------------------------------------------------ wire form
def _key(e: Event) -> tuple[float, int]:
    return (float(e.t0), 2) if isinstance(e, Odometry) else (float(e.t), 1)


def to_wire(e: OwnEvent) -> RawOdometry | RawDetection:
    """A robot's own event as it is forwarded (a detection's scoring-only truth is never sent)."""
    if isinstance(e, Odometry):
        return RawOdometry(float(e.t0), float(e.t1), float(e.v), float(e.w))
    target = None if e.target is None else int(e.target)
    return RawDetection(float(e.t), Kind(e.kind), flat(e.z), flat(e.cov), target, bool(e.target_is_robot))


def from_wire(robot: int, it: RawOdometry | RawDetection) -> Event:
    """The event of ``robot`` a forwarded item stands for."""
    if isinstance(it, RawOdometry):
        return Odometry(robot, it.t0, it.t1, it.v, it.w)
    d = len(it.z)
    return Detection(robot, it.t, it.kind, np.array(it.z, dtype=float), np.array(it.cov, dtype=float).reshape(d, d),
                     it.target, it.target_is_robot)  # fmt: skip


# ------------------------------------------------------------------------------------------------ the server's side
class _Stream:
    """One robot's forwards as the server has them: those ahead of a gap, the measurements not fused yet, where the
    stream stands, its cumulative counts, and when it was last heard from."""

    def __init__(self) -> None:
        self.seq: Numbered[Raw] = Numbered()  # its forward numbers: those ahead of a gap (``got``), the missing ones
        self.held = 0  # measurements in the forwards ahead of a gap
        self.items: deque[tuple[tuple[float, int], Any]] = deque()  # (key, Odometry or a detection group)
        self.upto: tuple[float, int] = (-math.inf, 0)
        self.first = math.inf
        self.odometry = self.detections = 0
        self.heard = -math.inf
        self.lost = False

    @property
    def ended(self) -> bool:
        return self.upto[0] == math.inf or self.lost


class Fusion:
    """The centralized ``node`` of ``robots`` fed by their forwards (:meth:`offer`), fused in key order by
    :meth:`pump`, which returns the final beliefs at ``record_times`` [s]. Waits [s] of wall time: ``gap_timeout``
    for a missing forward, ``lost_timeout`` for a silent robot, ``start_timeout`` for every robot's first forward."""

    def __init__(
        self,
        node: Node,
        robots: Iterable[int],
        record_times: Sequence[float] | np.ndarray,
        gap_timeout: float = 5.0,
        lost_timeout: float = 10.0,
        start_timeout: float = 30.0,
        clock: Any = time.monotonic,
        repair_wait: float = 0.2,
    ) -> None:
        self.node = node
        self.robots = sorted(robots)
        if sorted(node.robots) != self.robots:
            raise ValueError(f"Fusion: the node owns robots {sorted(node.robots)}, the team is {self.robots}")
        self.streams = {r: _Stream() for r in self.robots}
        self.gap_timeout, self.lost_timeout = float(gap_timeout), float(lost_timeout)
        self.repair_wait = float(repair_wait)
        self.clock = clock
        self.t_begin = clock()
        self.start_timeout = float(start_timeout)
        self.records = [(float(t), r) for t in np.asarray(record_times, dtype=float).tolist() for r in self.robots]
        heapq.heapify(self.records)
        self.counts: Counter[str] = Counter()
        """``raw_received``, ``raw_duplicate``, ``raw_repeats`` (a stream's end repeated), ``raw_lost_forwards``,
        ``raw_lost_odometry``, ``raw_lost_detections``, ``raw_late`` (an item keyed before where the merge stood),
        ``robots_lost``, ``fused_inputs``, ``messages_undeliverable``, ``record_too_old``."""
        self.reasons: Counter[str] = Counter()
        self.done = False
        self._merged: tuple = (-math.inf,)

    # ---------------------------------------------------------------------------------------- input
    def offer(self, raw: Raw) -> None:
        """Take robot ``raw.robot``'s forward (authenticated by the caller); anything else is counted and dropped."""
        s = self.streams.get(raw.robot)
        if s is None:
            self.counts["raw_unknown_robot"] += 1
            return
        q = s.seq
        if raw.n >= q.low + KEEP or (raw.n > q.low and s.held + len(raw.items) > AHEAD_ITEMS):
            why = "raw_too_far_ahead" if raw.n >= q.low + KEEP else "raw_ahead_full"
            self.counts[why] += 1
            self.reasons[f"{why}: forward of robot {raw.robot} refused"] += 1
            return
        s.heard = self.clock()
        if s.lost:
            s.lost = False
            log.warning("server: robot %s is heard again", raw.robot)
        if q.has(raw.n):
            self.counts["raw_repeats" if not raw.items else "raw_duplicate"] += 1
            return
        self.counts["raw_received"] += 1
        if raw.n in q.asked:
            self.counts["raw_repaired"] += 1
        q.heard_of(raw.n, s.heard)
        s.held += len(raw.items)
        for x in q.mark(raw.n, raw):
            self._consume(raw.robot, s, x)
        self._advance(raw.robot, s)

    def _advance(self, robot: int, s: _Stream) -> None:
        """Past a gap missing for ``gap_timeout`` s, count it lost and consume the forwards after it in number
        order."""
        q = s.seq
        while q.got and self.clock() - q.missing_since[q.low] >= self.gap_timeout:
            n = min(q.got)
            raw = q.got[n]
            assert raw is not None  # every forward received carries itself
            odo = sum(isinstance(i, RawOdometry) for i in raw.items)
            most = (n - q.low) * MAX_RAW_ITEMS  # what the lost forwards can have carried (the counts are the robot's)
            lost_odo = min(raw.odometry - odo - s.odometry, most)
            lost_det = min(raw.detections - (len(raw.items) - odo) - s.detections, most)
            self.counts["raw_lost_forwards"] += n - q.low
            self.counts["raw_lost_odometry"] += max(lost_odo, 0)
            self.counts["raw_lost_detections"] += max(lost_det, 0)
            log.warning("server: robot %s's forwards %d..%d lost (%d detections, %d odometry records)", robot,
                        q.low, n - 1, lost_det, lost_odo)  # fmt: skip
            for x in [x for lost in range(q.low, n) for x in q.mark(lost)]:
                self._consume(robot, s, x)

    def _consume(self, robot: int, s: _Stream, raw: Raw) -> None:
        s.held -= len(raw.items)
        s.first = min(s.first, raw.first)
        for it in raw.items:
            e = from_wire(robot, it)
            k = _key(e)
            last = s.items[-1] if s.items else None
            if isinstance(e, Detection) and last is not None and isinstance(last[1], list) and last[0] == k:
                last[1].append(e)
            else:
                s.items.append((k, [e] if isinstance(e, Detection) else e))
        s.upto = max(s.upto, (raw.upto, raw.prio))
        s.odometry, s.detections = raw.odometry, raw.detections

    def hear(self, robot: int) -> None:
        """Robot ``robot`` is alive (its authenticated progress): not silent, though it has nothing to forward."""
        s = self.streams.get(robot)
        if s is not None:
            s.heard = self.clock()

    def wanted(self) -> list[RawAck]:
        """What to ask the robots for again: per robot with a gap seen ``repair_wait`` s ago (and not asked for in
        the last ``repair_wait`` s), its missing forward numbers (at most 256)."""
        now, out = self.clock(), []
        for r, s in self.streams.items():
            missing = s.seq.due(now, self.repair_wait, self.repair_wait, most=MAX_REPAIR)
            if missing:
                self.counts["raw_repairs_asked"] += 1
                out.append(RawAck(robot=r, next=s.seq.low, missing=tuple(missing)))
        return out

    # ---------------------------------------------------------------------------------------- fusing
    def _mark(self, r: int, s: _Stream) -> Key:
        """Where robot ``r`` holds the merge back: its next measurement's key, or where its stream stands."""
        if s.items:
            return (*s.items[0][0], r)
        return (math.inf, 0, r) if s.ended else (*s.upto, r)

    def _check_silent(self) -> None:
        now = self.clock()
        for r, s in self.streams.items():
            if s.ended:
                continue
            if s.seq.got:
                self._advance(r, s)
            quiet = now - max(s.heard, self.t_begin)
            if quiet > (self.lost_timeout if s.seq.low else max(self.lost_timeout, self.start_timeout)):
                s.lost = True
                self.counts["robots_lost"] += 1
                log.warning("server: robot %s lost (no forward for %.1f s); fusing without it", r, quiet)

    def pump(self) -> list[Belief]:
        """Fuse every measurement the streams allow, in key order; the final beliefs that became due."""
        if self.done:
            return []
        self._check_silent()
        if not self.node.started:
            if any(s.seq.low == 0 and not s.lost for s in self.streams.values()):
                return []
            firsts = [s.first for s in self.streams.values() if math.isfinite(s.first)]
            if not firsts:  # every robot lost before its first forward (or forwarding nothing): nothing to fuse
                self.done = all(s.ended for s in self.streams.values())
                return []
            self.node.start(min(firsts))
        out: list[Belief] = []
        while True:
            r, mark = min(((r, self._mark(r, s)) for r, s in self.streams.items()), key=lambda x: x[1])
            s = self.streams[r]
            if not s.items:  # the lowest mark is a stream's position: wait for it to move
                break
            k, item = s.items.popleft()
            if mark < self._merged:
                self.counts["raw_late"] += 1
            self._merged = max(self._merged, mark)
            self._fuse(item, k[0], out)
        if all(s.ended and not s.items for s in self.streams.values()):
            self.counts["messages_undeliverable"] += len(self.node.expire() or ())
            self._resolve(math.inf, out)
            self.done = True
        return out

    def _fuse(self, item: Any, stamp: float, out: list[Belief]) -> None:
        """As :func:`swarmloc.runner.run` delivers an input: the records it can no longer change first."""
        node = self.node
        self._resolve(max(node.present, stamp) - node.horizon, out)
        self.counts["fused_inputs"] += 1
        if type(item) is Odometry and type(item.t0) is float and node._intake.odometry_fast(item):
            return
        msgs = node.step(item)
        self.counts["messages_undeliverable"] += len(msgs or ())

    def _resolve(self, upto: float, out: list[Belief]) -> None:
        while self.records and self.records[0][0] <= upto:
            t, r = heapq.heappop(self.records)
            try:
                b = self.node.belief_at(t, r)
            except ValueError:
                self.counts["record_too_old"] += 1
                continue
            out.append(Belief(robot=r, stamp=t, final=True, mean=flat(b.mean), cov=flat(b.cov), group=group_tag(b)))

    def report(self, wall: float = 0.0, cpu: float = 0.0) -> Report:
        """The server's report (``robot`` -1): the node's counters, the lost detections among them as ``unknown``."""
        stats = Counter({k: int(v) for k, v in self.node.stats().items()})
        reasons = Counter({k: int(v) for k, v in self.node.reasons.items()})
        lost = self.counts["raw_lost_detections"]
        if lost:
            stats["detections"] += lost
            stats["unknown"] += lost
            reasons[LOST_REASON] += lost
        return Report(robot=SERVER, stats=dict(stats), reasons=dict(reasons),
                      net={k: int(v) for k, v in self.counts.items()}, net_reasons=dict(self.reasons), wall_s=wall,
                      cpu_s=cpu)  # fmt: skip


# ------------------------------------------------------------------------------------------------ the robot's side
def batches(events: Sequence[OwnEvent], size: int, span: float = math.inf) -> list[list[OwnEvent]]:
    """A robot's events in key order, cut into forwards of at most ``size`` items spanning at most ``span`` s of data,
    never inside one key (a detection group goes whole)."""
    evs = sorted(events, key=_key)
    out: list[list[OwnEvent]] = []
    cur: list[OwnEvent] = []
    for e in evs:
        full = len(cur) >= size or (cur and _key(e)[0] - _key(cur[0])[0] > span)
        if full and _key(cur[-1]) != _key(e):
            out.append(cur)
            cur = []
        cur.append(e)
    if cur:
        out.append(cur)
    return out


class Forwarder:
    """Robot ``robot``'s process of a team whose estimator the server hosts: forwards its ``events`` (its own) to
    the server over its team's ``link`` (:class:`~swarmloc.net.teamlink.TeamLink`), signed with the robot's key,
    subject to the injected ``faults``, at most ``batch`` measurements per forward; paced at ``speed`` x real time
    (0: at once; paced, a forward spans at most ``SPAN`` s of data, and its progress is announced every second while
    it waits, so that the server does not take it for silent), after waiting up to ``start_timeout`` s for the
    server; then repeats its stream's end until the server has reported (or is gone for ``lost_timeout`` s)."""

    def __init__(
        self,
        robot: int,
        events: Sequence[OwnEvent],
        link: TeamLink,
        *,
        faults: Faults | None = None,
        speed: float = 0.0,
        batch: int = 64,
        start_timeout: float = 30.0,
        lost_timeout: float = 10.0,
    ) -> None:
        link.signing_as(robot, "Forwarder")
        self.robot, self.session, self.team, self.auth = robot, link.session, link.team, link.auth
        self.scope, self.roster = link.scope, link.roster
        self.forwards = batches(events, batch, SPAN if speed > 0 else math.inf)
        self.first = min((_key(e)[0] for e in events), default=math.inf)
        self.speed, self.start_timeout, self.lost_timeout = float(speed), float(start_timeout), float(lost_timeout)
        self.counts: Counter[str] = Counter()
        plan = faults.plan(robot) if faults is not None and faults.link else None
        self.sends = FaultySender(plan, self.counts, robot)
        """The forwards sent with the link faults (lost, delayed, duplicated)."""
        self._seal = Envelopes(self.auth, self.team, robot).seal  # its envelopes: numbered in one sequence, sealed
        self._server_done = threading.Event()
        self._server_alive = threading.Event()
        self._stop = threading.Event()
        self._end: Raw | None = None  # the stream's end, repeated once everything is forwarded
        self._kept: dict[int, Raw] = {}  # the last KEEP forwards, to send again when the server asks
        self._asked: queue.SimpleQueue = queue.SimpleQueue()  # RawAck from the server, handled on the main thread

    def stop(self) -> None:
        self._stop.set()

    def _from_server(self, x: Any, key: str) -> Any:
        """The body of sample ``x`` on the server's ``key`` when the server sent it (None otherwise); a refused one
        is counted ``rejected`` and logged."""
        try:
            env = open_envelope(self.auth, str(x.key_expr), x.payload.to_bytes(), self.team, self.roster)
        except Rejected as exc:
            self.counts["rejected"] += 1
            log.warning("robot %s: refused a message on the server's %s key: %s", self.robot, key, exc.reason)
            return None
        return env.body if env.from_robot == SERVER else None

    def _on_report(self, x: Any) -> None:
        if isinstance(self._from_server(x, "report"), Report):
            self._server_done.set()

    def _on_ack(self, x: Any) -> None:
        body = self._from_server(x, "ack")
        if isinstance(body, RawAck) and body.robot == self.robot:
            self._asked.put(body)

    def _resend(self, key: str) -> None:
        """Send again the forwards the server asked for (those still kept; the others stay lost)."""
        while True:
            try:
                ack = self._asked.get_nowait()
            except queue.Empty:
                return
            for n in ack.missing:
                raw = self._kept.get(n)
                self.counts["resent" if raw is not None else "asked_not_kept"] += 1
                if raw is not None:
                    self._send(key, raw)

    def _keep(self, raw: Raw) -> Raw:
        self._kept[raw.n] = raw
        self._kept.pop(raw.n - KEEP, None)
        return raw

    def _on_alive(self, x: Any) -> None:
        import zenoh

        (self._server_alive.set if x.kind == zenoh.SampleKind.PUT else self._server_alive.clear)()

    def _send(self, key: str, body: Raw) -> None:
        """One forward, as the link faults say (lost, delayed, duplicated)."""
        self.sends.faulty(partial(self.session.put, key, self._seal(body, key), congestion_control=self._block))

    def _put(self, key: str, body: Any) -> None:
        """``body`` sealed and put on ``key``, never dropped (not subject to the link faults: progress, report)."""
        self.session.put(key, self._seal(body, key), congestion_control=self._block)

    def run(self, max_wall: float | None = None) -> Report:
        """Forward everything, then wait for the server's report; returns this robot's report."""
        self._block = block()
        t_wall0, t_cpu0 = time.perf_counter(), time.process_time()
        end = math.inf if max_wall is None else time.monotonic() + max_wall
        s, sc, r = self.session, self.scope, self.robot
        p = Presence(s, sc, self.auth)
        p.join()
        p.decl += [
            s.declare_subscriber(server_key(sc, "report"), handler=self._on_report),
            s.declare_subscriber(server_key(sc, "ack"), handler=self._on_ack),
            s.liveliness().declare_subscriber(alive_key(sc, "server"), history=True, handler=self._on_alive),
        ]
        p.announce(r)
        try:
            self._forward(end)
            self._linger(end)
        finally:
            net = {**self.counts, **(self.auth.session_counts() if self.auth is not None else {})}
            report = Report(robot=r, net={k: int(v) for k, v in net.items()},
                            wall_s=time.perf_counter() - t_wall0, cpu_s=time.process_time() - t_cpu0)  # fmt: skip
            p.leave(lambda: self._put(robot_key(sc, r, "report"), report), f"robot {r}")
        return report

    def _forward(self, end: float) -> None:
        wait_end = min(end, time.monotonic() + self.start_timeout)
        while not self._server_alive.wait(0.05) and time.monotonic() < wait_end and not self._stop.is_set():
            pass
        if not self._server_alive.is_set():
            log.warning("robot %s: the server is not alive after %.0f s; forwarding anyway", self.robot,
                        self.start_timeout)  # fmt: skip
        elif self.auth is not None:  # in session with the server before its acks and report come
            self.auth.sessions.ensure(SERVER)
        key, pkey = robot_key(self.scope, self.robot, "raw"), robot_key(self.scope, self.robot, "progress")
        w0, odo, det = time.monotonic(), 0, 0
        for n, evs in enumerate(self.forwards):
            if self._stop.is_set() or time.monotonic() > end:
                return
            if self.speed > 0:
                due, beat = w0 + (_key(evs[-1])[0] - self.first) / self.speed, time.monotonic()
                while time.monotonic() < due and not self._stop.is_set():
                    self.sends.run_timers()
                    self._resend(key)
                    if time.monotonic() - beat >= 1.0:  # alive, and where it stands
                        beat = time.monotonic()
                        k = _key(evs[0])
                        self._put(pkey, Progress(robot=self.robot, t=k[0], prio=k[1]))
                    time.sleep(min(0.02, max(0.0, due - time.monotonic())))
            nxt = _key(self.forwards[n + 1][0]) if n + 1 < len(self.forwards) else (math.inf, 1)
            d = sum(isinstance(e, Detection) for e in evs)
            odo, det = odo + len(evs) - d, det + d
            raw = Raw(robot=self.robot, n=n, first=self.first, upto=nxt[0], prio=nxt[1], odometry=odo, detections=det,
                      items=tuple(to_wire(e) for e in evs))  # fmt: skip
            self._send(key, self._keep(raw))
            self._resend(key)
            self._put(pkey, Progress(robot=self.robot, t=nxt[0], prio=nxt[1]))
            self.sends.run_timers()
        self.counts.update(forwards=len(self.forwards), forwarded_odometry=odo, forwarded_detections=det)
        self._end = self._keep(Raw(robot=self.robot, n=len(self.forwards), first=self.first, upto=math.inf,
                                   odometry=odo, detections=det))  # fmt: skip

    def _linger(self, end: float) -> None:
        """Repeat the stream's end every 0.25 s until the server has reported, or is gone ``lost_timeout`` s."""
        if self._end is None:
            return
        key, pkey = robot_key(self.scope, self.robot, "raw"), robot_key(self.scope, self.robot, "progress")
        gone_since, last = None, -math.inf
        while not self._server_done.is_set() and not self._stop.is_set() and time.monotonic() < end:
            now = time.monotonic()
            self.sends.run_timers()
            self._resend(key)
            if now - last >= 0.25:
                last = now
                self._send(key, self._end)
                self.counts["end_sent"] += 1
                self._put(pkey, Progress(robot=self.robot, t=math.inf))
            gone_since = None if self._server_alive.is_set() else (gone_since or now)
            if gone_since is not None and now - gone_since > self.lost_timeout:
                log.warning("robot %s: the server is gone; stopping without its report", self.robot)
                self.counts["server_gone"] += 1
                return
            self._server_done.wait(0.02)
