"""Detection kinds of 3-D (SE(3)) teams, kept apart from the planar table :data:`swarmloc.sensors.models.MODELS`
(whose every entry the planar filters and the batched engine must handle).

* ``"pose3"``: relative pose of a robot in the observer's frame, ``z = (x, y, z, rx, ry, rz)``: translation [m]
  and rotation vector [rad] (``R = exp(r^)``, ``|r| <= pi``); its covariance ``(6, 6)`` is that of the SE(3)
  exponential coordinates (translation first) of the noise ``m_true^-1 m_measured``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarmloc.lie.se3 import so3_exp, so3_log

__all__ = ["KIND_ORDER3", "MODELS3", "Model3", "pose3_matrix", "pose3_vector"]


@dataclass(frozen=True, slots=True)
class Model3:
    """A 3-D detection kind: name, size of ``z``, what it observes, rank in a group's canonical order."""

    kind: str
    size: int
    targets: str
    order: int

    def problem(self, z: np.ndarray) -> str | None:
        """Why ``z`` (finite, of the right size) is not a value of this kind, or None."""
        if self.kind == "pose3" and float(np.linalg.norm(z[3:])) > math.pi + 1e-9:
            return f"rotation vector of norm {float(np.linalg.norm(z[3:])):.6g} rad exceeds pi"
        return None


MODELS3: dict[str, Model3] = {"pose3": Model3("pose3", 6, "robot", 11)}
"""3-D detection kinds by name."""

KIND_ORDER3: dict[str, int] = {k: m.order for k, m in MODELS3.items()}
"""Rank of each 3-D kind in the canonical order of a detection group (after the planar kinds)."""


def pose3_matrix(z: np.ndarray) -> np.ndarray:
    """``(..., 6)`` translation and rotation vector -> ``(..., 4, 4)`` homogeneous pose."""
    z = np.asarray(z, dtype=float)
    g = np.zeros((*z.shape[:-1], 4, 4))
    g[..., :3, :3] = so3_exp(z[..., 3:])
    g[..., :3, 3] = z[..., :3]
    g[..., 3, 3] = 1.0
    return g


def pose3_vector(g: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` pose -> ``(..., 6)`` translation and rotation vector (inverse of :func:`pose3_matrix`)."""
    g = np.asarray(g, dtype=float)
    return np.concatenate([g[..., :3, 3], so3_log(g[..., :3, :3])], axis=-1)
