"""The centralized EKF on SE(3) (``cekf`` for 3-D teams): one filter with every robot's 6-dof state.

The joint state holds each robot's position ``p_k`` (world frame) and attitude ``R_k``; the joint covariance
``P (6n, 6n)`` is that of the errors ``(dp_k, dtheta_k)`` (``p_true = p + dp``, ``R_true = R exp(dtheta^)``), the
error of the distributed ``dekf`` (:mod:`swarmloc.estimators.dekf3`), robots in increasing id order. As the planar
:class:`~swarmloc.estimators.cekf.CentralizedEKF`, each robot's block has its own clock and body-twist command; a
detection predicts the detected robot to the detection's stamp, then one Joseph-form Kalman update on the joint
state touches the two robots' columns of ``H`` (:func:`swarmloc.node.gated_kalman` with ``cols``), and the
correction is applied on the group (``p + dp``, ``R exp(dtheta^)``). First order everywhere:

* prediction of robot ``k`` over a constant body twist (increment ``(t_inc, R_inc)``, noise ``Sigma_inc``,
  :func:`swarmloc.motion.twist3.twist_increment`): ``F = [[I, -R t_inc^], [0, R_inc^T]]`` on its rows and columns
  of ``P`` (its cross-covariances move with it), plus ``G Sigma_inc G^T``, ``G = diag(R R_inc, I)``;
* a ``"pose3"``, ``"rbe3"`` or ``"bearing3"`` detection of a robot, or a ``"rbe3"`` / ``"bearing3"`` one of a known
  3-D landmark (only the observer's columns; the map's uncertainty joins the noise):
  :class:`~swarmloc.sensors.models3.Model3` (prediction, Jacobians, residual with wrapped angles, noise, the
  singular vertical direction), the same models as the distributed ``dekf``.

It tracks every correlation, so it does not double count; its Jacobians are evaluated at the current estimates, so
without absolute information it may still gain spurious information along the team's unobservable rigid motion
(the world-frame ``diekf`` does not).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar, NamedTuple

import numpy as np

from swarmloc.events import Kind
from swarmloc.gaussian import GroupGaussian
from swarmloc.kernels.cartesian3 import to_error, to_group, transition
from swarmloc.lie import SE3
from swarmloc.lie.se3 import so3_exp
from swarmloc.messages import Message
from swarmloc.motion.twist3 import as_twist, twist_increment
from swarmloc.node import FUSED, Group, Node, Outcome, TeamNode, belief_of, gated_kalman
from swarmloc.sensors.models3 import DEGENERATE3, MODELS3, model3

__all__ = ["CentralizedEKF3", "Team3State"]


class Team3State(NamedTuple):
    """Positions ``p (n, 3)``, attitudes ``R (n, 3, 3)``, joint error covariance ``P (6n, 6n)``, each robot's time
    [s] and command (linear and angular velocity)."""

    p: np.ndarray
    R: np.ndarray
    P: np.ndarray
    t: tuple[float, ...]
    cmd: tuple[tuple[Any, Any], ...]


def _pose(p: np.ndarray, R: np.ndarray) -> np.ndarray:
    g = np.eye(4)
    g[:3, :3], g[:3, 3] = R, p
    return g


class CentralizedEKF3(TeamNode):
    """Centralized EKF of a 3-D team (module docstring); takes ``"pose3"``, ``"rbe3"`` and ``"bearing3"``
    detections of robots and ``"rbe3"`` / ``"bearing3"`` ones of known 3-D landmarks."""

    name = "cekf"
    groups: ClassVar[tuple[type, ...]] = (SE3,)
    dim: ClassVar[int] = 6
    lazy_odometry = False
    error_frame: ClassVar[str] = "cartesian3"

    def __init__(self, initial: Mapping[int, GroupGaussian], **kw: Any) -> None:
        if kw.get("association", "tags") != "tags":
            raise ValueError(f"{type(self).__name__}: an SE(3) team has no association policy; use association='tags'")
        super().__init__(initial, **kw)

    def _initial_state(self, t0: float) -> Team3State:
        n = len(self.robots)
        p, R, P = np.zeros((n, 3)), np.zeros((n, 3, 3)), np.zeros((6 * n, 6 * n))
        for r, b in self.initial.items():
            k = self._idx[r] // 6
            p[k], R[k], P[6 * k : 6 * k + 6, 6 * k : 6 * k + 6] = to_error(np.asarray(b.mean), np.asarray(b.cov))
        return Team3State(p, R, P, (t0,) * n, ((0.0, 0.0),) * n)

    def _advance(self, s: Team3State, robot: int, t: float) -> Team3State:
        k = self._idx[robot] // 6
        dt = t - s.t[k]
        if dt <= 0:
            return s
        inc, S = twist_increment(as_twist(*s.cmd[k]), dt, self.noise)
        Ri, ti = inc[:3, :3], inc[:3, 3]
        Rk = s.R[k]
        F, G = transition(Rk, inc)
        i = 6 * k
        P = s.P.copy()
        P[i : i + 6, :] = F @ P[i : i + 6, :]
        P[:, i : i + 6] = P[:, i : i + 6] @ F.T
        P[i : i + 6, i : i + 6] += G @ S @ G.T
        blk = P[i : i + 6, i : i + 6]
        P[i : i + 6, i : i + 6] = 0.5 * (blk + blk.T)
        p, R = s.p.copy(), s.R.copy()
        p[k] = s.p[k] + Rk @ ti
        R[k] = Rk @ Ri
        times = list(s.t)
        times[k] = t
        return Team3State(p, R, P, tuple(times), s.cmd)

    def _set_command(self, s: Team3State, robot: int, v: Any, w: Any) -> Team3State:
        cmd = list(s.cmd)
        cmd[self._idx[robot] // 6] = (v, w)
        return Team3State(s.p, s.R, s.P, s.t, tuple(cmd))

    def _advance_commands(self, s: Any, cmds: Any) -> Any:
        return Node._advance_commands(self, s, cmds)

    def _belief(self, s: Team3State, robot: int) -> GroupGaussian:
        k = self._idx[robot] // 6
        i = 6 * k
        return belief_of(*to_group(s.p[k], s.R[k], s.P[i : i + 6, i : i + 6]))

    def joint_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Every robot's pose ``(n, 4, 4)`` and the joint error covariance ``(6n, 6n)`` with every robot predicted
        to ``t`` [s] (robots in increasing id order)."""
        at = (t, 3, 0, ())
        s = self._history.state_before(at)
        for r in self.robots:
            s = self._adv(s, r, t, at)
        return np.stack([_pose(p, R) for p, R in zip(s.p, s.R, strict=True)]), s.P.copy()

    def _fuse_group(self, s: Team3State, g: Group) -> tuple[Team3State, list[Outcome], list[Message]]:
        outcomes: list[Outcome] = []
        ko = self._idx[g.observer] // 6
        for d in g.detections:
            target = self._classify(g, d)
            if target[0] in ("rejected", "unknown"):
                outcomes.append(target)
                continue
            if d.kind not in MODELS3:  # a planar kind in a 3-D team
                outcomes.append(("rejected", f"kind {d.kind!r} is not supported on SE(3)"))
                continue
            m3 = model3(d.kind)
            gi = _pose(s.p[ko], s.R[ko])
            if target[0] == "robot":
                s = self._adv(s, target[1], g.t)  # the detected robot at the detection's stamp
                kt = self._idx[target[1]] // 6
                gk, Ck = _pose(s.p[kt], s.R[kt]), None
                cols = np.r_[6 * ko : 6 * ko + 6, 6 * kt : 6 * kt + 6]
            elif target[0] == "landmark" and m3.targets == "point" and np.shape(target[1][0]) == (3,):
                gk, Ck = target[1]
                cols = np.r_[6 * ko : 6 * ko + 6]
            else:
                outcomes.append(("rejected", f"kind {d.kind!r} of a {target[0]} is not supported on SE(3)"))
                continue
            if m3.kind == Kind.POSE3:
                h, Hi, Hk = m3.predict(gi, gk)
                r, Rn = m3.residual(d.z, h), m3.noise(d.z, d.cov)
            else:
                lin = m3.linearize(d.z, d.cov, gi, gk)
                if lin is None:
                    outcomes.append(("rejected", DEGENERATE3))
                    continue
                r, Hi, Hk, Rn = lin
            if Ck is None:
                H = np.hstack([Hi, Hk])
            else:  # a landmark: its map uncertainty joins the noise
                H, Rn = Hi, Rn + Hk @ Ck @ Hk.T
            res = gated_kalman(np.zeros(6 * len(self.robots)), s.P, r, H, 0.5 * (Rn + Rn.T), self.gate, cols=cols,
                               angles=())  # fmt: skip
            if isinstance(res[0], str):
                outcomes.append(res)
                continue
            dx, P = res
            dx = dx.reshape(-1, 6)
            p = s.p + dx[:, :3]
            R = s.R @ so3_exp(dx[:, 3:])
            s = Team3State(p, R, P, s.t, s.cmd)
            outcomes.append(FUSED)
        return s, outcomes, []
