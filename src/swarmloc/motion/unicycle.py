"""Unicycle ``(v, omega)`` odometry with a continuous-time body-twist diffusion (for real data).

Model: over an odometry interval of length ``dt`` with reported forward speed ``v`` [m/s] and yaw rate ``omega``
[rad/s], the pose increment is the SDE ``(g^-1 dg)^v = (v, 0, omega) dt + dW`` with ``dW`` white, covariance
``Q(v, omega) dt`` per step, ``Q = diag(q_fwd, q_lat, q_yaw)`` per second::

    q_fwd = q_v0 + q_v1 |v| + q_v2 v^2                        [m^2/s]
    q_lat = q_lat0 + q_lat1 |v|                               [m^2/s]
    q_yaw = q_w0 + q_w1 |omega| + q_w2 omega^2 + q_wv |v|     [rad^2/s]

(units of the coefficients follow: ``q_v1`` [m], ``q_v2`` [s], ``q_w1`` [rad], ``q_w2`` [s], ``q_wv`` [rad^2/m].)
Terms in ``|v|`` model noise growing with distance travelled (a variance per metre), terms in ``v^2`` noise
proportional to the speed (a relative speed error). A differential drive with wheel diffusion ``D`` is
``q_v0 = D r^2/2``, ``q_w0 = 2 D r^2/l^2`` (:meth:`UnicycleNoise.from_diff_drive`).

The increment is Gaussian on SE(2) with mean ``exp(dt (v, 0, omega)^)`` and covariance (5.4), evaluated in
closed form (:mod:`swarmloc.motion.closed_form`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from swarmloc.motion.closed_form import (
    increment_mean_closed,
    unicycle_cov,
    unicycle_increment_scalar,
    unicycle_increment_terms,
)
from swarmloc.motion.diffdrive import DiffDrive

Speed = TypeVar("Speed", float, np.ndarray)
"""A speed [m/s or rad/s]: a float, or an array of them (batched)."""


@dataclass(frozen=True, slots=True)
class UnicycleNoise:
    """Coefficients of the per-second body-twist diffusion ``Q(v, omega)`` (see module doc)."""

    q_v0: float = 1e-4
    q_v1: float = 0.0
    q_v2: float = 0.0
    q_lat0: float = 0.0
    q_lat1: float = 0.0
    q_w0: float = 1e-3
    q_w1: float = 0.0
    q_w2: float = 0.0
    q_wv: float = 0.0

    @classmethod
    def from_diff_drive(cls, dd: DiffDrive) -> UnicycleNoise:
        """The constant diffusion ``H H^T`` of a differential drive."""
        return cls(q_v0=dd.D * dd.r**2 / 2, q_w0=2 * dd.D * dd.r**2 / dd.l**2)

    def diag(self, v: Speed, omega: Speed) -> tuple[Speed, Speed, Speed]:
        """``(q_fwd, q_lat, q_yaw)`` for speeds ``v``, ``omega`` (scalars or broadcastable arrays)."""
        av, aw = abs(v), abs(omega)
        q_fwd = self.q_v0 + self.q_v1 * av + self.q_v2 * v * v
        q_lat = self.q_lat0 + self.q_lat1 * av
        q_yaw = self.q_w0 + self.q_w1 * aw + self.q_w2 * omega * omega + self.q_wv * av
        return q_fwd, q_lat, q_yaw

    def Q(self, v: np.ndarray | float, omega: np.ndarray | float) -> np.ndarray:
        """Diffusion per second ``diag(q_fwd, q_lat, q_yaw)``, shape ``(..., 3, 3)``."""
        v = np.asarray(v, dtype=float)
        omega = np.asarray(omega, dtype=float)
        d = np.stack(np.broadcast_arrays(*self.diag(v, omega)), axis=-1)
        return d[..., :, None] * np.eye(3)


def odometry_increment(
    v: np.ndarray | float, omega: np.ndarray | float, dt: np.ndarray | float, noise: UnicycleNoise
) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian increment ``(mean (..., 3, 3), cov (..., 3, 3))`` for odometry ``(v, omega)`` held over ``dt``.

    ``mean = exp(dt (v, 0, omega)^)``; ``cov`` = (5.4) with ``Q = noise.Q(v, omega)``, exact closed form, right
    perturbation (``g = mean exp(y)``, ``y ~ N(0, cov)``). Scalars take a pure-Python fast path.
    """
    scalars = (
        type(v) is float
        and type(omega) is float
        and type(dt) is float
        or (np.isscalar(v) and np.isscalar(omega) and np.isscalar(dt))
    )
    if scalars:
        v, omega, dt = float(v), float(omega), float(dt)
        q_fwd, q_lat, q_yaw = noise.diag(v, omega)
        return unicycle_increment_scalar(v, omega, dt, q_fwd, q_yaw, q_lat)
    Q_fwd, Q_lat, Q_yaw = noise.diag(np.asarray(v, dtype=float), np.asarray(omega, dtype=float))  # arrays
    return increment_mean_closed(v, omega, dt), unicycle_cov(v, omega, dt, Q_fwd, Q_yaw, Q_lat)


def odometry_increment_terms(
    v: float, omega: float, dt: float, noise: UnicycleNoise
) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """One increment as floats ``(cos, sin, tx, ty, S11, S12, S13, S22, S23, S33)``
    (:func:`swarmloc.motion.closed_form.unicycle_increment_terms`): what one robot's prediction needs."""
    q_fwd, q_lat, q_yaw = noise.diag(v, omega)
    return unicycle_increment_terms(v, omega, dt, q_fwd, q_yaw, q_lat)
