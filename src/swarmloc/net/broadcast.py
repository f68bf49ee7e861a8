"""A team estimator's broadcasts (``diekf``): all-to-all, numbered per sender, with repair of lost ones.

In-process, a ``diekf`` node returns one :class:`~swarmloc.messages.TeamUpdate` per teammate for each update (the
same numbers, one ``receiver`` each) and the runner hands each teammate its copy. Over the network the driver sends
them once: the copies of one exchange (its key ``(stamp, sub)``) become one :class:`~swarmloc.net.schema.Broadcast`
published on ``robot/<id>/broadcast`` with the sender's next **broadcast number** ``n`` (0, 1, 2, ...; a revision of
an exchange is a new broadcast with a new number), and every teammate steps its node with that update addressed to
itself: the very message the in-process runner would have delivered.

**Receipt.** A broadcast is signed and checked like every other message, as a *publication*: only robot ``id`` may
publish on ``robot/<id>/broadcast`` (:func:`~swarmloc.net.auth.open_envelope` with ``publication=True``; a signed
frame replayed is refused by its signature's sequence number). Then, per sender: a number (or a head's count)
more than ``WINDOW`` past the first one missing from that sender is refused and counted (``rejected``; before, one
head announcing 2^62 made every teammate track and allocate toward it: 2.7 GB, then ``MemoryError``); a number
already received is a duplicate (link faults), counted ``broadcast_duplicates`` and not applied again; an update
older than one already applied for the same exchange (a revision that overtook it) is counted ``broadcast_stale``
and dropped; anything else is applied (``broadcasts_applied``). Every broadcast received is counted
``broadcasts_received``.

**Repair.** A receiver knows each sender's numbers received and the highest one it has heard of (from a broadcast
or from the :class:`~swarmloc.net.schema.BroadcastHead` each sender announces when it changes, so that the last ones
lost are seen missing too). A receiver that needs the head of a live mate it hears and has none (it starts hearing
it: the node's start, a re-formed cluster) asks its sender for it after ``repair_wait`` s (a
:class:`~swarmloc.net.schema.BroadcastRepair` with ``head`` set, ``head_requests``, asked again every ``2
repair_wait + 0.2`` s while it has none); the sender announces its head again at its next flush (at most once per
``repair_wait`` s, however many ask). Unchanged, a head is announced again (a heartbeat, for a head lost on the way;
equal to the last heard from its sender, it is counted ``broadcast_heads_repeated`` too) once the node's present has
moved :data:`HEAD_EVERY` s of data on, or after ``lost_timeout`` s of wall time (a sender that waits: well before
its teammates would declare it stalled, after :data:`~swarmloc.net.timeouts.STALL_TIMEOUTS` lost timeouts). Before,
it came every second of wall time, to tell a mate that started hearing its sender the head: a replay slower than
real time received more of them per second of data the slower it ran.
A number missing for ``repair_wait`` s (the link's delay, plus 50 ms) is asked again
of its sender with a :class:`~swarmloc.net.schema.BroadcastRepair` on the sender's inbox (``repair_requests``),
again every ``2 repair_wait + 0.2`` s, ``REPAIR_TRIES`` times at most. The sender keeps its last ``BUFFER``
broadcasts and sends the ones asked for to the asker's inbox (``repairs_sent``); one it no longer keeps is
answered *gone* (a ``Broadcast`` without update), at most ``REPAIR_RATE`` numbers per asker and second (past it
a request is refused and counted). A number that arrives after it was asked for is counted ``broadcasts_repaired``.

**Beyond repair** (gone, or not answered after ``REPAIR_TRIES`` requests; counted ``broadcasts_given_up``). The
buffer holds far more broadcasts than one history horizon sees (a robot broadcasts a few per second; measured in
``benchmarks/diekf_traffic.py``), so a broadcast beyond it is also beyond the node's horizon, where no input can be
applied any more; and a receiver that misses an update of another robot keeps a consistent belief of its own: its
error is the one before that update, whose covariance it still holds (an update it never saw leaves its own pose
and covariance uncorrected, not overconfident). What it loses is replica agreement on the cross-covariances
(``docs/network.md``): the count says how often that happened.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

import msgspec

from swarmloc.messages import TeamUpdate
from swarmloc.net.intake import TokenBucket
from swarmloc.net.numbered import Numbered
from swarmloc.net.schema import ALL, MAX_REPAIR, Broadcast, BroadcastHead, BroadcastRepair
from swarmloc.node import Node
from swarmloc.node.protocol import same

if TYPE_CHECKING:
    from swarmloc.net.lockstep import Lockstep
    from swarmloc.net.outbound import Outbound
    from swarmloc.net.wiring import Wiring

log = logging.getLogger("swarmloc.net.process")  # the driver's one logger, whichever part logs

BUFFER = 4096
"""Broadcasts a sender keeps to answer repair requests (its latest)."""
WINDOW = BUFFER
"""A receiver takes a broadcast number (or a head's count) at most this far past the first number of its sender it
misses: what a sender announces further ahead is refused and counted, so that one message cannot make a receiver
track (and ask for) more numbers than the sender keeps. A receiver that first hears of a sender far into its
numbers (a late joiner) starts a window before them: those earlier are beyond the sender's buffer anyway."""
REPAIR_RATE = 2 * BUFFER
"""Broadcast numbers a sender sends again to one asker per second at most (``2 * REPAIR_RATE`` banked); a request
past it is refused and counted (it is asked again later), so that requests cannot make a node send without bound."""
REPAIR_TRIES = 8
"""Requests for one missing broadcast before it is given up."""
HEAD_EVERY = 1.0
"""[s] data time (the sender's present) before its unchanged head is announced again (at once when it changes)."""


class Broadcaster:
    """Part of :class:`~swarmloc.net.process.NetNode` (``node.broadcaster``): a team estimator's broadcasts (module
    docstring), for robot ``robot`` driving ``node``; ``active``: the node's estimator broadcasts (else it only
    answers what comes, and never holds lockstep).

    ``wiring``: the node's Zenoh side (the broadcast key's publisher); ``seal``: envelopes
    (:meth:`~.outbound.Envelopes.seal`); ``outbound``: sending (link faults, inboxes, ``coalesce``:
    :class:`~.outbound.Outbound`); ``lockstep``: the live teammates and the updates expected
    (:class:`~.lockstep.Lockstep`); ``step``: ``step(item)`` steps the node; ``reject``: ``reject(reason, where)``
    counts a dropped message (:meth:`~.inbound.Inbound.reject`); ``next_group``: the stamp of the node's next own
    detection group (with a live feed: at least its watermark; inf: none) (:meth:`~.inputs.Inputs.next_group`);
    ``delay``: [s] the link faults' delay."""

    def __init__(self, node: Node, robot: int, counts: Counter[str], *, active: bool, wiring: Wiring,
                 seal: Callable[..., bytes], outbound: Outbound, lockstep: Lockstep, step: Callable[[Any], None],
                 reject: Callable[[str, str], None], next_group: Callable[[], float],
                 delay: float = 0.0) -> None:  # fmt: skip
        self.node, self.robot, self.counts, self.active = node, robot, counts, active
        self.wiring, self.seal, self.outbound, self.lockstep = wiring, seal, outbound, lockstep
        self.step, self.reject, self.next_group = step, reject, next_group
        self._bn = 0  # this node's next broadcast number
        self._bbuf: OrderedDict[int, Broadcast] = OrderedDict()  # its latest broadcasts, by number
        self._bout: dict[tuple, TeamUpdate] = {}  # updates to broadcast with the next flush, the newest per exchange
        self._bsent: dict[tuple, TeamUpdate] = {}  # the last update broadcast per exchange (stamp, sub)
        self._rev_wait: dict[tuple, float] = {}  # (stamp, sub, target): since when a revised answer is expected
        self._revised: set[tuple] = set()  # (stamp, sub, target): revised answers received
        self._quiet: dict[float, float] = {}  # group stamp: wall time of its last broadcast or revised answer
        self._bflush = 0.0
        self._bhead: tuple[float, float, tuple] = (-1.0, -math.inf, ())  # (wall time, present, head) announced last
        self._head_asked = False  # a teammate asked for this node's head since it was last announced
        self._head_asks: dict[int, tuple[int, float]] = {}  # per live mate without head: (requests sent, since when)
        self._heads: dict[int, tuple[int, float, int]] = {}  # per teammate: its latest head (count, t, prio)
        self._peers: dict[int, Numbered[None]] = {}  # per teammate: its numbers received, missing, asked for
        self._bkey: dict[tuple, int] = {}  # (sender, stamp, sub): the number of the update applied for the exchange
        self._bkey_pruned = 0.0
        self._repair_budget: dict[int, TokenBucket] = {}  # per asker: broadcast numbers it may still have again
        self.repair_wait = delay + 0.05
        """[s] wall time a missing broadcast number waits (for a late copy) before it is asked for."""
        self.heard: set[int] | None = None
        """The teammates whose broadcasts it hears now (:class:`~.hearing.Hearing`'s); None: the node's ``team``."""
        self._fresh: set[int] = set()  # teammates heard again after :meth:`forget`
        self.settle = delay + 0.02
        """[s] wall time a group of this node must be quiet (no broadcast of it, no revised answer for it) before its
        head passes it."""

    # ------------------------------------------------------------------------------------------------ sending
    def queue(self, m: TeamUpdate) -> None:
        """A teammate's copy of an update the node returned: one broadcast per exchange goes out with the next flush."""
        k = (float(m.stamp), tuple(m.sub))
        old = self._bout.get(k)
        if old is not None and old.receiver != m.receiver:
            return  # another teammate's copy of the same update
        if old is not None:
            self.counts["coalesced"] += 1
        self._bout[k] = m

    def flush(self, force: bool = False) -> None:
        """Publish the queued broadcasts (at once without faults, at most every ``coalesce`` s with them), announce
        the head when it changed, was asked for, or is due again (module docstring), and ask for the teammates'
        missing broadcasts and heads."""
        now = time.monotonic()
        link, coalesce = self.outbound.link, self.outbound.coalesce
        if self._bout and (force or link is None or now - self._bflush >= coalesce):
            self._bflush = now
            out, self._bout = self._bout, {}
            for k, m in sorted(out.items()):
                m = msgspec.structs.replace(m, receiver=ALL)
                if same(self._bsent.get(k), m):  # a replay that changed nothing: nothing to send
                    self.counts["broadcasts_unchanged"] += 1
                    continue
                self._bsent[k] = m
                self._expect_revision(k, m, now)
                b = Broadcast(robot=self.robot, n=self._bn, update=m)
                self._bn += 1
                self._bbuf[b.n] = b
                if len(self._bbuf) > BUFFER:
                    self._bbuf.popitem(last=False)
                self.counts["broadcasts_sent"] += 1
                self._publish_b(b)
        for k, since in list(self._rev_wait.items()):
            if now - since > 2 * self.repair_wait + 0.2:
                del self._rev_wait[k]
                self.counts["revision_not_received"] += 1
        head, (when, at, last), present = (self._bn, *self._settled()), self._bhead, self.node.present
        again = present - at >= HEAD_EVERY or now - when >= self.lockstep.settings.lost_timeout
        if head != last or again or (self._head_asked and now - when >= self.repair_wait):
            self._bhead, self._head_asked = (now, present, head), False
            self.counts["broadcast_heads_sent"] += 1
            self._publish_b(BroadcastHead(robot=self.robot, n=head[0], t=head[1], prio=head[2]), faults=False)
        self.ask_missing(now)

    def _settled(self) -> tuple[float, int]:
        """``(t, prio)``: every update this node will broadcast for an exchange keyed before ``(t, prio, robot)`` is
        published (its next detection group, its oldest group waiting for answers, and the updates not flushed yet
        are not)."""
        out = (math.inf, 0)
        first = self.node.first_pending
        if first is not None:
            out = min(out, (first[0], first[1]))
        if self._bout:
            out = min(out, (min(k[0] for k in self._bout), 1))
        if self._rev_wait:
            out = min(out, (min(k[0] for k in self._rev_wait), 1))
        if self._quiet:  # a group whose broadcasts or revised answers came less than `settle` s ago
            now = time.monotonic()
            for t in [t for t, w in self._quiet.items() if now - w >= self.settle]:
                del self._quiet[t]
            if self._quiet:
                out = min(out, (min(self._quiet), 1))
        return min(out, (self.next_group(), 1))  # its next detection group (a live feed's: at its watermark or later)

    def _expect_revision(self, k: tuple, m: TeamUpdate, now: float) -> None:
        """A group's answers are given from the state before each detection of it, so a target's answer to a later
        detection does not yet include the group's earlier updates: once they reach it, the target revises that answer
        (as in-process), the group is fused again and the later update broadcast again. Until that revision came
        (or ``2 repair_wait + 0.2`` s passed: ``revision_not_received``) this node's head stays before the group, so
        that no teammate fuses or answers anything keyed after it on the first numbers."""
        t, sub = k
        self._quiet[t] = now
        for (t2, sub2), u in self._bsent.items():  # a (re-)broadcast of this exchange: the later ones' answers change
            if t2 == t and sub2 > sub and not u.empty and u.target != self.robot:
                self._revised.discard((t, sub2, u.target))
                self._rev_wait[(t, sub2, u.target)] = now
        if m.empty or m.target == self.robot or (t, sub, m.target) in self._revised:
            return
        if any(kk[0] == t and kk[1] < sub and not u.empty for kk, u in self._bsent.items()):
            self._rev_wait.setdefault((t, sub, m.target), now)

    def revision_came(self, a: Any) -> None:
        """A revised answer to one of this node's queries (pushed to its inbox), stamped where the node still takes
        inputs (between a horizon before its present and its clock tolerance past it: else nothing is remembered); only
        a node that broadcasts remembers it."""
        if not self.active:
            return
        now = self.node.present
        if a.seq >= 1 and now - self.node.horizon <= float(a.stamp) <= now + self.node.tolerance:
            k = (float(a.stamp), tuple(a.sub), a.sender)
            self._revised.add(k)
            self._rev_wait.pop(k, None)
            self._quiet[k[0]] = time.monotonic()

    def unsettled(self, key: tuple) -> str | None:
        """Why a teammate's broadcast keyed before ``key`` may still be missing here, or None: lockstep waits for
        them before this node fuses a group or answers a query keyed ``key`` (:mod:`swarmloc.net.lockstep`)."""
        if not self.active:
            return None
        for r in self.lockstep.alive & self._mates():
            why = self.unsettled_by(r, key)
            if why is not None:
                return why
        return None

    def _mates(self) -> set[int]:
        """The teammates whose broadcasts this node receives."""
        team_node: Any = self.node  # a team estimator's (diekf): its team, not declared on Node
        return set(team_node.team if self.heard is None else self.heard) - {self.robot}

    def unsettled_by(self, r: int, key: tuple) -> str | None:
        """Why live teammate ``r``'s broadcast keyed before ``key`` may still be missing here, or None (not live:
        None)."""
        if r not in self.lockstep.alive:
            return None
        h = self._heads.get(r)
        if h is None:
            return f"no broadcast head from robot {r} yet"
        n, t, prio = h
        if (t, prio, r) < key[:3]:
            return f"robot {r} may still broadcast updates keyed from {(t, prio)}"
        p = self._peers.get(r)
        if n > (p.low if p is not None else 0):
            return f"robot {r}'s broadcasts below {n} not all here"
        return None

    def forget(self, robots: Iterable[int]) -> None:
        """This node no longer hears ``robots``' broadcasts (:mod:`~.hearing`): what it knew of them is dropped, and
        one heard again starts from the first number it hears then (those before were not for it)."""
        for r in robots:
            self._heads.pop(r, None)
            self._peers.pop(r, None)
            self._head_asks.pop(r, None)
            self._fresh.add(r)

    def _publish_b(self, body: Any, faults: bool = True) -> None:
        """``body`` on this robot's broadcast key: with the link faults, or (a head: lockstep's, like progress) not."""
        key = self.wiring.key("broadcast")
        payload = self.seal(body, key)
        self.counts["broadcast_bytes" if isinstance(body, Broadcast) else "broadcast_head_bytes"] += len(payload)
        pub = self.wiring.publisher("broadcast")
        if not faults:
            pub.put(payload)
            return
        self.outbound.sends.faulty(lambda: pub.put(payload))

    def _push(self, body: Any, to: int) -> None:
        """``body`` to robot ``to``'s inbox (link faults apply)."""
        self.counts["repair_bytes"] += self.outbound.push(body, to)

    def on_repair(self, r: BroadcastRepair) -> None:
        """A teammate asks again for some of this node's broadcasts: the ones kept, or "gone" (within the asker's
        budget, :data:`REPAIR_RATE`); and, with ``head``, for this node's head (announced again at its next flush)."""
        self.counts["repair_requests_received"] += 1
        if r.head:
            self.counts["head_requests_received"] += 1
            self._head_asked = True
        last = min(r.last, self._bn - 1)
        now = time.monotonic()
        budget = self._repair_budget.setdefault(r.sender, TokenBucket(REPAIR_RATE, 2 * REPAIR_RATE, now))
        if last >= r.first and not budget.take(last - r.first + 1, now):
            self.reject("broadcast repair request past its asker's budget", "pushed message")
            return
        for n in range(r.first, last + 1):
            b = self._bbuf.get(n)
            if b is None:
                self.counts["repairs_gone"] += 1
                self._push(Broadcast(robot=self.robot, n=n, to=r.sender), r.sender)
            else:
                self.counts["repairs_sent"] += 1
                self._push(msgspec.structs.replace(b, to=r.sender), r.sender)

    # ------------------------------------------------------------------------------------------------ receiving
    def on_sample(self, b: Any) -> None:
        """What came on a teammate's broadcast key (authenticated: published by that teammate only): a broadcast or
        its head; one of a teammate no longer heard (:meth:`forget`: come before its subscriber was undeclared) is
        dropped, counted ``broadcasts_not_heard``."""
        if self.heard is not None and getattr(b, "robot", None) not in self.heard:
            self.counts["broadcasts_not_heard"] += 1
            return
        if isinstance(b, BroadcastHead):
            self.counts["broadcast_heads_received"] += 1
            if self._heads.get(b.robot) == (b.n, b.t, b.prio):  # the sender's heartbeat (:data:`HEAD_EVERY`)
                self.counts["broadcast_heads_repeated"] += 1
            if not self._in_window(b.robot, b.n - 1, b.n):
                return
            self._heads[b.robot] = max(self._heads.get(b.robot, (-1, -math.inf, 0)), (b.n, b.t, b.prio))
            self._head_asks.pop(b.robot, None)
            self._peers[b.robot].heard_of(b.n - 1, time.monotonic())
        elif isinstance(b, Broadcast) and b.to == ALL:
            self.on_broadcast(b)
        else:
            self.reject(f"{type(b).__name__} is not accepted on a broadcast key", "broadcast")

    def _in_window(self, robot: int, top: int, first: int) -> bool:
        """Whether broadcast number ``top`` of ``robot`` is within :data:`WINDOW` of the first one this node misses
        (on first hearing of ``robot``, a window before ``top`` is opened; heard again after :meth:`forget`, from
        number ``first`` on); if not, it is refused and counted."""
        p = self._peers.get(robot)
        if p is None:
            fresh = robot in self._fresh
            self._fresh.discard(robot)
            self._peers[robot] = Numbered(low=first if fresh else max(0, top + 1 - WINDOW))
            return True
        if top - p.low < WINDOW:
            return True
        self.reject(f"broadcast number more than {WINDOW} past the first one missing from its sender", "broadcast")
        return False

    def on_broadcast(self, b: Broadcast) -> None:
        """A teammate's broadcast (published, or sent again on request): applied once, unless overtaken."""
        self.counts["broadcasts_received"] += 1
        if not self._in_window(b.robot, b.n, b.n):
            return
        p = self._peers[b.robot]
        if p.has(b.n):
            self.counts["broadcast_duplicates"] += 1
            return
        p.heard_of(b.n, time.monotonic())
        if b.n in p.asked:
            self.counts["broadcasts_repaired"] += 1
        p.mark(b.n)
        if b.update is None:
            self.counts["broadcasts_given_up"] += 1
            log.warning("robot %s: robot %s no longer keeps its broadcast %d: given up", self.robot, b.robot, b.n)
            return
        u = b.update
        k = (b.robot, float(u.stamp), tuple(u.sub))
        if self._bkey.get(k, -1) > b.n:
            self.counts["broadcast_stale"] += 1
            return
        if k[1] <= self.node.present + self.node.tolerance:  # past it the node refuses it (future): not remembered
            self._bkey[k] = b.n
        self.counts["broadcasts_applied"] += 1
        expected = self.lockstep.update_came((float(u.stamp), 1, b.robot, tuple(u.sub)))
        self.step(msgspec.structs.replace(u, receiver=self.robot))
        if expected:  # this node answered the observer's query: what waited for its update may go on
            self.lockstep.release()
        self._prune_bkeys()

    def _prune_bkeys(self) -> None:
        present = self.node.present
        if present - self._bkey_pruned < self.node.horizon:
            return
        self._bkey_pruned = present
        cut = present - 2 * self.node.horizon
        for k in [k for k in self._bkey if k[1] < cut]:
            del self._bkey[k]
        for k in [k for k in self._bsent if k[0] < cut]:
            del self._bsent[k]
        self._revised = {k for k in self._revised if k[0] >= cut}

    def ask_missing(self, now: float) -> None:
        """Ask each teammate again for its broadcasts missing longer than ``repair_wait`` s (retries spaced, then given
        up), and each live mate heard for its head, none here for ``repair_wait`` s (retries spaced, while none)."""
        retry = 2 * self.repair_wait + 0.2
        for r in sorted(self.lockstep.alive & self._mates() - self._heads.keys()) if self.active else ():
            tries, since = self._head_asks.setdefault(r, (0, now))
            if now - since >= (self.repair_wait if tries == 0 else retry):
                self._head_asks[r] = (tries + 1, now)
                self.counts["head_requests"] += 1
                self._push(BroadcastRepair(sender=self.robot, receiver=r, first=0, last=-1, head=True), r)
        for r, p in self._peers.items():
            due = p.due(now, self.repair_wait, retry)
            for n in [n for n in due if p.asked[n][0] > REPAIR_TRIES]:
                self.counts["broadcasts_given_up"] += 1
                log.warning("robot %s: robot %s's broadcast %d not repaired after %d requests: given up",
                            self.robot, r, n, REPAIR_TRIES)  # fmt: skip
                p.mark(n)
            due = [n for n in due if n in p.asked]
            while due:
                first = due[0]
                run = [n for n in due if n - first < MAX_REPAIR]
                due = due[len(run) :]
                self.counts["repair_requests"] += 1
                self._push(BroadcastRepair(sender=self.robot, receiver=r, first=first, last=run[-1]), r)

    def busy(self) -> bool:
        """Broadcasts still to send, or teammates' broadcasts still missing."""
        return bool(self._bout) or any(p.missing_since for p in self._peers.values())
