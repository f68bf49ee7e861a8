"""A node that estimates one robot: the base of every distributed estimator."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar, Protocol

import numpy as np

from swarmloc.events import Detection
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, SE3
from swarmloc.messages import Answer, BeliefQuery, Message
from swarmloc.motion import UnicycleNoise
from swarmloc.motion.twist3 import TwistNoise
from swarmloc.node.associate import (
    AssociationView,
    answered_beliefs,
    associate,
    is_anonymous,
)
from swarmloc.node.base import Node
from swarmloc.node.keys import Group
from swarmloc.node.protocol import belief_answer
from swarmloc.node.update import Gate

__all__ = ["PeerProtocol", "RobotNode", "check_model"]


def check_model(where: str, initial: Mapping[int, Any], noise: object, groups: tuple[type, ...] = (SE2,)) -> None:
    """Every initial belief is one :class:`GroupGaussian` on a group of ``groups`` (default SE(2) only), all on
    the same group, and ``noise`` a :class:`UnicycleNoise` (SE(2)) or a
    :class:`~swarmloc.motion.twist3.TwistNoise` (SE(3))."""
    names = "SE(2)" if groups == (SE2,) else "SE(2) GroupGaussian or an SE(3)"
    for r, b in initial.items():
        if not isinstance(b, GroupGaussian) or b.group not in groups or b.batch_shape:
            raise ValueError(f"{where}: initial belief of robot {r} must be one {names} GroupGaussian, got {b!r}")
    kinds = {b.group for b in initial.values()}
    if len(kinds) > 1:
        raise ValueError(f"{where}: initial beliefs mix {sorted(g.name for g in kinds)}")
    if kinds == {SE3}:
        if not isinstance(noise, TwistNoise):
            raise ValueError(f"{where}: 'noise' of an SE(3) team must be a TwistNoise, got {type(noise).__name__}")
    elif not isinstance(noise, UnicycleNoise):
        raise ValueError(f"{where}: 'noise' must be a UnicycleNoise, got {type(noise).__name__}")


class PeerProtocol(Protocol):
    """A part of a robot's node that speaks its estimator's protocol with the teammates beyond belief queries
    (:attr:`RobotNode.protocol`; e.g. ``diekf``'s :class:`~swarmloc.estimators.team_protocol.TeamProtocol`): the
    queries a detection group asks, the answers it gives, the messages
    that close the exchanges a group did not use, the checks of a teammate's update, and what it forgets with the
    history."""

    def requests(self, g: Group, needs_answer: Callable[[Group, Detection], bool],
                 mates: Sequence[int]) -> list[Message]: ...  # fmt: skip
    def answer(self, s: Any, q: Message) -> Answer | None: ...
    def settle(self, g: Group) -> list[Message]: ...
    def update_problem(self, u: Message) -> str | None: ...
    def update_lie(self, u: Message, gate: Gate) -> str | None: ...
    def prune(self, cutoff: float) -> None: ...

    cluster: int
    """The size of the clusters the team is cut into (0: one team): the node hears the broadcasts of its cluster's
    members (its ``team``) only."""


class RobotNode(Node):
    """A node that estimates one robot (every distributed estimator): built from that robot's belief alone.

    Parameters
    ----------
    robot: the robot's id.
    initial: its initial belief, an SE(2) :class:`~swarmloc.gaussian.GroupGaussian` (holding at ``t0``).
    noise: process noise of its odometry (:class:`~swarmloc.motion.UnicycleNoise`).
    team: every robot id of the team (``make_team`` passes it): the candidates of an anonymous detection (the node
        asks every teammate for its belief at the stamp of a scan with anonymous detections under an ``association``
        policy other than ``tags``).
    Other keywords: see :class:`~swarmloc.node.base.Node`. Neighbours are learnt as they are detected; they are
    asked for their belief (:class:`~swarmloc.messages.BeliefQuery`) and never read otherwise.
    """

    groups: ClassVar[tuple[type, ...]] = (SE2,)
    """The groups this estimator's state can live on (``(SE2, SE3)`` for the estimators with an SE(3) form); the
    initial belief picks one."""
    associates: ClassVar[bool] = True
    """False for an estimator that cannot give anonymous detections an identity: it refuses an association policy
    other than ``tags`` (none of :data:`swarmloc.estimators.ESTIMATORS` does: the pairwise ``rdl``, ``irdl`` and
    the broadcasting ``diekf``, ``flsd`` ask every teammate with their own query, :mod:`~swarmloc.estimators.rdl`)."""
    protocol: PeerProtocol | None = None
    """The part that speaks the estimator's own protocol with the teammates (None: belief queries only); the node's
    exchange hooks (queries, answers, settling, a teammate's update checked, pruning) are its."""

    def __init__(
        self,
        robot: int,
        initial: GroupGaussian,
        *,
        noise: UnicycleNoise,
        team: Sequence[int] = (),
        **kw: Any,
    ) -> None:
        cls = type(self).__name__
        if not isinstance(robot, int | np.integer) or isinstance(robot, bool):
            raise ValueError(f"{cls}: 'robot' must be an integer id, got {robot!r}")
        check_model(cls, {robot: initial}, noise, self.groups)
        self.robot = int(robot)
        self.initial = initial
        self.group = initial.group
        """The group of the robot's pose (SE(2) or SE(3)), from the initial belief."""
        self.noise = noise
        self.team = tuple(sorted({int(r) for r in team} | {self.robot}))
        super().__init__((self.robot,), **kw)
        association = self.association  # checked by Node; what this node can do with it:
        if initial.group is SE3 and association != "tags":
            raise ValueError(f"{cls}: an SE(3) team has no association policy; use association='tags'")
        if association != "tags" and not self.associates:
            raise ValueError(
                f"{cls}: association {association!r} is not supported by {self.name}; use association='tags'"
            )
        if association != "tags" and len(self.team) < 2:
            raise ValueError(f"{cls}: association {association!r} needs the team's robot ids ('team')")

    def _teammates(self, g: Group) -> list[int]:
        """Teammates to ask for their belief at ``g``'s stamp for its anonymous detections (none for tags)."""
        if self.association == "tags" or not self.use_relative or not any(is_anonymous(d) for d in g.detections):
            return []
        return [r for r in self.team if r != self.robot]

    def _requests(self, g: Group) -> list[Message]:
        if self.protocol is not None:
            return self.protocol.requests(g, self._needs_answer, self._teammates(g))
        targets = sorted({d.target for d in g.detections if d.target is not None and self._needs_answer(g, d)}
                         | set(self._teammates(g)))  # fmt: skip
        return [BeliefQuery(sender=self.robot, receiver=t, stamp=g.t) for t in targets]

    def _candidates(self, g: Group, mates: Sequence[int]) -> dict[int, GroupGaussian]:
        """The teammates' beliefs before ``g`` among which its anonymous detections are associated: their answers to
        the group's :class:`~swarmloc.messages.BeliefQuery` (sub-key ``()``), whatever else an estimator asks (never
        a state the scan's own updates reached: :mod:`~swarmloc.estimators.state_exchange`)."""
        return answered_beliefs(g, mates)

    def _associate(self, s: Any, g: Group) -> AssociationView | None:
        mates = self._teammates(g)
        if not mates:
            return None
        own = self._belief(s, self.robot)
        return associate(g, self.association, self.association_gate, own, self._candidates(g, mates),
                         self.sensor_range, self.sensor_fov)  # fmt: skip

    def _answer(self, s: Any, q: Message) -> Answer | None:
        a = None if self.protocol is None else self.protocol.answer(s, q)
        if a is None and isinstance(q, BeliefQuery):
            return belief_answer(q, self._belief(s, q.receiver))
        return a

    def _settle(self, g: Group) -> list[Message]:
        return [] if self.protocol is None else self.protocol.settle(g)

    def _update_problem(self, u: Message) -> str | None:
        return None if self.protocol is None else self.protocol.update_problem(u)

    def _update_lie(self, u: Message) -> str | None:
        return None if self.protocol is None else self.protocol.update_lie(u, self.gate)

    def _prune(self) -> None:
        super()._prune()
        if self.protocol is not None:
            self.protocol.prune(self._clock.present - self.horizon)
