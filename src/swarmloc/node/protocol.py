"""A node's protocol with its neighbours: which messages it accepts, answers, refuses, and revises.

* **Refused at receipt** (counted ``messages_rejected`` with the reason, never reaching the history): a message
  that is not one of the declared types, with malformed numbers (:func:`swarmloc.messages.message_problem`),
  addressed from a robot to itself, or to a robot this node does not own. A node learns a neighbour only from a
  message it accepted.
* **Queries** (``BeliefQuery``, ``RdlStateQuery``) are answered from the state before the asker's key. A query
  stamped past the node's present plus its clock tolerance is answered "not yet" once and forgotten (never
  stored, never revised); one before the kept history, or before the node started, "not found" with the reason.
  Every other answer is remembered (:class:`Served`): when a late input changes it, the node sends it again
  with a higher revision ``seq``.
* **Answers** to the node's own queries complete its waiting detection groups; a stale or duplicate one (``seq``
  not higher than the one held) is refused. **Updates** from neighbours are filed in the history by the
  estimators that take them, once they pass their check (:mod:`~swarmloc.node.trust`: refused, counted against
  their sender otherwise).
* A **quarantined** teammate's messages are all refused (counted ``quarantined``); its queries are answered
  "not found", the answers it was given are not revised, and nothing is asked of it any more
  (:mod:`~swarmloc.node.trust`).
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections.abc import Iterator, Sequence
from typing import Any, Protocol

import msgspec

from swarmloc.gaussian import GroupGaussian
from swarmloc.messages import (
    Answer,
    BeliefAnswer,
    BeliefQuery,
    Message,
    RdlState,
    RdlStateQuery,
    RdlUpdate,
    TeamUpdate,
    flat,
    message_problem,
)
from swarmloc.node.filing import Filing
from swarmloc.node.keys import P_GROUP, Entry, Group, Key

__all__ = [
    "Exchange",
    "ExchangeHost",
    "Served",
    "answer_type",
    "belief_answer",
    "not_found",
    "quarantine_reason",
    "refusal",
    "same",
    "with_seq",
]

ServedKey = tuple[Key, int, str]
"""``(query key, asker, query type name)``."""


def refusal(m: Message, robots: Sequence[int], what: str) -> str | None:
    """Why a received message must be refused before it reaches the node's history, or None: malformed
    (:func:`~swarmloc.messages.message_problem`), sent by a robot to itself, or addressed to a robot the node does
    not own."""
    why = message_problem(m)
    if why:
        return why
    if m.sender == m.receiver:
        return f"{what} addressed from robot {m.sender} to itself"
    if m.receiver not in robots:
        return f"{what} addressed to robot {m.receiver}, not a robot of this node"
    return None


def answer_type(q: Message) -> type[BeliefAnswer] | type[RdlState]:
    return BeliefAnswer if isinstance(q, BeliefQuery) else RdlState


def not_found(q: Message, reason: str) -> Answer:
    """The answer to ``q`` saying that there is none, and why."""
    return answer_type(q)(sender=q.receiver, receiver=q.sender, stamp=q.stamp, sub=q.sub, found=False, reason=reason)


def quarantine_reason(robot: int) -> str:
    """Why a quarantined teammate's query is not answered and a query to it is not asked."""
    return f"robot {robot} is quarantined"


def belief_answer(q: Message, b: GroupGaussian) -> BeliefAnswer:
    """The answer to a :class:`~swarmloc.messages.BeliefQuery` carrying belief ``b``."""
    if b.group.dim == 6:
        return BeliefAnswer(sender=q.receiver, receiver=q.sender, stamp=q.stamp, sub=q.sub, group="SE3",
                            mean=flat(b.mean), cov=flat(b.cov))  # fmt: skip
    return BeliefAnswer(sender=q.receiver, receiver=q.sender, stamp=q.stamp, sub=q.sub, mean=flat(b.mean),
                        cov=flat(b.cov))  # fmt: skip


def same(a: Message | None, b: Message | None) -> bool:
    """Equal apart from the revision number, to the bit. A replay that re-derives a state along another path may
    change the last bits of what a node sent; such a change is sent all the same (a revision or a re-broadcast), so
    that every receiver ends on the numbers the ordered run has: a fixed-lag smoother's window, relinearized, grows
    a last-bit difference to 1e-8 and more. It cannot go on forever: a message keyed ``k`` depends only on what is
    keyed before ``k``, so a chain of revisions moves forward in key order and ends at the present."""
    if a is None or b is None:
        return a is b
    return type(a) is type(b) and all(getattr(a, f) == getattr(b, f) for f in a.__struct_fields__ if f != "seq")


def with_seq(m: Answer, seq: int) -> Answer:
    return msgspec.structs.replace(m, seq=seq)


