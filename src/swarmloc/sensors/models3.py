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

* ``"rbe3"``: range-bearing-elevation of a point (a robot's position or a known 3-D landmark) in the observer's
  body frame, ``z = (range [m], azimuth [rad], elevation [rad])``, covariance ``(3, 3)`` of those numbers
  (additive noise). With ``y = R_i^T (p_k - p_i)`` and ``rho = |(y1, y2)|``: ``range = |y|``, ``azimuth =
  atan2(y2, y1)`` in (-pi, pi], ``elevation = atan2(y3, rho)`` in [-pi/2, pi/2].
* ``"bearing3"``: bearing-only, ``z = (azimuth, elevation)`` of the same point, covariance ``(2, 2)``.

Their Jacobians: ``d y / d(dp_i, dtheta_i) = (-R_i^T, y^)``, ``d y / d(dp_k, dtheta_k) = (R_i^T, 0)`` (a landmark:
``R_i^T`` on its position), then ``d range / dy = y^T / r``, ``d azimuth / dy = (-y2, y1, 0) / rho^2``, ``d elevation /
dy = (-y1 y3 / rho, -y2 y3 / rho, rho) / r^2``. The residual ``z - h`` wraps both angles to (-pi, pi]. **The
singular direction**: straight above or below (``rho -> 0``, elevation +-90 deg) the azimuth is undefined and its
Jacobian grows like ``1 / rho``; where ``rho < SINGULAR_COS r`` (within 0.06 deg of the vertical) the azimuth row is
dropped (it carries no information about the point's position there) and the elevation's horizontal derivative
(bounded, but direction-less at the pole) with it: :meth:`Model3.linearize` fuses range only (``"rbe3"``), or
rejects a ``"bearing3"`` detection as degenerate; nothing divides by zero (``rho`` and ``r`` are floored). A
target within :data:`~swarmloc.sensors.models.MIN_RANGE` of the observer is degenerate for both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarmloc.events import Kind
from swarmloc.lie import wrap_angle
from swarmloc.lie.se3 import skew, so3_exp, so3_log
from swarmloc.sensors.models import MIN_RANGE, MODELS, MeasurementModel, model

__all__ = [
    "ALL_MODELS",
    "DEGENERATE3",
    "MODELS3",
    "SINGULAR_COS",
    "Model3",
    "group_model",
    "model3",
    "point_in_body",
    "pose3_matrix",
    "pose3_vector",
    "spherical",
]

DEGENERATE3 = "degenerate geometry: the target is at the observer's position (a bearing: straight above or below)"
"""The reason a ``"rbe3"`` / ``"bearing3"`` detection is refused where :meth:`Model3.degenerate`."""

SINGULAR_COS = 1e-3
"""Below this ``cos(elevation)`` (``rho / r``) the azimuth of a ``"rbe3"`` / ``"bearing3"`` detection is not used."""


_T = np.swapaxes


def _eye(n: int, batch: tuple[int, ...]) -> np.ndarray:
    return np.broadcast_to(np.eye(n), (*batch, n, n)).copy()


def point_in_body(gi: np.ndarray, pk: np.ndarray) -> np.ndarray:
    """``y = R_i^T (p_k - p_i)``: point ``pk (..., 3)`` [m] in the body frame of pose ``gi (..., 4, 4)``."""
    gi, pk = np.asarray(gi, dtype=float), np.asarray(pk, dtype=float)
    return np.einsum("...ji,...j->...i", gi[..., :3, :3], pk - gi[..., :3, 3])


def spherical(y: np.ndarray) -> np.ndarray:
    """``(..., 3)`` body-frame point -> ``(..., 3)`` range [m], azimuth (-pi, pi] and elevation [-pi/2, pi/2] [rad];
    straight above or below the azimuth is 0 (``atan2(0, 0)``)."""
    y = np.asarray(y, dtype=float)
    rho = np.hypot(y[..., 0], y[..., 1])
    return np.stack([np.linalg.norm(y, axis=-1), np.arctan2(y[..., 1], y[..., 0]), np.arctan2(y[..., 2], rho)], -1)


@dataclass(frozen=True, slots=True)
class Model3:
    """A 3-D detection kind: name, size of ``z``, what it observes (``"robot"``: a relative pose; ``"point"``: a
    robot's position or a landmark), rank in a group's canonical order, which components of ``z`` are angles."""

    kind: Kind
    size: int
    targets: str
    order: int
    angular: tuple[bool, ...] = ()
    why_degenerate = DEGENERATE3
    """The reason a detection is refused where :meth:`degenerate`."""

    def problem(self, z: np.ndarray) -> str | None:
        """Why ``z`` (finite, of the right size) is not a value of this kind, or None."""
        if self.kind == Kind.POSE3 and float(np.linalg.norm(z[3:])) > math.pi + 1e-9:
            return f"rotation vector of norm {float(np.linalg.norm(z[3:])):.6g} rad exceeds pi"
        if self.kind == Kind.RBE3 and not float(z[0]) > 0:
            return f"range must be positive, got {float(z[0])}"
        if self.kind in (Kind.RBE3, Kind.BEARING3) and abs(float(z[-1])) > math.pi / 2 + 1e-9:
            return f"elevation {float(z[-1]):.6g} rad is outside [-pi/2, pi/2]"
        return None

    def predict(self, gi: np.ndarray, gk: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(h, H_i, H_k)`` of target ``gk`` seen from pose ``gi (4, 4)``, Jacobians with respect to the
        ``(dp, dtheta)`` errors (module docstring). ``"pose3"``: ``gk (4, 4)``, ``h (4, 4)``, ``H (6, 6)``;
        ``"rbe3"`` / ``"bearing3"``: ``gk`` a pose ``(4, 4)`` (``H_k (m, 6)``) or a point ``(3,)`` (a landmark,
        ``H_k (m, 3)``), ``h (m,)``; the rows are finite everywhere (at the pole the azimuth row is 0). ``"pose3"`` is
        batched over leading axes (the engine's stacks, :mod:`swarmloc.engine.fuse_ekf`)."""
        if self.kind != Kind.POSE3:
            return self._predict_point(gi, gk)
        RiT = _T(gi[..., :3, :3], -1, -2)
        ht = (RiT @ (gk[..., :3, 3] - gi[..., :3, 3])[..., None])[..., 0]
        hR = RiT @ gk[..., :3, :3]
        h = _eye(4, ht.shape[:-1])
        h[..., :3, :3], h[..., :3, 3] = hR, ht
        Hi = np.zeros((*ht.shape[:-1], 6, 6))
        Hi[..., :3, :3] = -RiT
        Hi[..., :3, 3:] = skew(ht)
        Hi[..., 3:, 3:] = -_T(hR, -1, -2)
        Hk = np.zeros((*ht.shape[:-1], 6, 6))
        Hk[..., :3, :3] = RiT
        Hk[..., 3:, 3:] = np.eye(3)
        return h, Hi, Hk

    def _predict_point(self, gi: np.ndarray, gk: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        point = np.shape(gk) == (3,)
        y = self._point(gi, gk)
        Ri = gi[:3, :3]
        r2 = max(float(y @ y), MIN_RANGE**2)
        r = math.sqrt(r2)
        rho = math.hypot(y[0], y[1])
        J = np.zeros((3, 3))  # d (range, azimuth, elevation) / d y
        J[0] = y / r
        if rho >= SINGULAR_COS * r:
            J[1] = (-y[1] / rho**2, y[0] / rho**2, 0.0)
            J[2] = (-y[0] * y[2] / (rho * r2), -y[1] * y[2] / (rho * r2), rho / r2)
        else:  # the pole: azimuth undefined, elevation not differentiable in the horizontal
            J[2, 2] = rho / r2
        Ji = np.hstack([-Ri.T, skew(y)])
        Jk = Ri.T if point else np.hstack([Ri.T, np.zeros((3, 3))])
        rows = slice(0, 3) if self.kind == Kind.RBE3 else slice(1, 3)
        return spherical(y)[rows], J[rows] @ Ji, J[rows] @ Jk

    def residual(self, z: np.ndarray, h: np.ndarray) -> np.ndarray:
        """``"pose3"``: ``(t_z - h_t, log(h_R^T R_z))`` of ``z (6,)`` against the prediction ``h (4, 4)``; the other
        kinds: ``z - h`` with the angles wrapped to (-pi, pi]. Batched over leading axes."""
        if self.kind != Kind.POSE3:
            r = np.asarray(z, dtype=float) - np.asarray(h, dtype=float)
            for j, ang in enumerate(self.angular):
                if ang:
                    r[..., j] = wrap_angle(r[..., j])
            return r
        mz = pose3_matrix(z)
        rot = so3_log(_T(h[..., :3, :3], -1, -2) @ mz[..., :3, :3])
        return np.concatenate([mz[..., :3, 3] - h[..., :3, 3], rot], -1)

    def noise(self, z: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """The noise of the residual: ``"pose3"``: ``diag(R_z, I) cov diag(R_z, I)^T``; the others: ``cov``. Batched
        over leading axes."""
        if self.kind != Kind.POSE3:
            return np.asarray(cov, dtype=float)
        z = np.asarray(z, dtype=float)
        J = _eye(6, z.shape[:-1])
        J[..., :3, :3] = so3_exp(z[..., 3:])
        return J @ np.asarray(cov, dtype=float) @ _T(J, -1, -2)

    def degenerate(self, gi: np.ndarray, gk: np.ndarray) -> bool:
        """A relative pose never; a point within :data:`MIN_RANGE` of the observer, or straight above or below it
        for ``"bearing3"`` (only the elevation's vertical derivative is left there, and it is 0)."""
        if self.kind == Kind.POSE3:
            return False
        y = self._point(gi, gk)
        r = float(np.linalg.norm(y))
        return r < MIN_RANGE or (self.kind == Kind.BEARING3 and math.hypot(y[0], y[1]) < SINGULAR_COS * r)

    def linearize(
        self, z: np.ndarray, cov: np.ndarray, gi: np.ndarray, gk: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """``(r, H_i, H_k, R)`` of a detection ``z`` (covariance ``cov``) of target ``gk`` (pose or point) from
        ``gi``, as :meth:`swarmloc.sensors.models.MeasurementModel.linearize`: residual (angles wrapped), Jacobians
        and noise, for ``"rbe3"`` / ``"bearing3"`` restricted to the rows that carry information (at the pole the
        angles are dropped, module docstring); None where :meth:`degenerate`."""
        if self.degenerate(gi, gk):
            return None
        h, Hi, Hk = self.predict(gi, gk)
        r, R = self.residual(z, h), self.noise(z, cov)
        y = self._point(gi, gk)
        if self.kind != Kind.POSE3 and math.hypot(y[0], y[1]) < SINGULAR_COS * float(np.linalg.norm(y)):
            return r[:1], Hi[:1], Hk[:1], R[:1, :1]  # rbe3 at the pole: range only
        return r, Hi, Hk, R

    @staticmethod
    def _point(gi: np.ndarray, gk: np.ndarray) -> np.ndarray:
        """The target's position (a point ``(3,)``, or a pose's) in the body frame of ``gi``."""
        gk = np.asarray(gk, dtype=float)
        return point_in_body(gi, gk if gk.shape == (3,) else gk[:3, 3])


MODELS3: dict[str, Model3] = {
    m.kind: m
    for m in (
        Model3(Kind.POSE3, 6, "robot", 11),
        Model3(Kind.RBE3, 3, "point", 12, (False, True, True)),
        Model3(Kind.BEARING3, 2, "point", 13, (True, True)),
    )
}
"""3-D detection kinds by name."""


def model3(kind: str) -> Model3:
    """The :class:`Model3` of ``kind``; ValueError naming the known 3-D kinds otherwise."""
    try:
        return MODELS3[kind]
    except (KeyError, TypeError):
        raise ValueError(f"unknown 3-D measurement kind {kind!r}; expected one of {list(MODELS3)}") from None


ALL_MODELS: dict[str, MeasurementModel | Model3] = {**MODELS, **MODELS3}
"""The model of every detection kind, planar and 3-D, by name (a kind says its group): its size and its rank in the
canonical order of a detection group, whichever the team."""


def group_model(kind: str, planar: bool) -> MeasurementModel | Model3:
    """The model of ``kind`` in a planar team (:func:`~swarmloc.sensors.models.model`) or a 3-D one
    (:func:`model3`): ValueError naming that group's kinds otherwise. Its ``why_degenerate`` is the reason a
    detection is refused where the model is degenerate."""
    return model(kind) if planar else model3(kind)


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
