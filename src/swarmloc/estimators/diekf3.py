"""The exact distributed invariant EKF on SE(3) (``diekf`` for 3-D teams): :mod:`swarmloc.estimators.diekf`'s
exchange and broadcast with 6-dof poses, in the right-invariant (world-frame) error.

**Which error.** A pose ``g`` with estimate ``g^`` has the world-frame (right-invariant, Barrau & Bonnabel's
``eta = g g^-1``) error ``xi``, ``g = exp(xi^) g^``, or the body-frame (left-invariant) error ``y``,
``g = g^ exp(y^)`` (the thesis' right perturbation).

* Body-twist odometry ``g+ = g Delta exp(w^)`` is group-affine, so *both* errors propagate autonomously (without
  the estimate): ``y+ = Ad(Delta^-1) y + w`` and ``xi+ = xi + Ad(g^+) w``. The world-frame error's transition is
  the identity: a prediction adds ``Ad(g^+) Sigma_inc Ad(g^+)^T`` to the robot's own covariance and changes no
  cross-covariance, which is what lets every robot keep a replica of the team's cross-covariances without
  exchanging anything between updates (the body-frame error would change them by ``Ad(Delta^-1)`` at every
  odometry step of every robot).
* A relative pose ``z = g_i^-1 g_j exp(n^)`` is autonomous only in the world-frame error: exactly,
  ``g^_i z g^_j^-1 = exp(-xi_i^) exp(xi_j^) exp((Ad(g^_j) n)^)``, so the innovation ``r = log(g^_i z g^_j^-1)``
  has the *constant* Jacobians ``H_i = -I``, ``H_j = I`` and the noise ``Ad(g^_j) R_z Ad(g^_j)^T``. A rigid
  motion ``T`` of the whole team moves every world-frame error by the same ``log T``: the unobservable directions
  ``[I; I; ...]`` are constant and ``H`` annihilates them whatever the estimate, so the filter gains no false
  information along them (the body-frame error gives ``H_i = -Ad(z^^-1)``, ``H_j = I``, and unobservable
  directions ``Ad(g^_k^-1) log T`` that move with the estimate, the inconsistency of Huang et al. 2011).

**Point detections** (``"rbe3"``, ``"bearing3"``: a teammate's position or a known 3-D landmark seen in the
observer's body frame): not autonomous in any error, so their Jacobians depend on the estimates: the Cartesian
ones of :class:`~swarmloc.sensors.models3.Model3` times :func:`world_basis3` (``H_i = H_i^c B(g^_i)``, ``H_j =
H_j^c B(g^_j)``, a landmark: ``j = i``, ``H_j = 0``, map noise added). The invariance that matters survives: a rigid
motion of the whole team moves no body-frame point of a teammate, so ``H_i xi + H_j xi = 0`` for a common ``xi``
exactly, whatever the estimates (``H_j = -H_i`` on ``[I; I]``): the filter still gains no information along the
team's unobservable motion. What it loses against ``"pose3"`` is the constant Jacobian (its linearization error
is that of the EKF's, at the current estimates).

So the filter uses the world-frame error, as the planar ``diekf`` does. Each robot keeps its pose ``g_i (4, 4)``,
``P_ii (6, 6)`` and a replica ``Sigma (n, n, 6, 6)`` of the team's cross-covariances; an update of observer ``i``
detecting ``j``: ``i`` asks ``j`` for ``(g_j, P_jj)`` (:class:`~swarmloc.messages.RdlState` with 16 + 36 numbers),
forms ``S = P_ii - Sigma_ij - Sigma_ji + P_jj + Ad(g_j) R_z Ad(g_j)^T``, gates, broadcasts ``(H_i, H_j, S^-1,
S^-1 r, P_ii, P_jj)`` (:class:`~swarmloc.messages.TeamUpdate` with ``n = 6``) and every robot corrects its pose
``g_a <- exp((Gamma_a S^-1 r)^) g_a``, its covariance and its replica (:meth:`DistributedInvariantEKF._team_update`,
shared with SE(2)). Every step is first order in the errors (prediction: the noise; update: the Kalman gain);
nothing else is approximated, no correlation is left untracked, so the filter does not double count.

On planar motion (poses in the plane ``z = 0``, yaw only, planar twists and block-diagonal noises) the world-frame
errors' planar part ``(v1, v2, w3)`` decouples from the rest and follows the planar ``diekf`` (its prediction is the
same; its relative-pose residual is the Cartesian one, equal to first order; tests/test_se3_diekf.py).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from swarmloc.estimators.diekf import DistributedInvariantEKF
from swarmloc.events import Kind
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE3
from swarmloc.lie.se3 import skew
from swarmloc.messages import BeliefQuery, Message, RdlState, RdlStateQuery, flat
from swarmloc.motion.twist3 import as_twist, twist_increment
from swarmloc.node import Group, Node, belief_of
from swarmloc.sensors.models3 import DEGENERATE3, MODELS3, model3, pose3_matrix

__all__ = ["DistributedInvariantEKF3", "TeamState3", "relative_pose3_world", "world_basis3"]

_EYE6 = flat(np.eye(6))


class TeamState3(NamedTuple):
    """A robot's filter state: time [s], command (linear ``v (3,)`` [m/s], angular ``w (3,)`` [rad/s]), pose
    ``x (4, 4)``, world-frame error covariance ``P (6, 6)`` and the replica ``Sigma (n, n, 6, 6)`` of the team's
    cross-covariances (robots in ``team`` order; diagonal blocks unused)."""

    t: float
    v: Any
    w: Any
    x: np.ndarray
    P: np.ndarray
    Sigma: np.ndarray


def relative_pose3_world(
    gi: np.ndarray, gj: np.ndarray, z: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(r, H_i, H_j, R)`` of a ``"pose3"`` measurement ``z (6,)`` (covariance ``cov (6, 6)``) of pose ``gj`` by
    ``gi`` in world-frame errors: ``r = log(g_i z g_j^-1)``, ``H_i = -I``, ``H_j = I``, ``R = Ad(g_j) cov
    Ad(g_j)^T`` (module docstring)."""
    r = SE3.log(gi @ pose3_matrix(z) @ SE3.inverse(gj, validate=False), validate=False)
    A = SE3.Ad(gj, validate=False)
    R = A @ np.asarray(cov, dtype=float) @ A.T
    return r, -np.eye(6), np.eye(6), 0.5 * (R + R.T)


