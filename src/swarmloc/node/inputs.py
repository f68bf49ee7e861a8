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
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from swarmloc.events import Detection, Kind, Odometry
from swarmloc.gaussian import check_covariance
from swarmloc.node.keys import Position
from swarmloc.sensors.models import MODELS
from swarmloc.sensors.models3 import ALL_MODELS

__all__ = [
    "CONTIGUOUS",
    "Landmarks",
    "OdometryTimeline",
    "brief",
    "clearly_valid",
    "finite_number",
    "landmark_state",
    "odometry_problem",
    "validate_detection",
]


CONTIGUOUS = 1e-9
"""[s] Odometry intervals that overlap by less than this are contiguous (rounding of stamps)."""

Landmarks = Mapping[int, tuple[float, ...]]
"""Landmark id -> (x, y, std_x, std_y) in metres; a 3-D landmark (3-D teams): (x, y, z, std_x, std_y, std_z)."""

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
    return bool(a * d - b * b > 1e-9 * (a + d) * (a + d))  # not ** 2: a Python float's power raises on overflow


_NUMBER = frozenset({float, np.float64})  # not int: one too large for a float is checked one by one
_INTEGER = frozenset({int, np.int64})
_ID = 2**63  # ids are integers of 64 bits (:func:`_integer`)


def finite_number(x: object) -> bool:
    """True when ``x`` is a plain real number (int, float, numpy's floating) and finite (an int too large for a
    float is not: ``math.isfinite`` would raise on it)."""
    if not isinstance(x, int | float | np.floating):
        return False
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def _integer(x: object) -> bool:
    """An id: an int (not a bool) of 64 bits (as messages carry ids)."""
    return isinstance(x, int | np.integer) and not isinstance(x, bool) and bool(-_ID <= x < _ID)


def validate_detection(d: Detection) -> str | None:
    """Why a detection is unusable, or None when its kind, value, stamp, covariance and target are well formed."""
    try:
        z = np.asarray(d.z, dtype=float)
        cov = np.asarray(d.cov, dtype=float)
    except (TypeError, ValueError) as exc:
        return f"z or cov is not numeric: {exc}"
    model = ALL_MODELS.get(d.kind) if isinstance(d.kind, str) else None
    if model is None:
        return f"unknown measurement kind {brief(d.kind)}"
    want = model.size
    if z.shape != (want,):
        return f"z has shape {z.shape}, expected ({want},) for kind {brief(d.kind)}"
    if not np.isfinite(z).all():
        return "z contains NaN or inf"
    if not finite_number(d.t):
        return f"time stamp {brief(d.t)} is not a finite number"
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
        return f"target id must be an integer of 64 bits, got {brief(d.target)}"
    if not _integer(d.observer):
        return f"observer id must be an integer of 64 bits, got {brief(d.observer)}"
    return None


_KIND_TYPES = (str, Kind)
"""A kind's exact types the fast screen takes: a name, or a :class:`~swarmloc.events.Kind` member."""


def clearly_valid(ds: Sequence[Detection]) -> np.ndarray:
    """``(len(ds),)`` bool: True where :func:`validate_detection` certainly finds detection ``ds[k]`` well formed,
    decided on arrays per kind: a planar kind, ``z`` and ``cov`` numeric numpy arrays of the kind's sizes, finite,
    a positive range, a finite float stamp, 64-bit int ids, the covariance checked as :func:`_clearly_valid`
    checks it. False means "not sure": call :func:`validate_detection`, which says why. For checking many
    detections at once (a replay's): one odd detection leaves the others' screen as it is."""
    ok = np.zeros(len(ds), dtype=bool)
    by_kind: dict[str, list[int]] = {}
    for k, d in enumerate(ds):
        model = MODELS.get(d.kind) if type(d.kind) in _KIND_TYPES else None
        if model is None:
            continue
        m, z, cov = model.size, d.z, d.cov
        if (type(z) is np.ndarray and type(cov) is np.ndarray and z.shape == (m,) and cov.shape == (m, m)
                and z.dtype.kind in "fi" and cov.dtype.kind in "fi" and type(d.t) in _NUMBER
                and type(d.observer) in _INTEGER and -_ID <= d.observer < _ID
                and (d.target is None or (type(d.target) in _INTEGER and -_ID <= d.target < _ID))):  # fmt: skip
            by_kind.setdefault(d.kind, []).append(k)
    for kind, rows in by_kind.items():
        z = np.array([ds[k].z for k in rows], dtype=float)
        cov = np.array([ds[k].cov for k in rows], dtype=float)
        t = np.array([ds[k].t for k in rows], dtype=float)
        good = np.isfinite(z).all(axis=1) & np.isfinite(t) & _clearly_valid_batch(cov)
        if MODELS[kind].ranged:
            good &= z[:, 0] > 0
        ok[rows] = good
    return ok


