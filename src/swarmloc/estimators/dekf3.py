"""The distributed EKF on SE(3) (``dekf`` for 3-D teams): the first-order baseline of the thesis estimator.

Each node keeps its robot's position ``p`` (world frame), attitude ``R`` and the covariance ``P (6, 6)`` of the
error ``(dp, dtheta)``: ``p_true = p + dp`` (world frame), ``R_true = R exp(dtheta^)`` (body frame), the 3-D form of
the planar filter's ``(x, y, theta)`` error (:mod:`swarmloc.estimators.dekf`). Everything is first order:

* prediction over a constant body twist with increment ``(t_inc, R_inc) = exp(dt h^)`` and increment noise
  ``Sigma_inc`` (:func:`swarmloc.motion.twist3.twist_increment`): ``p' = p + R t_inc``, ``R' = R R_inc``,
  ``F = [[I, -R t_inc^], [0, R_inc^T]]``, ``G = diag(R R_inc, I)``, ``P' = F P F^T + G Sigma_inc G^T``;
* relative pose of neighbour ``k`` (:class:`~swarmloc.sensors.models3.Model3`): ``h = (R^T (p_k - p), R^T R_k)``,
  residual ``(t_z - h_t, log(h_R^T R_z))``,
  Jacobians ``d h_t / d(dp, dtheta) = (-R^T, h_t^)``, ``d h_R / d(dp, dtheta) = (0, -h_R^T)``, and for the
  neighbour ``(R^T, 0)``, ``(0, I)``; the neighbour's answered belief (converted to this error) and the measurement
  noise (``diag(R_z, I) Sigma_z diag(R_z, I)^T``) enter the innovation covariance; the cross-correlation is
  ignored (as in the planar DEKF). The correction is applied on the group (``R exp(dtheta^)``), no reset Jacobian;
* range-bearing-elevation (``"rbe3"``) and bearing-only (``"bearing3"``) detections of a neighbour's position or
  of a known 3-D landmark: the same with :class:`~swarmloc.sensors.models3.Model3`'s point models (angles wrapped;
  at the vertical the azimuth is not used, :meth:`~swarmloc.sensors.models3.Model3.linearize`); a landmark's map
  uncertainty enters the noise as a neighbour's does.

The belief a node answers and records is the right-perturbation Gaussian of the same first-order error:
``cov = J^-1 P J^-T`` with ``J = diag(R, I)`` (``g exp(xi)`` moves the position by ``R v`` to first order).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from swarmloc.events import Kind
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE3
from swarmloc.lie.se3 import skew, so3_exp
from swarmloc.messages import Message
from swarmloc.motion.twist3 import as_twist, twist_increment
from swarmloc.node import FUSED, Group, Outcome, RobotNode, belief_of, gated_kalman
from swarmloc.sensors.models3 import DEGENERATE3, MODELS3, model3


class Cart3State(NamedTuple):
    """Time [s], command (linear and angular velocity), position ``(3,)``, attitude ``(3, 3)``, ``P (6, 6)``."""

    t: float
    v: Any
    w: Any
    p: np.ndarray
    R: np.ndarray
    P: np.ndarray


def to_error(mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(p, R, P)`` of a right-perturbation SE(3) Gaussian: ``P = J cov J^T``, ``J = diag(R, I)``."""
    R = mean[:3, :3]
    J = np.eye(6)
    J[:3, :3] = R
    P = J @ cov @ J.T
    return mean[:3, 3].copy(), R.copy(), 0.5 * (P + P.T)


def transition(R: np.ndarray, inc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(F, G)`` of the step ``p' = p + R t_inc``, ``R' = R R_inc`` (increment ``inc (4, 4)``) in the error
    ``(dp, dtheta)``: ``F = [[I, -R t_inc^], [0, R_inc^T]]`` maps the error before to the error after, ``G =
    diag(R R_inc, I)`` the increment's right-perturbation noise to it (first order; tests/test_se3_cekf.py checks
    both against finite differences)."""
    Ri, ti = inc[:3, :3], inc[:3, 3]
    F = np.eye(6)
    F[:3, 3:] = -R @ skew(ti)
    F[3:, 3:] = Ri.T
    G = np.eye(6)
    G[:3, :3] = R @ Ri
    return F, G


def _pose(p: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The ``4 x 4`` pose of position ``p`` and attitude ``R``."""
    g = np.eye(4)
    g[:3, :3], g[:3, 3] = R, p
    return g


