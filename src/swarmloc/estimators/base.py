"""The one protocol every estimator implements, the neighbour channel, and belief conversions.

Protocol (driven identically by the simulator runner, the dataset runner and, later, the network node):

* ``predict(robot, t0, t1, v, w)``: propagate ``robot``'s belief over ``[t0, t1]`` with body-frame odometry
  ``(v [m/s], w [rad/s])`` held constant;
* ``update(robot, t, detections, channel)``: fuse the detections ``robot`` made at time ``t``; beliefs of other
  robots may only be obtained through ``channel.belief_of(k, t)`` (what ``k`` would send over the network);
* ``belief(robot) -> GroupGaussian``: the current belief as a Gaussian on SE(2) in exponential coordinates
  (right perturbation), whatever the estimator's internal parametrization;
* optional innovation gating (``gate``: a probability, e.g. 0.997): a measurement whose normalized innovation
  squared exceeds the chi-square quantile is not fused (real data has outliers: wrong barcodes, occlusions);
* ``shared_belief(robot) -> GroupGaussian``: what ``robot`` answers when a neighbour asks (defaults to its
  belief). A *distributed* estimator keeps one independent node per robot, and a node sees nothing of other
  nodes except what arrives through the channel.

Cartesian beliefs ``(x, y, theta), P`` are converted to and from exponential coordinates to first order:
``g = (x, y, theta)`` and ``y = (R^T dp, dtheta)``, so ``Sigma = T P T^T`` with ``T = diag(R^T, 1)``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Mapping, Sequence
from functools import cache
from typing import Protocol, runtime_checkable

import numpy as np

from swarmloc.events import Detection
from swarmloc.gaussian import GroupGaussian, check_covariance
from swarmloc.lie import SE2
from swarmloc.motion import UnicycleNoise

log = logging.getLogger(__name__)


@cache
def _chi2_ppf(p: float, m: int) -> float:
    from scipy.stats import chi2

    return float(chi2.ppf(p, m))


def _rot_block(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    B = np.eye(3)
    B[0, 0], B[0, 1], B[1, 0], B[1, 1] = c, -s, s, c
    return B


def cartesian_to_group(x: np.ndarray, P: np.ndarray) -> GroupGaussian:
    """``(x, y, theta), P`` (world-frame Cartesian covariance) -> exponential-coordinate Gaussian (first order)."""
    T = _rot_block(x[2]).T
    return GroupGaussian(SE2, SE2.from_xytheta(x), T @ P @ T.T, validate=False)


def group_to_cartesian(b: GroupGaussian) -> tuple[np.ndarray, np.ndarray]:
    """Exponential-coordinate Gaussian -> ``(x, y, theta), P`` (first order)."""
    x = SE2.to_xytheta(b.mean)
    B = _rot_block(x[2])
    return x, B @ b.cov @ B.T


def validate_detection(d: Detection) -> str | None:
    """Return why a detection is unusable (None if it is fine)."""
    try:
        z = np.asarray(d.z, dtype=float)
        cov = np.asarray(d.cov, dtype=float)
    except (TypeError, ValueError) as exc:
        return f"z or cov is not numeric: {exc}"
    want = {"pose": 3, "absolute": 3, "range_bearing": 2, "range": 1, "bearing": 1}.get(d.kind)
    if want is None:
        return f"unknown measurement kind {d.kind!r}"
    if z.shape != (want,):
        return f"z has shape {z.shape}, expected ({want},) for kind {d.kind!r}"
    if not np.isfinite(z).all():
        return "z contains NaN or inf"
    try:
        check_covariance(cov, want, "detection", "cov")
    except ValueError as exc:
        return str(exc)
    if d.kind in ("range_bearing", "range") and z[0] <= 0:
        return f"range must be positive, got {z[0]}"
    return None


@runtime_checkable
class Channel(Protocol):
    """Where an estimator obtains a neighbour's belief: in-process (tests, simulation) or over the network."""

    def belief_of(self, robot: int, t: float) -> GroupGaussian | None:
        """Belief that ``robot`` shares at time ``t``; ``None`` when it does not answer (unknown, offline)."""
        ...


class NoChannel:
    """A channel on which nobody answers (dead reckoning, centralized estimators)."""

    def belief_of(self, robot: int, t: float) -> GroupGaussian | None:
        return None


class CallbackChannel:
    """In-process channel: asks ``answer(robot, t)``; the runner brings the neighbour's filter to ``t`` first.

    Every answer is a fresh immutable :class:`GroupGaussian` (arrays are read-only), so a node can never
    reach into another node's state through it.
    """

    def __init__(
        self,
        answer: Callable[[int, float], GroupGaussian | None],
        call: Callable[[int, float, str, dict], object] | None = None,
    ) -> None:
        self._answer = answer
        self._call = call
        self.requests = 0

    def belief_of(self, robot: int, t: float) -> GroupGaussian | None:
        self.requests += 1
        return self._answer(robot, t)

    def call(self, robot: int, t: float, request: str, payload: dict) -> object:
        """Generic request to ``robot``'s node (e.g. the pairwise exchange of recursive decentralized fusion);
        ``None`` when nobody answers."""
        self.requests += 1
        return None if self._call is None else self._call(robot, t, request, payload)


