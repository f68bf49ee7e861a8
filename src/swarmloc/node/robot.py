"""A node that estimates one robot: the base of every distributed estimator."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np

from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.messages import BeliefQuery, Message
from swarmloc.motion import UnicycleNoise
from swarmloc.node.associate import AssociationView, answered_beliefs, associate, check_association, is_anonymous
from swarmloc.node.base import Node
from swarmloc.node.keys import Group
from swarmloc.node.protocol import belief_answer

__all__ = ["RobotNode", "check_model"]


def check_model(where: str, initial: Mapping[int, Any], noise: object) -> None:
    """Every initial belief is one SE(2) :class:`GroupGaussian` and ``noise`` a :class:`UnicycleNoise`."""
    for r, b in initial.items():
        if not isinstance(b, GroupGaussian) or b.group is not SE2 or b.batch_shape:
            raise ValueError(f"{where}: initial belief of robot {r} must be one SE(2) GroupGaussian, got {b!r}")
    if not isinstance(noise, UnicycleNoise):
        raise ValueError(f"{where}: 'noise' must be a UnicycleNoise, got {type(noise).__name__}")


class RobotNode(Node):
    """A node that estimates one robot (every distributed estimator): built from that robot's belief alone.

    Parameters
    ----------
    robot: the robot's id.
    initial: its initial belief, an SE(2) :class:`~swarmloc.gaussian.GroupGaussian` (holding at ``t0``).
    noise: process noise of its odometry (:class:`~swarmloc.motion.UnicycleNoise`).
    team: every robot id of the team (``make_team`` passes it): the candidates of an anonymous detection.
    association: ``tags`` (anonymous robot detections refused), ``nearest`` or ``joint``
        (:mod:`~swarmloc.node.associate`: the node asks every teammate for its belief at the stamp of a scan with
        anonymous detections, then gives each one an identity); association_gate: the chi-square probability of
        the association gate; sensor_range [m]: teammates predicted within it and given no detection of a scan
        are counted ``association_missed`` (None: not counted).
    Other keywords: see :class:`~swarmloc.node.base.Node`. Neighbours are learnt as they are detected; they are
    asked for their belief (:class:`~swarmloc.messages.BeliefQuery`) and never read otherwise.
    """

    associates: ClassVar[bool] = True
    """False for an estimator whose exchanges need the target's identity before the belief is asked (pairwise
    updates, broadcasts keyed by the detection): it refuses an association policy other than ``tags``."""

    def __init__(
        self,
        robot: int,
        initial: GroupGaussian,
        *,
        noise: UnicycleNoise,
        team: Sequence[int] = (),
        association: str = "tags",
        association_gate: float = 0.99,
        sensor_range: float | None = None,
        **kw: Any,
    ) -> None:
        cls = type(self).__name__
        if not isinstance(robot, int | np.integer) or isinstance(robot, bool):
            raise ValueError(f"{cls}: 'robot' must be an integer id, got {robot!r}")
        check_model(cls, {robot: initial}, noise)
        check_association(cls, association, association_gate)
        if association != "tags" and not self.associates:
            raise ValueError(
                f"{cls}: association {association!r} is not supported by {self.name} (its exchanges need the "
                f"target's identity first); use association='tags', or dekf, expfusion, ci, mcl, cekf, iekf or fej"
            )
        if sensor_range is not None and not sensor_range > 0:
            raise ValueError(f"{cls}: sensor_range must be > 0 m or None, got {sensor_range!r}")
        self.robot = int(robot)
        self.initial = initial
        self.noise = noise
        self.team = tuple(sorted({int(r) for r in team} | {self.robot}))
        self.association = association
        self.association_gate = float(association_gate)
        self.sensor_range = sensor_range
        if association != "tags" and len(self.team) < 2:
            raise ValueError(f"{cls}: association {association!r} needs the team's robot ids ('team')")
        super().__init__((self.robot,), **kw)

    def _teammates(self, g: Group) -> list[int]:
        """Teammates to ask for their belief at ``g``'s stamp for its anonymous detections (none for tags)."""
        if self.association == "tags" or not self.use_relative or not any(is_anonymous(d) for d in g.detections):
            return []
        return [r for r in self.team if r != self.robot]

    def _requests(self, g: Group) -> list[Message]:
        targets = sorted({d.target for d in g.detections if self._needs_answer(g, d)} | set(self._teammates(g)))
        return [BeliefQuery(sender=self.robot, receiver=t, stamp=g.t) for t in targets]

    def _associate(self, s: Any, g: Group) -> AssociationView | None:
        mates = self._teammates(g)
        if not mates:
            return None
        own = self._belief(s, self.robot)
        return associate(g, self.association, self.association_gate, own, answered_beliefs(g, mates),
                         self.sensor_range)  # fmt: skip

    def _answer(self, s: Any, q: Message) -> Message | None:
        if isinstance(q, BeliefQuery):
            return belief_answer(q, self._belief(s, q.receiver))
        return None
