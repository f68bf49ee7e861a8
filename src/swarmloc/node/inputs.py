"""A node's input contract: what a detection and an odometry record must be, and each robot's odometry timeline.

* A **detection** has a known kind, a finite value ``z`` of that kind's size that the kind allows (a positive
  range), a finite stamp, a symmetric positive-definite covariance of matching size and an integer target id
  (:func:`validate_detection`).
* An **odometry** record ``(robot, t0, t1, v, w)`` has finite numbers and ``t0 <= t1``; one robot's intervals
  ``[t0, t1]`` do not overlap (up to :data:`CONTIGUOUS` s of rounding): :class:`OdometryTimeline` keeps them and
  says where a new one would overlap and which one is in force at a point of the history. Past the end ``t1``
  of an interval, until the robot's next one starts (a gap) or when none follows, a node assumes the robot
  **stopped**: its command becomes ``(0, 0)`` at ``t1`` and the motion model's zero-speed diffusion keeps its
  covariance growing (counted once per interval: ``odometry_stops``).
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Mapping

import numpy as np

from swarmloc.events import Detection, Odometry
from swarmloc.gaussian import check_covariance
from swarmloc.sensors.models import MODELS

__all__ = ["CONTIGUOUS", "Landmarks", "OdometryTimeline", "landmark_state", "odometry_problem", "validate_detection"]

CONTIGUOUS = 1e-9
"""[s] Odometry intervals that overlap by less than this are contiguous (rounding of stamps)."""

Landmarks = Mapping[int, tuple[float, float, float, float]]
"""Landmark id -> (x, y, std_x, std_y) in metres."""

_VALID_COVS: dict[tuple[int, bytes], bool] = {}
"""Detection covariances already found valid, by ``(dimension, bytes)`` (sensors repeat one covariance)."""


def _clearly_valid(cov: np.ndarray) -> bool:
    """True when ``cov`` is ``1 x 1`` or ``2 x 2``, finite, exactly symmetric and positive definite with a margin
    (``det > 1e-9 trace^2``, so eigenvalues well above rounding): :func:`check_covariance` would accept it. False
    means "not sure": the full check decides."""
    if cov.shape == (1, 1):
        a = float(cov[0, 0])
        return math.isfinite(a) and a > 0
    if cov.shape != (2, 2):
        return False
    a, b, c, d = cov.ravel().tolist()
    if not (b == c and math.isfinite(a) and math.isfinite(b) and math.isfinite(d) and a > 0 and d > 0):
        return False
    return a * d - b * b > 1e-9 * (a + d) ** 2


def _integer(x: object) -> bool:
    return isinstance(x, int | np.integer) and not isinstance(x, bool)


def validate_detection(d: Detection) -> str | None:
    """Why a detection is unusable, or None when its kind, value, stamp, covariance and target are well formed."""
    try:
        z = np.asarray(d.z, dtype=float)
        cov = np.asarray(d.cov, dtype=float)
    except (TypeError, ValueError) as exc:
        return f"z or cov is not numeric: {exc}"
    model = MODELS.get(d.kind) if isinstance(d.kind, str) else None
    if model is None:
        return f"unknown measurement kind {d.kind!r}"
    want = model.size
    if z.shape != (want,):
        return f"z has shape {z.shape}, expected ({want},) for kind {d.kind!r}"
    if not np.isfinite(z).all():
        return "z contains NaN or inf"
    if not (isinstance(d.t, int | float | np.floating) and math.isfinite(d.t)):
        return f"time stamp {d.t!r} is not a finite number"
    seen = (want, cov.tobytes()) if cov.shape == (want, want) else None
    if seen is None or not (_clearly_valid(cov) or seen in _VALID_COVS):
        try:
            check_covariance(cov, want, "detection", "cov")
        except ValueError as exc:
            return str(exc)
        if seen is not None:
            if len(_VALID_COVS) >= 4096:
                _VALID_COVS.clear()
            _VALID_COVS[seen] = True
    why = model.problem(z)
    if why is not None:
        return why
    if d.target is not None and not _integer(d.target):
        return f"target id must be an integer, got {d.target!r}"
    if not _integer(d.observer):
        return f"observer id must be an integer, got {d.observer!r}"
    return None


def odometry_problem(e: Odometry) -> str | None:
    """Why an odometry record is malformed (non-numeric or non-finite numbers, ``t1 < t0``), or None."""
    try:
        finite = all(math.isfinite(x) for x in (e.t0, e.t1, e.v, e.w))
    except TypeError:
        finite = False
    if not finite:
        return "non-finite or non-numeric time or speed"
    if e.t1 < e.t0:
        return "t1 before t0"
    return None


def landmark_state(landmarks: Landmarks | None, lid: int | None) -> tuple[np.ndarray, np.ndarray] | None:
    """Position ``(2,)`` and covariance ``(2, 2)`` of a known landmark, or None."""
    if landmarks is None or lid is None or lid not in landmarks:
        return None
    lx, ly, sx, sy = landmarks[lid]
    return np.array([lx, ly], dtype=float), np.diag([sx * sx, sy * sy])


class OdometryTimeline:
    """Each robot's odometry intervals ``[t0, t1]``, sorted by ``t0``, non-overlapping."""

    def __init__(self) -> None:
        self._t0: dict[int, list[float]] = {}
        self._t1: dict[int, list[float]] = {}

    def clear(self) -> None:
        self._t0.clear()
        self._t1.clear()

    def overlap(self, robot: int, t0: float, t1: float) -> str | None:
        """Why ``[t0, t1]`` cannot join ``robot``'s intervals (it overlaps one), or None."""
        starts, ends = self._t0.get(robot), self._t1.get(robot)
        if not starts:
            return None
        i = bisect_left(starts, t0)
        for j in (i - 1, i):
            if 0 <= j < len(starts) and t0 < ends[j] - CONTIGUOUS and starts[j] < t1 - CONTIGUOUS:
                return f"overlaps the odometry interval [{starts[j]:.9g}, {ends[j]:.9g}] s filed before"
            if 0 <= j < len(starts) and starts[j] == t0:
                return f"overlaps the odometry interval [{starts[j]:.9g}, {ends[j]:.9g}] s filed before"
        return None

    def add(self, robot: int, t0: float, t1: float) -> None:
        starts = self._t0.setdefault(robot, [])
        ends = self._t1.setdefault(robot, [])
        if not starts or t0 > starts[-1]:  # in order: the common case
            starts.append(t0)
            ends.append(t1)
            return
        i = bisect_left(starts, t0)
        starts.insert(i, t0)
        ends.insert(i, t1)

    def last(self, robot: int) -> tuple[float, float] | None:
        """``robot``'s latest interval ``(t0, t1)``, or None."""
        starts = self._t0.get(robot)
        return (starts[-1], self._t1[robot][-1]) if starts else None

    def in_force(self, robot: int, after: tuple) -> tuple[float, float] | None:
        """The interval ``(t0, t1)`` of ``robot`` whose command is in force in a state after the history entries
        keyed before ``after``: the latest with key ``(t0, P_ODOMETRY, robot, ())`` before ``after``; None if none."""
        starts = self._t0.get(robot)
        if not starts:
            return None
        if after > (starts[-1], 2, robot, ()):  # the common case: after the latest interval
            return starts[-1], self._t1[robot][-1]
        i = bisect_left(starts, after[0])
        if i < len(starts) and starts[i] == after[0] and (2, robot, ()) < after[1:]:
            i += 1
        return (starts[i - 1], self._t1[robot][i - 1]) if i > 0 else None

    def prune(self, cutoff: float) -> None:
        """Forget intervals that started before ``cutoff``, but the one in force at ``cutoff``."""
        for robot, starts in self._t0.items():
            n = bisect_left(starts, cutoff) - 1
            if n > 0:
                del starts[:n]
                del self._t1[robot][:n]
