"""A node that estimates one robot: the base of every distributed estimator."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.messages import BeliefQuery, Message
from swarmloc.motion import UnicycleNoise
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
    Other keywords: see :class:`~swarmloc.node.base.Node`. Neighbours are learnt as they are detected; they are
    asked for their belief (:class:`~swarmloc.messages.BeliefQuery`) and never read otherwise.
    """

    def __init__(self, robot: int, initial: GroupGaussian, *, noise: UnicycleNoise, **kw: Any) -> None:
        cls = type(self).__name__
        if not isinstance(robot, int | np.integer) or isinstance(robot, bool):
            raise ValueError(f"{cls}: 'robot' must be an integer id, got {robot!r}")
        check_model(cls, {robot: initial}, noise)
        self.robot = int(robot)
        self.initial = initial
        self.noise = noise
        super().__init__((self.robot,), **kw)

    def _requests(self, g: Group) -> list[Message]:
        targets = sorted({d.target for d in g.detections if self._needs_answer(g, d)})
        return [BeliefQuery(sender=self.robot, receiver=t, stamp=g.t) for t in targets]

    def _answer(self, s: Any, q: Message) -> Message | None:
        if isinstance(q, BeliefQuery):
            return belief_answer(q, self._belief(s, q.receiver))
        return None
