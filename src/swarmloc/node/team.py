"""The node of a whole team (a centralized estimator: ``cekf``, ``iekf``, ``fej``): one node that owns every robot.

:class:`TeamNode` holds what such a node needs whatever its filter: the robots' initial beliefs by id (checked),
the odometry noise, each robot's block of the joint state (``dim`` per robot, robots in increasing id order), the
targets of robot detections (the node knows every teammate itself) and the association of anonymous detections among
the robots' marginals. The filter (state, prediction, update) is the estimator's :class:`JointForm`, one per group
(:attr:`TeamNode.forms`), picked once by the group of the initial beliefs.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from swarmloc.events import Detection
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, SE3
from swarmloc.messages import Message
from swarmloc.motion import UnicycleNoise
from swarmloc.motion.twist3 import TwistNoise
from swarmloc.node.associate import AssociationView, associate, is_anonymous
from swarmloc.node.base import Node, belief_of
from swarmloc.node.keys import Group, SubKey
from swarmloc.node.robot import check_model
from swarmloc.node.update import Outcome

__all__ = ["JointForm", "TeamNode", "WorldCross"]


class JointForm(Protocol):
    """A team node's filter: its joint state and the steps on it. The state is the form's own named tuple, with each
    robot's command ``(v, w)`` at its block's place in ``cmd`` (:meth:`TeamNode._set_command`) and its clock in ``t``.
    The steps take the node for the robots' blocks (``_idx``), the noise, the gate and the linearization log
    (``lin_log``)."""

    dim: int
    """Size of one robot's block of the joint state."""

    def initial(self, node: TeamNode, t0: float) -> Any:
        """The team's state at ``t0`` [s] from every robot's initial belief."""

    def advance(self, node: TeamNode, s: Any, robot: int, t: float) -> Any:
        """``s`` with ``robot`` predicted to ``t`` [s] (unchanged when ``t`` is not later)."""

    def belief(self, s: Any, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The marginal of the robot whose block starts at ``i`` as a right-perturbation belief ``(mean, cov)``."""

    def joint(self, s: Any) -> tuple[np.ndarray, np.ndarray]:
        """The joint mean and covariance of ``s`` in the form's error coordinates."""

    def fuse(self, node: TeamNode, s: Any, g: Group, d: Detection, target: tuple[str, Any]) -> tuple[Any, Outcome]:
        """One detection ``d`` of the classified ``target`` of group ``g``: the state after it (the detected robot
        predicted to the stamp) and its outcome."""


@runtime_checkable
class WorldCross(Protocol):
    """A planar joint form that gives the association its cross-covariances (:meth:`TeamNode._associate`)."""

    def world_cross(self, s: Any, i: int, ks: Sequence[int]) -> np.ndarray:
        """World-frame ``(x, y, theta)`` covariances ``(len(ks), 3, 3)`` of the pose of the robot whose block starts
        at ``i`` with those of the robots whose blocks start at ``ks``, pending predictions applied."""


class TeamNode(Node):
    """A node that owns every robot of a team.

    Parameters
    ----------
    initial: every robot's initial belief (:class:`~swarmloc.gaussian.GroupGaussian` of one of :attr:`groups`), by
        robot id.
    noise: process noise of the odometry (the same model for every robot; SE(3): a
        :class:`~swarmloc.motion.twist3.TwistNoise`).
    Other keywords: see :class:`~swarmloc.node.base.Node` (for ``association``: the marginals are the candidates).
    """

    distributed = False
    groups: ClassVar[tuple[type, ...]] = (SE2,)
    """The group of every robot's pose."""
    forms: ClassVar[Mapping[type, JointForm]]
    """The estimator's filter on each group of :attr:`groups`."""
    lin_log: list[tuple[Any, ...]] | None = None
    """Set to a list to record every applied linearization (:mod:`swarmloc.evaluation.observability`)."""

    def __init__(
        self,
        initial: Mapping[int, GroupGaussian],
        *,
        noise: UnicycleNoise | TwistNoise,
        **kw: Any,
    ) -> None:
        cls = type(self).__name__
        if not isinstance(initial, Mapping) or not initial:
            raise ValueError(f"{cls}: 'initial' must map each robot id to its initial belief (at least one robot)")
        check_model(cls, initial, noise, self.groups)
        self.initial = dict(initial)
        self.noise = noise
        self._form = self.forms[next(iter(initial.values())).group]
        robots = sorted(initial)
        self._idx = {r: self.dim * i for i, r in enumerate(robots)}
        """The first index of each robot's block of the joint state."""
        super().__init__(robots, **kw)
        if self.association != "tags" and any(b.group is SE3 for b in initial.values()):
            raise ValueError(f"{cls}: an SE(3) team has no association policy; use association='tags'")

    @property
    def dim(self) -> int:
        """Size of one robot's block of the joint state (the form's: 3 on SE(2), 6 on SE(3))."""
        return self._form.dim

    def joint_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The joint state and its covariance in the form's error coordinates (:meth:`JointForm.joint`) with every
        robot predicted to ``t`` [s] (robots in increasing id order)."""
        at = (t, 3, 0, ())
        s = self._history.state_before(at)
        for r in self.robots:
            s = self._adv(s, r, t, at)
        return self._form.joint(s)

    def _joint(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self.joint_at(t)

    def _initial_state(self, t0: float) -> Any:
        return self._form.initial(self, t0)

    def _advance(self, s: Any, robot: int, t: float) -> Any:
        return self._form.advance(self, s, robot, t)

    def _set_command(self, s: Any, robot: int, v: float, w: float) -> Any:
        cmd = list(s.cmd)
        cmd[self._idx[robot] // self.dim] = (v, w)
        return s._replace(cmd=tuple(cmd))

    def _belief(self, s: Any, robot: int) -> GroupGaussian:
        return belief_of(*self._form.belief(s, self._idx[robot]))

    def _fuse_group(self, s: Any, g: Group) -> tuple[Any, list[Outcome], list[Message]]:
        s, outcomes = self._fuse_each(s, g, lambda s, d, target: self._form.fuse(self, s, g, d, target))
        return s, outcomes, []

    def _robot_target(self, g: Group, d: Any, sub: SubKey) -> tuple[str, Any]:
        if d.target not in self._idx:
            return ("unknown", f"robot {d.target} is not in the team")
        return ("robot", d.target)

    def _associate(self, s: Any, g: Group) -> AssociationView | None:
        """Identities for the group's anonymous robot detections (:mod:`swarmloc.node.associate`) from every
        robot's marginal predicted to the group's stamp and, where the form gives them (:class:`WorldCross`), the
        joint's cross-covariances of observer and candidate, so that a detection's cost is the innovation the update
        would weigh; the prediction is for the choice only, the filter's own steps stay as with tags."""
        if self.association == "tags" or not self.use_relative or not any(is_anonymous(d) for d in g.detections):
            return None
        sf = s
        others = [r for r in self.robots if r != g.observer]
        for r in others:
            sf = self._adv(sf, r, g.t)
        cands = {r: self._belief(sf, r) for r in others}
        cross = None
        if isinstance(self._form, WorldCross):
            blocks = self._form.world_cross(sf, self._idx[g.observer], [self._idx[r] for r in others])
            cross = dict(zip(others, blocks, strict=True))
        return associate(g, self.association, self.association_gate, self._belief(s, g.observer), cands,
                         self.sensor_range, self.sensor_fov, cross)  # fmt: skip
