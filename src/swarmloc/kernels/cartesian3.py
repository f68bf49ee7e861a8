"""The first-order errors of an SE(3) pose, the 3-D form of :mod:`swarmloc.kernels.cartesian`'s ``(x, y, theta)``.

A pose is the ``4 x 4`` matrix ``g`` of its position ``p (3,)`` (world frame) and attitude ``R (3, 3)``. The
*Cartesian* error ``(dp, dtheta)`` (``p_true = p + dp``, ``R_true = R exp(dtheta^)``) is that of the first-order EKFs
(``dekf``, ``cekf`` on SE(3)); the *world-frame* error ``xi`` (``g_true = exp(xi^) g``) that of the invariant
``diekf``. Everything is first order:

* prediction over a constant body twist with increment ``(t_inc, R_inc) = exp(dt h^)`` and increment noise
  ``Sigma_inc`` (:func:`swarmloc.motion.twist3.twist_increment`): ``p' = p + R t_inc``, ``R' = R R_inc``,
  ``F = [[I, -R t_inc^], [0, R_inc^T]]``, ``G = diag(R R_inc, I)``, ``P' = F P F^T + G Sigma_inc G^T``
  (:func:`step`, :func:`predict_one`, batched: :func:`propagate`);
* the detections ``"pose3"``, ``"rbe3"``, ``"bearing3"`` of a robot (a pose) or of a known 3-D landmark (a point):
  :class:`~swarmloc.sensors.models3.Model3`'s residual, Jacobians and noise (its ``linearize``);
* the correction is applied on the group, ``p + dp``, ``R exp(dtheta^)`` (:func:`correct`), no reset Jacobian;
* a right-perturbation Gaussian ``g exp(y)`` has ``cov = J^-1 P J^-T`` with ``J = diag(R, I)`` (``g exp(y)`` moves
  the position by ``R v`` to first order): :func:`from_group`, :func:`to_group`.

:func:`step` and :func:`world_basis3` take one pose; the others are batched over leading axes
(the engine's :mod:`swarmloc.engine.se3` stacks robots). :func:`from_group`, :func:`to_group` and :func:`predict_one`
have the names and forms of :mod:`swarmloc.kernels.cartesian`'s (an EKF's form calls either module the same way)."""

from __future__ import annotations

from typing import Any

import numpy as np

from swarmloc.arrays import FloatArray
from swarmloc.gaussian import symmetric
from swarmloc.lie import SE3
from swarmloc.lie.se3 import skew, so3_exp
from swarmloc.motion.twist3 import TwistNoise, as_twist, twist_increment
from swarmloc.sensors.models3 import MODELS3, model3, pose3_matrix

__all__ = [
    "correct",
    "error_cov",
    "frame",
    "from_group",
    "predict_one",
    "propagate",
    "relative_pose3_world",
    "step",
    "to_group",
    "transition",
    "unsupported",
    "world_basis3",
]


_T = np.swapaxes


def frame(R: FloatArray) -> FloatArray:
    """``J = diag(R, I) (..., 6, 6)`` of attitudes ``R (..., 3, 3)``."""
    J = np.broadcast_to(np.eye(6), (*R.shape[:-2], 6, 6)).copy()
    J[..., :3, :3] = R
    return J


def error_cov(R: FloatArray, cov: FloatArray) -> FloatArray:
    """``J cov J^T`` (symmetrized) with ``J = frame(R)``: a right-perturbation covariance as that of
    ``(dp, dtheta)`` (``R`` the attitude), or back (``R^T``)."""
    J = frame(R)
    return symmetric(J @ cov @ _T(J, -1, -2))