def query_of(answer: Answer, asker: int) -> Message:
    """The query that ``answer`` (served to ``asker``) answers."""
    q_type = BeliefQuery if isinstance(answer, BeliefAnswer) else RdlStateQuery
    return q_type(sender=asker, receiver=answer.sender, stamp=answer.stamp, sub=answer.sub)


class Served:
    """The answers a node gave, by ``(query key, asker, query type)``, in key order: what a replay may revise."""

    def __init__(self) -> None:
        self.keys: list[ServedKey] = []
        self.answers: dict[ServedKey, Answer] = {}

    def clear(self) -> None:
        self.keys.clear()
        self.answers.clear()

    def get(self, skey: ServedKey) -> Answer | None:
        return self.answers.get(skey)

    def latest_key(self) -> Key | None:
        """The key of the latest answered query (None: none)."""
        return self.keys[-1][0] if self.keys else None

    def record(self, skey: ServedKey, ans: Answer) -> Answer:
        """Remember ``ans`` as the answer under ``skey``: the one given before when it is the same, else with a
        revision one higher than it."""
        old = self.answers.get(skey)
        if old is None:
            self.keys.insert(bisect_left(self.keys, skey), skey)
        elif same(old, ans):
            ans = old
        else:
            ans = with_seq(ans, old.seq + 1)
        self.answers[skey] = ans
        return ans

    def revise(self, skey: ServedKey, new: Answer) -> Answer | None:
        """``new`` with the next revision when it differs from the answer given under ``skey`` (else None)."""
        old = self.answers[skey]
        if same(old, new):
            return None
        new = with_seq(new, old.seq + 1)
        self.answers[skey] = new
        return new

    def after(self, key: Key) -> Iterator[tuple[ServedKey, Answer]]:
        """The answers keyed after ``key``, in key order."""
        i = bisect_right(self.keys, (key, math.inf))
        for skey in self.keys[i:]:
            yield skey, self.answers[skey]

    def prune(self, cutoff: float) -> None:
        """Forget answers to queries stamped before ``cutoff``."""
        m = bisect_left(self.keys, ((cutoff,),))
        if m > 0:
            for k in self.keys[:m]:
                del self.answers[k]
            del self.keys[:m]


class ExchangeHost(Protocol):
    """What the exchange asks of its node (:class:`~swarmloc.node.base.Node`): its hooks (the estimators override
    them), the query and revision steps included so that an estimator may extend them."""

    def _answer(self, s: Any, q: Message) -> Answer | None: ...
    def _on_query(self, q: Message) -> list[Message]: ...
    def _revise(self, after: Key) -> list[Message]: ...
    def _update_problem(self, u: Message) -> str | None: ...
    def _update_lie(self, u: Message) -> str | None: ...
    def _placeholder(self, data: Any) -> bool: ...


