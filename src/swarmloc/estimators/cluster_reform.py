"""``diekf`` clusters that re-form as the robots move (:mod:`swarmloc.estimators.diekf`, "Clusters that re-form"):
the membership schedule, a pure function of a recording, and the covariance-intersection bound a new cluster starts
from. The nodes and the centralized prototype (``benchmarks/diekf_reform.py``) share them.

**Schedule** (:func:`seen_schedule`, :class:`Schedule`). The team is first cut into clusters of ``K`` robots in id
order; at every boundary ``T = start + k period`` (``k >= 1``, up to the recording's last stamp) it is cut again by
:func:`seen_cut` from the robot detections stamped in ``[T - period, T)``. Only the recording's detections decide, not
an estimate, so every node computes the same schedule (as :func:`swarmloc.net.lockstep.watched` does with the
detected pairs); a live source has none (its clusters stay fixed).

**The bound** (:func:`stacked_bound`). A new cluster is made of pieces of ``m`` old clusters (a piece: the robots of
one old cluster in it). The pieces' joint covariance is known inside each piece (the old cluster's exact one) but
not across them; ``blockdiag(P_1 / w_1, ..., P_m / w_m)`` with ``w_k > 0``, ``sum w = 1`` bounds it whatever the
correlation across (covariance intersection, Julier & Uhlmann 1997), keeping each piece's own correlations. The
weights are the pieces' sizes to ``power`` (:func:`piece_weights`; 1: the bound's log det minimized); a cluster of
one piece keeps its covariance (``w = 1``), a robot that leaves is marginalized out.

**In the node** (:class:`Reforming`, a part of :class:`~swarmloc.estimators.diekf.DistributedInvariantEKF`): each
boundary is a history entry (:class:`Boundary`) keyed before every input stamped at it, filed before the first
input at or after it; the new mates' pieces (:class:`~swarmloc.messages.ClusterPiece`) are kept in it as they come,
and it is re-applied with each.
"""

from __future__ import annotations

import itertools
import math
from bisect import bisect_right
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from swarmloc.events import Detection
from swarmloc.messages import ClusterPiece, Message, message_problem
from swarmloc.node.keys import Entry, Key
from swarmloc.node.protocol import same

__all__ = [
    "MAX_BOUNDARIES", "P_REFORM", "Boundary", "Cut", "Pieces", "Reforming", "Schedule", "id_cut", "piece_weights",
    "seen_cut", "seen_schedule", "stacked_bound",
]  # fmt: skip

P_REFORM = 0
"""The priority of a re-forming's history entry ``(T, P_REFORM, -1, ())``: before every input stamped ``T``
(:mod:`swarmloc.node.keys`: groups 1, commands 2)."""

MAX_BOUNDARIES = 100_000
"""The most re-formings a schedule may hold (a period of 0.01 s over 1,000 s of recording)."""

Cut = tuple[tuple[int, ...], ...]
"""The team cut into clusters: each cluster's robot ids, in its replica's order."""


@dataclass(frozen=True)
class Schedule:
    """The team's cuts over time: ``cuts[0]`` from the start, ``cuts[k]`` from boundary ``times[k - 1]`` [s] on
    (``times`` increasing; an input stamped exactly at a boundary belongs to the new cut)."""

    times: tuple[float, ...]
    cuts: tuple[Cut, ...]

    def __post_init__(self) -> None:
        if len(self.cuts) != len(self.times) + 1 or any(b <= a for a, b in itertools.pairwise(self.times)):
            raise ValueError("Schedule: one cut more than boundaries, boundaries increasing")

    def period(self, t: float) -> int:
        """The index of the cut in force at stamp ``t`` [s]."""
        return bisect_right(self.times, t)

    def cluster(self, robot: int, k: int) -> tuple[int, ...]:
        """Robot ``robot``'s cluster in cut ``k``."""
        return next(g for g in self.cuts[k] if robot in g)


def id_cut(robots: Iterable[int], K: int) -> Cut:
    """The team cut into clusters of ``K`` robots in id order (``diekf``'s fixed clusters)."""
    ids = sorted(robots)
    return tuple(tuple(ids[a : a + K]) for a in range(0, len(ids), K))