Landmarks = Mapping[int, tuple[float, float, float, float]]
"""Landmark id -> (x, y, std_x, std_y) in metres."""


def landmark_state(landmarks: Landmarks | None, lid: int | None) -> tuple[np.ndarray, np.ndarray] | None:
    """Position ``(2,)`` and covariance ``(2, 2)`` of a known landmark, or None."""
    if landmarks is None or lid is None or lid not in landmarks:
        return None
    lx, ly, sx, sy = landmarks[lid]
    return np.array([lx, ly], dtype=float), np.diag([sx * sx, sy * sy])


class Estimator:
    """Base class with the protocol; subclasses override what they need.

    Parameters common to all
    ------------------------
    initial: each robot's initial belief (a :class:`GroupGaussian` on SE(2)).
    noise: process-noise model of the odometry (:class:`swarmloc.motion.UnicycleNoise`).
    landmarks: known landmarks ``id -> (x, y, std_x, std_y)``.
    use_relative, use_landmarks: whether detections of robots / of landmarks are fused.
    gate: chi-square gate probability for innovations, or None.
    """

    name = "estimator"
    distributed = True

    def __init__(
        self,
        initial: Mapping[int, GroupGaussian],
        noise: UnicycleNoise,
        landmarks: Landmarks | None = None,
        use_relative: bool = True,
        use_landmarks: bool = True,
        gate: float | None = None,
    ) -> None:
        self.noise = noise
        self.landmarks = landmarks
        self.use_relative = use_relative
        self.use_landmarks = use_landmarks
        if gate is not None and not 0 < gate < 1:
            raise ValueError(f"{type(self).__name__}: 'gate' must be a probability in (0, 1) or None, got {gate!r}")
        self.gate = gate
        if not initial:
            raise ValueError(f"{type(self).__name__}: 'initial' must give at least one robot's belief")
        for r, b in initial.items():
            if not isinstance(b, GroupGaussian) or b.group is not SE2 or b.batch_shape:
                raise ValueError(f"{type(self).__name__}: initial belief of robot {r} must be an SE(2) GroupGaussian")
        self.robots: list[int] = sorted(initial)
        self.stats: dict[str, int] = {
            "predict": 0, "update": 0, "fused": 0, "rejected": 0, "unknown": 0, "gated": 0
        }  # fmt: skip
        self._init_state(initial)

    def _init_state(self, initial: Mapping[int, GroupGaussian]) -> None:
        """Build the estimator's own state from the initial beliefs (subclasses)."""

    def usable(self, robot: int, detections: Sequence[Detection]) -> Iterator[Detection]:
        """The detections that pass :func:`validate_detection`; the others are counted and logged, never raised."""
        for d in detections:
            why = validate_detection(d)
            if why is None:
                yield d
            else:
                self.stats["rejected"] += 1
                log.warning("robot %s: detection at t=%.3f rejected: %s", robot, d.t, why)

    def resolve_target(
        self, robot: int, t: float, d: Detection, channel: Channel
    ) -> GroupGaussian | tuple[np.ndarray, np.ndarray] | None:
        """What a detection is of: the neighbour's belief (asked through the channel) for a robot target,
        ``(position, covariance)`` for a known landmark; None, counted in ``stats``, when it cannot be used."""
        if d.target_is_robot:
            if not self.use_relative:
                return None
            if d.target == robot or d.target is None:
                self.stats["rejected"] += 1
                return None
            nb = channel.belief_of(d.target, t)
            if nb is None:
                self.stats["unknown"] += 1
            return nb
        if not self.use_landmarks:
            return None
        if d.kind == "pose":  # a landmark is a point: it has no relative pose
            self.stats["rejected"] += 1
            return None
        lm = landmark_state(self.landmarks, d.target)
        if lm is None:
            self.stats["unknown"] += 1
        return lm

    def gated(self, nis: float | Callable[[], float], m: int) -> bool:
        """True (and counted) when an innovation fails the chi-square gate of probability ``self.gate``.

        ``nis`` may be a function computing the normalized innovation squared: it is not called without a gate.
        """
        if self.gate is None:
            return False
        value = nis() if callable(nis) else nis
        if not np.isfinite(value):
            return True
        if value > _chi2_ppf(self.gate, m):
            self.stats["gated"] += 1
            return True
        return False

    def _check_robot(self, robot: int) -> None:
        if robot not in self.robots:
            raise KeyError(f"{type(self).__name__}: unknown robot id {robot!r} (known: {self.robots})")

    def predict(self, robot: int, t0: float, t1: float, v: float, w: float) -> None:
        raise NotImplementedError

    def update(self, robot: int, t: float, detections: Sequence[Detection], channel: Channel) -> None:
        raise NotImplementedError

    def belief(self, robot: int) -> GroupGaussian:
        raise NotImplementedError

    def shared_belief(self, robot: int) -> GroupGaussian:
        return self.belief(robot)

    def predicted_belief(self, robot: int, dt: float, v: float, w: float) -> GroupGaussian:
        """Belief ``dt`` seconds ahead under odometry ``(v, w)``, *without* changing the filter.

        Used to record on a time grid and to answer a neighbour's "belief at t" query between odometry readings,
        so that neither depends on when it is asked.
        """
        raise NotImplementedError
