"""What a :class:`~swarmloc.net.process.NetNode` sends, and how: envelopes, link faults, the outbox, queries.

A query the node returns is a Zenoh ``get`` on the neighbour's ``query`` key (or the belief server's), waited for
``answer_timeout`` s; the answer to a neighbour's query is the reply to its ``get``; a revised answer or a pairwise
update goes to the receiver's ``inbox`` through the outbox, which coalesces them (the newest per exchange) over one
batch of received messages, and under link faults over ``coalesce`` s. Link faults (:mod:`swarmloc.net.faults`)
lose, delay and duplicate what is sent; delayed sends wait on the node's timers.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from collections import Counter
from collections.abc import Callable
from contextlib import suppress
from functools import partial
from typing import TYPE_CHECKING, Any

from swarmloc.messages import BeliefAnswer, BeliefQuery, Message, RdlState, RdlStateQuery, TeamUpdate
from swarmloc.net.auth import Auth, seal
from swarmloc.net.faults import Faults, FaultySender, LinkFaults
from swarmloc.net.intake import Intake
from swarmloc.net.schema import encode
from swarmloc.net.settings import NetSettings
from swarmloc.net.transport import close_query, get_all, robot_key, server_key
from swarmloc.node import Node

if TYPE_CHECKING:
    from swarmloc.net.lockstep import Lockstep
    from swarmloc.net.wiring import Wiring

log = logging.getLogger("swarmloc.net.process")  # the driver's one logger, whichever part logs

NOT_FOUND_SEQ = -2
"""Revision of the "not found" answer a node gives itself when a query got no answer (a real one replaces it)."""
REASK_SPACING = (0.05, 0.25)
"""[s] the spacing of a query's asks beyond ``answer_retries``: ``answer_timeout`` within these bounds
(:meth:`Outbound.ask_again`)."""


class Envelopes:
    """What robot ``robot`` of team ``team`` sends, in its envelopes: numbered in one sequence (every message it
    sends, on every key) and sealed with ``auth`` (None: unauthenticated)."""

    def __init__(self, auth: Auth | None, team: str, robot: int) -> None:
        self.auth, self.team, self.robot = auth, team, robot
        self._seq = itertools.count()

    def seal(self, body: Any, key: str, to: int | None = None) -> bytes:
        """``body`` in this robot's envelope, with its next sequence number, sealed for ``key`` and member ``to``
        (with ``auth``: MACed for a member in session, else signed; ``to`` defaults to the inbox's or query's
        member)."""
        return seal(self.auth, key, encode(self.team, self.robot, next(self._seq), body), to)


class Outbound:
    """Part of :class:`~swarmloc.net.process.NetNode` (``node.outbound``): sending, with the link faults, the outbox,
    the node's queries and the timers (module docstring).

    ``wiring``: the node's Zenoh side (its session, and its congestion control once opened); ``seal``: envelopes
    (:meth:`Envelopes.seal`); ``intake``: the node's queue, where the replies to its queries and their ends come
    (:class:`~.intake.Intake`); ``lockstep``: which teammates are alive or lost, and the updates expected
    (:class:`~.lockstep.Lockstep`); ``step``: ``step(item)`` steps the node and carries what it returns;
    ``broadcast``: takes a teammate's copy of an update to broadcast (:meth:`~.broadcast.Broadcaster.queue`);
    ``link``: this robot's link faults (None: none), ``faults`` their plan (the delay lengthens a query's wait)."""

    def __init__(self, node: Node, robot: int, roster: frozenset[int], scope: str, settings: NetSettings,
                 counts: Counter[str], *, wiring: Wiring, seal: Callable[..., bytes], intake: Intake,
                 lockstep: Lockstep, step: Callable[[Any], None], broadcast: Callable[[TeamUpdate], None],
                 link: LinkFaults | None = None, faults: Faults | None = None) -> None:  # fmt: skip
        self.node, self.robot, self.roster, self.scope, self.settings = node, robot, roster, scope, settings
        self.counts, self.wiring, self.seal, self.intake, self.lockstep = counts, wiring, seal, intake, lockstep
        self.step, self.broadcast, self.link, self.faults = step, broadcast, link, faults
        self._qids = itertools.count()  # ids of this node's queries
        self.sends = FaultySender(link, counts, robot)
        """Sending with the link faults, and the timers: delayed sends, lost gets, later asks."""
        self.outstanding: dict[int, tuple[Message, str, bool]] = {}
        """The node's queries out, by id: ``(query, "robot"/"server", answered)``."""
        self.gets: dict[int, int] = {}
        """Per query id: its copies out (link faults duplicate them), each ends once."""
        self.outbox: dict[tuple[Any, ...], Message] = {}
        """Pushed messages to send, the newest per exchange."""
        self.again: dict[int, tuple[int, float]] = {}
        """Per query id: (asks of its query before, unanswered; the first's time)."""
        self._last_flush = 0.0
        self.coalesce = 0.05
        """[s] with link faults: the outbox is sent at most this often."""

    def busy(self) -> bool:
        """Queries out, timers set or pushed messages waiting."""
        return bool(self.outstanding or self.sends.timers or self.outbox)

    def route(self, msgs: list[Message], query: Any = None, asked: Message | None = None) -> None:
        """Carry what the node returned: a query is asked (:meth:`ask`), the answer to ``asked`` is the reply to the
        Zenoh ``query``, a revision or an update goes to the receiver's inbox (through the outbox)."""
        for m in msgs:
            if isinstance(m, BeliefQuery | RdlStateQuery):
                self.ask(m)
            elif (
                query is not None
                and isinstance(m, BeliefAnswer | RdlState)
                and isinstance(asked, BeliefQuery | RdlStateQuery)
                and (m.receiver, m.stamp, m.sub) == (asked.sender, asked.stamp, asked.sub)
            ):
                payload, q = self.seal(m, key_of(query), to=m.receiver), query
                query = None
                if isinstance(m, RdlState) and m.found:  # the observer's update (or "no update") follows
                    self.lockstep.expect_update((float(m.stamp), 1, m.receiver, tuple(m.sub)))
                answer = lambda q=q, payload=payload: q.reply(q.key_expr, payload)  # noqa: E731
                self.sends.faulty(answer, finish=partial(close_query, q))
            elif isinstance(m, TeamUpdate):  # a teammate's copy of a broadcast (:mod:`swarmloc.net.broadcast`)
                self.broadcast(m)
            elif m.receiver in self.roster:
                # pushed revisions and updates are coalesced: the newest per exchange goes out with the next flush
                k = (type(m).__name__, m.receiver, m.stamp, m.sub)
                if k in self.outbox:
                    self.counts["coalesced"] += 1
                self.outbox[k] = m
            else:
                self.counts["undeliverable"] += 1
        if query is not None:  # the query was not answered by the node (cannot happen for a well-formed query)
            reply_err(query, "no answer")

    def flush(self, force: bool = False) -> None:
        """Send the pushed messages waiting in the outbox: without faults at once, or at the end of the batch of
        received messages being handled (:meth:`~swarmloc.net.inbound.Inbound.drain`), so that the revisions one
        batch makes of one exchange go out as one; with faults at most every ``coalesce`` s, so that a burst of
        revisions of one exchange (late and lost messages make them) costs the neighbour one replay instead of one
        per revision."""
        if not self.outbox:
            return
        now = time.monotonic()
        if not force and self.link is not None and now - self._last_flush < self.coalesce:
            return
        self._last_flush = now
        out, self.outbox = self.outbox, {}
        for m in out.values():
            self.push(m, m.receiver)

    def push(self, body: Any, to: int) -> int:
        """``body`` to robot ``to``'s inbox (link faults apply); the bytes of its payload."""
        key = robot_key(self.scope, to, "inbox")
        payload = self.seal(body, key)
        self.sends.faulty(partial(self.wiring.session.put, key, payload, congestion_control=self.wiring.block))
        return len(payload)

    def ask(self, m: Message, via_server: bool = False, again: int = 0, first: float | None = None) -> None:
        """Ask ``m`` of its receiver (or of the belief server) as a Zenoh get; its replies and its end come back on
        the node's queue (:meth:`~.inbound.Inbound.handle`). ``again``: how many times it was asked before and went
        unanswered, ``first``: the monotonic time of its first ask (None: this one) (:meth:`ask_again`)."""
        kind = BeliefAnswer if isinstance(m, BeliefQuery) else RdlState
        if m.receiver not in self.roster:
            self.feed_local(kind, m, f"robot {m.receiver} is not in the team")
            return
        if m.receiver in self.lockstep.lost and not via_server:
            self.counts["asked_lost"] += 1
            if self.server_answers(m):
                self.ask(m, via_server=True)
            else:
                why = self.lockstep.lost_why.get(m.receiver, "declared lost")
                self.feed_local(kind, m, f"robot {m.receiver} is lost ({why}){self.no_server_for(m)}")
            return
        qid = next(self._qids)
        self.outstanding[qid] = (m, "server" if via_server else "robot", False)
        self.again[qid] = (again, time.monotonic() if first is None else first)
        key = server_key(self.scope) if via_server else robot_key(self.scope, m.receiver, "query")
        payload = self.seal(m, key)
        timeout = self.settings.answer_timeout + (2 * self.faults.delay if self.faults else 0.0)
        intake, session = self.intake, self.wiring.session

        def send() -> None:  # replies within the intake's budgets; the end always (a failed get: a missing answer)
            exc = get_all(session, key, payload, timeout, lambda r: intake.offer(("reply", qid, r)),
                          lambda: intake.put(("reply_end", qid, None)))  # fmt: skip
            if exc is not None:
                log.warning("robot %s: get %s failed: %s", self.robot, key, exc)

        if via_server:
            self.counts["sent"] += 1
            send()
            return
        # every copy's get ends on the queue, handled on this thread after this returns: count them first
        self.gets[qid] = copies = self.sends.faulty(send)
        if not copies:
            # a lost query: its get never goes out, so nothing will end it but a timer
            end: Callable[[], None] = partial(intake.put, ("reply_end", qid, None))
            self.sends.later(time.monotonic() + timeout, end)

    def answered(self, qid: int) -> None:
        """Query ``qid`` got its answer (a later reply is a duplicate); counted ``server_answers`` if the server's."""
        m, via, _ = self.outstanding[qid]
        if via == "server":
            self.counts["server_answers"] += 1
        self.outstanding[qid] = (m, via, True)

    def ended(self, qid: int) -> None:
        """The end of query ``qid`` (all replies in, or its ``answer_timeout`` passed): unanswered, it is asked of the
        belief server (``use_server``), else of its robot again while asks are left (:meth:`ask_again`), else
        answered "not found" with the reason. A query sent twice (link faults) ends when both copies have."""
        if self.gets.get(qid, 0) > 1:
            self.gets[qid] -= 1
            return
        self.gets.pop(qid, None)
        entry = self.outstanding.pop(qid, None)
        again, first = self.again.pop(qid, (0, -math.inf))  # (every ask records it; -inf: by count alone)
        if entry is None:
            return
        m, via, answered = entry
        if answered:
            return
        self.counts["no_reply"] += 1
        if via == "robot" and self.server_answers(m):
            self.ask(m, via_server=True, again=again, first=first)
            return
        if self.ask_again(m, again + 1, first):  # the node waits on: lockstep holds its group
            return
        kind = BeliefAnswer if isinstance(m, BeliefQuery) else RdlState
        who = "robot or server" if via == "server" else "robot"
        asks = f" ({again + 1} asks)" if again else ""
        self.feed_local(
            kind, m, f"no answer from the {who} within {self.settings.answer_timeout:g} s{asks}{self.no_server_for(m)}"
        )

    def server_answers(self, m: Message) -> bool:
        """Whether query ``m`` goes to the belief server when its robot cannot answer: with ``use_server``, a
        :class:`BeliefQuery` only. The server stores each robot's Gaussian, not the pairwise factors ``sigma_ji``
        of an :class:`RdlStateQuery` that only robot ``j`` holds (it refuses one), so asking it would cost a
        round trip for a certain refusal."""
        return self.settings.use_server and isinstance(m, BeliefQuery)

    def no_server_for(self, m: Message) -> str:
        """The reason's tail when a query the server cannot answer was not asked of it (empty otherwise)."""
        if self.settings.use_server and not isinstance(m, BeliefQuery):
            return f"; not asked of the belief server, which does not answer {type(m).__name__}"
        return ""

    def ask_again(self, m: Message, again: int, first: float) -> bool:
        """Ask query ``m``, asked ``again`` times already (the first at monotonic time ``first``) and unanswered each
        time, of its robot once more, while the robot is alive (not declared lost) and ``m``'s stamp is within the
        node's horizon: ``answer_retries`` times, and beyond that while less than ``lost_timeout`` s have passed
        since the first ask (as long as a silent teammate is waited for); whether it was asked.
        A reply that a get missed (the neighbour held the query, or was stalled, past ``answer_timeout``: a Zenoh get
        drops a reply that comes after its timeout, and the neighbour does not know) is then taken by the next ask
        instead of being lost for good; the node gets its "not found" answer only once no ask is left, so a stalled
        but live neighbour costs a wait and its answer is applied as in-process.
        **Bounded by count and rate**: beyond ``answer_retries``, the ``k``-th ask goes out no sooner than ``k``
        spacings after the first (``answer_timeout``, within ``REASK_SPACING``), so a get that ends at once (a
        liveliness token without a process behind it: no queryable to answer) waits on a timer instead of being
        asked again at once (counted ``asked_again_later``; before, one query was asked 22,662 times while a fake
        token lasted), and a query is asked at most ``answer_retries + ceil(lost_timeout / spacing) + 1`` times."""
        lo, hi = REASK_SPACING
        now, spacing = time.monotonic(), min(max(self.settings.answer_timeout, lo), hi)
        if (
            (again > self.settings.answer_retries and now - first >= self.settings.lost_timeout)
            or again > self.settings.answer_retries + math.ceil(self.settings.lost_timeout / spacing) + 1
            or m.receiver not in self.lockstep.alive
            or m.receiver in self.lockstep.lost
            or m.stamp < self.node.present - self.node.horizon
        ):
            return False
        self.counts["asked_again"] += 1
        due = first + again * spacing if again > self.settings.answer_retries else now
        if due > now:
            self.counts["asked_again_later"] += 1
            self.sends.later(due, lambda: self.ask(m, again=again, first=first))
        else:
            self.ask(m, again=again, first=first)
        return True

    def feed_local(self, kind: type, m: Message, reason: str, seq: int = NOT_FOUND_SEQ) -> None:
        """Step the node with a "not found" answer to its own query ``m``, with the reason."""
        a = kind(sender=m.receiver, receiver=m.sender, stamp=m.stamp, sub=m.sub, found=False, reason=reason, seq=seq)
        self.step(a)


def key_of(x: Any) -> str:
    """The key expression of a Zenoh sample, query or reply sample (what a signature covers)."""
    return str(getattr(x, "key_expr", ""))


def reply_err(query: Any, reason: str) -> None:
    """Refuse a neighbour's Zenoh query with ``reason`` and close it (the asker may be gone: nothing then)."""
    with suppress(Exception):
        query.reply_err(reason.encode())
    close_query(query)
