"""The node of a whole team (a centralized estimator, ``cekf`` and its forms): one node that owns every robot.

:class:`TeamNode` holds what such a node needs whatever its filter: the robots' initial beliefs by id (checked),
the odometry noise, each robot's block of the joint state (``dim`` per robot, robots in increasing id order), the
targets of robot detections (the node knows every teammate itself) and the association of anonymous detections among
the robots' marginals. The filter (state, prediction, update, :meth:`TeamNode.joint_at`) is the estimator's.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, SE3
from swarmloc.motion import UnicycleNoise
from swarmloc.node.associate import AssociationView, associate, check_association, check_sensor, is_anonymous
from swarmloc.node.base import Node
from swarmloc.node.keys import Group, SubKey
from swarmloc.node.robot import check_model

__all__ = ["TeamNode"]


class TeamNode(Node):
    """A node that owns every robot of a team.

    Parameters
    ----------
    initial: every robot's initial belief (:class:`~swarmloc.gaussian.GroupGaussian` of one of :attr:`groups`), by
        robot id.
    noise: process noise of the odometry (the same model for every robot).
    association, association_gate, sensor_range [m], sensor_fov [rad]: as
        :class:`~swarmloc.node.robot.RobotNode`'s (the marginals are the candidates).

    Other keywords: see :class:`~swarmloc.node.base.Node`.
    """

    distributed = False
    groups: ClassVar[tuple[type, ...]] = (SE2,)
    """The group of every robot's pose."""
    dim: ClassVar[int] = 3
    """Size of one robot's block of the joint state."""

    def __init__(
        self,
        initial: Mapping[int, GroupGaussian],
        *,
        noise: UnicycleNoise,
        association: str = "tags",
        association_gate: float = 0.99,
        sensor_range: float | None = None,
        sensor_fov: float | None = None,
        **kw: Any,
    ) -> None:
        cls = type(self).__name__
        if not isinstance(initial, Mapping) or not initial:
            raise ValueError(f"{cls}: 'initial' must map each robot id to its initial belief (at least one robot)")
        check_association(cls, association, association_gate)
        check_sensor(cls, sensor_range, sensor_fov)
        self.association = association
        self.association_gate = float(association_gate)
        self.sensor_range = sensor_range
        self.sensor_fov = sensor_fov
        check_model(cls, initial, noise, self.groups)
        if association != "tags" and any(b.group is SE3 for b in initial.values()):
            raise ValueError(f"{cls}: an SE(3) team has no association policy; use association='tags'")
        self.initial = dict(initial)
        self.noise = noise
        robots = sorted(initial)
        self._idx = {r: self.dim * i for i, r in enumerate(robots)}
        """The first index of each robot's block of the joint state."""
        super().__init__(robots, **kw)

    def joint_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The joint state and its covariance with every robot predicted to ``t`` [s] (the estimator's)."""
        raise NotImplementedError

    def _joint(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self.joint_at(t)

    def _robot_target(self, g: Group, d: Any, sub: SubKey) -> tuple[str, Any]:
        if d.target not in self._idx:
            return ("unknown", f"robot {d.target} is not in the team")
        return ("robot", d.target)

    def _associate(self, s: Any, g: Group) -> AssociationView | None:
        """Identities for the group's anonymous robot detections (:mod:`swarmloc.node.associate`) from every
        robot's marginal predicted to the group's stamp (the joint's cross-covariances are left out of the choice,
        not of the update); the prediction is for the choice only, the filter's own steps stay as with tags."""
        if self.association == "tags" or not self.use_relative or not any(is_anonymous(d) for d in g.detections):
            return None
        sf = s
        others = [r for r in self.robots if r != g.observer]
        for r in others:
            sf = self._adv(sf, r, g.t)
        cands = {r: self._belief(sf, r) for r in others}
        return associate(g, self.association, self.association_gate, self._belief(s, g.observer), cands,
                         self.sensor_range, self.sensor_fov)  # fmt: skip
