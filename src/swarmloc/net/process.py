"""One robot = one process: a :class:`~swarmloc.node.base.Node` driven over a Zenoh session.

:class:`NetNode` is the network driver of the sans-I/O node. It reads the robot's own events from its source,
steps the node, and carries the messages the node returns: a query to a neighbour is a Zenoh ``get`` on the
neighbour's ``query`` key (the reply is the answer), a revised answer or a pairwise update is a ``put`` on the
receiver's ``inbox``. Everything received is decoded and validated (:func:`swarmloc.net.schema.decode`) on the
node's one thread; a bad message is dropped, counted with its reason, and logged; the node keeps running.

**Time and determinism.** Stamps are the source's (data) clock; wall time only paces. Lockstep: a node reads its
next input (stamp ``s``) once every live teammate has announced (:class:`~swarmloc.net.schema.Progress`) that it
has read its own source up to ``s - lag`` (the node with the lowest next stamp can always go on, so this never
deadlocks), with ``speed > 0`` not before ``(s - t_start) / speed`` wall seconds, and not more than half a horizon
past its own oldest detection group still waiting for answers. A detection group is read only once every teammate
has read its source up to the group's key and no ``rdl`` update keyed before it is expected. A query is answered
only once nothing keyed before it can still change the answer (:meth:`NetNode._ready`). Groups are thus applied
across the team in key order, as :func:`swarmloc.runner.run` applies them, the first answer is the final one,
and the networked run equals the in-process run on the same events (tested to 1e-6; measured: equal).

**Missing answers.** A query that gets no valid reply within ``answer_timeout`` s is asked of the belief server
(with ``use_server``); without an answer there either, the node gets a "not found" answer (revision ``-2``) with
the reason, so the detection ends ``unknown`` instead of waiting forever; a real answer that arrives later
(revision >= 0; the server's: -1) replaces it and is replayed if it is within the horizon. A query held longer
than half the asker's timeout is answered as things stand, and revised if they change. With link faults,
pushed revisions and updates are coalesced (the newest per exchange, every ``coalesce`` s).

**Beliefs.** At each record time ``t`` the node publishes its belief once its history has passed ``t``
(provisional) and again once it is final (the history is a horizon past ``t``, or the run ended); a final belief
that a later message still changes is published again with a higher revision. With ``ros_domain`` each belief is
also published as a ROS 2 ``geometry_msgs/msg/PoseWithCovarianceStamped`` under rmw_zenoh's key layout.

**The end.** When its source is exhausted the node announces ``Progress(t=inf)``; once every live member has and
the node has been idle (no reply outstanding, nothing queued) for ``quiet`` s, it expires what still waits,
publishes its final beliefs, announces ``done`` and its :class:`~swarmloc.net.schema.Report`, and keeps answering
until every live member is done and ``quiet`` s passed without traffic (at most ``linger`` s).
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from swarmloc.events import Detection, Event, Odometry
from swarmloc.messages import BeliefAnswer, BeliefQuery, Message, RdlState, RdlStateQuery, RdlUpdate, flat
from swarmloc.net.faults import Faults
from swarmloc.net.schema import SERVER, Belief, Envelope, Progress, Rejected, Report, decode, encode
from swarmloc.net.transport import alive_key, robot_key, robot_of, server_key
from swarmloc.node import Node

log = logging.getLogger(__name__)
BLOCK: Any = None  # zenoh.CongestionControl.BLOCK, set when a session is opened (zenoh is imported lazily)

NOT_FOUND_SEQ = -2
SERVER_SEQ = -1


def _stamp(e: Event) -> float:
    return e.t0 if isinstance(e, Odometry) else e.t


def _groups(events: Sequence[Event]) -> list[tuple[float, Any]]:
    """``(stamp, item)`` in order; consecutive detections at one instant form one list."""
    out: list[tuple[float, Any]] = []
    for e in events:
        if isinstance(e, Detection) and out and isinstance(out[-1][1], list) and out[-1][1][0].t == e.t:
            out[-1][1].append(e)
        elif isinstance(e, Detection):
            out.append((float(e.t), [e]))
        elif isinstance(e, Odometry):
            out.append((float(e.t0), e))
    return out


class NetNode:
    """Drive ``node`` (owning one robot) over ``session`` with ``events`` (that robot's own, in stamp order).

    Parameters
    ----------
    team, roster: the team's name and robot ids (messages from anybody else are dropped).
    record_times: times [s] at which the robot's belief is published.
    speed: 0 = as fast as lockstep allows; X > 0: X times real time.
    lag: [s] lockstep slack (well below the node's horizon).
    answer_timeout: [s] wall time to wait for a neighbour's reply.
    use_server: ask the belief server when a neighbour does not answer.
    faults: link faults on the messages this node sends (:mod:`swarmloc.net.faults`).
    wait_for: robots to wait for (alive) before starting (default: the whole roster but this robot);
    wait_timeout: [s] how long.
    ros_domain: publish beliefs as ROS 2 messages too (rmw_zenoh layout, this domain id).
    """

    def __init__(
        self,
        node: Node,
        events: Sequence[Event],
        *,
        session: Any,
        team: str,
        roster: Iterable[int],
        record_times: Sequence[float] | np.ndarray = (),
        speed: float = 0.0,
        lag: float = 0.5,
        answer_timeout: float = 2.0,
        use_server: bool = False,
        faults: Faults | None = None,
        wait_for: Iterable[int] | None = None,
        wait_timeout: float = 30.0,
        quiet: float = 0.3,
        linger: float = 10.0,
        ros_domain: int | None = None,
        on_belief: Callable[[Belief], None] | None = None,
    ) -> None:
        if len(node.robots) != 1:
            raise ValueError("NetNode drives a node of one robot (a distributed estimator)")
        self.node = node
        self.robot = node.robots[0]
        self.items = _groups(events)
        self.session = session
        self.team = team
        self.roster = frozenset(int(r) for r in roster)
        if self.robot not in self.roster:
            raise ValueError(f"robot {self.robot} is not in the roster {sorted(self.roster)}")
        self.record_times = np.asarray(record_times, dtype=float)
        self.speed = float(speed)
        self.lag = float(lag)
        self.answer_timeout = float(answer_timeout)
        self.use_server = use_server
        self.faults = faults if faults is not None and faults.link else None
        self.link = self.faults.plan(self.robot) if self.faults else None
        self.wait_for = set(self.roster - {self.robot}) if wait_for is None else set(wait_for) - {self.robot}
        self.wait_timeout = float(wait_timeout)
        self.quiet = float(quiet)
        self.linger = float(linger)
        self.ros_domain = ros_domain
        self.on_belief = on_belief
        self.counts: Counter[str] = Counter()
        """Network counters: ``received``, ``rejected`` (with ``reasons``), ``sent``, ``lost``/``duplicated``/
        ``delayed`` (injected), ``no_reply``, ``server_answers``, ``beliefs_published``..."""
        self.reasons: Counter[str] = Counter()
        self._inq: queue.SimpleQueue = queue.SimpleQueue()
        self._seq = itertools.count()
        self._progress: dict[int, float] = {}
        self._progress_key: dict[int, tuple[float, int]] = {}
        self._done: set[int] = set()
        self._alive: set[int] = set()
        self._outstanding: dict[int, tuple[Message, str, bool]] = {}
        self._qids = itertools.count()
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._published: dict[float, Belief] = {}
        self._prov = 0
        self._final = 0
        self._pruned_at = 0
        self._last_progress = -math.inf
        self._last_progress_wall = 0.0
        self._last_key: tuple[float, int] = (-math.inf, 0)
        self._stop = threading.Event()
        self._decl: list[Any] = []
        self._ros_pub = None
        self._i = 0
        self._deferred: list[tuple[float, Message, Any]] = []
        self._expect: dict[tuple, float] = {}
        self._held: list[Message] = []
        self._outbox: dict[tuple, Message] = {}
        self._last_flush = 0.0
        self.coalesce = 0.05
        self._last_status = 0.0

    # ------------------------------------------------------------------------------------------- wiring
    def _open(self) -> None:
        import zenoh

        global BLOCK
        BLOCK = zenoh.CongestionControl.BLOCK

        s, team, r = self.session, self.team, self.robot
        put = self._inq.put
        self._decl.append(s.declare_queryable(robot_key(team, r, "query"), handler=lambda q: put(("query", q))))
        self._decl.append(s.declare_subscriber(robot_key(team, r, "inbox"), handler=lambda x: put(("inbox", x))))
        self._decl.append(
            s.declare_subscriber(robot_key(team, "*", "progress"), handler=lambda x: put(("progress", x)))
        )
        self._decl.append(
            s.liveliness().declare_subscriber(alive_key(team), history=True, handler=lambda x: put(("alive", x)))
        )
        block = zenoh.CongestionControl.BLOCK  # never drop a belief or a progress announcement under load
        self._pub_belief = s.declare_publisher(robot_key(team, r, "belief"), congestion_control=block)
        self._pub_progress = s.declare_publisher(robot_key(team, r, "progress"), congestion_control=block)
        if self.ros_domain is not None:
            import hashlib

            from swarmloc.net import ros

            self.ros_topic = f"/swarmloc/{team.replace('-', '_')}/robot{r}/pose"
            key = ros.ros_key(self.ros_topic, self.ros_domain)
            self._ros_pub = s.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
            self._ros_gid = hashlib.blake2b(key.encode(), digest_size=16).digest()
            self._ros_seq = 0
        self._token = s.liveliness().declare_token(alive_key(team, r))

    def _close(self) -> None:
        for d in [*self._decl, getattr(self, "_token", None)]:
            if d is not None:
                try:
                    d.undeclare()
                except Exception:  # noqa: BLE001 - closing: nothing left to do about it
                    pass
        self._decl.clear()

    def stop(self) -> None:
        """Ask :meth:`run` to finish (from another thread or a signal handler)."""
        self._stop.set()
        self._inq.put(("wake", None))

    # ------------------------------------------------------------------------------------------- sending
    def _env(self, body: Any) -> bytes:
        return encode(self.team, self.robot, next(self._seq), body)

    def _faulty(self, send: Callable[[], None]) -> int:
        """Send now, or as the link faults say (lost, delayed, duplicated); returns the copies sent."""
        if self.link is None:
            self.counts["sent"] += 1
            send()
            return 1
        delays = self.link.schedule()
        if not delays:
            self.counts["lost"] += 1
            return 0
        if len(delays) > 1:
            self.counts["duplicated"] += 1
        for d in delays:
            self.counts["sent"] += 1
            if d <= 0:
                send()
            else:
                self.counts["delayed"] += 1
                heapq.heappush(self._timers, (time.monotonic() + d, next(self._qids), send))
        return len(delays)

    def _route(self, msgs: list[Message], query: Any = None, asked: Message | None = None) -> None:
        for m in msgs:
            if isinstance(m, BeliefQuery | RdlStateQuery):
                self._ask(m)
            elif (
                query is not None
                and isinstance(m, BeliefAnswer | RdlState)
                and isinstance(asked, BeliefQuery | RdlStateQuery)
                and (m.receiver, m.stamp, m.sub) == (asked.sender, asked.stamp, asked.sub)
            ):
                payload, q = self._env(m), query
                query = None
                if isinstance(m, RdlState) and m.found:  # the observer's update (or "no update") follows
                    self._expect[(float(m.stamp), 1, m.receiver, tuple(m.sub))] = time.monotonic()
                self._faulty(lambda q=q, payload=payload: _reply(q, payload))
            elif m.receiver in self.roster:
                # pushed revisions and updates are coalesced: the newest per exchange goes out with the next flush
                k = (type(m).__name__, m.receiver, m.stamp, m.sub)
                if k in self._outbox:
                    self.counts["coalesced"] += 1
                self._outbox[k] = m
            else:
                self.counts["undeliverable"] += 1
        if query is not None:  # the query was not answered by the node (cannot happen for a well-formed query)
            _reply_err(query, "no answer")

    def _flush(self, force: bool = False) -> None:
        """Send the pushed messages waiting in the outbox: at once without faults (a revision or update is final
        then), at most every ``coalesce`` s otherwise, so that a burst of revisions of one exchange (late and lost
        messages make them) costs the neighbour one replay instead of one per revision."""
        if not self._outbox:
            return
        now = time.monotonic()
        if not force and self.link is not None and now - self._last_flush < self.coalesce:
            return
        self._last_flush = now
        out, self._outbox = self._outbox, {}
        for m in out.values():
            payload, key = self._env(m), robot_key(self.team, m.receiver, "inbox")
            self._faulty(lambda key=key, payload=payload: self.session.put(key, payload, congestion_control=BLOCK))

    def _ask(self, m: Message, via_server: bool = False) -> None:
        kind = BeliefAnswer if isinstance(m, BeliefQuery) else RdlState
        if m.receiver not in self.roster:
            self._feed_local(kind, m, f"robot {m.receiver} is not in the team")
            return
        qid = next(self._qids)
        self._outstanding[qid] = (m, "server" if via_server else "robot", False)
        key = server_key(self.team) if via_server else robot_key(self.team, m.receiver, "query")
        payload = self._env(m)
        timeout = self.answer_timeout + (2 * self.faults.delay if self.faults else 0.0)
        put = self._inq.put

        def send() -> None:
            import zenoh

            try:
                self.session.get(
                    key,
                    payload=payload,
                    timeout=timeout,
                    handler=zenoh.handlers.Callback(
                        lambda reply: put(("reply", qid, reply)), lambda: put(("reply_end", qid, None))
                    ),
                )
            except Exception as exc:  # noqa: BLE001 - a failed get is a missing answer, not a crash
                log.warning("robot %s: get %s failed: %s", self.robot, key, exc)
                put(("reply_end", qid, None))

        if via_server:
            self.counts["sent"] += 1
            send()
        elif not self._faulty(send):
            # a lost query: its get never goes out, so nothing will end it but a timer
            heapq.heappush(
                self._timers,
                (time.monotonic() + timeout, next(self._qids), lambda qid=qid: put(("reply_end", qid, None))),
            )

    def _feed_local(self, kind: type, m: Message, reason: str, seq: int = NOT_FOUND_SEQ) -> None:
        a = kind(sender=m.receiver, receiver=m.sender, stamp=m.stamp, sub=m.sub, found=False, reason=reason, seq=seq)
        self._step(a)

    # ------------------------------------------------------------------------------------------- receiving
    def _step(self, item: Any, query: Any = None) -> None:
        out = self.node.step(item)
        if out or query is not None:
            self._route(out, query, item)
        self._flush()

    def _reject(self, reason: str, where: str) -> None:
        self.counts["rejected"] += 1
        self.reasons[reason] += 1
        if self.reasons[reason] == 1 and len(self.reasons) <= 20:  # the first of each of the first 20 reasons
            log.warning("robot %s: dropped a %s: %s", self.robot, where, reason)
        else:
            log.debug("robot %s: dropped a %s: %s", self.robot, where, reason)

    def _decode(self, payload: bytes | None, where: str) -> Envelope | None:
        if payload is None:
            self._reject("empty payload", where)
            return None
        try:
            env = decode(payload, self.team, self.roster, to_robot=self.robot)
        except Rejected as exc:
            self._reject(exc.reason, where)
            return None
        b = env.body
        if env.from_robot != SERVER and getattr(b, "seq", 0) < 0:
            self._reject("negative revision from a robot", where)
            return None
        return env

    def _handle(self, kind: str, x: Any, y: Any = None) -> None:
        if kind == "query":
            self.counts["received"] += 1
            raw = x.payload.to_bytes() if x.payload is not None else None
            env = self._decode(raw, "query")
            if env is None or not isinstance(env.body, BeliefQuery | RdlStateQuery):
                if env is not None:
                    self._reject(f"{type(env.body).__name__} sent as a query", "query")
                _reply_err(x, "rejected")
                return
            self._deferred.append((time.monotonic(), env.body, x))
            self._answer_ready()
        elif kind == "inbox":
            self.counts["received"] += 1
            env = self._decode(x.payload.to_bytes(), "pushed message")
            if env is None:
                return
            if isinstance(env.body, BeliefQuery | RdlStateQuery | Belief | Progress | Report):
                self._reject(f"{type(env.body).__name__} is not accepted on the inbox", "pushed message")
                return
            if isinstance(env.body, RdlUpdate):
                self._expect.pop((float(env.body.stamp), 1, env.body.sender, tuple(env.body.sub)), None)
                self._step(env.body)
                self._release()
                return
            self._step(env.body)
        elif kind == "reply":
            self._on_reply(x, y)
        elif kind == "reply_end":
            self._on_reply_end(x)
        elif kind == "progress":
            try:
                env = decode(x.payload.to_bytes(), self.team, self.roster, server_ok=False)
            except Rejected as exc:
                self._reject(exc.reason, "progress message")
                return
            p = env.body
            if isinstance(p, Progress) and p.robot != self.robot:
                self._progress[p.robot] = max(self._progress.get(p.robot, -math.inf), p.t)
                self._progress_key[p.robot] = max(self._progress_key.get(p.robot, (-math.inf, 0)), (p.t, p.prio))
                if p.done:
                    self._done.add(p.robot)
        elif kind == "alive":
            import zenoh

            r = robot_of(str(x.key_expr))
            if r is None or r == self.robot:
                return
            if r not in self.roster:
                self.counts["alive_outside_roster"] += 1
                return
            if x.kind == zenoh.SampleKind.PUT:
                self._alive.add(r)
                self._done.discard(r)
            else:
                self._alive.discard(r)
                self._progress.pop(r, None)
                self._progress_key.pop(r, None)
                self.counts["peers_left"] += 1

    def _ready(self, q: Message, since: float) -> bool:
        """A query is answered once nothing this node will still read or apply is keyed before it: its source has
        passed the query's key, no earlier detection group waits, no pairwise update it expects is keyed earlier,
        and every live teammate has read its source past the stamp (so no earlier exchange can still start). Then
        the first answer is the final one and no revision follows (without faults). After half the asker's timeout
        it is answered whatever the state (a revision follows if needed)."""
        qkey = (float(q.stamp), 1, q.sender, tuple(q.sub))
        why = self._unsettled(qkey)
        if why is None:
            return True
        if time.monotonic() - since < self.answer_timeout / 2:
            return False
        self.counts["answered_unsettled"] += 1
        log.debug("robot %s: answering %s at %s unsettled: %s", self.robot, type(q).__name__, qkey, why)
        return True

    def _unsettled(self, qkey: tuple) -> str | None:
        """What may still change the state before ``qkey``, or None."""
        if self._i < len(self.items):
            s, item = self.items[self._i]
            nxt = (s, 2, self.robot, ()) if isinstance(item, Odometry) else (s, 1, self.robot, ())
            if nxt < qkey:
                return f"own source at {nxt}"
        early = [k for k in self._expect if k < qkey]
        if early:
            return f"expects updates at {early[:3]}"
        for r in self._alive:  # a teammate whose next input is keyed before the query may still start an exchange
            if r not in self._done:
                t, prio = self._progress_key.get(r, (-math.inf, 0))
                if (t, prio, r) < qkey[:3]:
                    return f"robot {r} has read its source only to {(t, prio)}"
        first = self.node.first_pending
        if first is not None and first < qkey:
            return f"own detection group {first} waits for answers"
        return None

    def _answer_ready(self) -> None:
        if not self._deferred:
            return
        keep = []
        for since, q, zq in self._deferred:
            if self._ready(q, since):
                self._step(q, query=zq)
            else:
                keep.append((since, q, zq))
        self.counts["queries_answered"] += len(self._deferred) - len(keep)
        self._deferred = keep

    def _on_reply(self, qid: int, reply: Any) -> None:
        self.counts["received"] += 1
        entry = self._outstanding.get(qid)
        if entry is None:
            return
        m, via, _ = entry
        ok = reply.ok
        if ok is None:
            self._reject(f"error reply: {reply.err.payload.to_bytes()[:80]!r}", "reply")
            return
        env = self._decode(ok.payload.to_bytes(), "reply")
        if env is None:
            return
        a = env.body
        if not isinstance(a, BeliefAnswer | RdlState) or (a.sender, a.receiver, a.stamp, a.sub) != (
            m.receiver,
            m.sender,
            m.stamp,
            m.sub,
        ):
            self._reject("reply does not answer the query", "reply")
            return
        if via == "server":
            self.counts["server_answers"] += 1
        self._outstanding[qid] = (m, via, True)
        self._held.append(a)
        self._release()

    def _release(self) -> None:
        """Give the node the answers to its own detection groups once no pairwise update keyed before the group is
        still expected (so the group is applied after it, not replayed under it); an expected update that does not
        come within the answer timeout is given up (counted ``update_not_received``)."""
        if self._expect:
            now = time.monotonic()
            for k, since in list(self._expect.items()):
                if now - since > self.answer_timeout:
                    del self._expect[k]
                    self.counts["update_not_received"] += 1
        if not self._held:
            return
        keep = []
        for a in self._held:
            key = (float(a.stamp), 1, self.robot, ())
            if any(k < key for k in self._expect):
                keep.append(a)
            else:
                self._step(a)
        self._held = keep

    def _on_reply_end(self, qid: int) -> None:
        entry = self._outstanding.pop(qid, None)
        if entry is None:
            return
        m, via, answered = entry
        if answered:
            return
        self.counts["no_reply"] += 1
        if via == "robot" and self.use_server:
            self._ask(m, via_server=True)
            return
        kind = BeliefAnswer if isinstance(m, BeliefQuery) else RdlState
        who = "robot or server" if via == "server" else "robot"
        self._feed_local(kind, m, f"no answer from the {who} within {self.answer_timeout:g} s")

    def _drain(self, timeout: float) -> bool:
        """Handle everything queued; wait up to ``timeout`` s for the first item. True if neighbours' traffic (queries,
        replies, pushed messages) came: progress and liveliness do not count."""
        got = False
        try:
            item = self._inq.get(timeout=timeout) if timeout > 0 else self._inq.get_nowait()
        except queue.Empty:
            item = None
        while item is not None and not self._stop.is_set():
            got = got or item[0] in ("query", "inbox", "reply", "reply_end")
            if item[0] != "wake":
                try:
                    self._handle(*item)
                    self._answer_ready()
                except Exception as exc:  # a node must never die of one message
                    log.exception("robot %s: error handling %s", self.robot, item[0])
                    self._reject(f"internal error: {type(exc).__name__}: {exc}", item[0])
            try:
                item = self._inq.get_nowait()
            except queue.Empty:
                item = None
        return got

    def _run_timers(self) -> float:
        """Send what is due; seconds until the next timer (inf if none)."""
        now = time.monotonic()
        while self._timers and self._timers[0][0] <= now:
            _, _, fn = heapq.heappop(self._timers)
            try:
                fn()
            except Exception as exc:  # noqa: BLE001 - e.g. the duplicate of a reply whose query is already closed
                self.counts["send_failed"] += 1
                log.debug("robot %s: delayed send failed: %s", self.robot, exc)
        return self._timers[0][0] - now if self._timers else math.inf

    # ------------------------------------------------------------------------------------------- beliefs
    def _next_key(self) -> tuple[float, int]:
        if self._i >= len(self.items):
            return (math.inf, 3)
        s, item = self.items[self._i]
        return (s, 2 if isinstance(item, Odometry) else 1)

    def _publish_progress(self, t: float, done: bool = False, force: bool = False) -> None:
        """Announce the next input's key (rate-limited to every ``lag / 4`` s of data or 0.2 s of wall time unless
        ``force``: a node about to wait forces it, since teammates may be waiting for it)."""
        now = time.monotonic()
        key = self._next_key()
        if not force and t - self._last_progress < self.lag / 4 and now - self._last_progress_wall < 0.2:
            return
        if force and key == self._last_key and not done and now - self._last_progress_wall < 0.2:
            return
        self._last_progress = t
        self._last_key = key
        self._last_progress_wall = now
        self._pub_progress.put(self._env(Progress(robot=self.robot, t=key[0], prio=key[1], done=done)))

    def _publish_belief(self, t: float, final: bool) -> None:
        try:
            b = self.node.belief_at(float(t))
        except ValueError:
            self.counts["record_too_old"] += 1
            return
        old = self._published.get(t)
        mean, cov = flat(b.mean), flat(b.cov)
        if old is not None and old.mean == mean and old.cov == cov and (old.final or not final):
            return  # nothing new: same numbers, and not a provisional belief becoming final
        rev = 0 if old is None else old.rev + 1
        msg = Belief(robot=self.robot, stamp=float(t), rev=rev, final=final, mean=mean, cov=cov)
        self._published[t] = msg
        self._pub_belief.put(self._env(msg))
        self.counts["beliefs_published"] += 1
        if self.on_belief is not None:
            self.on_belief(msg)
        if self._ros_pub is not None:
            from swarmloc.net import ros

            self._ros_seq += 1  # rmw_zenoh drops samples without its attachment (sequence, source time, gid)
            att = ros.ros_attachment(self._ros_seq, time.time_ns(), self._ros_gid)
            self._ros_pub.put(ros.to_cdr(ros.pose_message(t, b.mean, b.cov)), attachment=att)

    def _publish_due(self, end: bool = False, upto: float = -math.inf) -> None:
        """Publish the beliefs due: provisional ones up to the watermark, final ones a horizon before it (or before
        ``upto``: called before an input stamped ``upto`` is applied, whose pruning could drop them otherwise)."""
        rt = self.record_times
        wm = max(self.node.present, upto)
        while self._prov < rt.size and (end or rt[self._prov] <= wm):
            self._publish_belief(rt[self._prov], final=False)
            self._prov += 1
        while self._final < rt.size and (end or rt[self._final] < wm - self.node.horizon):
            self._publish_belief(rt[self._final], final=True)
            self._final += 1
        if self._final - self._pruned_at >= 256:  # forget beliefs no input can change any more (two horizons back)
            self._pruned_at = self._final
            cut = wm - 2 * self.node.horizon
            for t in [t for t in self._published if t < cut]:
                del self._published[t]

    def _republish_changed(self) -> None:
        """After the end: publish again every final belief a late message changed."""
        for t in sorted(self._published):
            old = self._published[t]
            try:
                b = self.node.belief_at(t)
            except ValueError:
                continue
            if flat(b.mean) != old.mean or flat(b.cov) != old.cov:
                self.counts["finals_revised"] += 1
                self._publish_belief(t, final=True)

    # ------------------------------------------------------------------------------------------- loop
    def _may_feed(self, s: float) -> bool:
        """Lockstep: every live teammate has read its source to ``s - lag``; and this node's oldest detection group
        still waiting for answers is less than half a horizon before ``s`` (reading on would push it beyond the
        horizon before its answers or their timeout come)."""
        first = self.node.first_pending
        if first is not None and s - first[0] > self.node.horizon / 2:
            return False
        need = s - self.lag
        for r in self._alive:
            if r not in self._done and self._progress.get(r, -math.inf) < need:
                return False
        return True

    def _group_may_go(self, s: float) -> bool:
        """A detection group (key ``(s, 1, robot)``) is read once every live teammate has read its source up to
        ``s`` (their exchanges keyed before it have started) and no pairwise update keyed before it is still
        expected, so that groups are applied across the team in key order, as the in-process runner does, and an
        update never has to be replayed under a group applied before it."""
        key = (s, 1, self.robot, ())
        if any(k < key for k in self._expect):
            return False
        return all(r in self._done or (*self._progress_key.get(r, (-math.inf, 0)), r) > key[:3] for r in self._alive)

    def run(self, max_wall: float | None = None) -> Report:
        """Run until the source is exhausted and the team settled (or :meth:`stop`, or ``max_wall`` s)."""
        t_wall0, t_cpu0 = time.perf_counter(), time.process_time()
        deadline = math.inf if max_wall is None else time.monotonic() + max_wall
        self._open()
        try:
            self._publish_progress(self.items[0][0] if self.items else math.inf, force=True)
            t_wait = time.monotonic() + self.wait_timeout
            while not self.wait_for <= self._alive and time.monotonic() < t_wait and not self._stop.is_set():
                self._drain(0.05)
                self._publish_progress(self._last_progress, force=True)
            missing = self.wait_for - self._alive
            if missing:
                log.warning("robot %s: starting without robots %s (not alive after %.0f s)", self.robot,
                            sorted(missing), self.wait_timeout)  # fmt: skip
            self._main(deadline)
            if not self._stop.is_set():
                self._finish(deadline)
        finally:
            report = self.report(time.perf_counter() - t_wall0, time.process_time() - t_cpu0)
            try:
                self._pub_progress.put(self._env(Progress(robot=self.robot, t=math.inf, done=True)))
                self.session.put(
                    robot_key(self.team, self.robot, "report"), self._env(report), congestion_control=BLOCK
                )
                time.sleep(0.2)  # let Zenoh flush the report before the session closes
            except Exception as exc:  # noqa: BLE001 - the session may be gone (Ctrl-C)
                log.debug("robot %s: final report not sent: %s", self.robot, exc)
            self._close()
        return report

    def _main(self, deadline: float) -> None:
        items, n, i = self.items, len(self.items), 0
        t_start = items[0][0] if items else 0.0
        w0 = time.monotonic()
        while i < n and not self._stop.is_set():
            if time.monotonic() > deadline:
                log.warning("robot %s: wall-time limit reached at %d/%d inputs", self.robot, i, n)
                self._stop.set()
                break
            self._drain(0)
            self._answer_ready()
            self._release()
            self._flush()
            self._status()
            wait = self._run_timers()
            s, item = items[i]
            if self.speed > 0:
                due = w0 + (s - t_start) / self.speed - time.monotonic()
                if due > 0:
                    self._drain(min(due, wait, 0.05))
                    continue
            if not self._may_feed(s) or (isinstance(item, list) and not self._group_may_go(s)):
                self._publish_progress(s, force=True)
                self._drain(min(wait, 0.02))
                continue
            if self._final < self.record_times.size and s - self.node.horizon > self.record_times[self._final]:
                self._publish_due(upto=s)
            self._step(item)
            i += 1
            self._i = i
            self._answer_ready()
            nxt = items[i][0] if i < n else math.inf
            self._publish_progress(nxt)
            self._publish_due()
        self._i = n
        self._answer_ready()
        self._publish_progress(math.inf, force=True)

    def _status(self) -> None:
        now = time.monotonic()
        if now - self._last_status > 2.0:
            self._last_status = now
            log.info("robot %s: %d/%d inputs, present %.2f, pending %d, deferred %d, expecting %d, outstanding %d; "
                     "node %s; net %s", self.robot, self._i, len(self.items), self.node.present, self.node.pending,
                     len(self._deferred), len(self._expect), len(self._outstanding),
                     {k: v for k, v in self.node.stats().items() if v}, dict(self.counts))  # fmt: skip

    def _idle(self) -> bool:
        return not (self._outstanding or self._timers or self._deferred or self._expect or self._held or self._outbox)

    def _finish(self, deadline: float) -> None:
        """Wait for the team to finish its sources and the traffic to settle, then publish the final beliefs."""
        quiet_since = time.monotonic()
        while not self._stop.is_set() and time.monotonic() < deadline:
            got = self._drain(0.02)
            self._answer_ready()
            self._release()
            self._flush()
            self._status()
            self._run_timers()
            if time.monotonic() - self._last_progress_wall > 0.2:
                self._publish_progress(math.inf, force=True)
            if got or not self._idle():
                quiet_since = time.monotonic()
            all_read = all(self._progress.get(r, -math.inf) == math.inf or r in self._done for r in self._alive)
            if all_read and time.monotonic() - quiet_since >= self.quiet:
                break
        self._route(self.node.expire())
        self._flush(force=True)
        self._publish_due(end=True)
        self._publish_progress(math.inf, done=True, force=True)
        t_end = time.monotonic() + self.linger
        quiet_since = time.monotonic()
        while not self._stop.is_set() and time.monotonic() < min(t_end, deadline):
            got = self._drain(0.02)
            self._run_timers()
            self._flush()
            if got:
                self._route(self.node.expire())
                self._republish_changed()
                quiet_since = time.monotonic()
            if time.monotonic() - self._last_progress_wall > 0.2:
                self._publish_progress(math.inf, done=True, force=True)
            if self._alive <= self._done and self._idle() and time.monotonic() - quiet_since >= self.quiet:
                break

    def report(self, wall: float = 0.0, cpu: float = 0.0) -> Report:
        net = dict(self.counts)
        if self.link is not None:
            net.update(injected_lost=self.link.lost, injected_dup=self.link.duplicated)
        return Report(
            robot=self.robot,
            stats={k: int(v) for k, v in self.node.stats().items()},
            reasons={k: int(v) for k, v in self.node.reasons.items()},
            net={k: int(v) for k, v in net.items()},
            net_reasons={k: int(v) for k, v in self.reasons.items()},
            wall_s=wall,
            cpu_s=cpu,
        )


def _reply(query: Any, payload: bytes) -> None:
    try:
        query.reply(query.key_expr, payload)
    finally:
        query.drop()


def _reply_err(query: Any, reason: str) -> None:
    try:
        query.reply_err(reason.encode())
    except Exception:  # noqa: BLE001 - the asker may be gone
        pass
    finally:
        query.drop()
