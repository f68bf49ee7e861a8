"""Planar measurement models in Cartesian coordinates, with Jacobians (for the EKF-family estimators).

States are ``x = (x, y, theta)`` in the world frame. The observed object is either a robot (``(x, y, theta)``)
or a landmark (``(x, y)``). Measurements are in the observer's body frame (x forward, y left); bearings and
relative headings are wrapped to (-pi, pi]. Lecture slides 19 (bearing, distance, orientation) and thesis
eqs. 2.6-2.9 (relative pose).

Every function is batched over leading axes: ``xi`` ``(..., 3)``, ``xk`` ``(..., 3)`` for a robot or ``(..., 2)``
for a landmark, broadcast against each other. Each returns ``(h, H_i, H_k)``: the predicted measurement
``(..., m)``, its Jacobian with respect to the observer's state ``(..., m, 3)`` and with respect to the target's
state ``(..., m, 3)`` for a robot, ``(..., m, 2)`` for a landmark. The math is :mod:`swarmloc.sensors.planar`'s,
written once on an array namespace: the engine's compiled replays and its fast EKF path evaluate the same
expressions.

Range and bearing are undefined when the target sits on the observer (range 0): the Jacobians divide by the
range. :func:`degenerate` tells the callers, which reject such a measurement instead of fusing NaNs.

**One object per sensor kind.** :data:`MODELS` maps each measurement kind to its :class:`MeasurementModel`: the
size of ``z``, which components are angles, what it may observe, its canonical order in a detection group, the
prediction with Jacobians, the residual, the noise in the coordinates the prediction uses and a check of ``z``.
Every estimator, the node's input checks, the event-file reader and the batched engine read these objects, so the
table of kinds exists once.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from swarmloc.events import Kind
from swarmloc.sensors import planar
from swarmloc.sensors.planar import MIN_RANGE as MIN_RANGE  # ranges [m] below it are degenerate (:func:`degenerate`)

DEGENERATE = "degenerate geometry: the target is at the observer's position"
"""The reason a detection is refused where its planar model is :meth:`MeasurementModel.degenerate`."""

Prediction = tuple[np.ndarray, np.ndarray, np.ndarray]
"""``(h, H_i, H_k)``: a predicted measurement and its Jacobians w.r.t. the observer and the target."""


class _Numpy:
    """numpy as :func:`swarmloc.sensors.planar.build` uses it, ``mod`` the operator ``%``: numpy's floor modulo on
    arrays, and on one pair's NumPy scalars its bits 4x faster (:func:`swarmloc.lie.wrap_angle`'s float path)."""

    cos, sin, sqrt, arctan2, hypot, mod = np.cos, np.sin, np.sqrt, np.arctan2, np.hypot, staticmethod(operator.mod)


_P = planar.build(_Numpy)
"""The planar models' math (:mod:`swarmloc.sensors.planar`) on numpy arrays and scalars."""


def _matrix(rows: Sequence[Sequence[np.ndarray | float]], shape: tuple[int, ...], cols: int = 0) -> np.ndarray:
    """``(*shape, len(rows), cols)`` (``cols`` 0: the rows' length; zero columns pad) from rows of entries, each a
    scalar or an array broadcast to ``shape``."""
    cols = cols or len(rows[0])
    if not shape and cols == len(rows[0]):  # one pair: a plain array is ~5x faster
        return np.array(rows, dtype=float)
    out = np.zeros((*shape, len(rows), cols))
    for i, row in enumerate(rows):
        for j, v in enumerate(row):
            out[..., i, j] = v
    return out


def relative_pose(xi: np.ndarray, xk: np.ndarray) -> Prediction:
    """Pose of robot ``k`` in robot ``i``'s frame: ``(R_i^T (p_k - p_i), theta_k - theta_i)``."""
    xi, xk = np.asarray(xi, dtype=float), np.asarray(xk, dtype=float)
    h, Hi, Hk = _P.pose(xi[..., 0], xi[..., 1], xi[..., 2], xk[..., 0], xk[..., 1], xk[..., 2])
    shape = np.shape(h[0])
    return _matrix((h,), shape)[..., 0, :], _matrix(Hi, shape), _matrix(Hk, shape)


def range_bearing(xi: np.ndarray, pk: np.ndarray, target_dim: int | None = None) -> Prediction:
    """Range [m] and bearing [rad] of point/robot ``k`` seen from robot ``i``.

    ``target_dim`` (2 for a landmark, 3 for a robot) defaults to the last dimension of ``pk``.
    """
    xi, pk = np.asarray(xi, dtype=float), np.asarray(pk, dtype=float)
    h, Hi, Hk = _P.range_bearing(xi[..., 0], xi[..., 1], xi[..., 2], pk[..., 0], pk[..., 1])
    shape = np.shape(h[0])
    return _matrix((h,), shape)[..., 0, :], _matrix(Hi, shape), _matrix(Hk, shape, target_dim or pk.shape[-1])