def world_basis3(g: np.ndarray) -> np.ndarray:
    """``B (6, 6)`` mapping a world-frame error ``xi = (v, w)`` of pose ``g`` (``exp(xi^) g``) to the Cartesian error
    ``(dp, dtheta)`` of :mod:`swarmloc.estimators.dekf3` to first order: ``dp = v - p^ w``, ``dtheta = R^T w``."""
    B = np.eye(6)
    B[:3, 3:] = -skew(g[:3, 3])
    B[3:, 3:] = g[:3, :3].T
    return B


class DistributedInvariantEKF3(DistributedInvariantEKF):
    """Exact distributed invariant EKF on SE(3) (module docstring); takes ``"pose3"``, ``"rbe3"`` and ``"bearing3"``
    detections of robots and ``"rbe3"`` / ``"bearing3"`` ones of known 3-D landmarks."""

    groups = (SE3,)
    lazy_odometry = False
    dim = 6
    _state = TeamState3
    clusters = False  # the covariance-intersection weight of an outsider is SE(2)'s

    def _initial_state(self, t0: float) -> TeamState3:
        g = np.asarray(self.initial.mean, dtype=float)
        A = SE3.Ad(g, validate=False)
        P = A @ np.asarray(self.initial.cov, dtype=float) @ A.T
        n = len(self.team)
        return TeamState3(t0, 0.0, 0.0, g.copy(), 0.5 * (P + P.T), np.zeros((n, n, 6, 6)))

    def _advance(self, s: TeamState3, robot: int, t: float) -> TeamState3:
        dt = t - s.t
        if dt <= 0:
            return s
        inc, S = twist_increment(as_twist(s.v, s.w), dt, self.noise)
        g = s.x @ inc
        A = SE3.Ad(g, validate=False)
        P = s.P + A @ S @ A.T
        return TeamState3(t, s.v, s.w, g, 0.5 * (P + P.T), s.Sigma)

    def _set_command(self, s: TeamState3, robot: int, v: Any, w: Any) -> TeamState3:
        return TeamState3(s.t, v, w, s.x, s.P, s.Sigma)

    def _advance_commands(self, s: Any, cmds: Any) -> Any:
        return Node._advance_commands(self, s, cmds)

    def _belief(self, s: TeamState3, robot: int) -> GroupGaussian:
        A = SE3.Ad(SE3.inverse(s.x, validate=False), validate=False)
        return belief_of(s.x, A @ s.P @ A.T)

    def _answer(self, s: TeamState3, q: Message) -> Message | None:
        if isinstance(q, RdlStateQuery):
            return RdlState(
                sender=q.receiver, receiver=q.sender, stamp=q.stamp, sub=q.sub, x=flat(s.x), P=flat(s.P), sigma=_EYE6
            )
        return super()._answer(s, q) if isinstance(q, BeliefQuery) else None

    def _correct(self, x: np.ndarray, delta: np.ndarray) -> np.ndarray:
        g = SE3.exp(delta, validate=False) @ x
        return SE3.normalize(g)

    def _one(self, s: TeamState3, g: Group, d: Any, target: tuple[str, Any]) -> Any:
        """One detection: the new state and the broadcast's numbers, or an outcome."""
        i = self.robot
        if d.kind not in MODELS3:  # a planar kind in a 3-D team
            return ("rejected", f"kind {d.kind!r} is not supported on SE(3)")
        m3 = model3(d.kind)
        if target[0] == "landmark" and m3.targets == "point" and np.shape(target[1][0]) == (3,):
            pl, Cl = target[1]
            lin = m3.linearize(d.z, d.cov, s.x, pl)
            if lin is None:
                return ("rejected", DEGENERATE3)
            r, Hi_c, Hl, R = lin
            j, Pjj = i, s.P
            Hi = Hi_c @ world_basis3(s.x)
            Hj = np.zeros_like(Hi)
            S = Hi @ s.P @ Hi.T + R + Hl @ Cl @ Hl.T
        elif target[0] == "robot":
            a: RdlState = target[1]
            j = d.target
            if j not in self._pos:
                return ("unknown", f"robot {j} is not in this node's team {list(self.team)}")
            xj, Pjj, _ = a.arrays()
            if xj.shape != (4, 4):
                return ("rejected", "the neighbour's answer is not an SE(3) state")
            Sij = s.Sigma[self._pos[i], self._pos[j]]
            if d.kind == Kind.POSE3:
                r, Hi, Hj, R = relative_pose3_world(s.x, xj, d.z, d.cov)
                S = s.P - Sij - Sij.T + Pjj + R  # H P H^T with H_i = -I, H_j = I
            else:
                lin = m3.linearize(d.z, d.cov, s.x, xj)
                if lin is None:
                    return ("rejected", DEGENERATE3)
                r, Hi_c, Hj_c, R = lin
                Hi, Hj = Hi_c @ world_basis3(s.x), Hj_c @ world_basis3(xj)
                S = Hi @ s.P @ Hi.T + Hi @ Sij @ Hj.T + Hj @ Sij.T @ Hi.T + Hj @ Pjj @ Hj.T + R
        else:
            return ("rejected", f"kind {d.kind!r} of a {target[0]} is not supported on SE(3)")
        return self._gated_update(s, i, j, Hi, Hj, 0.5 * (S + S.T), r, Pjj)
