"""The distributed EKF (thesis 2.1 and 5.2, Roumeliotis & Bekey): one Cartesian EKF per robot.

Each node keeps its robot's ``(x, y, theta)`` and covariance ``P`` (world frame). Prediction and the update are
the kernels of :mod:`swarmloc.kernels.cartesian`; measurement models (relative pose, range-bearing, range,
bearing; robots or landmarks with known position and standard deviation, slides 9-11 and 18-19) are
:mod:`swarmloc.sensors.models`. A detected neighbour's belief is asked for (:class:`~swarmloc.messages.BeliefQuery`)
and its covariance enters the innovation covariance; the cross-correlation is ignored, which makes the filter
over-confident when robots measure each other repeatedly.

**SE(3).** With an SE(3) initial belief the same node runs on SE(3): its error is the 3-D form of ``(x, y, theta)``,
``(dp, dtheta)`` with ``p_true = p + dp`` (world frame) and ``R_true = R exp(dtheta^)`` (body frame); prediction over
the body twist, the ``"pose3"``, ``"rbe3"`` and ``"bearing3"`` models (robots, and known 3-D landmarks for the point
kinds) and the correction on the group are :mod:`swarmloc.kernels.cartesian3`'s. The group picks the node's
:class:`CartesianForm` once (:data:`FORMS`); the filter's steps are the same.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar, NamedTuple, Protocol, cast

import numpy as np

from swarmloc.events import Detection, Kind
from swarmloc.gaussian import GroupGaussian, symmetric
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import cartesian3 as C3
from swarmloc.lie import SE2, SE3
from swarmloc.messages import Message
from swarmloc.motion import UnicycleNoise
from swarmloc.node import Gate, Group, Outcome, RobotNode, applied, belief_of, gated_kalman
from swarmloc.sensors.models3 import group_model


class CartState(NamedTuple):
    """A node's filter state: time [s], command (SE(2): ``(v, w)``; SE(3): the body twist's linear and angular
    velocity), mean in the form's coordinates (:class:`CartesianForm`) and covariance of its error."""

    t: float
    v: Any
    w: Any
    x: Any
    P: np.ndarray


Linearized = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]
"""``(r, H_i, R_eff, H_k)`` of a detection (:func:`linearize`): ``H_k`` None for an absolute fix."""

Commands = Sequence[tuple[float, int, float, float]]
"""A run of odometry commands ``(t, robot, v, w)`` (time [s], the robot, its velocities [m/s], [rad/s])."""


class FilterState(Protocol):
    """A node's filter state as :func:`predict_run` and ``diekf``'s team protocol read it: time [s], command (SE(2):
    ``(v, w)``; SE(3): the body twist's linear and angular velocity), mean ``x`` and covariance ``P``
    (:class:`CartState`, rdl's and diekf's states)."""

    @property
    def t(self) -> float: ...
    @property
    def v(self) -> Any: ...
    @property
    def w(self) -> Any: ...
    @property
    def x(self) -> np.ndarray: ...
    @property
    def P(self) -> np.ndarray: ...


def linearize(d: Detection, x: Any, target: tuple[str, Any], group: type = SE2) -> Linearized | str:
    """``(r, H_i, R_eff, H_k)`` of detection ``d`` at observer state ``x`` (the :class:`CartesianForm` of ``group``)
    against a classified target (its :class:`~swarmloc.sensors.models.MeasurementModel`, on SE(3) its
    :class:`~swarmloc.sensors.models3.Model3`): innovation, Jacobian w.r.t. the observer, noise plus the target's
    propagated covariance, Jacobian w.r.t. the target. Returns the reason it cannot be fused instead: a degenerate
    geometry (range ~ 0), on SE(3) a kind or target it does not support
    (:func:`~swarmloc.kernels.cartesian3.unsupported`) or a neighbour's answer that is not an SE(3) belief."""
    planar = group is SE2
    why = None if planar else C3.unsupported(d, target)
    if why is not None:
        return why
    m = group_model(d.kind, planar)
    xk = Pk = cast(Any, None)
    if target[0] == "robot":
        mean, Pk = target[1].belief_arrays()
        if not planar and mean.shape != (4, 4):
            return "the neighbour's answer is not an SE(3) belief"
        xk, Pk = KERNELS[group].from_group(mean, Pk)
    elif target[0] != Kind.ABSOLUTE:
        xk, Pk = target[1]
    lin = m.linearize(d.z, d.cov, x, xk)
    if lin is None:
        return m.why_degenerate
    r, Hi, Hk, R = lin
    if Hk is not None:
        R = R + Hk @ Pk @ Hk.T
    return r, Hi, R if planar else symmetric(R), Hk


def predict_run(
    s: FilterState, shear: tuple[float, float], cmds: Commands, noise: UnicycleNoise
) -> tuple[np.ndarray, np.ndarray, float, tuple[float, float], tuple[float, float]]:
    """:func:`~swarmloc.kernels.cartesian.predict_run` of the odometry run ``cmds`` (``(t, robot, v, w)``) with
    process noise ``noise`` on a state with ``t, v, w, x, P``: the new ``(x, P, t, (v, w), shear)`` (``x`` and ``P``
    the same objects when nothing was predicted; ``shear``: rdl's deferred factor shear, accumulated)."""
    p00, p01, p02, _, p11, p12, _, _, p22 = s.P.ravel().tolist()
    x, p, t, cmd, shear = C.predict_run(
        tuple(s.x.tolist()), (p00, p01, p02, p11, p12, p22), s.t, (s.v, s.w), shear,
        [(tk, vk, wk) for tk, _, vk, wk in cmds], noise,
    )  # fmt: skip
    if t == s.t:  # no prediction: only the command changed
        return s.x, s.P, t, cmd, shear
    return np.array(x), C.sym3(p), t, cmd, shear


