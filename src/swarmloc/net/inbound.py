"""What a :class:`~swarmloc.net.process.NetNode` receives: its queue, decoded and validated, by kind.

Every sample Zenoh hands the node waits on its one queue and is handled on the node's thread (:meth:`Inbound.drain`).
A neighbour's message is decoded and validated before anything reaches the node (:meth:`Inbound._decode`: schema,
team, roster, sender, addressee, numbers; a negative revision only from the server); a bad one is dropped,
counted with its reason and logged, and the node keeps running, whatever the error.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from swarmloc.messages import BeliefAnswer, BeliefQuery, RdlState, RdlStateQuery, RdlUpdate
from swarmloc.net.auth import Auth, Refusals, open_envelope
from swarmloc.net.intake import Intake
from swarmloc.net.lockstep import MAX_HELD, MAX_HELD_FROM, Lockstep
from swarmloc.net.outbound import Outbound, key_of, reply_err
from swarmloc.net.schema import (
    SERVER,
    Belief,
    Broadcast,
    BroadcastHead,
    BroadcastRepair,
    Envelope,
    Progress,
    Rejected,
    Report,
)
from swarmloc.net.transport import close_query

if TYPE_CHECKING:
    from swarmloc.net.broadcast import Broadcaster

log = logging.getLogger("swarmloc.net.process")  # the driver's one logger, whichever part logs

DRAIN_SLICE = 0.1
"""[s] wall time one :meth:`Inbound.drain` handles queued items at most (past its wait for the first)."""


class Inbound:
    """Part of :class:`~swarmloc.net.process.NetNode` (``node.inbound``): its queue, the decoding with its bounds, and
    the handling of queries, pushed messages and replies, for robot ``robot`` of team ``team`` (``roster``; ``auth``:
    what it receives must be signed, None: unauthenticated).

    ``intake``: the node's one queue (:class:`~.intake.Intake`); ``stop``: set when the node stops; ``counts``,
    ``reasons``: its network counters; ``lockstep``, ``outbound``, ``broadcaster``: the parts what comes is handed
    to; ``step``: ``step(item)`` steps the node and carries what it returns; ``flush``: ``flush()`` sends what the
    node pushed (:meth:`~.process.NetNode._flush`)."""

    def __init__(self, robot: int, team: str, roster: frozenset[int], auth: Auth | None, counts: Counter[str],
                 reasons: Counter[str], *, intake: Intake, stop: threading.Event, lockstep: Lockstep,
                 outbound: Outbound, broadcaster: Broadcaster, step: Callable[[Any], None],
                 flush: Callable[[], None]) -> None:  # fmt: skip
        self.robot, self.team, self.roster, self.auth = robot, team, roster, auth
        self.counts, self.reasons = counts, reasons
        self.intake, self.stop, self.step, self.flush = intake, stop, step, flush
        self.lockstep, self.outbound, self.broadcaster = lockstep, outbound, broadcaster
        self.draining = False
        """Handling a batch of the queue: what the node pushes waits for its end (:meth:`drain`)."""
        self._replayed = False  # the last refusal was of a replayed copy
        self.refusals = Refusals(counts, reasons, f"robot {robot}", log)
        """Counts (and logs) what it drops, by reason (:class:`~.auth.Refusals`)."""

    def wake(self) -> None:
        """Wake the node's loop from another thread (or a signal handler)."""
        self.intake.put(("wake", None))

    def drain(self, timeout: float) -> bool:
        """Handle what is queued, for at most ``DRAIN_SLICE`` s (the rest waits for the next call, so that a flood
        never keeps the loops from their deadlines and timers); wait up to ``timeout`` s for the first item. What
        the batch pushes (revisions, updates, broadcasts) goes out once at its end, the newest per exchange: under
        load a batch is long and its revisions of one exchange are sent as one. True if neighbours' traffic
        (queries, replies, pushed messages) came: progress and liveliness do not count."""
        got = False
        end = time.monotonic() + max(timeout, 0.0) + DRAIN_SLICE
        self.intake.fold(self.counts, self.reasons)  # what the intake dropped since (:mod:`.intake`)
        try:
            item = self.intake.get(timeout=timeout) if timeout > 0 else self.intake.get_nowait()
        except queue.Empty:
            item = None
        self.draining = True
        try:
            while item is not None and not self.stop.is_set():
                got = got or item[0] in ("query", "inbox", "reply", "reply_end", "broadcast")
                if item[0] != "wake":
                    try:
                        self.handle(*item)
                        self.lockstep.answer_ready()
                    except Exception as exc:  # a node must never die of one message
                        log.exception("robot %s: error handling %s", self.robot, item[0])
                        self.reject(f"internal error: {type(exc).__name__}: {exc}", item[0])
                if time.monotonic() > end:
                    break
                try:
                    item = self.intake.get_nowait()
                except queue.Empty:
                    item = None
        finally:
            self.draining = False
        try:  # outside the per-item guard now: a failing send is counted, never raised into the loop
            self.flush()
        except Exception as exc:  # noqa: BLE001
            self.outbound.sends.send_failed(exc)
        return got

    def handle(self, kind: str, x: Any, y: Any = None) -> None:
        """Handle one item of the node's queue: ``(kind, sample)`` as the wiring queued it (:mod:`.wiring`)."""
        if kind == "query":
            self._on_query(x)
        elif kind == "inbox":
            self._on_inbox(x)
        elif kind == "reply":
            self._on_reply(x, y)
        elif kind == "reply_end":
            self.outbound.ended(x)
        elif kind == "progress":
            env = self._publication(x, "progress message")
            if env is not None:
                self.lockstep.on_progress(env.body)
        elif kind == "alive":
            self.lockstep.on_alive(x)
        elif kind == "broadcast":
            self.counts["received"] += 1
            env = self._publication(x, "broadcast", to_robot=self.robot)
            if env is not None:
                self.broadcaster.on_sample(env.body)

    def _publication(self, x: Any, where: str, to_robot: int | None = None) -> Envelope | None:
        """A teammate's publication (its progress, its broadcasts: a robot's own key), authenticated (published by
        that robot only) and validated; None when it is dropped (counted with the reason)."""
        try:
            return open_envelope(self.auth, key_of(x), x.payload.to_bytes(), self.team, self.roster,
                                 to_robot=to_robot, server_ok=False, publication=True)  # fmt: skip
        except Rejected as exc:
            self._refuse(exc, where)
            return None

    def _on_query(self, x: Any) -> None:
        """A neighbour's query: held until the node may answer it (:meth:`~.lockstep.Lockstep.answer_ready`);
        anything else sent as a query is refused at once."""
        self.counts["received"] += 1
        raw = x.payload.to_bytes() if x.payload is not None else None
        self._replayed = False
        env = self._decode(raw, "query", key_of(x))
        if env is None and self._replayed:  # a copy of a query taken before (a duplicate, or replayed): no answer
            close_query(x)
            return
        if env is None or not isinstance(env.body, BeliefQuery | RdlStateQuery):
            if env is not None:
                self.reject(f"{type(env.body).__name__} sent as a query", "query")
            reply_err(x, "rejected")
            return
        if not self.lockstep.first_copy(env):  # a copy of a query held or answered: answered once, this copy closed
            close_query(x)
            return
        if not self.lockstep.defer(env.body, x):
            self.reject(f"more than {MAX_HELD_FROM} queries of one robot (or {MAX_HELD} in all) held", "query")
            reply_err(x, "busy")
            return
        self.lockstep.answer_ready()

    def _on_inbox(self, x: Any) -> None:
        """A pushed message: a revised answer or a pairwise update (an expected update releases what waited for it)."""
        self.counts["received"] += 1
        env = self._decode(x.payload.to_bytes(), "pushed message", key_of(x))
        if env is None:
            return
        if isinstance(env.body, BeliefQuery | RdlStateQuery | Belief | Progress | Report | BroadcastHead) or (
            isinstance(env.body, Broadcast) and env.body.to != self.robot
        ):
            self.reject(f"{type(env.body).__name__} is not accepted on the inbox", "pushed message")
            return
        if isinstance(env.body, RdlUpdate):
            self.lockstep.update_came((float(env.body.stamp), 1, env.body.sender, tuple(env.body.sub)))
            self.step(env.body)
            self.lockstep.release()
            return
        if isinstance(env.body, Broadcast):  # a repair of a teammate's broadcast (:mod:`swarmloc.net.broadcast`)
            self.broadcaster.on_broadcast(env.body)
            return
        if isinstance(env.body, BroadcastRepair):
            self.broadcaster.on_repair(env.body)
            return
        if isinstance(env.body, RdlState):  # a revised answer: a team estimator's node waits for some
            self.broadcaster.revision_came(env.body)
        self.step(env.body)

    def reject(self, reason: str, where: str) -> None:
        """Count a dropped message with its reason (``rejected``, ``reasons``: at most 256 distinct,
        :func:`~swarmloc.node.accounting.reason_key`) and log the first of each reason (:class:`~.auth.Refusals`)."""
        self.refusals(reason, where)

    def _refuse(self, exc: Rejected, where: str) -> None:
        """Count a dropped message: an authentication failure also as ``auth_<category>``, logged with its detail
        (:func:`~swarmloc.net.auth.note_refusal`)."""
        self._replayed = getattr(exc, "category", None) == "replay"
        self.refusals(exc.reason, where, exc)

    def _decode(self, payload: bytes | None, where: str, key: str = "") -> Envelope | None:
        """A neighbour's (or the server's) message for this robot received on ``key``, authenticated (with ``auth``:
        signed by the sender it names, :mod:`swarmloc.net.auth`) and validated (:func:`~swarmloc.net.schema.decode`:
        team, roster, sender, addressee, numbers); None when it is dropped (counted with the reason)."""
        if payload is None:
            self.reject("empty payload", where)
            return None
        try:
            env = open_envelope(self.auth, key, payload, self.team, self.roster, to_robot=self.robot)
        except Rejected as exc:
            self._refuse(exc, where)
            return None
        b = env.body
        if env.from_robot != SERVER and getattr(b, "seq", 0) < 0:
            self.reject("negative revision from a robot", where)
            return None
        return env

    def _on_reply(self, qid: int, reply: Any) -> None:
        """A reply to the node's query ``qid``: held for the node (:meth:`~.lockstep.Lockstep.answer_came`) if it
        answers that query."""
        self.counts["received"] += 1
        entry = self.outbound.outstanding.get(qid)
        if entry is None:
            return
        m, via, answered = entry
        ok = reply.ok
        if ok is None:
            if not answered:
                self.reject(f"error reply: {reply.err.payload.to_bytes()[:80]!r}", "reply")
            return
        env = self._decode(ok.payload.to_bytes(), "reply", key_of(ok))  # authenticated first: a forgery is counted
        if env is None:
            return
        if answered:  # a duplicate reply (link faults): the first was taken
            self.counts["duplicate_replies"] += 1
            return
        a = env.body
        asked = (m.receiver, m.sender, m.stamp, m.sub)  # its answer comes from its receiver to its sender
        if not isinstance(a, BeliefAnswer | RdlState) or (a.sender, a.receiver, a.stamp, a.sub) != asked:
            self.reject("reply does not answer the query", "reply")
            return
        self.outbound.answered(qid)
        self.lockstep.answer_came(a)
