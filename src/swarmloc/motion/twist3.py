"""Body-twist odometry on SE(3): the Gaussian increment of a constant 6-dof twist with white twist noise.

The robot's pose obeys ``(g^-1 dg)^v = h dt + H dw`` with body twist ``h = (v1, v2, v3, w1, w2, w3)`` (translation
first, DESIGN.md) held constant over an odometry interval and diffusion ``Q = H H^T`` per second. Started at the
identity, to first order in the noise (right perturbation ``g(t) = mu(t) exp(y)``), as for SE(2) (thesis 5.3, 5.4)::

    mu(t)    = exp(t h^)
    Sigma(t) = int_0^t Ad(exp(-tau h^)) Q Ad(exp(-tau h^))^T dtau

Since ``Ad(exp(-tau h^)) = expm(-tau ad(h))``, ``Sigma`` is the Gramian of a linear system and has the closed form
of Van Loan (1978): with ``M = [[ad(h), Q], [0, -ad(h)^T]] t``, ``expm(M) = [[E11, E12], [0, E22]]`` and
``Sigma(t) = E22^T E12``. One ``12 x 12`` matrix exponential per interval, exact for any twist (no series in the
rotation angle). This is the same covariance the SE(2) closed forms give (:mod:`swarmloc.motion.closed_form`) when
``h`` and ``Q`` live in the plane (tested). The estimators convolve the belief with this increment to second order
(:func:`swarmloc.kernels.group.predict`); tests/test_se3_team.py checks both against Monte Carlo of the SDE.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.linalg import expm

from swarmloc.arrays import readonly
from swarmloc.lie import SE3

__all__ = ["TwistNoise", "as_twist", "twist_increment", "twist_increments"]


@dataclass(frozen=True, slots=True)
class TwistNoise:
    """Per-second diffusion of the body twist, diagonal: translational ``q_lin0 + q_lin1 |v|`` [m^2/s] on each of
    the three axes and rotational ``q_ang0 + q_ang1 |w|`` [rad^2/s] on each of the three axes (``|v|``, ``|w|``
    the norms of the commanded linear and angular velocity)."""

    q_lin0: float = 1e-4
    q_lin1: float = 0.0
    q_ang0: float = 1e-4
    q_ang1: float = 0.0

    def __post_init__(self) -> None:
        for name in ("q_lin0", "q_lin1", "q_ang0", "q_ang1"):
            val = getattr(self, name)
            if not (isinstance(val, int | float) and math.isfinite(val) and val >= 0):
                raise ValueError(f"TwistNoise: '{name}' must be a finite number >= 0, got {val!r}")
        if self.q_lin0 <= 0 or self.q_ang0 <= 0:
            raise ValueError("TwistNoise: q_lin0 and q_ang0 must be > 0 (a stopped robot still diffuses)")

    def Q(self, twist: np.ndarray) -> np.ndarray:
        """Diffusion per second ``(6, 6)`` for the body twist ``(6,)``."""
        h = np.asarray(twist, dtype=float)
        ql = self.q_lin0 + self.q_lin1 * float(np.linalg.norm(h[:3]))
        qa = self.q_ang0 + self.q_ang1 * float(np.linalg.norm(h[3:]))
        return np.diag([ql, ql, ql, qa, qa, qa])


def as_twist(v: object, w: object) -> np.ndarray:
    """The body twist ``(6,)`` of a 3-D command: ``v`` the linear velocity ``(3,)`` [m/s], ``w`` the angular
    velocity ``(3,)`` [rad/s]; scalars (a node's stop command ``(0, 0)``) broadcast to all three axes."""
    out = np.empty(6)
    out[:3] = np.broadcast_to(np.asarray(v, dtype=float), (3,))
    out[3:] = np.broadcast_to(np.asarray(w, dtype=float), (3,))
    return out


def twist_increment(twist: np.ndarray, dt: float, noise: TwistNoise) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian increment ``(mean (4, 4), cov (6, 6))`` of the body twist ``(6,)`` held over ``dt`` [s] with
    diffusion ``noise.Q(twist)``: ``mean = exp(dt twist^)``, ``cov`` the Van Loan closed form (module doc).

    Memoized on the exact numbers (a node's history replays the same odometry many times; the ``12 x 12`` matrix
    exponential dominates a 3-D team's run otherwise): the arrays returned are read-only and shared."""
    return _increment_cached(tuple(np.asarray(twist, dtype=float).tolist()), float(dt), noise)


@lru_cache(maxsize=1 << 14)
def _increment_cached(twist: tuple[float, ...], dt: float, noise: TwistNoise) -> tuple[np.ndarray, np.ndarray]:
    mean, cov = twist_increments(np.array(twist, dtype=float), np.asarray(float(dt)), noise)
    return readonly(mean), readonly(cov)


def twist_increments(h: np.ndarray, dt: np.ndarray, noise: TwistNoise) -> tuple[np.ndarray, np.ndarray]:
    """:func:`twist_increment` batched over leading axes, not memoized: twists ``h (..., 6)`` held over ``dt (...)``
    [s] -> ``(mean (..., 4, 4), cov (..., 6, 6))`` (one ``12 x 12`` matrix exponential each, on a stack)."""
    ql = noise.q_lin0 + noise.q_lin1 * np.linalg.norm(h[..., :3], axis=-1)
    qa = noise.q_ang0 + noise.q_ang1 * np.linalg.norm(h[..., 3:], axis=-1)
    ad = SE3.ad(h, validate=False)
    M = np.zeros((*h.shape[:-1], 12, 12))
    M[..., :6, :6] = ad
    idx = np.arange(6)
    M[..., idx, 6 + idx] = np.stack([ql, ql, ql, qa, qa, qa], axis=-1)
    M[..., 6:, 6:] = -np.swapaxes(ad, -1, -2)
    E = expm(M * dt[..., None, None])
    S = np.swapaxes(E[..., 6:, 6:], -1, -2) @ E[..., :6, 6:]
    return SE3.exp(dt[..., None] * h, validate=False), 0.5 * (S + np.swapaxes(S, -1, -2))