def seen_cut(cut: Sequence[Sequence[int]], seen: Mapping[tuple[int, int], float], K: int,
             margin: float = 2.0) -> Cut:  # fmt: skip
    """The clusters ``cut`` kept but for the robots that saw (or were seen by) the robots of another cluster more
    than ``margin`` times as often as their own's, plus one (``seen[a, b]``: detections between ``a`` and ``b``,
    either way): such a robot moves to that cluster if it has room (fewer than ``3K / 2`` robots) and its own keeps
    one. Robots with the largest gain ``c_best - margin (c_own + 1)`` first (ties: lower id), counts as they stand (a
    move changes the others'); a moved robot joins its new cluster's end; empty clusters are dropped."""
    groups = [list(g) for g in cut]
    own = {r: k for k, g in enumerate(groups) for r in g}

    def counts(r: int) -> list[float]:
        return [float(sum(seen.get((r, b), 0) for b in g)) for g in groups]

    def gain(r: int) -> float:
        c = counts(r)
        return max(c) - margin * (c[own[r]] + 1)

    for r in sorted(own, key=lambda r: (-gain(r), r)):
        c, k = counts(r), own[r]
        best = max(range(len(groups)), key=lambda q: (c[q], -q))
        if best != k and c[best] > margin * (c[k] + 1) and len(groups[best]) < K + K // 2 and len(groups[k]) > 1:
            groups[k].remove(r)
            groups[best].append(r)
            own[r] = best
    return tuple(tuple(g) for g in groups if g)


def seen_schedule(events: Iterable[Any], robots: Iterable[int], K: int, period: float, margin: float = 2.0,
                  start: float | None = None) -> Schedule:  # fmt: skip
    """The schedule of a recording's team (module docstring): clusters of ``K`` in id order, cut again every
    ``period`` [s] > 0 from ``start`` (default: the earliest stamp) by :func:`seen_cut` with ``margin``."""
    if not (period > 0 and math.isfinite(period)):
        raise ValueError(f"seen_schedule: period must be a positive number of seconds, got {period!r}")
    events = list(events)
    stamps = [float(e.stamp) for e in events]
    dets = sorted((float(e.stamp), int(e.observer), int(e.target)) for e in events
                  if isinstance(e, Detection) and e.target_is_robot and e.target is not None)  # fmt: skip
    cut = id_cut(robots, K)
    times: list[float] = []
    cuts = [cut]
    t0 = min(stamps, default=0.0) if start is None else float(start)
    end, k, q = max(stamps, default=t0), 1, 0
    if (end - t0) / period > MAX_BOUNDARIES:  # bounded before the loop: a tiny period over a long recording
        raise ValueError(f"seen_schedule: a period of {period!r} s over {end - t0:.6g} s of recording makes more than "
                         f"{MAX_BOUNDARIES} re-formings: take a longer period")  # fmt: skip
    while t0 + k * period <= end:
        T = t0 + k * period
        seen: Counter[tuple[int, int]] = Counter()
        while q < len(dets) and dets[q][0] < T:
            _, a, b = dets[q]
            seen[a, b] += 1
            seen[b, a] += 1
            q += 1
        cut = seen_cut(cut, seen, K, margin)
        times.append(T)
        cuts.append(cut)
        k += 1
    return Schedule(tuple(times), tuple(cuts))


def piece_weights(sizes: Sequence[int], power: float = 1.0) -> list[float]:
    """The covariance-intersection weights of pieces of ``sizes`` robots: ``s_k^power / sum s^power`` (one piece:
    1)."""
    p = [s**power for s in sizes]
    tot = sum(p)
    return [x / tot for x in p]


def stacked_bound(cluster: Sequence[int], old: Mapping[int, Any], block: Callable[[int, int], np.ndarray], dim: int,
                  power: float = 1.0) -> np.ndarray:  # fmt: skip
    """The blocks ``(n, n, dim, dim)`` (robots in ``cluster``'s order) of the covariance a new cluster starts from
    (module docstring): ``block(a, b) / w`` for ``a``, ``b`` of one piece (``old[a] == old[b]``, its weight ``w``,
    :func:`piece_weights` of the pieces' sizes), zero across pieces."""
    sizes = Counter(old[r] for r in cluster)
    keys = list(sizes)
    w = dict(zip(keys, piece_weights([sizes[c] for c in keys], power), strict=True))
    n = len(cluster)
    out = np.zeros((n, n, dim, dim))
    for ka, a in enumerate(cluster):
        for kb, b in enumerate(cluster):
            if old[a] == old[b]:
                out[ka, kb] = block(a, b) / w[old[a]]
    return out


@dataclass(slots=True)
class Boundary:
    """A re-forming's history entry (key ``(t, P_REFORM, -1, ())``): the schedule's boundary ``k`` at ``t`` [s], the
    pieces received for it so far (by sender), and this robot's own as last sent (by receiver) with the state before
    the boundary they were made from."""

    k: int
    t: float
    pieces: dict[int, ClusterPiece] = field(default_factory=dict)
    sent: dict[int, Message] = field(default_factory=dict)
    before: Any = None


