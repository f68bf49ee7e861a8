"""The order of a :class:`~swarmloc.net.process.NetNode`: what makes the networked run equal the in-process one.

A node reads its next input once every live teammate has announced that it has read its own source up to
``lag`` s before it (:meth:`_may_feed`), and a detection group once every teammate has read up to the group's key
and no pairwise update keyed before it is expected (:meth:`_group_may_go`). It answers a query once nothing keyed
before it can still change the answer (:meth:`_ready`), and gives its own detection groups their answers once no
update keyed before them is expected (:meth:`_release`). Teammates are known from their liveliness tokens and
progress announcements (:meth:`_on_alive`, :meth:`_on_progress`).
"""

from __future__ import annotations

import logging
import math
import time
from collections import OrderedDict
from typing import Any, cast

from swarmloc.messages import Message
from swarmloc.net.auth import open_envelope
from swarmloc.net.outbound import key_of
from swarmloc.net.parts import NodeParts
from swarmloc.net.schema import Envelope, Progress, Rejected
from swarmloc.net.timeouts import STALL_TIMEOUTS
from swarmloc.net.transport import robot_of

log = logging.getLogger("swarmloc.net.process")  # the driver's one logger, whichever part logs


class Lockstep(NodeParts):
    """Part of :class:`~swarmloc.net.process.NetNode`: the teammates' progress and the rules of when to read an
    input, answer a query and release an answer."""

    def _init_lockstep(self) -> None:
        self._progress: dict[int, float] = {}  # per live teammate: the stamp of its next input
        self._progress_key: dict[int, tuple[float, int]] = {}  # ... and its priority
        self._done: set[int] = set()  # teammates that announced they are done
        self._alive: set[int] = set()  # teammates whose liveliness token is up (and not declared lost)
        self._lost: set[int] = set()  # teammates declared lost while waited for: silent, or stalled (see _check_lost)
        self._lost_why: dict[int, str] = {}  # ... why, as the "not found" answers to queries to them say
        self._lost_silent: set[int] = set()  # ... of them, those declared for silence (back on any announcement)
        self._heard: dict[int, float] = {}  # per live teammate: wall time its progress last advanced (or it came)
        self._beat: dict[int, float] = {}  # per live teammate: wall time of its last announcement (repeated or not)
        self._seen: set[int] = set()  # teammates ever seen alive or heard from
        self._server_up = False  # the belief server's liveliness token is up
        self._deferred: list[tuple[float, Message, Any]] = []  # neighbours' queries held: (since, query, Zenoh query)
        self._expect: dict[tuple, float] = {}  # pairwise updates expected, by key: since when
        self._held: list[Message] = []  # answers to this node's queries not yet given to it
        self._queries_seen: OrderedDict[tuple, None] = OrderedDict()  # neighbours' queries held or answered (bounded)

    def _on_progress(self, x: Any) -> None:
        """A teammate's progress announcement: how far it has read its source (and whether it is done)."""
        try:
            env = open_envelope(self.auth, key_of(x), x.payload.to_bytes(), self.team, self.roster, server_ok=False,
                                publication=True)  # fmt: skip
        except Rejected as exc:
            self._refuse(exc, "progress message")
            return
        p = env.body
        if isinstance(p, Progress) and p.robot != self.robot:
            r, old = p.robot, self._progress_key.get(p.robot, (-math.inf, 0))
            self._seen.add(r)
            now = time.monotonic()
            self._beat[r] = now
            if (p.t, p.prio) > old or (p.done and r not in self._done):
                self._heard[r] = now
                if r in self._lost:
                    self._found(r, "it announced progress again")
            elif r in self._lost_silent:
                self._found(r, "it announces again (waiting, not hung)")
            self._progress[r] = max(self._progress.get(r, -math.inf), p.t)
            self._progress_key[r] = max(old, (p.t, p.prio))
            if p.done:
                self._done.add(r)

    def _check_lost(self, s: float) -> None:
        """Declare lost every live teammate this node waits for (not done, its source read only to before ``s``)
        that is **silent** (no announcement, not even a repeated one, for ``lost_timeout`` s: a process that hangs,
        or a token that outlived its process) or **stalled** (announcing, but its progress has not advanced for
        ``STALL_TIMEOUTS`` lost timeouts). A node waiting announces its unchanged progress every 0.2 s, so a
        teammate that waits legitimately (for answers lost on the link, asked again) is neither: before, its
        progress not advancing for ``lost_timeout`` s was read as hung. The node goes on without a lost teammate
        (counted ``peers_lost``, logged); its queries to it are answered "not found" at once. It is back if it
        announces progress again (a silent one: if it announces at all) or its token comes anew."""
        now = time.monotonic()
        stall = STALL_TIMEOUTS * self.settings.lost_timeout
        for r in sorted(self._alive):
            if r in self._done or self._progress.get(r, -math.inf) >= s:
                continue
            quiet, still = now - self._beat.setdefault(r, now), now - self._heard.setdefault(r, now)
            silent = quiet > self.settings.lost_timeout
            if silent or still > stall:
                why = f"silent for {self.settings.lost_timeout:g} s" if silent else f"no progress for {stall:g} s"
                self._alive.discard(r)
                self._lost.add(r)
                self._lost_why[r] = why
                if silent:
                    self._lost_silent.add(r)
                self.counts["peers_lost_silent" if silent else "peers_lost_stalled"] += 1
                self.counts["peers_lost"] += 1
                log.warning("robot %s: robot %s declared lost: %s (its source read only to %.3f s, last announced "
                            "%.1f s ago, progress %.1f s ago); going on without it", self.robot, r, why,
                            self._progress.get(r, -math.inf), quiet, still)  # fmt: skip

    def _found(self, r: int, why: str) -> None:
        """A teammate declared lost is back: lockstep waits for it again."""
        self._lost.discard(r)
        self._lost_why.pop(r, None)
        self._lost_silent.discard(r)
        self._alive.add(r)
        self.counts["peers_back"] += 1
        log.warning("robot %s: robot %s, declared lost, is back: %s", self.robot, r, why)

    def _first_copy(self, env: Envelope) -> bool:
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

    def _on_alive(self, x: Any) -> None:
        """A teammate's liveliness token came or went: lockstep waits only for live teammates."""
        import zenoh

        key = str(x.key_expr)
        if key.endswith("/alive/server"):  # the belief server (its subscribers are declared before its token)
            self._server_up = x.kind == zenoh.SampleKind.PUT
            return
        r = robot_of(key)
        if r is None or r == self.robot:
            return
        if r not in self.roster:
            self.counts["alive_outside_roster"] += 1
            return
        if x.kind == zenoh.SampleKind.PUT:
            self._seen.add(r)
            self._heard[r] = self._beat[r] = time.monotonic()
            if r in self._lost:
                self._found(r, "its token came anew")
            self._alive.add(r)
            self._done.discard(r)
        else:
            self._alive.discard(r)
            self._lost.discard(r)
            self._lost_why.pop(r, None)
            self._lost_silent.discard(r)
            self._progress.pop(r, None)
            self._progress_key.pop(r, None)
            self.counts["peers_left"] += 1

    def _may_feed(self, s: float) -> bool:
        """Lockstep: every live teammate has read its source to ``s - lag``; and this node's oldest detection group
        still waiting for answers is less than half a horizon before ``s`` (reading on would push it beyond the
        horizon before its answers or their timeout come)."""
        first = self.node.first_pending
        if first is not None and s - first[0] > self.node.horizon / 2:
            return False
        need = s - self.settings.lag
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
        if any(k < key for k in self._expect) or self._broadcasts_unsettled(key) is not None:
            return False
        return all(r in self._done or (*self._progress_key.get(r, (-math.inf, 0)), r) > key[:3] for r in self._alive)

    def _ready(self, q: Message, since: float) -> bool:
        """A query is answered once nothing this node will still read or apply is keyed before it: its source has
        passed the query's key, no earlier detection group waits, no pairwise update it expects is keyed earlier,
        and every live teammate has read its source past the stamp (so no earlier exchange can still start). Then
        the first answer is the final one and no revision follows (without faults). Held ``hold_timeout`` s, it is
        answered whatever the state (a revision follows if needed)."""
        qkey = (float(q.stamp), 1, q.sender, tuple(q.sub))
        why = self._unsettled(qkey)
        if why is None:
            return True
        if time.monotonic() - since < self.settings.hold_timeout:
            return False
        self.counts["answered_unsettled"] += 1
        log.debug("robot %s: answering %s at %s unsettled: %s", self.robot, type(q).__name__, qkey, why)
        return True

    def _unsettled(self, qkey: tuple) -> str | None:
        """What may still change the state before ``qkey``, or None."""
        s, prio = self._next_key()  # the key of the next own input (a lower bound of it with a live feed)
        if (s, prio, self.robot, ()) < qkey:
            return f"own source at {(s, prio)}"
        early = [k for k in self._expect if k < qkey]
        if early:
            return f"expects updates at {early[:3]}"
        why = self._broadcasts_unsettled(qkey)
        if why is not None:
            return why
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
        """Answer the held queries that are ready (:meth:`_ready`), in the order they came."""
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

    def _release(self) -> None:
        """Give the node the answers to its own detection groups once no pairwise update keyed before the group is
        still expected (so the group is applied after it, not replayed under it); an expected update that does not
        come within ``update_timeout`` s is given up (counted ``update_not_received``)."""
        if self._expect:
            now = time.monotonic()
            for k, since in list(self._expect.items()):
                if now - since > self.settings.update_timeout:
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
