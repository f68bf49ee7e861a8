"""What a :class:`~swarmloc.net.process.NetNode` receives: its queue, decoded and validated, by kind.

Every sample Zenoh hands the node waits on its one queue and is handled on the node's thread (:meth:`_drain`).
A neighbour's message is decoded and validated before anything reaches the node (:meth:`_decode`: schema,
team, roster, sender, addressee, numbers; a negative revision only from the server); a bad one is dropped,
counted with its reason and logged, and the node keeps running, whatever the error.
"""

from __future__ import annotations

import logging
import math
import queue
import time
from typing import Any

from swarmloc.messages import BeliefAnswer, BeliefQuery, RdlState, RdlStateQuery, RdlUpdate
from swarmloc.net.auth import note_refusal, open_envelope
from swarmloc.net.outbound import close, key_of, reply_err
from swarmloc.net.parts import NodeParts
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
from swarmloc.node.accounting import reason_key

log = logging.getLogger("swarmloc.net.process")  # the driver's one logger, whichever part logs

DRAIN_SLICE = 0.1
"""[s] wall time one :meth:`Inbound._drain` handles queued items at most (past its wait for the first)."""
MAX_HELD_FROM = 256
"""Neighbours' queries a node holds at once from one robot (a robot asks about one detection group at a time, a few
queries each); one more is refused ("busy") and counted."""
MAX_HELD = 1024
"""... and from all robots together."""