class CartesianForm:
    """The first-order Cartesian error of a pose on ``group``: on SE(2) the mean ``(x, y, theta)`` and covariance
    ``(3, 3)`` (:mod:`swarmloc.kernels.cartesian`, the planar models :mod:`swarmloc.sensors.models`), on SE(3) the pose
    ``(4, 4)`` and the covariance ``(6, 6)`` of ``(dp, dtheta)`` (:mod:`swarmloc.kernels.cartesian3`, the models of
    :mod:`swarmloc.sensors.models3`), corrected on the group."""

    def __init__(self, group: type) -> None:
        self.group = group
        self.kernel: Any = KERNELS[group]
        self.runs = group is SE2
        """Whether a run of odometry has a one-loop form (:func:`predict_run`)."""

    def initial(self, mean: np.ndarray, cov: np.ndarray) -> tuple[Any, np.ndarray]:
        """Mean and covariance of the error of a right-perturbation belief."""
        x, P = self.kernel.from_group(mean, cov)
        return x, P

    def predict(self, x: Any, P: np.ndarray, v: Any, w: Any, dt: float, noise: Any) -> tuple[Any, np.ndarray]:
        """Mean and covariance after the command ``(v, w)`` held over ``dt > 0`` [s]."""
        x, P, *_ = self.kernel.predict_one(x, P, v, w, dt, noise)
        return x, P

    def belief(self, x: Any, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`initial`."""
        mean, cov = self.kernel.to_group(x, P)
        return mean, cov

    def update(self, x: Any, P: np.ndarray, d: Detection, target: tuple[str, Any], gate: Gate) -> Any:
        """``(x, P)`` after detection ``d`` of a classified ``target`` (a neighbour's uncertainty in the noise), or
        the outcome that stops it."""
        lin = linearize(d, x, target, self.group)
        if isinstance(lin, str):
            return ("rejected", lin)
        r, Hi, R_eff, _ = lin
        if self.group is SE2:  # the Kalman update on (x, y, theta)
            return gated_kalman(x, P, r, Hi, R_eff, gate)
        res = gated_kalman(np.zeros(6), P, r, Hi, R_eff, gate, angles=())
        return res if isinstance(res[0], str) else (C3.correct(x, res[0]), res[1])


KERNELS: dict[type, Any] = {SE2: C, SE3: C3}
"""The Cartesian error's kernels of each group (the same names and forms)."""

FORMS: dict[type, CartesianForm] = {SE2: CartesianForm(SE2), SE3: CartesianForm(SE3)}
"""The Cartesian error form of each group."""


class DistributedEKF(RobotNode):
    """Distributed EKF: one Cartesian EKF per robot, neighbours' covariances as noise, one detection at a time; on
    SE(2) or SE(3) (the initial belief's group; on SE(3) it takes ``"pose3"``, ``"rbe3"`` and ``"bearing3"``
    detections of robots and ``"rbe3"`` / ``"bearing3"`` ones of known 3-D landmarks)."""

    name = "dekf"
    lazy_odometry = True
    groups: ClassVar[tuple[type, ...]] = (SE2, SE3)

    def __init__(self, robot: int, initial: GroupGaussian, **kw: Any) -> None:
        self._form = FORMS.get(getattr(initial, "group", SE2), FORMS[SE2])  # a wrong belief: RobotNode says so
        super().__init__(robot, initial, **kw)

    def _initial_state(self, t0: float) -> CartState:
        x, P = self._form.initial(self.initial.mean, self.initial.cov)
        return CartState(t0, 0.0, 0.0, x, P)

    def _advance(self, s: CartState, robot: int, t: float) -> CartState:
        dt = t - s.t
        if dt <= 0:
            return s
        x, P = self._form.predict(s.x, s.P, s.v, s.w, dt, self.noise)
        return CartState(t, s.v, s.w, x, P)

    def _set_command(self, s: CartState, robot: int, v: Any, w: Any) -> CartState:
        return CartState(s.t, v, w, s.x, s.P)

    def _advance_commands(self, s: CartState, cmds: Commands) -> CartState:
        """A run of odometry in one float loop (:func:`swarmloc.kernels.cartesian.predict_run`: the same bits as one
        :meth:`_advance` per command; tests/test_node.py checks it for every estimator)."""
        if self.measure_time or not self._form.runs:
            stepped: CartState = super()._advance_commands(s, cmds)
            return stepped
        x, P, t, (v, w), _ = predict_run(s, (0.0, 0.0), cmds, self.noise)
        return CartState(t, v, w, x, P)

    def _belief(self, s: CartState, robot: int) -> GroupGaussian:
        return belief_of(*self._form.belief(s.x, s.P))

    def _fuse_group(self, s: CartState, g: Group) -> tuple[CartState, list[Outcome], list[Message]]:
        (x, P), outcomes = self._fuse_each((s.x, s.P), g, self._fuse_one)
        return CartState(s.t, s.v, s.w, x, P), outcomes, []

    def _fuse_one(self, xP: tuple[Any, np.ndarray], d: Detection, target: tuple[str, Any]) -> tuple[Any, Outcome]:
        """One detection's update of the mean and covariance ``xP`` (:meth:`CartesianForm.update`) and its outcome."""
        x, P = xP
        return applied(xP, self._form.update(x, P, d, target, self.gate))