def range_only(xi: np.ndarray, pk: np.ndarray, target_dim: int | None = None) -> Prediction:
    """Range [m] of ``k`` from ``i`` (slides eq. 4)."""
    h, Hi, Hk = range_bearing(xi, pk, target_dim)
    return h[..., :1], Hi[..., :1, :], Hk[..., :1, :]


def bearing_only(xi: np.ndarray, pk: np.ndarray, target_dim: int | None = None) -> Prediction:
    """Bearing [rad] of ``k`` in ``i``'s frame (slides eq. 3)."""
    h, Hi, Hk = range_bearing(xi, pk, target_dim)
    return h[..., 1:], Hi[..., 1:, :], Hk[..., 1:, :]


_PREDICT: dict[str, Callable[[np.ndarray, np.ndarray], Prediction]] = {
    Kind.POSE: relative_pose, Kind.RANGE_BEARING: range_bearing, Kind.RANGE: range_only, Kind.BEARING: bearing_only
}  # fmt: skip


def predict(kind: Kind, xi: np.ndarray, xk: np.ndarray) -> Prediction:
    """Dispatch on the measurement kind; ``xk`` with last dimension 2 is a landmark, 3 a robot."""
    if kind not in _PREDICT:
        raise ValueError(f"unknown measurement kind {kind!r}; expected one of {sorted(_PREDICT)}")
    xk = np.asarray(xk, dtype=float)
    if kind == Kind.POSE:
        if xk.shape[-1] != 3:
            raise ValueError("relative pose measurements need a robot target (x, y, theta)")
        return relative_pose(xi, xk)
    return _PREDICT[kind](xi, xk)


def degenerate(kind: Kind, xi: np.ndarray, xk: np.ndarray) -> np.ndarray:
    """True where a range/bearing model is undefined: the target is within :data:`MIN_RANGE` of the observer."""
    if kind == Kind.POSE:
        return np.zeros(np.broadcast_shapes(np.shape(xi)[:-1], np.shape(xk)[:-1]), dtype=bool)
    xi, xk = np.asarray(xi, dtype=float), np.asarray(xk, dtype=float)
    return _P.degenerate(xi[..., 0], xi[..., 1], xk[..., 0], xk[..., 1])


