"""The thesis estimator: exponential-coordinate prediction and n-neighbour fusion, one node per robot.

Each node holds its robot's Gaussian on SE(2) ``(mu, Sigma)`` (right perturbation).

* Prediction (thesis 4.13-4.15): the belief is convolved (second order) with the odometry increment, whose mean
  is ``exp(dt (v, 0, w)^)`` and covariance eq. (5.4) for the body-twist diffusion ``Q(v, w)``
  (:func:`swarmloc.motion.odometry_increment`, exact closed form rather than the Simpson rule 5.12).
* Update (thesis 4.16-4.19 as corrected in :mod:`swarmloc.fusion`): all relative-pose detections a robot made at
  one instant are fused at once, each with the neighbour's belief *answered by the neighbour*
  (:class:`~swarmloc.messages.BeliefQuery`); GPS-like absolute fixes are fused as direct observations of the
  pose. Range/bearing detections of robots and of landmarks with known position (which the thesis has no model
  for) are fused by an iterated update on the group that includes the target's uncertainty
  (:func:`swarmloc.kernels.group.point_update`).

**SE(3).** With an SE(3) initial belief the same node runs on SE(3) (``self.group``): odometry carries the body
twist (:func:`swarmloc.events.twist_odometry`), the increment is :func:`swarmloc.motion.twist3.twist_increment`
(its noise a :class:`~swarmloc.motion.twist3.TwistNoise`), relative poses are ``"pose3"`` detections; the
prediction and fusion kernels are the group-generic ones. Range/bearing and absolute fixes are planar only.

The fusion assumes the neighbour's belief is independent of the robot's own. When two robots measure each other
again and again this is false (their beliefs become correlated through earlier fusions) and the estimator
becomes over-confident: the NEES shows it. :mod:`swarmloc.estimators.ci` and :mod:`swarmloc.estimators.rdl`
fix that.
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple, Protocol, cast

import numpy as np

from swarmloc.events import Kind
from swarmloc.gaussian import GroupGaussian, convolution_F_tensor, symmetric
from swarmloc.kernels import group as K
from swarmloc.lie import SE2, SE3
from swarmloc.messages import BeliefAnswer, Message
from swarmloc.motion import UnicycleNoise, odometry_increment
from swarmloc.motion.twist3 import TwistNoise, as_twist, twist_increment
from swarmloc.node import FUSED, NUMERICAL, Group, Outcome, RobotNode, belief_of, usable_covariance
from swarmloc.sensors.models import DEGENERATE
from swarmloc.sensors.models3 import pose3_matrix

STEP_CACHE_SIZE = 1 << 15
"""Odometry steps kept per (noise model, order) by :func:`_step_map` (the cache is emptied when it is full)."""

StepMap = tuple[np.ndarray, np.ndarray, np.ndarray]
"""One odometry step as an affine map ``(inc_mean (3, 3), L (9, 9), b (9,))`` (:func:`_step_map`)."""
StepCache = dict[tuple[float, float, float], StepMap]

_STEP_CACHES: dict[tuple[int, int], tuple[UnicycleNoise, StepCache]] = {}
_TRANSPOSE = np.array([3 * j + i for i in range(3) for j in range(3)])  # row-major vec(C) -> vec(C^T)


def _step_cache(noise: UnicycleNoise, order: int) -> StepCache:
    hit = _STEP_CACHES.get((id(noise), order))
    if hit is None or hit[0] is not noise:
        if len(_STEP_CACHES) > 64:
            _STEP_CACHES.clear()
        hit = _STEP_CACHES[(id(noise), order)] = (noise, {})
    return hit[1]


def _step_map(cache: StepCache, v: float, w: float, dt: float, noise: UnicycleNoise, order: int) -> StepMap:
    """One prediction step as an affine map: ``(inc_mean (3, 3), L (9, 9), b (9,))`` such that
    :func:`swarmloc.kernels.group.predict` gives mean ``mu @ inc_mean`` and ``vec(cov') = L vec(cov) + b`` (row-major
    ``vec``; the convolution covariance is linear in ``cov``: ``Ad cov Ad^T + B + F(Ad cov Ad^T, B)``, symmetrized).
    Equal to the kernel to rounding; memoized in ``cache`` by ``(v, w, dt)`` (logged odometry repeats itself)."""
    key = (v, w, dt)
    hit = cache.get(key)
    if hit is not None:
        return hit
    inc_mean, inc_cov = odometry_increment(v, w, dt, noise)
    c, s, x, y = inc_mean[0, 0], inc_mean[1, 0], inc_mean[0, 2], inc_mean[1, 2]
    Ad = np.array([[c, s, s * x - c * y], [-s, c, c * x + s * y], [0.0, 0.0, 1.0]])  # Ad(inc^-1)
    L = (Ad[:, None, :, None] * Ad[None, :, None, :]).reshape(9, 9)  # kron(Ad, Ad): vec(Ad C Ad^T) = L vec(C)
    if order == 2:  # vec F(A, B) = M^T vec(A), M[a, k] = sum_b T[9 a + b, k] vec(B)[b]
        M = convolution_F_tensor(SE2).reshape(9, 9, 9).transpose(0, 2, 1) @ inc_cov.ravel()
        L = L + M.T @ L
    L = 0.5 * (L + L[_TRANSPOSE])
    for a in (inc_mean, L):
        a.setflags(write=False)
    b = inc_cov.ravel().copy()
    b.setflags(write=False)
    if len(cache) >= STEP_CACHE_SIZE:
        cache.clear()
    hit = cache[key] = (inc_mean, L, b)
    return hit


class ExpState(NamedTuple):
    """A node's filter state: time [s], command ``(v [m/s], w [rad/s])``, mean ``(3, 3)``, covariance ``(3, 3)``
    (SE(3): ``v``, ``w`` the linear and angular velocity tuples, mean ``(4, 4)``, covariance ``(6, 6)``)."""

    t: float
    v: float
    w: float
    mean: np.ndarray
    cov: np.ndarray


class ExpNode(RobotNode):
    """The exponential-coordinate node (not an estimator itself): one robot's Gaussian on SE(2) or SE(3), the
    thesis' prediction, and the update of :attr:`rule`, the part each estimator class chooses
    (:class:`ThesisFusion`: ``expfusion``; :class:`~swarmloc.estimators.ci.CovarianceIntersection`: ``ci``;
    :class:`~swarmloc.estimators.dr.NoFusion`: ``dr``).

    Parameters (besides :class:`~swarmloc.node.robot.RobotNode`'s)
    --------------------------------------------------------------------
    order: 2 (thesis) or 1 (first-order convolution and fusion).
    iterations: Gauss-Newton passes of the relative-pose fusion; 1 is the thesis' closed form, the default 2
        re-linearizes once (as :func:`swarmloc.fuse_relative`).
    point_iterations: passes of the range/bearing update on the group.
    """

    lazy_odometry = True
    groups = (SE2, SE3)
    rule: ClassVar[UpdateRule]
    """How a detection group updates the state (the estimator's part)."""
    ci_weight: ClassVar[str]
    """The covariance-intersection weight rule (``ci``'s: :attr:`swarmloc.estimators.ExpCI.ci_weight`)."""

    def __init__(
        self,
        robot: int,
        initial: GroupGaussian,
        *,
        order: int = 2,
        iterations: int = K.FUSE_ITERATIONS,
        point_iterations: int = K.POINT_ITERATIONS,
        **kw: Any,
    ) -> None:
        if order not in (1, 2):
            raise ValueError(f"{type(self).__name__}: 'order' must be 1 or 2, got {order!r}")
        for name, val in (("iterations", iterations), ("point_iterations", point_iterations)):
            if not isinstance(val, int) or val < 1:
                raise ValueError(f"{type(self).__name__}: '{name}' must be an integer >= 1, got {val!r}")
        self.order = order
        self.iterations = iterations
        self.point_iterations = point_iterations
        super().__init__(robot, initial, **kw)

    # ------------------------------------------------------------------------------------------------ filter
    def _initial_state(self, t0: float) -> ExpState:
        return ExpState(t0, 0.0, 0.0, np.array(self.initial.mean), np.array(self.initial.cov))

    def _advance(self, s: ExpState, robot: int, t: float) -> ExpState:
        dt = t - s.t
        if dt <= 0:
            return s
        if self.group is SE3:
            inc_mean, inc_cov = twist_increment(as_twist(s.v, s.w), dt, cast(TwistNoise, self.noise))  # SE(3)'s
        else:
            inc_mean, inc_cov = odometry_increment(s.v, s.w, dt, self.noise)
        mean, cov = K.predict(self.group, s.mean, s.cov, inc_mean, inc_cov, self.order)
        return ExpState(t, s.v, s.w, mean, cov)

    def _set_command(self, s: ExpState, robot: int, v: float, w: float) -> ExpState:
        return ExpState(s.t, v, w, s.mean, s.cov)

    def _advance_commands(self, s: Any, cmds: Any) -> Any:
        """A run of odometry with each step an affine map of the covariance (:func:`_step_map`, memoized): one
        ``9 x 9`` product per step instead of a convolution; equal to :meth:`_advance` per command to rounding
        (tests/test_node.py checks it for every estimator)."""
        if self.measure_time or self.group is SE3:
            return super()._advance_commands(s, cmds)
        cache = _step_cache(self.noise, self.order)
        t, v, w = s.t, s.v, s.w
        mu, c = s.mean, None
        for tk, _, vk, wk in cmds:
            dt = tk - t
            if dt > 0:
                hit = cache.get((v, w, dt))
                if hit is None:
                    hit = _step_map(cache, v, w, dt, self.noise, self.order)
                if c is None:
                    c = s.cov.ravel()
                mu = mu @ hit[0]
                c = hit[1] @ c + hit[2]
                t = tk
            v, w = vk, wk
        if c is None:
            return ExpState(s.t, v, w, s.mean, s.cov)
        C = c.reshape(3, 3)
        return ExpState(t, v, w, mu, symmetric(C))

    def _belief(self, s: ExpState, robot: int) -> GroupGaussian:
        return belief_of(s.mean, s.cov)

    def _fuse_group(self, s: ExpState, g: Group) -> tuple[ExpState, list[Outcome], list[Message]]:
        return self.rule.fuse_group(self, s, g)


class UpdateRule(Protocol):
    """How an exponential-coordinate node fuses a detection group (:attr:`ExpNode.rule`)."""

    def fuse_group(self, node: ExpNode, s: ExpState, g: Group) -> tuple[ExpState, list[Outcome], list[Message]]:
        """The state after group ``g`` (the observer predicted to ``g.t``), the outcomes, the messages to send."""
        ...


# ---------------------------------------------------------------------------------------------------- update
def pseudo(node: ExpNode, d: Any, target: tuple[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """Pseudo-observation ``(nu, W)`` of the robot's own pose (absolute fix or relative pose of a robot), None for
    a point detection (range/bearing)."""
    if node.group is SE3:
        if target[0] == "robot" and d.kind == Kind.POSE3:
            mean, cov = target[1].belief_arrays()
            if mean.shape != (4, 4):
                return None
            return K.relative_to_pseudo(SE3, mean, cov, pose3_matrix(d.z), np.asarray(d.cov, float), node.order)
        return None
    if target[0] == Kind.ABSOLUTE:
        return K.absolute_to_pseudo(d.z, np.asarray(d.cov, float))
    if target[0] == "robot" and d.kind == Kind.POSE:
        nb: BeliefAnswer = target[1]
        mean, cov = nb.belief_arrays()
        return K.relative_to_pseudo(SE2, mean, cov, SE2.from_xytheta(d.z), np.asarray(d.cov, float), node.order)
    return None


def point_gate(node: ExpNode, mean: np.ndarray, cov: np.ndarray, meas: K.PointMeasurement) -> Outcome | None:
    """The gate's verdict on a range/bearing measurement (None: pass, or no gate)."""
    if node.gate.p is None:
        return None
    nis = float(K.point_nis(mean, cov, meas))
    if not np.isfinite(nis):
        return ("rejected", DEGENERATE)
    return node._gated(nis, len(meas.z))


def point(node: ExpNode, mean: np.ndarray, cov: np.ndarray, d: Any, target: tuple[str, Any]) -> Any:
    """Range/bearing update; returns ``(mean, cov)`` or the outcome when it cannot be fused."""
    if target[0] == "robot":
        tm, tc = target[1].belief_arrays()
    else:
        tm, tc = target[1]
    robot = target[0] == "robot"
    meas = K.PointMeasurement(d.kind, d.z, np.asarray(d.cov, float), tm, tc, robot)
    verdict = point_gate(node, mean, cov, meas)
    if verdict is not None:
        return verdict
    m2, c2, ok = K.point_update(mean, cov, meas, node.point_iterations, node.order)
    if not bool(ok):
        return ("rejected", DEGENERATE)
    if not usable_covariance(c2):
        return ("rejected", NUMERICAL)
    return m2, c2


class ThesisFusion:
    """The thesis' update (``expfusion``): every pose pseudo-observation of a group fused at once
    (:func:`swarmloc.kernels.group.fuse_pseudo`), then the range/bearing detections one at a time."""

    def fuse_group(self, node: ExpNode, s: ExpState, g: Group) -> tuple[ExpState, list[Outcome], list[Message]]:
        outcomes: list[Outcome | None] = [None] * len(g.detections)
        nus, Ws, idx, points = [], [], [], []
        G = node.group
        for i, d in enumerate(g.detections):
            target = node._classify(g, d)
            if target[0] in ("rejected", "unknown"):
                outcomes[i] = target
                continue
            obs = pseudo(node, d, target)
            if obs is None:
                points.append((i, d, target))
                continue
            verdict = None if node.gate.p is None else node._gated(float(K.pseudo_nis(G, s.mean, s.cov, *obs)), G.dim)
            if verdict is not None:
                outcomes[i] = verdict
                continue
            nus.append(obs[0])
            Ws.append(obs[1])
            idx.append(i)
        mean, cov = s.mean, s.cov
        if nus:
            m2, c2 = K.fuse_pseudo(G, mean, cov, np.stack(nus), np.stack(Ws), node.order, node.iterations)
            ok = np.isfinite(m2).all() and usable_covariance(c2)
            if ok:
                mean, cov = m2, c2
            for i in idx:
                outcomes[i] = FUSED if ok else ("rejected", NUMERICAL)
        for i, d, target in points:
            if G is SE3 or d.kind == Kind.POSE3:
                outcomes[i] = ("rejected", f"kind {d.kind!r} is not supported on {G.name}")
                continue
            res = point(node, mean, cov, d, target)
            if isinstance(res[0], str):
                outcomes[i] = res
            else:
                mean, cov = res
                outcomes[i] = FUSED
        return ExpState(s.t, s.v, s.w, mean, cov), [o for o in outcomes if o is not None], []  # (every slot set)


class ExpFusion(ExpNode):
    """Thesis estimator (distributed): second-order exponential-coordinate prediction and n-neighbour fusion
    (:class:`ExpNode` with :class:`ThesisFusion`)."""

    name = "expfusion"
    rule = ThesisFusion()
