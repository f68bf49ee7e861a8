"""Whom a networked ``diekf`` node with re-forming clusters hears, period by period.

Its clusters change at the schedule's boundaries (:mod:`swarmloc.estimators.cluster_reform`), so the broadcasts it
subscribes to, the progress it subscribes to and the lock step's watched set (:func:`~.lockstep.watched`) follow the
schedule (:func:`~.lockstep.heard_in`): in cut ``k`` (the node has reached ``k`` boundaries) its clusters of cuts
``k`` and ``k + 1``, the next one a period ahead, so that a new mate, which waits for this node's progress from then
on, cannot broadcast anything stamped in the new period before this node's subscription is up (it is on this node's
session before its progress announces the period). A mate of cut ``k - 1`` only is kept until it has settled
everything keyed before the boundary (its broadcast head past it, every broadcast below the head here:
:meth:`~.broadcast.Broadcaster.unsettled_by`), then undeclared, and what this node knew of its broadcasts forgotten
(a mate heard again later, or first heard after the start, starts from the first number it hears then: what it
broadcast before was not for this node)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from swarmloc.net.lockstep import heard_in, watched
from swarmloc.node import Node, RobotNode

if TYPE_CHECKING:
    from collections.abc import Iterable

    from swarmloc.estimators.cluster_reform import Schedule
    from swarmloc.net.broadcast import Broadcaster
    from swarmloc.net.lockstep import Lockstep
    from swarmloc.net.wiring import Wiring


class Hearing:
    """Part of :class:`~swarmloc.net.process.NetNode` with a re-forming ``schedule`` and the team's detected pairs
    known in advance (``detected``, :func:`~.lockstep.detected_pairs`: a robot it detects or is detected by in the
    run is watched throughout): keeps ``wiring``'s subscriptions, ``lockstep``'s watched set and ``broadcaster``'s
    heard mates on the current cut's (module docstring) for robot ``robot`` driving ``node``."""

    def __init__(self, node: Node, robot: int, schedule: Schedule, detected: Iterable[tuple[int, int]]) -> None:
        self.node, self.robot, self.schedule = node, robot, schedule
        pairs = list(detected)
        self.plan = [
            (mates, watched(robot, mates, pairs) or mates)
            for mates in (heard_in(robot, schedule, k, ())[0] for k in range(len(schedule.cuts)))
        ]
        """Per cut: the mates whose broadcasts it hears and the teammates it watches."""
        self.cut = 0
        """The cut the node is in (boundaries reached)."""
        self.leaving: set[int] = set()
        """Mates of the cut before only, heard until they have settled what is keyed before the boundary."""
        self._parts: tuple[Wiring, Lockstep, Broadcaster] | None = None

    def attach(self, wiring: Wiring, lockstep: Lockstep, broadcaster: Broadcaster) -> None:
        """The parts it keeps in step (once made; before the wiring is opened)."""
        self._parts = (wiring, lockstep, broadcaster)
        broadcaster.heard = set(self.plan[0][0])
        broadcaster.forget(frozenset().union(*(m for m, _ in self.plan)) - self.plan[0][0])  # heard from later on

    def mates(self) -> list[str]:
        """The mates whose broadcasts it hears now (keys' ids)."""
        return [str(r) for r in sorted(self.plan[self.cut][0] | self.leaving)]

    def watched(self) -> frozenset[int]:
        """The teammates it watches now."""
        return self.plan[self.cut][1] | self.leaving

    def follow(self) -> None:
        """After a step: a boundary reached moves it to the next cut; a leaving mate that has settled is let go."""
        b = self.node.boundary()
        cut = len(self.schedule.times) if b is None else self.schedule.times.index(b)
        changed = cut != self.cut
        if changed:
            self.leaving |= self.plan[self.cut][0] - self.plan[cut][0]
            self.cut = cut
        if self.leaving and self._parts is not None and cut > 0:
            key = (self.schedule.times[cut - 1], 0, -1, ())
            gone = {r for r in self.leaving if self._parts[2].unsettled_by(r, key) is None}
            if gone:
                self.leaving -= gone
                self._parts[2].forget(gone - self.plan[cut][0])
                changed = True
        if changed:
            self._apply()

    def _apply(self) -> None:
        if self._parts is None:
            return
        wiring, lockstep, broadcaster = self._parts
        mates = self.mates()
        broadcaster.heard = {int(r) for r in mates}
        lockstep.watch(self.watched())
        wiring.hear("broadcast", mates)
        wiring.hear("progress", [str(r) for r in sorted(self.watched())])


def hearing_of(
    node: Node, robot: int, broadcasts: bool, detected: Iterable[tuple[int, int]] | None
) -> tuple[list[str] | None, frozenset[int] | None, Hearing | None]:
    """Whom robot ``robot``'s ``node`` hears at its start: the mates whose broadcasts it subscribes to (``["*"]``:
    all; None: a node without ``broadcasts``; ``diekf`` in clusters: its cluster's), the teammates it watches
    (:func:`~.lockstep.watched` with the team's ``detected`` pairs; None: all), and with re-forming clusters and the
    detections known, the :class:`Hearing` that keeps them on the schedule (None: they stay)."""
    mates: list[str] | None = None
    cluster: tuple[int, ...] | None = None
    if broadcasts:
        mates = ["*"]
        if isinstance(node, RobotNode) and node.protocol is not None and node.protocol.cluster:
            cluster = tuple(node.team)
            mates = [str(m) for m in cluster if m != robot]
    pairs = None if detected is None else list(detected)
    w = watched(robot, cluster, pairs)
    schedule: Schedule | None = getattr(getattr(node, "protocol", None), "schedule", None)  # diekf's, once planned
    if w is None or pairs is None or schedule is None:
        return mates, w, None
    h = Hearing(node, robot, schedule, pairs)
    return h.mates(), h.watched(), h
