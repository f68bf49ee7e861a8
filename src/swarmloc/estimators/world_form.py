"""The world-frame error form of ``diekf`` (:mod:`swarmloc.estimators.diekf`) on each group: a robot's filter state
(:class:`TeamState`), its prediction with the world-frame process noise, and a detection linearized in world-frame
errors (:class:`WorldForm` on SE(2), :class:`WorldForm3` on SE(3)); :data:`FORMS` picks one by group."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from swarmloc.estimators.dekf import DEGENERATE, linearize
from swarmloc.events import Kind
from swarmloc.gaussian import symmetric
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import cartesian3 as C3
from swarmloc.kernels import invariant as I
from swarmloc.lie import SE2, SE3
from swarmloc.lie.base import SEGroup
from swarmloc.messages import flat
from swarmloc.motion.twist3 import as_twist, twist_increment
from swarmloc.sensors.models import model

__all__ = ["FORMS", "TeamState", "WorldForm", "WorldForm3", "robot_pair", "world_step"]

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


def robot_pair(d: Any, xi: np.ndarray, xj: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """A robot detection ``d`` linearized at the two poses in world-frame errors: ``(r, H_i, H_j, R)`` (innovation,
    Jacobians, noise), or None for a degenerate geometry."""
    mm = model(d.kind)
    if mm.degenerate(xi, xj):
        return None
    h, Hi_c, Hj_c = mm.predict(xi, xj)
    assert Hj_c is not None  # noqa: S101  (a robot's model: the target's Jacobian)
    return mm.residual(d.z, h), Hi_c @ I.world_basis(xi), Hj_c @ I.world_basis(xj), mm.noise(d.z, d.cov)


def world_step(x0: float, y0: float, th0: float, P: np.ndarray, v: float, w: float, dt: float,
               noise: Any) -> tuple[float, float, float, np.ndarray]:  # fmt: skip
    """One SE(2) prediction over ``dt`` [s] > 0: the new pose (floats) and world-frame covariance ``P + N^-1 Q N^-T``
    (:func:`swarmloc.kernels.invariant.cartesian_to_world_cov` at the new pose, its products inlined)."""
    x0, y0, th, _, _, q00, q01, q02, q11, q12, q22 = C.increment_terms_xy(x0, y0, th0, v, w, dt, noise)
    Qc = np.array([[q00, q01, q02], [q01, q11, q12], [q02, q12, q22]])
    Ni = np.array([[1.0, 0.0, y0], [0.0, 1.0, -x0], [0.0, 0.0, 1.0]])  # I.world_basis_inv
    return x0, y0, th, P + Ni @ Qc @ Ni.T


class WorldForm:
    """The world-frame error on SE(2): pose ``(x, y, theta)``, the planar models' Jacobians times
    :func:`~swarmloc.kernels.invariant.world_basis` (:mod:`swarmloc.kernels.invariant`)."""

    group: type[SEGroup] = SE2
    dim = 3
    runs = True
    """Whether a run of odometry has a float loop (:meth:`DistributedInvariantEKF._advance_commands`)."""
    clusters = True
    """Whether the covariance-intersection weight of an outsider is defined (SE(2)'s)."""
    eye = _EYE

    def initial(self, mean: np.ndarray, cov: np.ndarray) -> tuple[Any, np.ndarray]:
        """Pose and world-frame covariance of a right-perturbation belief."""
        x, _ = C.from_group(mean, cov)
        return x, I.body_to_world(mean, cov)

    def predict(self, x: Any, P: np.ndarray, v: Any, w: Any, dt: float, noise: Any) -> tuple[Any, np.ndarray]:
        """Pose and covariance after the command held over ``dt > 0`` [s] (:func:`world_step`)."""
        x0, y0, th0 = x.tolist()
        x0, y0, th, P = world_step(x0, y0, th0, P, v, w, dt, noise)
        return np.array([x0, y0, th]), P

    def belief(self, x: Any, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The right-perturbation belief of pose ``x`` with world-frame covariance ``P``."""
        g = SE2.from_xytheta(x)
        return g, I.world_to_body(g, P)

    def correct(self, x: Any, delta: np.ndarray) -> Any:
        """The pose ``x`` corrected by the world-frame ``delta``: ``exp(hat(delta)) g(x)``."""
        return I.left_correct(x, delta)

    def unsupported(self, d: Any, target: tuple[str, Any]) -> str | None:
        """Why ``d`` of ``target`` cannot be fused on this group (None: it can)."""
        return None

    def robot(self, d: Any, s: Any, xj: Any, Pjj: np.ndarray, Sij: np.ndarray) -> tuple[Any, ...] | str:
        """``(r, H_i, H_j, S, R)`` of robot detection ``d`` of pose ``xj`` (covariance ``Pjj``, cross-covariance
        ``Sij`` with the observer), or the reason it cannot be fused."""
        lin = robot_pair(d, s.x, xj)
        if lin is None:
            return DEGENERATE
        r, Hi, Hj, R = lin
        return r, Hi, Hj, Hi @ s.P @ Hi.T + Hi @ Sij @ Hj.T + Hj @ Sij.T @ Hi.T + Hj @ Pjj @ Hj.T + R, R

    def landmark(self, d: Any, s: Any, target: tuple[str, Any]) -> tuple[Any, ...] | str:
        """``(r, H_i, S, R)`` of a landmark detection (the map's uncertainty in ``R``), or the reason."""
        lin = linearize(d, s.x, target)
        if isinstance(lin, str):
            return lin
        r, Hi_c, R, _ = lin
        Hi = Hi_c @ I.world_basis(s.x)
        return r, Hi, Hi @ s.P @ Hi.T + R, R


class WorldForm3(WorldForm):
    """The world-frame error on SE(3): pose ``(4, 4)``, ``"pose3"`` with constant Jacobians
    (:func:`~swarmloc.kernels.cartesian3.relative_pose3_world`), the point kinds' Cartesian Jacobians times
    :func:`~swarmloc.kernels.cartesian3.world_basis3` (module docstring)."""

    group = SE3
    dim = 6
    runs = False
    clusters = False
    eye = flat(np.eye(6))

    def initial(self, mean: np.ndarray, cov: np.ndarray) -> tuple[Any, np.ndarray]:
        g = np.asarray(mean, dtype=float)
        A = SE3.Ad(g, validate=False)
        P = A @ np.asarray(cov, dtype=float) @ A.T
        return g.copy(), symmetric(P)

    def predict(self, x: Any, P: np.ndarray, v: Any, w: Any, dt: float, noise: Any) -> tuple[Any, np.ndarray]:
        inc, S = twist_increment(as_twist(v, w), dt, noise)
        g = x @ inc
        A = SE3.Ad(g, validate=False)
        P = P + A @ S @ A.T
        return g, symmetric(P)

    def belief(self, x: Any, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        A = SE3.Ad(SE3.inverse(x, validate=False), validate=False)
        return x, A @ P @ A.T

    def correct(self, x: Any, delta: np.ndarray) -> Any:
        return SE3.normalize(SE3.exp(delta, validate=False) @ x)

    def unsupported(self, d: Any, target: tuple[str, Any]) -> str | None:
        return C3.unsupported(d, target)

    def robot(self, d: Any, s: Any, xj: Any, Pjj: np.ndarray, Sij: np.ndarray) -> tuple[Any, ...] | str:
        if d.kind == Kind.POSE3:
            r, Hi, Hj, R = C3.relative_pose3_world(s.x, xj, d.z, d.cov)
            S = s.P - Sij - Sij.T + Pjj + R  # H P H^T with H_i = -I, H_j = I
        else:
            lin = C3.linearize(d, s.x, xj)
            if isinstance(lin, str):
                return lin
            r, Hi_c, Hj_c, R = lin
            Hi, Hj = Hi_c @ C3.world_basis3(s.x), Hj_c @ C3.world_basis3(xj)
            S = Hi @ s.P @ Hi.T + Hi @ Sij @ Hj.T + Hj @ Sij.T @ Hi.T + Hj @ Pjj @ Hj.T + R
        return r, Hi, Hj, symmetric(S), R

    def landmark(self, d: Any, s: Any, target: tuple[str, Any]) -> tuple[Any, ...] | str:
        pl, Cl = target[1]
        lin = C3.linearize(d, s.x, pl)
        if isinstance(lin, str):
            return lin
        r, Hi_c, Hl, R = lin
        Hi = Hi_c @ C3.world_basis3(s.x)
        S = Hi @ s.P @ Hi.T + R + Hl @ Cl @ Hl.T
        return r, Hi, symmetric(S), R


FORMS: dict[type, WorldForm] = {SE2: WorldForm(), SE3: WorldForm3()}
"""The world-frame error form of each group."""