def _clearly_valid_batch(cov: np.ndarray) -> np.ndarray:
    """:func:`_clearly_valid` over ``cov (k, m, m)`` (``m`` 1 or 2; False for other sizes)."""
    if cov.shape[1:] == (1, 1):
        a = cov[:, 0, 0]
        ok: np.ndarray = np.isfinite(a) & (a > 0)
        return ok
    if cov.shape[1:] != (2, 2):
        return np.zeros(cov.shape[0], dtype=bool)
    a, b, c, d = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 0], cov[:, 1, 1]
    finite = np.isfinite(a) & np.isfinite(b) & np.isfinite(d)
    with np.errstate(invalid="ignore", over="ignore"):
        ok = finite & (b == c) & (a > 0) & (d > 0) & (a * d - b * b > 1e-9 * (a + d) * (a + d))
    return ok


def brief(x: object) -> str:
    """``repr(x)`` for a message, at most 40 characters (an int of 5000 digits has no repr at all)."""
    try:
        text = repr(x)
    except ValueError:
        return f"<{type(x).__name__} too large to show>"
    return text if len(text) <= 40 else text[:37] + "..."


def _components(x: object) -> tuple[Any, ...]:
    """A command's numbers: ``(x,)`` for a planar speed, the 3 components of a 3-D velocity (a tuple)."""
    if isinstance(x, tuple):
        if len(x) != 3:
            raise TypeError("a 3-D velocity has 3 components")
        return x
    return (x,)


def command_value(x: float | tuple[float, ...]) -> float | tuple[float, ...]:
    """A command's value as filed: a float (planar), or a tuple of 3 floats (a 3-D velocity)."""
    return tuple(float(c) for c in x) if isinstance(x, tuple) else float(x)


def odometry_problem(e: Odometry) -> str | None:
    """Why an odometry record is malformed (non-numeric or non-finite numbers, ``t1 < t0``), or None."""
    try:
        finite = all(math.isfinite(x) for x in (e.t0, e.t1, *_components(e.v), *_components(e.w)))
    except (TypeError, OverflowError):  # not a number; an int too large for a float
        finite = False
    if not finite:
        return "non-finite or non-numeric time or speed"
    if e.t1 < e.t0:
        return "t1 before t0"
    return None


def landmark_state(landmarks: Landmarks | None, lid: int | None) -> tuple[np.ndarray, np.ndarray] | None:
    """Position ``(2,)`` and covariance ``(2, 2)`` of a known landmark (a 3-D one: ``(3,)`` and ``(3, 3)``), or
    None."""
    if landmarks is None or lid is None or lid not in landmarks:
        return None
    row = landmarks[lid]
    d = len(row) // 2
    std = np.asarray(row[d:], dtype=float)
    return np.asarray(row[:d], dtype=float), np.diag(std * std)


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
        if not starts or ends is None:
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

    def extend(self, robot: int, t0: list[float], t1: list[float]) -> None:
        """File ``robot``'s intervals ``[t0[k], t1[k]]``, sorted and non-overlapping, all after its last one (the
        caller has checked them)."""
        starts = self._t0.setdefault(robot, [])
        if starts and t0 and t0[0] <= starts[-1]:
            raise ValueError("OdometryTimeline.extend: intervals must come after the robot's last one")
        starts.extend(t0)
        self._t1.setdefault(robot, []).extend(t1)

    def intervals(self) -> dict[int, tuple[list[float], list[float]]]:
        """Every robot's intervals as ``(starts, ends)`` (sorted, read-only views of the timeline)."""
        return {r: (self._t0[r], self._t1[r]) for r in self._t0}

    def last(self, robot: int) -> tuple[float, float] | None:
        """``robot``'s latest interval ``(t0, t1)``, or None."""
        starts = self._t0.get(robot)
        return (starts[-1], self._t1[robot][-1]) if starts else None

    def in_force(self, robot: int, after: Position) -> tuple[float, float] | None:
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
