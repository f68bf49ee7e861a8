"""Time-ordered events: what every source (simulator, dataset reader, network) produces and the runner consumes.

Conventions: times in seconds, robots and landmarks identified by integer ids, planar poses as ``(x, y, theta)``
in the world frame, relative quantities in the observer's body frame (x forward, y left).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Literal

import numpy as np

from swarmloc.text import number, numbers, stamp


class Kind(StrEnum):
    """The kind of a :class:`Detection` (what its ``z`` holds; :class:`Detection` lists them).

    A ``str`` whose value is the kind's name as event files, JSON and network messages spell it, so a member equals,
    hashes and encodes as that string (``Kind.POSE == "pose"``) and prints as it does (``repr`` is the string's):
    a detection read from a file (plain ``str`` kind) and one built with a member are the same. Code compares
    kinds with these members, or asks the kind's model (:data:`swarmloc.sensors.models.MODELS`,
    :data:`swarmloc.sensors.models3.MODELS3`), never with string literals.
    """

    def __repr__(self) -> str:  # a function, not str's slot wrapper, which Sphinx's autodoc cannot describe
        return str.__repr__(self)

    POSE = "pose"
    RANGE_BEARING = "range_bearing"
    RANGE = "range"
    BEARING = "bearing"
    ABSOLUTE = "absolute"
    POSE3 = "pose3"
    RBE3 = "rbe3"
    BEARING3 = "bearing3"


MeasurementKind = Kind | Literal["pose", "range_bearing", "range", "bearing", "absolute", "pose3", "rbe3", "bearing3"]
"""A detection's kind: a :class:`Kind` member or its name."""


@dataclass(frozen=True, slots=True)
class Odometry:
    """Body-frame forward speed ``v`` [m/s] and yaw rate ``w`` [rad/s], held constant over ``[t0, t1]``.

    A 3-D robot (SE(3) team) carries its body twist instead: ``v`` the linear velocity ``(vx, vy, vz)`` and ``w``
    the angular velocity ``(wx, wy, wz)``, tuples of 3 floats (:func:`twist_odometry`)."""

    robot: int
    t0: float
    t1: float
    v: float
    w: float

    @property
    def t(self) -> float:
        """End of the interval (when encoder odometry over it becomes available)."""
        return self.t1

    @property
    def stamp(self) -> float:
        """The command's start ``t0``: where a node files it (the command is in force from ``t0`` on)."""
        return self.t0

    @property
    def dt(self) -> float:
        return self.t1 - self.t0

    def __repr__(self) -> str:
        v, w = (numbers(x) if isinstance(x, tuple) else number(x) for x in (self.v, self.w))
        return f"Odometry(robot={self.robot}, t0={stamp(self.t0)}, t1={stamp(self.t1)}, v={v}, w={w})"


def twist_odometry(robot: int, t0: float, t1: float, twist: object) -> Odometry:
    """Odometry of a 3-D robot: body twist ``(v1, v2, v3, w1, w2, w3)`` [m/s, rad/s] held over ``[t0, t1]``."""
    h = [float(x) for x in np.asarray(twist, dtype=float).ravel()]
    if len(h) != 6:
        raise ValueError(f"twist_odometry: 'twist' must have 6 components, got {len(h)}")
    return Odometry(robot, float(t0), float(t1), tuple(h[:3]), tuple(h[3:]))  # type: ignore[arg-type]


@dataclass(frozen=True, slots=True)
class Detection:
    """One exteroceptive measurement taken by ``observer`` at time ``t``.

    ``kind`` says what ``z`` holds:

    * ``"pose"``: relative pose of the target in the observer's frame, ``z = (x, y, theta)``;
    * ``"range_bearing"``: ``z = (range [m], bearing [rad])``;
    * ``"range"``: ``z = (range,)``; ``"bearing"``: ``z = (bearing,)``;
    * ``"absolute"``: the observer's own world pose ``z = (x, y, theta)`` (GPS-like fix, ``target`` is None);
    * ``"pose3"`` (3-D teams): relative pose of the target in the observer's frame, ``z = (x, y, z, rx, ry, rz)``:
      translation [m] and rotation vector [rad] (``R = exp(r^)``); ``cov`` ``(6, 6)`` of the SE(3) exponential
      coordinates of ``m_true^-1 m_measured`` (translation first);
    * ``"rbe3"`` (3-D): range [m], azimuth and elevation [rad] of the target's position (a robot, or a 3-D
      landmark) in the observer's body frame; ``"bearing3"``: azimuth and elevation only
      (:mod:`swarmloc.sensors.models3`).

    ``target`` is a robot id when ``target_is_robot`` else a landmark id; None for an *anonymous* robot detection
    (a robot was seen, which one is not known): an estimator gives it an identity only with an association policy
    (:mod:`swarmloc.association`), and refuses it otherwise. ``cov`` is the noise covariance
    of ``z`` (in the same coordinates; for ``"pose"``, of the exponential coordinates of the noise
    ``m_true^-1 m_measured``).

    ``truth_target`` is the ground truth behind an anonymous detection (the robot's id, -1 for clutter), for
    scoring only: no estimator reads it, it is not written to event files or sent over the network
    (:mod:`swarmloc.sim.anonymous`).
    """

    observer: int
    t: float
    kind: MeasurementKind
    z: np.ndarray
    cov: np.ndarray
    target: int | None = None
    target_is_robot: bool = True
    truth_target: int | None = None
    """For scoring only, never read by an estimator: the robot an anonymous detection (``target`` None) truly saw,
    or -1 for a false detection (clutter); None when not known."""

    @property
    def stamp(self) -> float:
        return self.t

    def __repr__(self) -> str:
        """Observer, time, kind, what was seen, ``z`` and the noise std (square roots of ``cov``'s diagonal)."""
        if self.kind == Kind.ABSOLUTE:
            of = ""
        elif self.target is None:
            of = ", target=anonymous robot"
        else:
            of = f", target={'robot' if self.target_is_robot else 'landmark'} {self.target}"
        try:
            std = numbers(np.sqrt(np.clip(np.diagonal(np.asarray(self.cov, dtype=float)), 0.0, None)))
            z = numbers(self.z)
        except (TypeError, ValueError):  # a malformed detection (refused by any node) still prints
            std, z = "?", repr(type(self.z).__name__)
        return f"Detection(observer={self.observer}, t={stamp(self.t)}, kind={self.kind!r}{of}, z={z}, std={std})"


@dataclass(frozen=True, slots=True)
class Truth:
    """Ground-truth world pose ``(x, y, theta)`` of ``robot`` at time ``t`` (3-D teams: ``(x, y, z, qx, qy, qz,
    qw)``, the TUM order, unit quaternion)."""

    robot: int
    t: float
    pose: np.ndarray = field(repr=False)

    @property
    def stamp(self) -> float:
        return self.t


Event = Odometry | Detection | Truth

OwnEvent = Odometry | Detection
"""A robot's own measurement: its odometry, or a detection it made (what a robot has, and forwards)."""


def sim_order(e: Event) -> tuple[float, int]:
    """Sort key of a simulated stream: time ``t`` [s] (odometry at its end ``t1``), then at one time odometry (0)
    before detections (1) before truth (2)."""
    if isinstance(e, Odometry):
        return (e.t1, 0)
    return (e.t, 2 if isinstance(e, Truth) else 1)