def from_group(mean: FloatArray, cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(g, P)`` of right-perturbation SE(3) Gaussians (batched): the pose and ``P = J cov J^T``, ``J = diag(R, I)``
    (the name and form of :func:`swarmloc.kernels.cartesian.from_group`)."""
    mean = np.asarray(mean, dtype=float)
    return mean.copy(), error_cov(mean[..., :3, :3], cov)


def to_group(g: FloatArray, P: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverse of :func:`from_group`: mean ``(..., 4, 4)`` and right-perturbation covariance ``(..., 6, 6)``."""
    return g.copy(), error_cov(_T(g[..., :3, :3], -1, -2), P)


def transition(R: FloatArray, inc: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(F, G)`` of the step ``p' = p + R t_inc``, ``R' = R R_inc`` (increment ``inc (4, 4)``) in the error
    ``(dp, dtheta)``: ``F`` maps the error before to the error after, ``G`` the increment's right-perturbation noise
    to it (first order; tests/test_se3_cekf.py checks both against finite differences)."""
    Ri, ti = inc[..., :3, :3], inc[..., :3, 3]
    F = frame(np.broadcast_to(np.eye(3), R.shape))
    F[..., :3, 3:] = -R @ skew(ti)
    F[..., 3:, 3:] = _T(Ri, -1, -2)
    G = frame(R @ Ri)
    return F, G


def step(g: FloatArray, v: Any, w: Any, dt: float, noise: TwistNoise) -> tuple[FloatArray, ...]:
    """``(g', F, G, Sigma_inc)`` of the pose ``g`` moved by the body twist ``(v, w)`` over ``dt > 0`` [s]."""
    inc, S = twist_increment(as_twist(v, w), dt, noise)
    R = g[:3, :3]
    F, G = transition(R, inc)
    out = g.copy()
    out[:3, 3], out[:3, :3] = g[:3, 3] + R @ inc[:3, 3], R @ inc[:3, :3]
    return out, F, G, S


def predict_one(
    g: FloatArray, P: FloatArray, v: Any, w: Any, dt: float, noise: TwistNoise
) -> tuple[FloatArray, FloatArray]:
    """``(g', P')`` of one robot moved by the body twist ``(v, w)`` over ``dt > 0`` [s] (:func:`propagate`)."""
    return propagate(g, P, *twist_increment(as_twist(v, w), dt, noise))


def propagate(g: FloatArray, P: FloatArray, inc: FloatArray, S: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(g', P')`` of poses ``g`` moved by increments ``inc (..., 4, 4)`` of covariance ``S (..., 6, 6)``, batched
    over leading axes: ``p' = p + R t_inc``, ``R' = R R_inc``, ``P' = F P F^T + G S G^T`` (symmetrized;
    :func:`transition`)."""
    R = g[..., :3, :3]
    F, G = transition(R, inc)
    P1 = F @ P @ _T(F, -1, -2) + G @ S @ _T(G, -1, -2)
    out = g.copy()
    out[..., :3, 3], out[..., :3, :3] = g[..., :3, 3] + (R @ inc[..., :3, 3:])[..., 0], R @ inc[..., :3, :3]
    return out, symmetric(P1)


def correct(g: FloatArray, dx: FloatArray) -> FloatArray:
    """Poses (batched over leading axes) corrected by ``dx = (dp, dtheta)``: ``p + dp``, ``R exp(dtheta^)``."""
    out = g.copy()
    out[..., :3, 3], out[..., :3, :3] = g[..., :3, 3] + dx[..., :3], g[..., :3, :3] @ so3_exp(dx[..., 3:])
    return out


def unsupported(d: Any, target: tuple[str, Any]) -> str | None:
    """Why detection ``d`` of a classified ``target`` cannot be fused on SE(3) (a planar kind, a landmark that is not
    a 3-D point); None when it can."""
    if d.kind not in MODELS3:  # a planar kind in a 3-D team
        return f"kind {d.kind!r} is not supported on SE(3)"
    if target[0] == "robot":
        return None
    if target[0] == "landmark" and model3(d.kind).targets == "point" and np.shape(target[1][0]) == (3,):
        return None
    return f"kind {d.kind!r} of a {target[0]} is not supported on SE(3)"


def world_basis3(g: FloatArray) -> FloatArray:
    """``B (6, 6)`` mapping a world-frame error ``xi = (v, w)`` of pose ``g`` (``exp(xi^) g``) to the Cartesian error
    ``(dp, dtheta)`` to first order: ``dp = v - p^ w``, ``dtheta = R^T w``."""
    B = np.eye(6)
    B[:3, 3:] = -skew(g[:3, 3])
    B[3:, 3:] = g[:3, :3].T
    return B


def relative_pose3_world(
    gi: FloatArray, gj: FloatArray, z: FloatArray, cov: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """``(r, H_i, H_j, R)`` of a ``"pose3"`` measurement ``z (6,)`` (covariance ``cov (6, 6)``) of pose ``gj`` by
    ``gi`` in world-frame errors: ``r = log(g_i z g_j^-1)``, ``H_i = -I``, ``H_j = I``, ``R = Ad(g_j) cov
    Ad(g_j)^T`` (exactly ``g_i z g_j^-1 = exp(-xi_i^) exp(xi_j^) exp((Ad(g_j) n)^)``)."""
    r = SE3.log(gi @ pose3_matrix(z) @ SE3.inverse(gj, validate=False), validate=False)
    A = SE3.Ad(gj, validate=False)
    R = A @ np.asarray(cov, dtype=float) @ A.T
    return r, -np.eye(6), np.eye(6), symmetric(R)