class Pieces(Protocol):
    """What :class:`Reforming` asks of its node's team protocol
    (:class:`~swarmloc.estimators.team_protocol.TeamProtocol`): this robot's pieces for a boundary ``k`` from the
    state before it, the mates that owe it one, why a received piece is not one they owe, and the state re-formed at
    a boundary."""

    def pieces(self, s: Any, k: int, t: float) -> list[Message]: ...
    def owed(self, k: int) -> set[int]: ...
    def piece_problem(self, m: ClusterPiece) -> str | None: ...
    def reform(self, s: Any, k: int, pieces: Mapping[int, ClusterPiece]) -> Any: ...


class Reforming:
    """Part of a ``diekf`` node whose clusters re-form (:mod:`swarmloc.estimators.diekf`, "Clusters that re-form"):
    files each boundary of the schedule in the history before the first input stamped at or after it, sends this
    robot's pieces (again, revised, when a late input changed the state before the boundary: :meth:`revise`), and
    takes its new mates' pieces (the boundary's entry re-applied with each). Made with the node's protocol, the
    schedule, the node's history, its filing's ``file`` and ``replay``, and its accounting."""

    def __init__(self, protocol: Pieces, schedule: Schedule, history: Any, file: Callable[..., list[Message]],
                 replay: Callable[..., list[Message]], accounting: Any) -> None:  # fmt: skip
        self.protocol, self.schedule, self.history = protocol, schedule, history
        self.file, self.replay, self.accounting = file, replay, accounting
        self.next = 0
        """The index of the next boundary to reach."""
        self.owed: dict[int, set[int]] = {}
        """Per boundary reached (index ``k``): the new mates whose pieces have not come yet."""
        self.filed: list[Boundary] = []
        """The boundaries filed in the history (those before its base are forgotten)."""

    def boundary(self) -> float | None:
        """The stamp [s] of the next boundary to reach (None: all reached)."""
        return self.schedule.times[self.next] if self.next < len(self.schedule.times) else None

    def awaits(self, t: float) -> str | None:
        """The pieces owed for the boundaries reached up to ``t`` [s], or None."""
        for k, who in self.owed.items():
            if who and self.schedule.times[k - 1] <= t:
                return f"the pieces of robots {sorted(who)} for the clusters re-formed at {self.schedule.times[k - 1]}"
        return None

    def reach(self, stamp: float) -> list[Message]:
        """File every boundary up to ``stamp`` [s] not filed yet (the state before it final: every input before it
        has come, as in the in-process runner and the lock step) and send this robot's pieces for it."""
        out: list[Message] = []
        times = self.schedule.times
        while self.next < len(times) and times[self.next] <= stamp:
            t, k = times[self.next], self.next + 1
            self.next += 1
            key: Key = (t, P_REFORM, -1, ())
            if self.history.base_key is not None and key < self.history.base_key:  # before the node's start
                self.history.base = self.protocol.reform(self.history.base, k, {})  # (nobody's piece taken)
                continue
            b = Boundary(k, t)
            out += self.file([Entry(key, "update", b)], accept=False)
            self.filed.append(b)
            out += self.send(b)
            self.owed[k] = self.protocol.owed(k)
        return out

    def send(self, b: Boundary) -> list[Message]:
        """This robot's pieces for boundary ``b`` from the state before it, those that differ from what it sent."""
        b.before = self.history.state_before((b.t, P_REFORM, -1, ()))
        new = {m.receiver: m for m in self.protocol.pieces(b.before, b.k, b.t)}
        out = [m for r, m in new.items() if not same(b.sent.get(r), m)]
        b.sent.update({m.receiver: m for m in out})
        return out

    def revise(self) -> list[Message]:
        """The pieces of every boundary kept whose state before it changed since they were sent (a late input before
        the boundary: a network driver may reach a boundary before every input before it is in), revised."""
        base = self.history.base_key
        self.filed = [b for b in self.filed if base is None or (b.t, P_REFORM, -1, ()) > base]
        out: list[Message] = []
        for b in self.filed:
            if self.history.state_before((b.t, P_REFORM, -1, ())) is not b.before:
                out += self.send(b)
        return out

    def take(self, m: ClusterPiece) -> list[Message]:
        """A new mate's piece: kept in its boundary's entry, which is applied again (and what follows it)."""
        self.accounting.counts["messages"] += 1
        why = message_problem(m) or self.protocol.piece_problem(m)
        pos = None if why else self.history.find((float(m.stamp), P_REFORM, -1, ()))
        if why is None and pos is None:
            why = "cluster piece for a re-forming not in the kept history"
        if why is not None or pos is None:
            self.accounting.message_rejected(why or "")
            return []
        b: Boundary = self.history.entries[pos].data
        if b.pieces.get(m.sender) == m:
            self.accounting.message_rejected("duplicate cluster piece")
            return []
        b.pieces[m.sender] = m
        self.owed.get(b.k, set()).discard(m.sender)
        self.accounting.counts["pieces_received"] += 1
        return self.replay(pos, late=False)