def to_group(p: np.ndarray, R: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`to_error`: mean ``(4, 4)`` and right-perturbation covariance ``(6, 6)``."""
    g = np.eye(4)
    g[:3, :3] = R
    g[:3, 3] = p
    Ji = np.eye(6)
    Ji[:3, :3] = R.T
    C = Ji @ P @ Ji.T
    return g, 0.5 * (C + C.T)


class DistributedEKF3(RobotNode):
    """Distributed first-order EKF on SE(3) (module doc); takes ``"pose3"``, ``"rbe3"`` and ``"bearing3"``
    detections of robots and ``"rbe3"`` / ``"bearing3"`` ones of known 3-D landmarks."""

    name = "dekf"
    groups = (SE3,)

    def _initial_state(self, t0: float) -> Cart3State:
        p, R, P = to_error(np.asarray(self.initial.mean), np.asarray(self.initial.cov))
        return Cart3State(t0, 0.0, 0.0, p, R, P)

    def _advance(self, s: Cart3State, robot: int, t: float) -> Cart3State:
        dt = t - s.t
        if dt <= 0:
            return s
        inc, S = twist_increment(as_twist(s.v, s.w), dt, self.noise)
        Ri, ti = inc[:3, :3], inc[:3, 3]
        F, G = transition(s.R, inc)
        P = F @ s.P @ F.T + G @ S @ G.T
        return Cart3State(t, s.v, s.w, s.p + s.R @ ti, s.R @ Ri, 0.5 * (P + P.T))

    def _set_command(self, s: Cart3State, robot: int, v: Any, w: Any) -> Cart3State:
        return Cart3State(s.t, v, w, s.p, s.R, s.P)

    def _belief(self, s: Cart3State, robot: int) -> GroupGaussian:
        return belief_of(*to_group(s.p, s.R, s.P))

    def _linearize(self, gi: np.ndarray, d: Any, target: tuple[str, Any]) -> Any:
        """``(r, H_i, R)`` of detection ``d`` of ``target`` (a neighbour's answered belief, its uncertainty folded
        into ``R``, or a landmark ``(p, C)``) from pose ``gi``; or an outcome when it cannot be fused."""
        if d.kind not in MODELS3:  # a planar kind in a 3-D team
            return ("rejected", f"kind {d.kind!r} is not supported on SE(3)")
        m3 = model3(d.kind)
        if target[0] == "robot":
            nb_mean, nb_cov = target[1].belief_arrays()
            if nb_mean.shape != (4, 4):
                return ("rejected", "the neighbour's answer is not an SE(3) belief")
            pk, Rk, Pk = to_error(nb_mean, nb_cov)
            gk, Ck = _pose(pk, Rk), Pk
        elif target[0] == "landmark" and m3.targets == "point" and np.shape(target[1][0]) == (3,):
            gk, Ck = target[1]
        else:
            return ("rejected", f"kind {d.kind!r} of a {target[0]} is not supported on SE(3)")
        if m3.kind == Kind.POSE3:
            h, Hi, Hk = m3.predict(gi, gk)
            r, Rn = m3.residual(d.z, h), m3.noise(d.z, d.cov)
        else:
            lin = m3.linearize(d.z, d.cov, gi, gk)
            if lin is None:
                return ("rejected", DEGENERATE3)
            r, Hi, Hk, Rn = lin
        return r, Hi, Rn + Hk @ Ck @ Hk.T

    def _fuse_group(self, s: Cart3State, g: Group) -> tuple[Cart3State, list[Outcome], list[Message]]:
        p, R, P = s.p, s.R, s.P
        outcomes: list[Outcome] = []
        for d in g.detections:
            target = self._classify(g, d)
            if target[0] in ("rejected", "unknown"):
                outcomes.append(target)
                continue
            lin = self._linearize(_pose(p, R), d, target)
            if isinstance(lin[0], str):
                outcomes.append(lin)
                continue
            r, Hi, Rn = lin
            res = gated_kalman(np.zeros(6), P, r, Hi, 0.5 * (Rn + Rn.T), self.gate, angles=())
            if isinstance(res[0], str):
                outcomes.append(res)
                continue
            dx, P = res
            p, R = p + dx[:3], R @ so3_exp(dx[3:])
            outcomes.append(FUSED)
        return Cart3State(s.t, s.v, s.w, p, R, P), outcomes, []