class Inbound(NodeParts):
    """Part of :class:`~swarmloc.net.process.NetNode`: its queue, the decoding with its bounds, and the handling of
    queries, pushed messages and replies."""

    def _drain(self, timeout: float) -> bool:
        """Handle what is queued, for at most ``DRAIN_SLICE`` s (the rest waits for the next call, so that a flood
        never keeps the loops from their deadlines and timers); wait up to ``timeout`` s for the first item. What
        the batch pushes (revisions, updates, broadcasts) goes out once at its end, the newest per exchange: under
        load a batch is long and its revisions of one exchange are sent as one. True if neighbours' traffic
        (queries, replies, pushed messages) came: progress and liveliness do not count."""
        got = False
        end = time.monotonic() + max(timeout, 0.0) + DRAIN_SLICE
        self._intake.fold(self.counts, self.reasons)  # what the intake dropped since (:mod:`.intake`)
        try:
            item = self._inq.get(timeout=timeout) if timeout > 0 else self._inq.get_nowait()
        except queue.Empty:
            item = None
        self._draining = True
        try:
            while item is not None and not self._stop.is_set():
                got = got or item[0] in ("query", "inbox", "reply", "reply_end", "broadcast")
                if item[0] != "wake":
                    try:
                        self._handle(*item)
                        self._answer_ready()
                    except Exception as exc:  # a node must never die of one message
                        log.exception("robot %s: error handling %s", self.robot, item[0])
                        self._reject(f"internal error: {type(exc).__name__}: {exc}", item[0])
                if time.monotonic() > end:
                    break
                try:
                    item = self._inq.get_nowait()
                except queue.Empty:
                    item = None
        finally:
            self._draining = False
        try:  # outside the per-item guard now: a failing send is counted, never raised into the loop
            self._flush()
        except Exception as exc:  # noqa: BLE001
            self._send_failed(exc)
        return got

    def _handle(self, kind: str, x: Any, y: Any = None) -> None:
        """Handle one item of the node's queue: ``(kind, sample)`` as :meth:`_open` queued it."""
        if kind == "query":
            self._on_query(x)
        elif kind == "inbox":
            self._on_inbox(x)
        elif kind == "reply":
            self._on_reply(x, y)
        elif kind == "reply_end":
            self._on_reply_end(x)
        elif kind == "progress":
            self._on_progress(x)
        elif kind == "alive":
            self._on_alive(x)
        elif kind == "broadcast":
            self._on_broadcast_sample(x)

    def _on_query(self, x: Any) -> None:
        """A neighbour's query: held until the node may answer it (:meth:`_answer_ready`); anything else sent as a
        query is refused at once."""
        self.counts["received"] += 1
        raw = x.payload.to_bytes() if x.payload is not None else None
        self._replayed = False
        env = self._decode(raw, "query", key_of(x))
        if env is None and self._replayed:  # a copy of a query taken before (a duplicate, or replayed): no answer
            close(x)
            return
        if env is None or not isinstance(env.body, BeliefQuery | RdlStateQuery):
            if env is not None:
                self._reject(f"{type(env.body).__name__} sent as a query", "query")
            reply_err(x, "rejected")
            return
        if not self._first_copy(env):  # a duplicate of a query held or answered: answered once, this copy closed
            close(x)
            return
        asker = env.body.sender
        if len(self._deferred) >= MAX_HELD or sum(q.sender == asker for _, q, _ in self._deferred) >= MAX_HELD_FROM:
            self._reject(f"more than {MAX_HELD_FROM} queries of one robot (or {MAX_HELD} in all) held", "query")
            reply_err(x, "busy")
            return
        self._deferred.append((time.monotonic(), env.body, x))
        self._answer_ready()

    def _on_inbox(self, x: Any) -> None:
        """A pushed message: a revised answer or a pairwise update (an expected update releases what waited for it)."""
        self.counts["received"] += 1
        env = self._decode(x.payload.to_bytes(), "pushed message", key_of(x))
        if env is None:
            return
        if isinstance(env.body, BeliefQuery | RdlStateQuery | Belief | Progress | Report | BroadcastHead) or (
            isinstance(env.body, Broadcast) and env.body.to != self.robot
        ):
            self._reject(f"{type(env.body).__name__} is not accepted on the inbox", "pushed message")
            return
        if isinstance(env.body, RdlUpdate):
            self._expect.pop((float(env.body.stamp), 1, env.body.sender, tuple(env.body.sub)), None)
            self._step(env.body)
            self._release()
            return
        if isinstance(env.body, Broadcast):  # a repair of a teammate's broadcast (:mod:`swarmloc.net.broadcast`)
            self._on_broadcast(env.body)
            return
        if isinstance(env.body, BroadcastRepair):
            self._on_repair(env.body)
            return
        if self.broadcasts and isinstance(env.body, RdlState):
            self._revision_came(env.body)
        self._step(env.body)

    def _step(self, item: Any, query: Any = None) -> None:
        """Step the node with ``item`` (answering the Zenoh ``query`` with it if given) and send what it returns.
        A message stamped past the node's present moves it: the beliefs that become final are published first,
        before the history's pruning can drop what they are computed from (as before a source input)."""
        stamp, now = getattr(item, "stamp", None), self.node.present
        if isinstance(stamp, int | float) and now < stamp <= now + self.node.tolerance:  # past it: refused (future)
            self.publishing.due(upto=stamp)
        out = self.node.step(item)
        if out or query is not None:
            self._route(out, query, item)
        if not self._draining:  # within a drain, what the batch pushes goes out once at its end (:meth:`_drain`)
            self._flush()

    def _reject(self, reason: str, where: str) -> None:
        """Count a dropped message with its reason (``rejected``, ``reasons``: at most 256 distinct,
        :func:`~swarmloc.node.accounting.reason_key`) and log the first of each reason."""
        self.counts["rejected"] += 1
        reason = reason_key(self.reasons, reason)
        self.reasons[reason] += 1
        if self.reasons[reason] == 1 and len(self.reasons) <= 20:  # the first of each of the first 20 reasons
            log.warning("robot %s: dropped a %s: %s", self.robot, where, reason)
        else:
            log.debug("robot %s: dropped a %s: %s", self.robot, where, reason)

    def _refuse(self, exc: Rejected, where: str) -> None:
        """Count a dropped message: an authentication failure also as ``auth_<category>``, logged with its detail
        (:func:`~swarmloc.net.auth.note_refusal`)."""
        self._replayed = getattr(exc, "category", None) == "replay"
        if note_refusal(self.counts, exc, f"robot {self.robot}", where):
            self.counts["rejected"] += 1
            self.reasons[reason_key(self.reasons, exc.reason)] += 1
        else:
            self._reject(exc.reason, where)

    def _decode(self, payload: bytes | None, where: str, key: str = "") -> Envelope | None:
        """A neighbour's (or the server's) message for this robot received on ``key``, authenticated (with ``auth``:
        signed by the sender it names, :mod:`swarmloc.net.auth`) and validated (:func:`~swarmloc.net.schema.decode`:
        team, roster, sender, addressee, numbers); None when it is dropped (counted with the reason)."""
        if payload is None:
            self._reject("empty payload", where)
            return None
        try:
            env = open_envelope(self.auth, key, payload, self.team, self.roster, to_robot=self.robot)
        except Rejected as exc:
            self._refuse(exc, where)
            return None
        b = env.body
        if env.from_robot != SERVER and getattr(b, "seq", 0) < 0:
            self._reject("negative revision from a robot", where)
            return None
        return env

    def _on_reply(self, qid: int, reply: Any) -> None:
        """A reply to the node's query ``qid``: held for the node (:meth:`_release`) if it answers that query."""
        self.counts["received"] += 1
        entry = self._outstanding.get(qid)
        if entry is None:
            return
        m, via, answered = entry
        ok = reply.ok
        if ok is None:
            if not answered:
                self._reject(f"error reply: {reply.err.payload.to_bytes()[:80]!r}", "reply")
            return
        env = self._decode(ok.payload.to_bytes(), "reply", key_of(ok))  # authenticated first: a forgery is counted
        if env is None:
            return
        if answered:  # a duplicate reply (link faults): the first was taken
            self.counts["duplicate_replies"] += 1
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

    def _on_reply_end(self, qid: int) -> None:
        """The end of query ``qid`` (all replies in, or its ``answer_timeout`` passed): unanswered, it is asked of the
        belief server (``use_server``), else of its robot again while asks are left (:meth:`_ask_again`), else
        answered "not found" with the reason. A query sent twice (link faults) ends when both copies have."""
        if self._gets.get(qid, 0) > 1:
            self._gets[qid] -= 1
            return
        self._gets.pop(qid, None)
        entry = self._outstanding.pop(qid, None)
        again, first = self._again.pop(qid, (0, -math.inf))  # (every ask records it; -inf: by count alone)
        if entry is None:
            return
        m, via, answered = entry
        if answered:
            return
        self.counts["no_reply"] += 1
        if via == "robot" and self.settings.use_server:
            self._ask(m, via_server=True, again=again, first=first)
            return
        if self._ask_again(m, again + 1, first):  # the node waits on: lockstep holds its group
            return
        kind = BeliefAnswer if isinstance(m, BeliefQuery) else RdlState
        who = "robot or server" if via == "server" else "robot"
        asks = f" ({again + 1} asks)" if again else ""
        self._feed_local(kind, m, f"no answer from the {who} within {self.settings.answer_timeout:g} s{asks}")
