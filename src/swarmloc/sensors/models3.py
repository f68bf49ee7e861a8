"""Detection kinds of 3-D (SE(3)) teams, kept apart from the planar table :data:`swarmloc.sensors.models.MODELS`
(whose every entry the planar filters and the batched engine must handle).

* ``"pose3"``: relative pose of a robot in the observer's frame, ``z = (x, y, z, rx, ry, rz)``: translation [m]
  and rotation vector [rad] (``R = exp(r^)``, ``|r| <= pi``); its covariance ``(6, 6)`` is that of the SE(3)
  exponential coordinates (translation first) of the noise ``m_true^-1 m_measured``.

Like the planar :class:`~swarmloc.sensors.models.MeasurementModel`, a :class:`Model3` predicts with Jacobians,
forms residuals and maps the noise, for the first-order filters (``dekf``, ``cekf`` on SE(3)). Their error of a pose
``(p, R)`` is ``(dp, dtheta)``: ``p_true = p + dp`` (world frame), ``R_true = R exp(dtheta^)`` (body frame), the 3-D
form of the planar ``(x, y, theta)`` error. For ``"pose3"``: ``h = (R_i^T (p_k - p_i), R_i^T R_k)``; residual
``(t_z - h_t, log(h_R^T R_z))``; ``d h / d(dp_i, dtheta_i) = [[-R_i^T, h_t^], [0, -h_R^T]]``, ``d h / d(dp_k,
dtheta_k) = [[R_i^T, 0], [0, I]]``; noise ``diag(R_z, I) cov diag(R_z, I)^T`` (``m exp(n)`` moves the translation
by ``R_z n_v``). tests/test_se3_cekf.py checks the Jacobians against finite differences.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarmloc.lie.se3 import skew, so3_exp, so3_log

__all__ = ["KIND_ORDER3", "MODELS3", "Model3", "model3", "pose3_matrix", "pose3_vector"]


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

    def predict(self, gi: np.ndarray, gk: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(h (4, 4), H_i (6, 6), H_k (6, 6))``: the predicted relative pose of ``gk`` seen from ``gi`` (``4 x 4``
        poses) and its Jacobians with respect to the two poses' ``(dp, dtheta)`` errors (module docstring)."""
        Ri, Rk = gi[:3, :3], gk[:3, :3]
        ht = Ri.T @ (gk[:3, 3] - gi[:3, 3])
        hR = Ri.T @ Rk
        h = np.eye(4)
        h[:3, :3], h[:3, 3] = hR, ht
        Hi = np.zeros((6, 6))
        Hi[:3, :3] = -Ri.T
        Hi[:3, 3:] = skew(ht)
        Hi[3:, 3:] = -hR.T
        Hk = np.zeros((6, 6))
        Hk[:3, :3] = Ri.T
        Hk[3:, 3:] = np.eye(3)
        return h, Hi, Hk

    def residual(self, z: np.ndarray, h: np.ndarray) -> np.ndarray:
        """``(t_z - h_t, log(h_R^T R_z))`` of ``z (6,)`` against the prediction ``h (4, 4)``."""
        mz = pose3_matrix(z)
        return np.concatenate([mz[:3, 3] - h[:3, 3], so3_log(h[:3, :3].T @ mz[:3, :3])])

    def noise(self, z: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """The noise of the residual: ``diag(R_z, I) cov diag(R_z, I)^T``."""
        J = np.eye(6)
        J[:3, :3] = so3_exp(np.asarray(z, dtype=float)[3:])
        return J @ np.asarray(cov, dtype=float) @ J.T

    def degenerate(self, gi: np.ndarray, gk: np.ndarray) -> bool:
        """Never: a relative pose is defined everywhere."""
        return False


MODELS3: dict[str, Model3] = {"pose3": Model3("pose3", 6, "robot", 11)}
"""3-D detection kinds by name."""


def model3(kind: str) -> Model3:
    """The :class:`Model3` of ``kind``; ValueError naming the known 3-D kinds otherwise."""
    try:
        return MODELS3[kind]
    except (KeyError, TypeError):
        raise ValueError(f"unknown 3-D measurement kind {kind!r}; expected one of {list(MODELS3)}") from None


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
