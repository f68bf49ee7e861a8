"""The world-frame error form of ``diekf`` (:mod:`swarmloc.estimators.diekf`) on each group: a robot's filter state
(:class:`TeamState`), its prediction with the world-frame process noise, and a detection linearized in world-frame
errors (:class:`WorldForm` of SE(2) or SE(3)); :data:`FORMS` holds one per group."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from swarmloc.estimators.dekf import KERNELS, linearize
from swarmloc.events import Kind
from swarmloc.gaussian import symmetric
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import cartesian3 as C3
from swarmloc.kernels import invariant as I
from swarmloc.lie import SE2, SE3
from swarmloc.lie.base import SEGroup
from swarmloc.messages import flat
from swarmloc.motion.twist3 import as_twist, twist_increment
from swarmloc.sensors.models3 import group_model

__all__ = ["FORMS", "TeamState", "WorldForm", "robot_pair", "world_step"]

_EYE = flat(np.eye(3))
_NO_SIGMA = np.zeros((0, 0, 3, 3))
_NO_SIGMA.setflags(write=False)


class TeamState(NamedTuple):
    """A robot's filter state: time [s], command (SE(2): ``(v, w)``; SE(3): the body twist's linear and angular
    velocity), pose (SE(2): ``x (3,)``; SE(3): ``(4, 4)``), world-frame covariance ``P (d, d)`` and the replica
    ``Sigma (n, n, d, d)`` of the team's cross-covariances (robots in ``team`` order; diagonal blocks unused)."""

    t: float
    v: Any
    w: Any
    x: np.ndarray
    P: np.ndarray
    Sigma: np.ndarray


def robot_pair(d: Any, xi: np.ndarray, xj: np.ndarray, group: type[SEGroup] = SE2) -> tuple[np.ndarray, ...] | None:
    """A robot detection ``d`` linearized at the two poses of ``group`` in world-frame errors: ``(r, H_i, H_j, R)``
    (innovation, Jacobians: the model's Cartesian ones times the world basis,
    :func:`~swarmloc.kernels.invariant.world_basis` or :func:`~swarmloc.kernels.cartesian3.world_basis3`; noise), or
    None for a degenerate geometry."""
    planar = group is SE2
    lin: Any = group_model(d.kind, planar).linearize(d.z, d.cov, xi, xj)
    if lin is None:
        return None
    r, Hi, Hj, R = lin
    basis = I.world_basis if planar else C3.world_basis3
    return r, Hi @ basis(xi), Hj @ basis(xj), R


def world_step(x0: float, y0: float, th0: float, P: np.ndarray, v: float, w: float, dt: float,
               noise: Any) -> tuple[float, float, float, np.ndarray]:  # fmt: skip
    """One SE(2) prediction over ``dt`` [s] > 0: the new pose (floats) and world-frame covariance ``P + N^-1 Q N^-T``
    (:func:`swarmloc.kernels.invariant.cartesian_to_world_cov` at the new pose, its products inlined)."""
    x0, y0, th, _, _, q00, q01, q02, q11, q12, q22 = C.increment_terms_xy(x0, y0, th0, v, w, dt, noise)
    Qc = np.array([[q00, q01, q02], [q01, q11, q12], [q02, q12, q22]])
    Ni = np.array([[1.0, 0.0, y0], [0.0, 1.0, -x0], [0.0, 0.0, 1.0]])  # I.world_basis_inv
    return x0, y0, th, P + Ni @ Qc @ Ni.T