class Exchange:
    """How a :class:`~swarmloc.node.base.Node` takes messages from its neighbours (module docstring). Its own state:
    the answers it gave (``served``), the detection groups waiting for answers (``pending``) and the robots heard
    from (``neighbours``). Its collaborators: the node (``host``), its robots and the update types it files, and its
    filing (history, replay, and the node's clock, accounting and trust it was made with)."""

    def __init__(
        self,
        host: ExchangeHost,
        robots: tuple[int, ...],
        update_types: tuple[type[RdlUpdate] | type[TeamUpdate], ...],
        filing: Filing,
    ) -> None:
        self.host = host
        self.robots = robots
        self.update_types = update_types
        self.filing = filing
        self.history = filing.history
        self.clock, self.accounting, self.trust = filing.clock, filing.accounting, filing.trust
        self.counts = filing.accounting.counts
        self.served = Served()
        self.pending: dict[Key, Group] = {}
        self.neighbours: set[int] = set()

    # ------------------------------------------------------------------------------------------------ messages
    def on_message(self, m: Message) -> list[Message]:
        self.counts["messages"] += 1
        what = type(m).__name__
        why = refusal(m, self.robots, what)
        if why is not None:
            self.accounting.message_rejected(why)
            return []
        if self.trust.shut_out(m.sender):
            return [not_found(m, quarantine_reason(m.sender))] if isinstance(m, BeliefQuery | RdlStateQuery) else []
        if isinstance(m, BeliefQuery | RdlStateQuery):
            return self.host._on_query(m)
        if isinstance(m, BeliefAnswer | RdlState):
            return self.on_answer(m)
        if isinstance(m, self.update_types):
            return self.on_update(m)
        self.accounting.message_rejected(f"{self.accounting.name} does not take {what}")
        return []

    def query_state(self, key: Key, robot: int) -> Any:
        """The state before ``key`` with ``robot`` predicted to its stamp: what a query keyed ``key`` is answered
        from."""
        return self.filing.adv(self.history.state_before(key), robot, key[0], key)

    def on_query(self, q: Message) -> list[Message]:
        key: Key = (float(q.stamp), P_GROUP, q.sender, tuple(q.sub))
        if self.clock.t0 is None:
            return [not_found(q, "the node has not started")]
        why = self.clock.too_old(key[0])
        if why is not None:
            return [not_found(q, why)]
        why = self.clock.future(key[0])
        if why is not None:  # answered once, never stored or revised
            self.counts["not_yet_sent"] += 1
            return [not_found(q, f"not yet: {why}")]
        ans = self.host._answer(self.query_state(key, q.receiver), q)
        if ans is None:
            return [not_found(q, f"{self.accounting.name} does not answer {type(q).__name__}")]
        self.counts["answers_sent"] += 1
        return [self.served.record((key, q.sender, type(q).__name__), ans)]

    def revise(self, after: Key) -> list[Message]:
        """Recompute the answers given to queries keyed after ``after``; send those that changed, revised."""
        latest = self.served.latest_key()
        if latest is None or not latest > after:  # none keyed after it: the common case
            return []
        out: list[Message] = []
        for skey, old in list(self.served.after(after)):
            key, asker, _ = skey
            if asker in self.trust.quarantined:  # nothing more is sent to it, revisions included
                continue
            q = query_of(old, asker)
            new = self.host._answer(self.query_state(key, q.receiver), q)
            if new is not None and (new := self.served.revise(skey, new)) is not None:
                self.counts["revisions_sent"] += 1
                out.append(new)
        return out

    def on_answer(self, a: Answer) -> list[Message]:
        key: Key = (float(a.stamp), P_GROUP, a.receiver, ())
        slot = (a.sender, tuple(a.sub))
        g = self.pending.get(key)
        pos = None  # the answer's group: pending (g), or filed in the history at pos
        if g is not None and slot in g.answers:
            answers = g.answers
        else:
            g, pos = None, self.history.find(key)
            if pos is None or slot not in self.history.entries[pos].data.answers:
                why = "older than the history horizon" if self.clock.too_old(key[0]) else "to no query of this node"
                self.accounting.message_rejected(f"answer {why}")
                return []
            answers = self.history.entries[pos].data.answers
        old = answers[slot]
        if old is not None and a.seq <= old.seq:
            self.accounting.message_rejected("stale or duplicate answer")
            return []
        answers[slot] = a
        if a.found:
            self.neighbours.add(a.sender)
        if g is None:
            assert pos is not None  # noqa: S101  (filed: found above)
            return self.filing.replay(pos, late=True)
        if g.waiting():
            return []
        del self.pending[key]
        return self.filing.commit_group(key, g)

    def on_update(self, u: RdlUpdate | TeamUpdate) -> list[Message]:
        why = self.host._update_problem(u)
        if why is None:
            why = self.clock.too_old(float(u.stamp)) or self.clock.future(float(u.stamp))
            why = None if why is None else f"update {why}"
        if why is not None:
            self.accounting.message_rejected(why)
            return []
        self.neighbours.add(u.sender)
        key: Key = (float(u.stamp), P_GROUP, u.sender, tuple(u.sub))
        hist = self.history
        pos = hist.find(key)
        if u.empty:  # no update follows (the neighbour did not fuse this exchange), or one filed is retracted
            if pos is None:
                self.counts["no_update"] += 1
                return []
            if self.host._placeholder(hist.entries[pos].data):
                self.counts["updates_missing"] -= 1
                self.counts["no_update"] += 1
            hist.remove(pos)
            return self.filing.replay(pos, late=True, changed_at=key) if pos < len(hist) else self.host._revise(key)
        lie = self.host._update_lie(u)
        if lie is not None:
            return self.shut_out_pending(u.sender) if self.trust.refused(u.sender, lie) else []
        self.trust.accepted(u.sender)
        if pos is not None:
            old = hist.entries[pos].data
            if old == u:
                self.accounting.message_rejected("duplicate update")
                return []
            hist.entries[pos].data = u
            if self.host._placeholder(old):  # the update a placeholder waited for: in order if nothing followed it
                self.counts["updates_missing"] -= 1
                return self.filing.replay(pos, late=pos < len(hist) - 1)
            return self.filing.replay(pos, late=True)
        return self.filing.file([Entry(key, "update", u)])

    def shut_out_pending(self, robot: int) -> list[Message]:
        """``robot`` quarantined: the answers the waiting groups still expect from it are given up (not found), and the
        groups that wait for nothing else are applied."""
        out: list[Message] = []
        for key in sorted(self.pending):
            g: Group = self.pending[key]
            for slot, a in g.answers.items():
                if slot[0] == robot and a is None:
                    g.answers[slot] = BeliefAnswer(sender=robot, receiver=g.observer, stamp=g.t, sub=slot[1],
                                                   found=False, reason=quarantine_reason(robot))  # fmt: skip
            if not g.waiting():
                del self.pending[key]
                out += self.filing.commit_group(key, g)
        return out

    def prune(self, cutoff: float) -> None:
        """Forget answers to queries stamped before ``cutoff``."""
        self.served.prune(cutoff)
