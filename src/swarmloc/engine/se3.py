"""SE(3) teams in the engine: the per-robot nodes' 3-D prediction and first-order model, batched over robots.

The formulas are those of the nodes (:mod:`swarmloc.estimators.expfusion` and :mod:`swarmloc.estimators.dekf` on
SE(3), :mod:`swarmloc.kernels.cartesian3`, :mod:`swarmloc.motion.twist3`, :mod:`swarmloc.sensors.models3`) on
stacked arrays: poses ``(B, 4, 4)``, covariances ``(B, 6, 6)`` (translation first), commands ``v (B, 3)`` [m/s] and
``w (B, 3)`` [rad/s] (the body twist), intervals ``dt (B,)`` [s].

* :func:`twist_increments`: the Gaussian increments of constant body twists, Van Loan's closed form with one
  batched ``12 x 12`` matrix exponential (:func:`swarmloc.motion.twist3.twist_increments`);
* :func:`predict_group`: the thesis estimator's (and covariance intersection's) prediction on the group;
* :func:`predict_error`, :func:`to_error`, :func:`to_group`: the first-order EKF's state ``(pose, P)``, ``P`` the
  covariance of ``(dp, dtheta)`` (world-frame position, body-frame attitude); the ``"pose3"`` model itself is the
  node's, batched (:mod:`swarmloc.engine.fuse_ekf`).
"""

from __future__ import annotations

import numpy as np

from swarmloc.kernels import cartesian3 as C3
from swarmloc.kernels import group as K
from swarmloc.lie import SE3
from swarmloc.motion import twist3 as T3
from swarmloc.motion.twist3 import TwistNoise


def twist_increments(v: np.ndarray, w: np.ndarray, dt: np.ndarray, noise: TwistNoise) -> tuple[np.ndarray, ...]:
    """Increments ``(mean (B, 4, 4), cov (B, 6, 6))`` of the body twists ``(v, w)`` held over ``dt`` [s] with
    diffusion ``noise.Q``: :func:`swarmloc.motion.twist3.twist_increments` of the stacked twists."""
    return T3.twist_increments(np.concatenate([v, w], axis=-1), dt, noise)


def predict_group(
    mean: np.ndarray, cov: np.ndarray, v: np.ndarray, w: np.ndarray, dt: np.ndarray, noise: TwistNoise, order: int
) -> tuple[np.ndarray, np.ndarray]:
    """Beliefs ``(mean, cov)`` on SE(3) convolved with their increments (:func:`swarmloc.kernels.group.predict`)."""
    inc_mean, inc_cov = twist_increments(v, w, dt, noise)
    return K.predict(SE3, mean, cov, inc_mean, inc_cov, order)


def predict_error(
    g: np.ndarray, P: np.ndarray, v: np.ndarray, w: np.ndarray, dt: np.ndarray, noise: TwistNoise
) -> tuple[np.ndarray, np.ndarray]:
    """The first-order EKF's prediction (:class:`~swarmloc.estimators.dekf.DistributedEKF` on SE(3)): the node's
    :func:`swarmloc.kernels.cartesian3.propagate` on the stack."""
    return C3.propagate(g, P, *twist_increments(v, w, dt, noise))


to_error = C3.from_group
"""``(pose, P)`` of right-perturbation beliefs: ``P = J cov J^T``, ``J = diag(R, I)`` (the node's
:func:`swarmloc.kernels.cartesian3.from_group`, on the stack)."""

to_group = C3.to_group
"""Inverse of :func:`to_error`: the beliefs ``(mean, cov)`` the EKF's nodes answer and record
(:func:`swarmloc.kernels.cartesian3.to_group`)."""


def correct(g: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """Poses corrected by ``dx = (dp, dtheta)`` on the group: ``p + dp``, ``R exp(dtheta^)``."""
    return C3.correct(g, dx)