class WorldForm:
    """The world-frame error ``xi`` (``g = exp(xi^) g^``) of a pose on ``group`` (module docstring): on SE(2) the pose
    ``(x, y, theta)`` (:mod:`swarmloc.kernels.invariant`), on SE(3) the pose ``(4, 4)``, ``"pose3"`` with constant
    Jacobians (:func:`~swarmloc.kernels.cartesian3.relative_pose3_world`); every other kind's Cartesian Jacobians
    times the world basis (:func:`robot_pair`). The covariances of SE(3)'s products are symmetrized."""

    def __init__(self, group: type[SEGroup] = SE2) -> None:
        self.group, self.dim, self.planar = group, group.dim, group is SE2
        self.runs = self.clusters = self.planar
        """``runs``: whether a run of odometry has a float loop (:meth:`DistributedInvariantEKF._advance_commands`);
        ``clusters``: whether the covariance-intersection weight of an outsider is defined (SE(2)'s)."""
        self.eye = flat(np.eye(self.dim))

    def _sym(self, P: np.ndarray) -> np.ndarray:
        """``P`` symmetrized on SE(3), as it is on SE(2)."""
        return P if self.planar else symmetric(P)

    def initial(self, mean: np.ndarray, cov: np.ndarray) -> tuple[Any, np.ndarray]:
        """Pose and world-frame covariance ``Ad(g) cov Ad(g)^T`` of a right-perturbation belief."""
        x, _ = KERNELS[self.group].from_group(mean, cov)
        A = self.group.Ad(mean, validate=False)
        return x, self._sym(A @ np.asarray(cov, dtype=float) @ A.T)

    def predict(self, x: Any, P: np.ndarray, v: Any, w: Any, dt: float, noise: Any) -> tuple[Any, np.ndarray]:
        """Pose and covariance after the command held over ``dt > 0`` [s] (SE(2): :func:`world_step`; SE(3):
        ``g Delta``, ``P + Ad(g Delta) Sigma_inc Ad(g Delta)^T``)."""
        if self.runs:
            x0, y0, th0 = x.tolist()
            x0, y0, th, P = world_step(x0, y0, th0, P, v, w, dt, noise)
            return np.array([x0, y0, th]), P
        inc, S = twist_increment(as_twist(v, w), dt, noise)
        g = x @ inc
        A = SE3.Ad(g, validate=False)
        return g, symmetric(P + A @ S @ A.T)

    def belief(self, x: Any, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The right-perturbation belief of pose ``x`` with world-frame covariance ``P``: ``Ad(g^-1) P Ad(g^-1)^T``."""
        g = SE2.from_xytheta(x) if self.planar else x
        A = self.group.Ad(self.group.inverse(g, validate=False), validate=False)
        return g, A @ P @ A.T

    def correct(self, x: Any, delta: np.ndarray) -> Any:
        """The pose ``x`` corrected by the world-frame ``delta``: ``exp(hat(delta)) g(x)``."""
        return I.left_correct(x, delta) if self.planar else SE3.normalize(SE3.exp(delta, validate=False) @ x)

    def unsupported(self, d: Any, target: tuple[str, Any]) -> str | None:
        """Why ``d`` of ``target`` cannot be fused on this group (None: it can)."""
        return None if self.planar else C3.unsupported(d, target)

    def robot(self, d: Any, s: Any, xj: Any, Pjj: np.ndarray, Sij: np.ndarray) -> tuple[Any, ...] | str:
        """``(r, H_i, H_j, S, R)`` of robot detection ``d`` of pose ``xj`` (covariance ``Pjj``, cross-covariance
        ``Sij`` with the observer), or the reason it cannot be fused."""
        if d.kind == Kind.POSE3:
            lin: Any = C3.relative_pose3_world(s.x, xj, d.z, d.cov)
        else:
            lin = robot_pair(d, s.x, xj, self.group)
        if lin is None:
            return group_model(d.kind, self.planar).why_degenerate
        r, Hi, Hj, R = lin
        S = Hi @ s.P @ Hi.T + Hi @ Sij @ Hj.T + Hj @ Sij.T @ Hi.T + Hj @ Pjj @ Hj.T + R
        return r, Hi, Hj, self._sym(S), R

    def landmark(self, d: Any, s: Any, target: tuple[str, Any]) -> tuple[Any, ...] | str:
        """``(r, H_i, S, R)`` of a landmark detection (the map's uncertainty in ``S``; on SE(2) in ``R`` too), or the
        reason."""
        if self.planar:
            lin = linearize(d, s.x, target)
            if isinstance(lin, str):
                return lin
            r, Hi_c, R, _ = lin
            Hi = Hi_c @ I.world_basis(s.x)
            return r, Hi, Hi @ s.P @ Hi.T + R, R
        pl, Cl = target[1]
        m = group_model(d.kind, self.planar)
        lin3: Any = m.linearize(d.z, d.cov, s.x, pl)
        if lin3 is None:
            return m.why_degenerate
        r, Hi_c, Hl, R = lin3
        Hi = Hi_c @ C3.world_basis3(s.x)
        return r, Hi, symmetric(Hi @ s.P @ Hi.T + R + Hl @ Cl @ Hl.T), R


FORMS: dict[type, WorldForm] = {SE2: WorldForm(SE2), SE3: WorldForm(SE3)}
"""The world-frame error form of each group."""
