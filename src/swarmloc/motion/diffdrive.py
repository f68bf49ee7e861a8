"""Differential-drive robot as a body-twist SDE on SE(2) (thesis eqs. 4.12, 5.1, 5.14).

The pose ``g in SE(2)`` obeys ``(g^-1 dg)^v = h dt + H dw`` with ``w`` a 2-D standard Wiener process (one per
wheel) and, with the misprint of eq. (5.1) fixed (third drift entry ``r/l``, not ``r/2``; compare eq. 5.14)::

    h = [r/2 (w1 + w2), 0, r/l (w1 - w2)]          (forward speed v, lateral 0, yaw rate omega)
    H = sqrt(D) [[r/2, r/2], [0, 0], [r/l, -r/l]]

``w1`` is the wheel whose faster rotation turns the robot left (positive yaw), ``r`` the wheel radius [m], ``l`` the
axle length [m], ``D`` the wheel-speed diffusion [rad^2/s]: each wheel's angular speed is its commanded value plus
white noise of spectral density ``D``. The body-frame diffusion per second is
``Q = H H^T = D diag(r^2/2, 0, 2 r^2/l^2)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class DiffDrive:
    """Differential drive: wheel radius ``r`` [m], axle length ``l`` [m], wheel-speed diffusion ``D`` [rad^2/s]."""

    r: float = 0.033
    l: float = 0.2
    D: float = 5.0

    def twist(self, w1: np.ndarray | float, w2: np.ndarray | float) -> np.ndarray:
        """Drift ``h = (r/2 (w1 + w2), 0, r/l (w1 - w2))`` [m/s, m/s, rad/s] for wheel speeds [rad/s], ``(..., 3)``."""
        w1, w2 = np.broadcast_arrays(np.asarray(w1, dtype=float), np.asarray(w2, dtype=float))
        return np.stack([0.5 * self.r * (w1 + w2), np.zeros(w1.shape), self.r / self.l * (w1 - w2)], axis=-1)

    def H(self) -> np.ndarray:
        """Noise matrix ``sqrt(D) [[r/2, r/2], [0, 0], [r/l, -r/l]]``, shape ``(3, 2)``."""
        r, l = self.r, self.l
        return np.sqrt(self.D) * np.array([[r / 2, r / 2], [0.0, 0.0], [r / l, -r / l]])

    def diffusion(self) -> np.ndarray:
        """Body-frame diffusion per second ``Q = H H^T = D diag(r^2/2, 0, 2 r^2/l^2)``, shape ``(3, 3)``."""
        H = self.H()
        return H @ H.T

    def to_unicycle(self, w1: np.ndarray | float, w2: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Wheel speeds [rad/s] to ``(v [m/s], omega [rad/s])`` (thesis eq. 5.14)."""
        w1 = np.asarray(w1, dtype=float)
        w2 = np.asarray(w2, dtype=float)
        return 0.5 * self.r * (w1 + w2), self.r / self.l * (w1 - w2)

    def from_unicycle(self, v: np.ndarray | float, w: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`to_unicycle`: ``w1 = (v + w l/2)/r``, ``w2 = (v - w l/2)/r``."""
        v = np.asarray(v, dtype=float)
        w = np.asarray(w, dtype=float)
        return (v + 0.5 * w * self.l) / self.r, (v - 0.5 * w * self.l) / self.r