def residual(kind: str, z: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``z - h`` with angular components wrapped (batched, ``z`` and ``h`` broadcast): :mod:`swarmloc.sensors.planar`'s
    residual of a pose (an absolute fix's too), or the entries of a range and bearing's that a point kind holds."""
    c = MODELS[kind].components
    zs, hs = np.asarray(z, dtype=float).T, np.asarray(h, dtype=float).T  # axes reversed: the entries first
    if not c:
        return np.array(_P.pose_residual(zs, hs)).T
    zp, hp = ([a[c.index(i)] if i in c else 0.0 for i in (0, 1)] for a in (zs, hs))  # (range, bearing): lacking 0
    r = _P.range_bearing_residual(zp, hp)
    return np.array([r[i] for i in c]).T


def pose_noise_to_cartesian(z: np.ndarray, cov_exp: np.ndarray) -> np.ndarray:
    """Covariance of a measured relative pose ``z = (x, y, theta)`` in Cartesian coordinates (first order).

    Pose measurements carry noise as ``m = m_true exp(n)`` (right perturbation, ``n ~ N(0, cov_exp)``), so
    ``d(x, y) = R(theta_z) d(v1, v2)`` and ``d theta = d alpha``. Batched.
    """
    z = np.asarray(z, dtype=float)
    B = _matrix(_P.rotation(z[..., 2]), z.shape[:-1])
    return B @ cov_exp @ np.swapaxes(B, -1, -2)


@dataclass(frozen=True, slots=True)
class MeasurementModel:
    """One kind of detection (:class:`swarmloc.events.Detection`): everything a filter needs about it.

    ``kind``: its name; ``size``: the dimension of ``z``; ``angular``: which components of ``z`` are angles
    (residuals wrapped to (-pi, pi]); ``targets``: ``"self"`` (an absolute fix of the observer's own pose),
    ``"robot"`` (only a robot: a relative pose) or ``"point"`` (a robot or a landmark); ``order``: its rank in the
    canonical order of a detection group; ``components``: for a point kind, which of (range, bearing) ``z`` holds,
    in order (``(0, 1)``, ``(0,)``, ``(1,)``), empty for a pose.
    """

    kind: Kind
    size: int
    angular: tuple[bool, ...]
    targets: str
    order: int
    components: tuple[int, ...] = ()
    why_degenerate = DEGENERATE
    """The reason a detection is refused where :meth:`degenerate`."""

    @property
    def ranged(self) -> bool:
        """True when ``z[0]`` is a range [m] (it must be positive)."""
        return self.components[:1] == (0,)

    @property
    def bearing_last(self) -> bool:
        """True when ``z[-1]`` is a bearing [rad] of a point (within [-pi, pi])."""
        return self.components[-1:] == (1,)

    def predict(self, xi: np.ndarray, xk: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``(h, H_i, H_k)`` at observer state ``xi`` (``(..., 3)``) and target ``xk`` (robot ``(..., 3)`` or
        landmark ``(..., 2)``); an absolute fix observes ``xi`` itself (``H_i = I``, ``H_k`` None)."""
        if self.targets == "self":
            xi = np.asarray(xi, dtype=float)
            return xi.copy(), np.broadcast_to(np.eye(3), (*xi.shape[:-1], 3, 3)).copy(), None
        if xk is None:
            raise ValueError(f"a {self.kind!r} measurement is predicted from a target's state; none was given")
        return predict(self.kind, xi, xk)

    def residual(self, z: np.ndarray, h: np.ndarray) -> np.ndarray:
        """``z - h`` with the angular components wrapped (batched)."""
        return residual(self.kind, z, h)

    def degenerate(self, xi: np.ndarray, xk: np.ndarray | None) -> np.ndarray:
        """True where the model is undefined at these states (a range/bearing target on the observer)."""
        if xk is None or self.targets != "point":
            return np.zeros(np.shape(xi)[:-1], dtype=bool)
        return degenerate(self.kind, xi, xk)

    def linearize(
        self, z: np.ndarray, cov: np.ndarray, xi: np.ndarray, xk: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray] | None:
        """``(r, H_i, H_k, R)`` of a detection ``z`` (covariance ``cov``) of target ``xk`` (None: an absolute fix)
        from ``xi``: the residual, the Jacobians (:meth:`predict`) and the noise (:meth:`noise`); None where
        :meth:`degenerate`. The SE(3) models (:class:`~swarmloc.sensors.models3.Model3`) answer it too."""
        if self.degenerate(xi, xk):
            return None
        h, Hi, Hk = self.predict(xi, xk)
        return self.residual(z, h), Hi, Hk, self.noise(z, cov)

    def noise(self, z: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """The noise covariance of ``z`` in the coordinates :meth:`predict` uses: a relative pose's noise is given
        on the exponential coordinates of ``m_true^-1 m_measured`` and mapped to Cartesian ones
        (:func:`pose_noise_to_cartesian`); every other kind's is used as given."""
        cov = np.asarray(cov, dtype=float)
        if self.kind == Kind.POSE:
            return pose_noise_to_cartesian(np.asarray(z, dtype=float), cov)
        return cov

    def problem(self, z: np.ndarray) -> str | None:
        """Why a finite ``z`` of the right shape is not a possible measurement (None: it is): a range must be
        positive."""
        if self.ranged and not float(z[0]) > 0:
            return f"range must be positive, got {float(z[0])}"
        return None


MODELS: dict[str, MeasurementModel] = {
    m.kind: m
    for m in (
        MeasurementModel(Kind.ABSOLUTE, 3, (False, False, True), "self", 0),
        MeasurementModel(Kind.POSE, 3, (False, False, True), "robot", 1),
        MeasurementModel(Kind.RANGE_BEARING, 2, (False, True), "point", 2, (0, 1)),
        MeasurementModel(Kind.RANGE, 1, (False,), "point", 3, (0,)),
        MeasurementModel(Kind.BEARING, 1, (True,), "point", 4, (1,)),
    )
}
"""The measurement model of every detection kind, by name (in canonical group order)."""

KIND_ORDER: dict[str, int] = {k: m.order for k, m in MODELS.items()}
"""Rank of each kind in the canonical order of a detection group."""

SIZES: dict[str, int] = {k: m.size for k, m in MODELS.items()}
"""Dimension of ``z`` for each kind."""


def model(kind: str) -> MeasurementModel:
    """The :class:`MeasurementModel` of ``kind``; ValueError naming the known kinds otherwise."""
    try:
        return MODELS[kind]
    except (KeyError, TypeError):
        raise ValueError(f"unknown measurement kind {kind!r}; expected one of {list(MODELS)}") from None
