"""The distributed EKF (thesis 2.1 and 5.2, Roumeliotis & Bekey): one Cartesian EKF per robot.

Each node keeps its robot's ``(x, y, theta)`` and covariance ``P`` (world frame). Prediction and the update are
the kernels of :mod:`swarmloc.kernels.cartesian`; measurement models (relative pose, range-bearing, range,
bearing; robots or landmarks with known position and standard deviation, slides 9-11 and 18-19) are
:mod:`swarmloc.sensors.models`. A detected neighbour's belief is asked for (:class:`~swarmloc.messages.BeliefQuery`)
and its covariance enters the innovation covariance; the cross-correlation is ignored, which makes the filter
over-confident when robots measure each other repeatedly.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from swarmloc.events import Kind
from swarmloc.gaussian import GroupGaussian
from swarmloc.kernels import cartesian as C
from swarmloc.messages import Message
from swarmloc.node import FUSED, Group, Outcome, RobotNode, belief_of, gated_kalman
from swarmloc.sensors.models import model

DEGENERATE = "degenerate geometry: the target is at the observer's position"


class CartState(NamedTuple):
    """A node's filter state: time [s], command ``(v, w)``, Cartesian mean ``(3,)`` and covariance ``(3, 3)``."""

    t: float
    v: float
    w: float
    x: np.ndarray
    P: np.ndarray


def measurement_noise(d: Any) -> np.ndarray:
    """Noise covariance of ``d.z`` in the coordinates the Cartesian models predict."""
    return model(d.kind).noise(d.z, d.cov)


def linearize(d: Any, x: np.ndarray, target: tuple[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray, Any]:
    """``(r, H_i, R_eff, H_k)`` of detection ``d`` at observer state ``x`` against a classified target (its
    :class:`~swarmloc.sensors.models.MeasurementModel`): innovation, Jacobian w.r.t. the observer, noise plus the
    target's propagated covariance, Jacobian w.r.t. the target. Returns None for a degenerate geometry (range ~ 0).
    """
    m = model(d.kind)
    R = m.noise(d.z, d.cov)
    if target[0] == Kind.ABSOLUTE:
        h, Hi, _ = m.predict(x)
        return m.residual(d.z, h), Hi, R, None
    if target[0] == "robot":
        xk, Pk = C.from_group(*target[1].belief_arrays())
    else:
        xk, Pk = target[1]
    if m.degenerate(x, xk):
        return None
    h, Hi, Hk = m.predict(x, xk)
    return m.residual(d.z, h), Hi, R + Hk @ Pk @ Hk.T, Hk


def predict_run(s: Any, shear: tuple[float, float], cmds: Any, noise: Any) -> tuple:
    """:func:`~swarmloc.kernels.cartesian.predict_run` of the odometry run ``cmds`` (``(t, robot, v, w)``) with
    process noise ``noise`` on a state with ``t, v, w, x, P``: the new ``(x, P, t, (v, w), shear)`` (``x`` and ``P``
    the same objects when nothing was predicted; ``shear``: rdl's deferred factor shear, accumulated)."""
    p00, p01, p02, _, p11, p12, _, _, p22 = s.P.ravel().tolist()
    x, p, t, cmd, shear = C.predict_run(
        tuple(s.x.tolist()), (p00, p01, p02, p11, p12, p22), s.t, (s.v, s.w), shear,
        [(tk, vk, wk) for tk, _, vk, wk in cmds], noise,
    )  # fmt: skip
    if t == s.t:  # no prediction: only the command changed
        return s.x, s.P, t, cmd, shear
    p00, p01, p02, p11, p12, p22 = p
    return np.array(x), np.array([[p00, p01, p02], [p01, p11, p12], [p02, p12, p22]]), t, cmd, shear


class DistributedEKF(RobotNode):
    """Distributed EKF: one Cartesian EKF per robot, neighbours' covariances as noise, one detection at a time."""

    name = "dekf"
    lazy_odometry = True

    def _initial_state(self, t0: float) -> CartState:
        x, P = C.from_group(self.initial.mean, self.initial.cov)
        return CartState(t0, 0.0, 0.0, x, P)

    def _advance(self, s: CartState, robot: int, t: float) -> CartState:
        dt = t - s.t
        if dt <= 0:
            return s
        x, P, _, _ = C.predict_one(s.x, s.P, s.v, s.w, dt, self.noise)
        return CartState(t, s.v, s.w, x, P)

    def _set_command(self, s: CartState, robot: int, v: float, w: float) -> CartState:
        return CartState(s.t, v, w, s.x, s.P)

    def _advance_commands(self, s: Any, cmds: Any) -> Any:
        """A run of odometry in one float loop (:func:`swarmloc.kernels.cartesian.predict_run`: the same bits as one
        :meth:`_advance` per command; tests/test_node.py checks it for every estimator)."""
        if self.measure_time:
            return super()._advance_commands(s, cmds)
        x, P, t, (v, w), _ = predict_run(s, (0.0, 0.0), cmds, self.noise)
        return CartState(t, v, w, x, P)

    def _belief(self, s: CartState, robot: int) -> GroupGaussian:
        return belief_of(*C.to_group(s.x, s.P))

    def _fuse_group(self, s: CartState, g: Group) -> tuple[CartState, list[Outcome], list[Message]]:
        x, P = s.x, s.P
        outcomes: list[Outcome] = []
        for d in g.detections:
            target = self._classify(g, d)
            if target[0] in ("rejected", "unknown"):
                outcomes.append(target)
                continue
            lin = linearize(d, x, target)
            if lin is None:
                outcomes.append(("rejected", DEGENERATE))
                continue
            r, Hi, R_eff, _ = lin
            res = gated_kalman(x, P, r, Hi, R_eff, self.gate)
            if isinstance(res[0], str):
                outcomes.append(res)
                continue
            x, P = res
            outcomes.append(FUSED)
        return CartState(s.t, s.v, s.w, x, P), outcomes, []
