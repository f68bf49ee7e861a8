"""The thesis estimator (exponential-coordinate prediction and fusion) and dead reckoning.

Each robot runs a node with a Gaussian on SE(2) ``(mu, Sigma)``.

* Prediction (thesis 4.13-4.15): the belief is convolved (second order) with the odometry increment, whose
  mean is ``exp(dt (v, 0, w)^)`` and covariance eq. (5.4) for the body-twist diffusion ``Q(v, w)``
  (:func:`swarmloc.motion.odometry_increment`, exact closed form rather than the Simpson rule 5.12).
* Update (thesis 4.16-4.19 as corrected in :mod:`swarmloc.fusion`): all relative-pose detections a robot made at
  one instant are fused at once, each with the neighbour's belief obtained *from the neighbour* through the
  channel; GPS-like absolute fixes are fused as direct observations of the pose. Range/bearing detections of
  robots and of landmarks with known position (which the thesis has no model for) are fused by an iterated
  update on the group that includes the target's uncertainty (:func:`swarmloc.fusion.fuse_point_measurement`).

The fusion assumes the neighbour's belief is independent of the robot's own. When two robots measure each other
again and again this is false (their beliefs become correlated through earlier fusions) and the estimator
becomes over-confident: the NEES shows it. :mod:`swarmloc.estimators.consistent` fixes that.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import partial

import numpy as np

from swarmloc.estimators.base import Channel, Estimator, _rot_block
from swarmloc.events import Detection
from swarmloc.fusion import (
    fuse_point_measurement,
    fuse_pseudo,
    point_innovation,
    pseudo_innovation,
    relative_to_pseudo,
)
from swarmloc.gaussian import GroupGaussian, convolve_moments
from swarmloc.lie import SE2
from swarmloc.motion import UnicycleNoise, odometry_increment


class _Node:
    """State of one robot: mean (3x3) and covariance (3x3) in exponential coordinates."""

    __slots__ = ("mean", "cov", "t")

    def __init__(self, b: GroupGaussian, t: float = 0.0) -> None:
        self.mean = np.array(b.mean)
        self.cov = np.array(b.cov)
        self.t = t

    def belief(self) -> GroupGaussian:
        return GroupGaussian(SE2, self.mean, self.cov, validate=False)


class ExpFusion(Estimator):
    """Thesis estimator: second-order exponential-coordinate prediction and n-neighbour fusion (distributed).

    Parameters
    ----------
    initial: initial belief per robot.
    noise: process-noise model of the odometry (per-second body-twist diffusion).
    order: 2 (thesis) or 1 (first-order convolution and fusion).
    iterations: re-linearizations of the fusion (1 = thesis closed form).
    use_relative: fuse relative-pose detections of other robots.
    """

    name = "expfusion"

    def __init__(
        self,
        initial: Mapping[int, GroupGaussian],
        noise: UnicycleNoise,
        order: int = 2,
        iterations: int = 1,
        use_relative: bool = True,
        landmarks: Mapping[int, tuple[float, float, float, float]] | None = None,
        use_landmarks: bool = True,
        point_iterations: int = 3,
        gate: float | None = None,
    ) -> None:
        self.order = order
        self.iterations = iterations
        self.point_iterations = point_iterations
        super().__init__(initial, noise, landmarks, use_relative, use_landmarks, gate)

    def _init_state(self, initial: Mapping[int, GroupGaussian]) -> None:
        self._nodes = {r: _Node(b) for r, b in initial.items()}

    # ------------------------------------------------------------------ protocol
    def predict(self, robot: int, t0: float, t1: float, v: float, w: float) -> None:
        self._check_robot(robot)
        dt = t1 - t0
        if dt <= 0:
            return
        node = self._nodes[robot]
        inc_mean, inc_cov = odometry_increment(float(v), float(w), float(dt), self.noise)
        node.mean, node.cov = convolve_moments(SE2, node.mean, node.cov, inc_mean, inc_cov, self.order)
        node.t = t1
        self.stats["predict"] += 1

    def belief(self, robot: int) -> GroupGaussian:
        self._check_robot(robot)
        return self._nodes[robot].belief()

    def predicted_belief(self, robot: int, dt: float, v: float, w: float) -> GroupGaussian:
        self._check_robot(robot)
        node = self._nodes[robot]
        if dt <= 0:
            return node.belief()
        inc_mean, inc_cov = odometry_increment(float(v), float(w), float(dt), self.noise)
        mean, cov = convolve_moments(SE2, node.mean, node.cov, inc_mean, inc_cov, self.order)
        return GroupGaussian(SE2, mean, cov, validate=False)

    def update(self, robot: int, t: float, detections: Sequence[Detection], channel: Channel) -> None:
        self._check_robot(robot)
        node = self._nodes[robot]
        nus: list[np.ndarray] = []
        Ws: list[np.ndarray] = []
        rest: list[Detection] = []
        for d in self.usable(robot, detections):
            pseudo = self._pseudo(robot, t, d, channel)
            if pseudo is None:
                rest.append(d)
            elif pseudo is not False:
                if self.gated(partial(pseudo_innovation, node.mean, node.cov, pseudo[0], pseudo[1]), 3):
                    continue
                nus.append(pseudo[0])
                Ws.append(pseudo[1])
        if nus:
            node.mean, node.cov = fuse_pseudo(
                SE2, node.mean, node.cov, np.stack(nus), np.stack(Ws), self.order, self.iterations
            )
            self.stats["fused"] += len(nus)
        if rest:
            self._update_other(robot, t, rest, channel)
        self.stats["update"] += 1

    # ------------------------------------------------------------------ pieces
    def _pseudo(
        self, robot: int, t: float, d: Detection, channel: Channel
    ) -> tuple[np.ndarray, np.ndarray] | None | bool:
        """Pseudo-observation ``(nu, W)`` of the robot's own pose; None: not handled here; False: skipped."""
        if d.kind == "absolute":
            T = _rot_block(d.z[2]).T
            return SE2.from_xytheta(d.z), T @ d.cov @ T.T
        if d.kind != "pose" or not d.target_is_robot:
            return None
        nb = self.resolve_target(robot, t, d, channel)
        if nb is None:
            return False
        return relative_to_pseudo(SE2, nb.mean, nb.cov, SE2.from_xytheta(d.z), np.asarray(d.cov), self.order)

    def _point_target(
        self, robot: int, t: float, d: Detection, channel: Channel
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Target of a range/bearing detection: a neighbour's (mean 3x3, cov) or a landmark's (xy, cov 2x2)."""
        tgt = self.resolve_target(robot, t, d, channel)
        return (np.asarray(tgt.mean), np.asarray(tgt.cov)) if isinstance(tgt, GroupGaussian) else tgt

    def _fuse_point(self, node: _Node, d: Detection, target: tuple[np.ndarray, np.ndarray]) -> None:
        node.mean, node.cov = fuse_point_measurement(
            node.mean, node.cov, d.kind, d.z, np.asarray(d.cov), target[0], target[1], self.point_iterations, self.order
        )

    def _update_other(self, robot: int, t: float, detections: Sequence[Detection], channel: Channel) -> None:
        """Range/bearing detections of robots and landmarks: iterated update on the group, one at a time.

        The thesis has no model for them; see :func:`swarmloc.fusion.fuse_point_measurement`.
        """
        node = self._nodes[robot]
        for d in detections:
            target = self._point_target(robot, t, d, channel)
            if target is None:
                continue
            nis = partial(point_innovation, node.mean, node.cov, d.kind, d.z, np.asarray(d.cov), *target)
            if self.gated(nis, len(d.z)):
                continue
            self._fuse_point(node, d, target)
            self.stats["fused"] += 1


class DeadReckoning(ExpFusion):
    """Exponential-coordinate prediction only: every detection is ignored."""

    name = "dr"

    def __init__(self, initial: Mapping[int, GroupGaussian], noise: UnicycleNoise, order: int = 2, **_: object) -> None:
        super().__init__(initial, noise, order=order, use_relative=False)
        # keyword arguments of the cooperative estimators (landmarks, gate, ...) are accepted and unused

    def update(self, robot: int, t: float, detections: Sequence[Detection], channel: Channel) -> None:
        self._check_robot(robot)
        self.stats["update"] += 1
