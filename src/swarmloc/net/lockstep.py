"""The order of a :class:`~swarmloc.net.process.NetNode`: what makes the networked run equal the in-process one.

A node reads its next input once every live teammate has announced that it has read its own source up to
``lag`` s before it (:meth:`Lockstep.may_feed`), and a detection group once every teammate has read up to the
group's key and no pairwise update keyed before it is expected (:meth:`Lockstep.group_may_go`). It answers a query
once nothing keyed before it can still change the answer (:meth:`Lockstep.ready`), and gives its own detection
groups their answers once no update keyed before them is expected (:meth:`Lockstep.release`). A node with planned
boundaries (``diekf``'s re-forming clusters) reaches each once nothing keyed before it can still come, and its groups
after it wait for what it awaits there (:meth:`Lockstep.reach`, :meth:`Lockstep.boundaries_in`). Teammates are known
from their liveliness tokens and progress announcements (:meth:`Lockstep.on_alive`, :meth:`Lockstep.on_progress`).
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Collection, Iterable
from typing import TYPE_CHECKING, Any, cast

from swarmloc.events import Detection
from swarmloc.messages import Message
from swarmloc.net.schema import MAX_MOVED, Envelope, Progress
from swarmloc.net.settings import NetSettings
from swarmloc.net.timeouts import STALL_TIMEOUTS
from swarmloc.net.transport import robot_of
from swarmloc.node import Node
from swarmloc.node.base import Reach

if TYPE_CHECKING:
    from swarmloc.estimators.cluster_reform import Schedule

log = logging.getLogger("swarmloc.net.process")  # the driver's one logger, whichever part logs

MAX_HELD_FROM = 256
"""Neighbours' queries a node holds at once from one robot (a robot asks about one detection group at a time, a few
queries each); one more is refused ("busy") and counted."""
MAX_HELD = 1024
"""... and from all robots together."""

Key = tuple[Any, ...]
"""An exchange's key ``(stamp, priority, robot, sub)`` (or a prefix of it): the order the in-process runner applies."""


def watched(
    robot: int, cluster: Collection[int] | None, detected: Iterable[tuple[int, int]] | None
) -> frozenset[int] | None:
    """The teammates whose progress robot ``robot``'s lockstep waits for (and subscribes to); None: every teammate.

    ``cluster``: the robots whose broadcasts it hears, ``diekf`` in clusters (None: any other node); ``detected``:
    the ``(observer, target)`` of every robot detection of the team's run, known in advance from a recording
    (:func:`detected_pairs`; None: a live source). In clusters, the cluster's mates and the robots it detects or
    that detect it. That is enough: the node's state changes only by its own inputs, its cluster's broadcasts (a
    mate's progress and broadcast head tell when none keyed before a key can still come) and the answers to its own
    queries; an outsider's detection of it changes nothing of it (the covariance intersection is one-sided). A
    robot it detects must have read its source to the detection's stamp when its query comes (else the query is
    held, and past ``hold_timeout`` answered as things stand: "not yet" beyond the answerer's tolerance). A robot
    that detects it must not be left more than ``lag`` behind (its queries are answered from a history of one
    horizon) nor left before it is done. Every wait is for something keyed before, as with the whole team, so the
    robot with the lowest next key still goes on. Any other node (and a live source, whose detections are not
    known in advance): every teammate, unchanged."""
    if cluster is None or detected is None:
        return None
    pairs = {(int(o), int(t)) for o, t in detected}
    return frozenset({*cluster, *(t for o, t in pairs if o == robot), *(o for o, t in pairs if t == robot)} - {robot})


def heard_in(
    robot: int, schedule: Schedule, k: int, detected: Iterable[tuple[float, int, int]]
) -> tuple[frozenset[int], frozenset[int]]:
    """Whom robot ``robot``'s node hears in cut ``k`` of a re-forming ``schedule`` (``diekf``'s clusters,
    :mod:`swarmloc.estimators.cluster_reform`): the mates whose broadcasts it subscribes to, its clusters of cuts
    ``k`` and ``k + 1`` (the next cut's a period ahead, so that no broadcast a new mate stamps at or after the
    boundary is missed), and the teammates whose progress it waits for (:func:`watched` of those, with the
    detections stamped in the two periods). ``detected``: ``(stamp, observer, target)`` of the team's robot
    detections (:func:`timed_detections`). A mate of cut ``k - 1`` only is the hand-over's: kept by the driver until
    the node has passed the boundary; a mate of another time is not heard."""
    ks = range(k, min(k + 2, len(schedule.cuts)))
    mates = frozenset(r for q in ks for r in schedule.cluster(robot, q)) - {robot}
    w = watched(robot, mates, [(o, t) for s, o, t in detected if schedule.period(s) in ks])
    return mates, mates if w is None else w


def timed_detections(events: Iterable[Any]) -> list[tuple[float, int, int]]:
    """``(stamp, observer, target)`` of the robot detections among ``events`` (a recording of the whole team): for
    :func:`heard_in`."""
    return [(float(e.stamp), e.observer, e.target) for e in events if isinstance(e, Detection)
            and e.target_is_robot and e.target is not None]  # fmt: skip


def detected_pairs(events: Iterable[Any]) -> set[tuple[int, int]]:
    """``(observer, target)`` of the robot detections among ``events`` (a recording of the whole team): for
    :func:`watched`."""
    return {(o, t) for _, o, t in timed_detections(events)}


class Lockstep:
    """Part of :class:`~swarmloc.net.process.NetNode` (``node.lockstep``): the teammates' progress and the rules of
    when to read an input, answer a query and release an answer (module docstring), for robot ``robot`` of
    ``roster`` driving ``node``.

    ``next_key``: ``(stamp, priority)`` of the node's next own input (:meth:`~.inputs.Inputs.next_key`);
    ``step``: ``step(item, query=None)`` steps the node and carries what it returns (:meth:`~.process.NetNode._step`);
    ``others``: why a teammate's broadcast keyed before a key may still be missing, or None
    (:meth:`~.broadcast.Broadcaster.unsettled`); ``counts``: the node's network counters; ``watched``: the
    teammates it waits for (:func:`watched`; None: all)."""

    def __init__(self, node: Node, robot: int, roster: frozenset[int], settings: NetSettings, counts: Counter[str], *,
                 next_key: Callable[[], tuple[float, int]], step: Callable[..., None],
                 others: Callable[[Key], str | None], watched: frozenset[int] | None = None) -> None:  # fmt: skip
        self.node, self.robot, self.roster, self.settings, self.counts = node, robot, roster, settings, counts
        self.next_key, self.step, self.others, self.watched = next_key, step, others, watched
        self.progress: dict[int, float] = {}
        """Per live teammate: the stamp of its next input."""
        self._progress_key: dict[int, tuple[float, int]] = {}  # ... and its priority
        self.done: set[int] = set()
        """Teammates that announced they are done."""
        self.alive: set[int] = set()
        """Teammates whose liveliness token is up (and not declared lost)."""
        self.lost: set[int] = set()
        """Teammates declared lost while waited for: silent, or stalled (:meth:`check_lost`)."""
        self.lost_why: dict[int, str] = {}
        """... why, as the "not found" answers to queries to them say."""
        self._lost_silent: set[int] = set()  # ... of them, those declared for silence (back on any announcement)
        self._heard: dict[int, float] = {}  # per live teammate: wall time its progress last advanced (or it came)
        self._beat: dict[int, float] = {}  # per live teammate: wall time of its last announcement (repeated or not)
        self._moved: dict[int, int] = {}  # per teammate: the ``moved`` of its last announcement
        self.moved = 0
        """How many times the progress of a teammate this node waits for advanced while behind its next input
        (modulo :data:`~swarmloc.net.schema.MAX_MOVED`): announced with its progress (``Progress.moved``)."""
        self.seen: set[int] = set()
        """Teammates ever seen alive or heard from."""
        self.server_up = False
        """The belief server's liveliness token is up."""
        self.deferred: list[tuple[float, Message, Any]] = []
        """Neighbours' queries held: ``(since, query, Zenoh query)``."""
        self.expect: dict[Key, float] = {}
        """Pairwise updates expected, by key: since when."""
        self.held: list[Message] = []
        """Answers to this node's queries not yet given to it."""
        self._queries_seen: OrderedDict[Key, None] = OrderedDict()  # neighbours' queries held or answered (bounded)
        self._awaiting: dict[str, float] = {}  # what the node awaits for its boundaries (Node.awaits): since when
        self._given_up: set[str] = set()  # ... and what it went on without

    def on_progress(self, p: Any) -> None:
        """A teammate's progress announcement (authenticated): how far it has read its source (and whether it is
        done)."""
        if isinstance(p, Progress) and p.robot != self.robot:
            self.counts["progress_received"] += 1
            r, old = p.robot, self._progress_key.get(p.robot, (-math.inf, 0))
            self.seen.add(r)
            now = time.monotonic()
            self._beat[r] = now
            chain = self._moved.get(r, p.moved) != p.moved
            self._moved[r] = p.moved
            if (p.t, p.prio) > old or (p.done and r not in self.done):
                self._heard[r] = now
                if (self.watched is None or r in self.watched) and old < self.next_key():
                    self.moved = (self.moved + 1) % MAX_MOVED
                if r in self.lost:
                    self._found(r, "it announced progress again")
            else:
                if chain:  # it waits, and what it waits on moved: not stalled (check_lost)
                    self._heard[r] = now
                    self.counts["stall_clock_chain_moved"] += 1
                if r in self._lost_silent:
                    self._found(r, "it announces again (waiting, not hung)")
            self.progress[r] = max(self.progress.get(r, -math.inf), p.t)
            self._progress_key[r] = max(old, (p.t, p.prio))
            if p.done:
                self.done.add(r)

    def check_lost(self, s: float) -> None:
        """Declare lost every live teammate this node waits for (not done, its source read only to before ``s``)
        that is **silent** (no announcement, not even a repeated one, for ``lost_timeout`` s: a process that hangs,
        or a token that outlived its process) or **stalled** (announcing, but its progress has not advanced for
        ``STALL_TIMEOUTS`` lost timeouts). A node waiting announces its unchanged progress every 0.2 s, so a
        teammate that waits legitimately (for answers lost on the link, asked again) is neither: before, its
        progress not advancing for ``lost_timeout`` s was read as hung. **A teammate is not stalled while what it
        waits on moves**: its announcement carries ``moved`` (:attr:`moved`: how many times the progress of a
        teammate it waits for advanced while behind its next input), and a change of it restarts the teammate's
        stall clock as an advance would (counted ``stall_clock_chain_moved``), so the clock measures nothing moving
        in the whole chain of waits. Before, a node waiting at a cluster boundary for a slow new mate whose
        progress advanced was declared stalled by its other mates, who do not hear that mate; its late broadcasts
        then set off a cascade of re-broadcasts. A teammate whose chain does not move either is still stalled after
        the same time, a silent one after ``lost_timeout``. The node goes on without a lost teammate
        (counted ``peers_lost``, logged); its queries to it are answered "not found" at once. It is back if it
        announces progress again (a silent one: if it announces at all) or its token comes anew."""
        now = time.monotonic()
        stall = STALL_TIMEOUTS * self.settings.lost_timeout
        for r in sorted(self.waited()):
            if r in self.done or self.progress.get(r, -math.inf) >= s:
                continue
            quiet, still = now - self._beat.setdefault(r, now), now - self._heard.setdefault(r, now)
            silent = quiet > self.settings.lost_timeout
            if silent or still > stall:
                why = f"silent for {self.settings.lost_timeout:g} s" if silent else f"no progress for {stall:g} s"
                self.alive.discard(r)
                self.lost.add(r)
                self.lost_why[r] = why
                if silent:
                    self._lost_silent.add(r)
                self.counts["peers_lost_silent" if silent else "peers_lost_stalled"] += 1
                self.counts["peers_lost"] += 1
                log.warning("robot %s: robot %s declared lost: %s (its source read only to %.3f s, last announced "
                            "%.1f s ago, progress %.1f s ago); going on without it", self.robot, r, why,
                            self.progress.get(r, -math.inf), quiet, still)  # fmt: skip

    def _found(self, r: int, why: str) -> None:
        """A teammate declared lost is back: lockstep waits for it again."""
        self.lost.discard(r)
        self.lost_why.pop(r, None)
        self._lost_silent.discard(r)
        self.alive.add(r)
        self.counts["peers_back"] += 1
        log.warning("robot %s: robot %s, declared lost, is back: %s", self.robot, r, why)

    def first_copy(self, env: Envelope) -> bool:
        """False for a copy of a neighbour's query this node already holds or answered (the same sender, sequence
        number and query: link faults duplicate them), so that each query is answered once (counted
        ``duplicate_queries``). The last 4096 queries are remembered."""
        q = cast(Message, env.body)  # a neighbour's query (Inbound)
        key = (env.from_robot, env.seq, type(q).__name__, float(q.stamp), tuple(q.sub))
        if key in self._queries_seen:
            self.counts["duplicate_queries"] += 1
            return False
        self._queries_seen[key] = None
        if len(self._queries_seen) > 4096:
            self._queries_seen.popitem(last=False)
        return True

    def defer(self, q: Message, zq: Any) -> bool:
        """Hold a neighbour's query ``q`` (its Zenoh query ``zq``) until it may be answered (:meth:`answer_ready`);
        False (not held) past :data:`MAX_HELD_FROM` of its robot or :data:`MAX_HELD` in all."""
        asker = q.sender
        if len(self.deferred) >= MAX_HELD or sum(d.sender == asker for _, d, _ in self.deferred) >= MAX_HELD_FROM:
            return False
        self.deferred.append((time.monotonic(), q, zq))
        return True

    def expect_update(self, key: Key) -> None:
        """This node gave its state to an observer: its update (or "no update") keyed ``key`` is expected."""
        self.expect[key] = time.monotonic()

    def update_came(self, key: Key) -> bool:
        """A pairwise update keyed ``key`` came (or a teammate's broadcast of it): whether it was expected."""
        return self.expect.pop(key, None) is not None

    def answer_came(self, a: Message) -> None:
        """An answer to one of this node's queries: held until it may be given to the node (:meth:`release`)."""
        self.held.append(a)
        self.release()

    def on_alive(self, x: Any) -> None:
        """A teammate's liveliness token came or went: lockstep waits only for live teammates."""
        import zenoh

        key = str(x.key_expr)
        if key.endswith("/alive/server"):  # the belief server (its subscribers are declared before its token)
            self.server_up = x.kind == zenoh.SampleKind.PUT
            return
        r = robot_of(key)
        if r is None or r == self.robot:
            return
        if r not in self.roster:
            self.counts["alive_outside_roster"] += 1
            return
        if x.kind == zenoh.SampleKind.PUT:
            self.seen.add(r)
            self._heard[r] = self._beat[r] = time.monotonic()
            if r in self.lost:
                self._found(r, "its token came anew")
            self.alive.add(r)
            self.done.discard(r)
        else:
            self.alive.discard(r)
            self.lost.discard(r)
            self.lost_why.pop(r, None)
            self._lost_silent.discard(r)
            self.progress.pop(r, None)
            self._progress_key.pop(r, None)
            self.counts["peers_left"] += 1

    def watch(self, robots: frozenset[int]) -> None:
        """Watch ``robots`` from now on (:class:`~.hearing.Hearing`: the schedule's cut changed); one watched anew is
        not judged silent or stalled by what was heard of it before."""
        for r in robots - (self.watched or frozenset()):
            self._beat.pop(r, None)
            self._heard.pop(r, None)
        self.watched = robots

    def waited(self) -> set[int]:
        """The live teammates lockstep waits for: :attr:`alive`, those of :attr:`watched` only."""
        return self.alive if self.watched is None else self.alive & self.watched

    def all_read(self) -> bool:
        """Every live teammate waited for has read its source (or is done)."""
        return all(self.progress.get(r, -math.inf) == math.inf or r in self.done for r in self.waited())

    def busy(self) -> bool:
        """Queries held, updates expected or answers held."""
        return bool(self.deferred or self.expect or self.held)

    def may_feed(self, s: float) -> bool:
        """Lockstep: every live teammate waited for (:meth:`waited`) has read its source to ``s - lag``; and this
        node's oldest detection group still waiting for answers is less than half a horizon before ``s`` (reading on
        would push it beyond the horizon before its answers or their timeout come)."""
        self.reach(s)
        first = self.node.first_pending
        if first is not None and s - first[0] > self.node.horizon / 2:
            return False
        need = s - self.settings.lag
        for r in self.waited():
            if r not in self.done and self.progress.get(r, -math.inf) < need:
                return False
        return True

    def group_may_go(self, s: float) -> bool:
        """A detection group (key ``(s, 1, robot)``) is read once every live teammate waited for has read its source
        up to ``s`` (their exchanges keyed before it have started) and no pairwise update keyed before it is still
        expected, so that groups are applied across the team in key order, as the in-process runner does, and an
        update never has to be replayed under a group applied before it."""
        key = (s, 1, self.robot, ())
        if any(k < key for k in self.expect) or self.others(key) is not None or not self.boundaries_in(s):
            return False
        return all(r in self.done or (*self._progress_key.get(r, (-math.inf, 0)), r) > key[:3] for r in self.waited())

    def reach(self, s: float) -> None:
        """A node with planned boundaries (``diekf``'s re-forming clusters, :meth:`~swarmloc.node.base.Node.boundary`)
        reaches each one up to ``s`` (its next input's stamp) once nothing keyed before the boundary's key ``(T, 0,
        -1)`` can still come: no own group before it waits for answers, and the rule of :meth:`group_may_go` holds
        there. Reached then, not at the node's next input, it sends its pieces while the teammates that need them
        wait (each waiting for the other's piece, two robots would wait for ever)."""
        T = self.node.boundary()
        while T is not None and T <= s:
            key = (T, 0, -1, ())
            first = self.node.first_pending
            if (first is not None and first < key) or any(k < key for k in self.expect) or self.others(key):
                return
            if not all(r in self.done or (*self._progress_key.get(r, (-math.inf, 0)), r) > key[:3]
                       for r in self.waited()):  # fmt: skip
                return
            self.step(Reach(T))
            T = self.node.boundary()

    def boundaries_in(self, s: float) -> bool:
        """The node has what it awaits for its boundaries up to ``s`` (its new mates' pieces,
        :meth:`~swarmloc.node.base.Node.awaits`), or waited ``update_timeout`` s for it (counted
        ``boundary_not_received``: the node goes on without, and re-applies the boundary if it comes)."""
        why = self.node.awaits(s)
        if why is None or why in self._given_up:
            return True
        since = self._awaiting.setdefault(why, time.monotonic())
        if time.monotonic() - since <= self.settings.update_timeout:
            return False
        self._given_up.add(why)
        self.counts["boundary_not_received"] += 1
        log.warning("robot %s: going on without %s", self.robot, why)
        return True

    def ready(self, q: Message, since: float) -> bool:
        """A query is answered once nothing this node will still read or apply is keyed before it: its source has
        passed the query's key, no earlier detection group waits, no pairwise update it expects is keyed earlier,
        and every live teammate waited for has read its source past the stamp (so no earlier exchange can still
        start). Then the first answer is the final one and no revision follows (without faults). Held
        ``hold_timeout`` s, it is answered whatever the state (a revision follows if needed)."""
        qkey = (float(q.stamp), 1, q.sender, tuple(q.sub))
        why = self.unsettled(qkey)
        if why is None:
            return True
        if time.monotonic() - since < self.settings.hold_timeout:
            return False
        self.counts["answered_unsettled"] += 1
        log.debug("robot %s: answering %s at %s unsettled: %s", self.robot, type(q).__name__, qkey, why)
        return True

    def unsettled(self, qkey: Key) -> str | None:
        """What may still change the state before ``qkey``, or None."""
        s, prio = self.next_key()  # the key of the next own input (a lower bound of it with a live feed)
        if (s, prio, self.robot, ()) < qkey:
            return f"own source at {(s, prio)}"
        early = [k for k in self.expect if k < qkey]
        if early:
            return f"expects updates at {early[:3]}"
        why = self.others(qkey)
        if why is not None:
            return why
        for r in self.waited():  # a teammate whose next input is keyed before the query may still start an exchange
            if r not in self.done:
                t, prio = self._progress_key.get(r, (-math.inf, 0))
                if (t, prio, r) < qkey[:3]:
                    return f"robot {r} has read its source only to {(t, prio)}"
        first = self.node.first_pending
        if first is not None and first < qkey:
            return f"own detection group {first} waits for answers"
        return None

    def answer_ready(self) -> None:
        """Answer the held queries that are ready (:meth:`ready`), in the order they came."""
        if not self.deferred:
            return
        keep = []
        for since, q, zq in self.deferred:
            if self.ready(q, since):
                self.step(q, query=zq)
            else:
                keep.append((since, q, zq))
        self.counts["queries_answered"] += len(self.deferred) - len(keep)
        self.deferred = keep

    def release(self) -> None:
        """Give the node the answers to its own detection groups once no pairwise update keyed before the group is
        still expected (so the group is applied after it, not replayed under it); an expected update that does not
        come within ``update_timeout`` s is given up (counted ``update_not_received``)."""
        if self.expect:
            now = time.monotonic()
            for k, since in list(self.expect.items()):
                if now - since > self.settings.update_timeout:
                    del self.expect[k]
                    self.counts["update_not_received"] += 1
        if not self.held:
            return
        keep = []
        for a in self.held:
            key = (float(a.stamp), 1, self.robot, ())
            if any(k < key for k in self.expect):
                keep.append(a)
            else:
                self.step(a)
        self.held = keep
