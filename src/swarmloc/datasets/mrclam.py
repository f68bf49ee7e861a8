"""Reader for the UTIAS Multi-Robot Cooperative Localization and Mapping (MRCLAM) dataset.

Leung, Halpern, Barfoot, Liu (2011): five iRobot Create robots read barcodes on each other and on 15 landmarks
with monocular cameras; Vicon ground truth. One dataset is one folder ``MRCLAM_DatasetN`` holding

* ``RobotN_Odometry.dat``: time [s, Unix epoch], forward velocity v [m/s], angular velocity w [rad/s];
* ``RobotN_Measurement.dat``: time [s], *barcode* number, range [m], bearing [rad];
* ``RobotN_Groundtruth.dat``: time [s], x [m], y [m], heading [rad];
* ``Landmark_Groundtruth.dat``: subject, x [m], y [m], std x [m], std y [m];
* ``Barcodes.dat``: subject, barcode.

Lines starting with ``#`` are headers; columns are separated by blanks or tabs. Subjects 1-5 are robots, 6-20
landmarks. Times stay absolute (Unix epoch seconds) everywhere in this module; poses are ``(x, y, theta)`` in the
Vicon world frame with ``theta`` in ``(-pi, pi]``; bearings are in the observer's body frame (x forward, y left).

Every problem with the data raises :class:`MRCLAMError` (a ``ValueError``) with a one-line message naming the file
(and the line number for a malformed line).

Two known defects of the recordings are corrected on loading, each reported in :attr:`MRCLAMData.notes` (pass
``corrections=False`` to :func:`load_mrclam` for the files as they are):

* **Dataset 1 swaps the barcodes of landmarks 11 and 17.** Its ``Barcodes.dat`` gives subject 11 barcode 18 and
  subject 17 barcode 61, but the readings of barcode 18 fit the map position of subject 17 and those of barcode 61
  that of subject 11 (each landmark located from the robots' readings of it, with the observer's pose fitted at the
  same instant from the other landmarks it saw: 6.0 and 6.1 m from their map entries; after the swap all 15 lie
  within 0.19 m of theirs). Recognised by content (those two barcode rows and those two map positions), not by
  folder name: :data:`BARCODE_SWAPS`.
* **Turn commands beyond the robots' yaw rate.** The odometry files log *commanded* velocities. In dataset 9 the
  turn commands are +0.902 and -1.003 rad/s, but the robots turned at 0.60 rad/s (median over 109 turns with
  landmark snapshots before and after; quartiles 0.53, 0.70; the same for both commands), i.e. two thirds of the
  commanded angle. The yaw rate is clipped to :data:`MAX_YAW_RATE`; no other dataset commands more than
  0.57 rad/s, so they load unchanged.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.arrays import readonly
from swarmloc.datasets import _mrclam_files as readers
from swarmloc.datasets._mrclam_files import BARCODE_SWAPS, MAX_YAW_RATE, ROBOT_SUBJECTS, MRCLAMError
from swarmloc.datasets.tum import interpolate
from swarmloc.events import Detection, Event, Kind, Odometry
from swarmloc.sensors.decorrelate import PRIOR_BEARING_STD, PRIOR_RANGE_STD

__all__ = [
    "BARCODE_SWAPS",
    "DEFAULT_BEARING_STD",
    "DEFAULT_RANGE_STD",
    "MAX_YAW_RATE",
    "MRCLAMData",
    "MRCLAMError",
    "ROBOT_SUBJECTS",
    "load_mrclam",
    "mrclam_events",
]

DEFAULT_RANGE_STD = PRIOR_RANGE_STD
"""Default range noise std [m] for :func:`mrclam_events` (the camera's a-priori value, not fitted to any dataset)."""

DEFAULT_BEARING_STD = PRIOR_BEARING_STD
"""Default bearing noise std [rad] (about 2 degrees) for :func:`mrclam_events` (the camera's a-priori value)."""


# ----------------------------------------------------------------------------------------------------------------
# data container


@dataclass
class MRCLAMData:
    """One loaded MRCLAM dataset. Times are absolute Unix-epoch seconds; poses ``(x [m], y [m], theta [rad])``.

    Arrays are sorted by time (stable, so rows with equal times keep file order):

    * ``odometry[r]``: ``(N, 3)`` rows ``(t, v [m/s], w [rad/s])``;
    * ``measurements[r]``: ``(M, 4)`` rows ``(t, subject, range [m], bearing [rad])``, barcodes already mapped to
      subject ids through ``Barcodes.dat``; rows with unknown barcodes removed and counted in ``skipped_barcodes``;
    * ``truth[r]``: ``(K, 4)`` rows ``(t, x, y, theta)``; empty dict when the dataset has no ground truth.

    ``t_start``/``t_end`` bound the common time span: latest first odometry time and earliest last odometry time
    over ``robots`` (earliest and latest measurement when no odometry was loaded), intersected with the
    ground-truth spans when ground truth was loaded. ``missing`` lists the files looked for and not found;
    ``notes`` lists oddities found while loading (e.g. rows out of time order, truth ending early).
    """

    name: str
    path: Path
    robots: list[int]
    odometry: dict[int, np.ndarray]
    measurements: dict[int, np.ndarray]
    skipped_barcodes: dict[int, int]
    truth: dict[int, np.ndarray]
    landmarks: dict[int, tuple[float, float, float, float]]
    barcode_to_subject: dict[int, int]
    t_start: float
    t_end: float
    missing: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def has_truth(self) -> bool:
        """True when every robot in ``robots`` has ground truth."""
        return bool(self.robots) and all(r in self.truth for r in self.robots)

    @property
    def duration(self) -> float:
        """Length of the common time span [s]."""
        return self.t_end - self.t_start

    def truth_at(self, robot: int, t: float | Sequence[float] | np.ndarray) -> np.ndarray:
        """Ground-truth poses of ``robot`` at times ``t`` [s], shape ``(len(t), 3)`` (a scalar counts as one time).

        ``x``, ``y`` are interpolated linearly; the heading is interpolated on the unwrapped angle and wrapped back
        to ``(-pi, pi]``, so interpolation across the +-pi seam takes the short way. Raises :class:`MRCLAMError`
        when the robot has no ground truth or a time lies outside its ground-truth span.
        """
        gt = self.truth.get(robot)
        if gt is None or gt.shape[0] == 0:
            raise MRCLAMError(
                f"{self.name}: no ground truth for robot {robot} "
                f"(Robot{robot}_Groundtruth.dat not loaded; robots with truth: {sorted(self.truth) or 'none'})"
            )
        tq = np.atleast_1d(np.asarray(t, dtype=np.float64)).ravel()
        t0, t1 = float(gt[0, 0]), float(gt[-1, 0])
        outside = (tq < t0) | (tq > t1) | ~np.isfinite(tq)
        if outside.any():
            bad = float(tq[np.flatnonzero(outside)[0]])
            raise MRCLAMError(
                f"{self.name}: time {bad:.3f} is outside the ground-truth span [{t0:.3f}, {t1:.3f}] of robot {robot}"
            )
        return interpolate(gt[:, 0], gt[:, 1:], tq)

    def initial_pose(self, robot: int) -> np.ndarray:
        """Pose ``(x, y, theta)`` of ``robot`` at ``t_start``: ground truth when available.

        Without ground truth this returns ``(0, 0, 0)``: the robot's own start frame. The robots' start frames are
        then unrelated, so callers must supply the prior themselves (e.g. from landmarks) for a shared world frame.
        """
        if robot not in self.robots:
            raise MRCLAMError(f"{self.name}: robot {robot} not loaded (robots: {self.robots})")
        if robot in self.truth:
            return self.truth_at(robot, self.t_start)[0]
        return np.zeros(3)

    def subject_counts(self, t_start: float, t_end: float) -> dict[str, Any]:
        """What the measurements stamped in ``[t_start, t_end]`` [s] saw: ``{"robots": n, "landmarks": n,
        "unknown": {subject: n}}``; unknown: subjects (of a known barcode) that are neither robots 1-5 nor landmarks
        of ``Landmark_Groundtruth.dat``. Each counted measurement is a detection a node counts (unknown subjects end
        "unknown" there) or, with landmarks off, one the events leave out with the landmarks."""
        out: dict[str, Any] = {"robots": 0, "landmarks": 0, "unknown": {}}
        lm = np.array(sorted(self.landmarks), dtype=np.float64)
        for m in self.measurements.values():
            sub = m[(m[:, 0] >= t_start) & (m[:, 0] <= t_end), 1]
            rob, land = np.isin(sub, ROBOT_SUBJECTS), np.isin(sub, lm)
            out["robots"] += int(rob.sum())
            out["landmarks"] += int(land.sum())
            vals, counts = np.unique(sub[~rob & ~land].astype(np.int64), return_counts=True)
            for v, n in zip(vals.tolist(), counts.tolist(), strict=True):
                out["unknown"][v] = out["unknown"].get(v, 0) + n
        out["unknown"] = dict(sorted(out["unknown"].items()))
        return out

    def describe(self) -> str:
        """Short human-readable summary: robots, span, row counts, skipped barcodes, missing files, notes."""
        lines = [
            f"{self.name} ({self.path}): robots {self.robots}, common span {self.duration:.1f} s "
            f"[{self.t_start:.3f}, {self.t_end:.3f}], ground truth: {'yes' if self.has_truth else 'no'}, "
            f"{len(self.landmarks)} landmarks"
        ]
        for r in self.robots:
            parts = []
            if r in self.odometry:
                parts.append(f"{self.odometry[r].shape[0]} odometry rows")
            if r in self.measurements:
                m = self.measurements[r]
                n_rob = int(np.count_nonzero(np.isin(m[:, 1], ROBOT_SUBJECTS)))
                parts.append(f"{m.shape[0]} measurements ({n_rob} of robots)")
            if r in self.truth:
                parts.append(f"{self.truth[r].shape[0]} truth rows")
            lines.append(f"  robot {r}: " + ", ".join(parts))
        if self.skipped_barcodes:
            total = sum(self.skipped_barcodes.values())
            detail = ", ".join(f"{b}: {n}" for b, n in sorted(self.skipped_barcodes.items()))
            lines.append(f"  skipped {total} measurements of unknown barcodes ({detail})")
        else:
            lines.append("  skipped barcodes: none")
        lines.append(f"  missing files: {', '.join(self.missing) if self.missing else 'none'}")
        lines.extend(f"  note: {n}" for n in self.notes)
        return "\n".join(lines)


# ----------------------------------------------------------------------------------------------------------------
# loading


def load_mrclam(
    path: str | os.PathLike[str],
    robots: Iterable[int] | None = None,
    require: Iterable[str] = ("odometry", "measurements"),
    require_truth: bool = False,
    corrections: bool = True,
) -> MRCLAMData:
    """Load one MRCLAM dataset folder (e.g. ``.../MRCLAM_Dataset6``).

    ``require`` names the per-robot files a robot must have to be loaded, among ``"odometry"``, ``"measurements"``
    and ``"truth"`` (``require_truth=True`` adds ``"truth"``). With ``robots=None`` every robot 1-5 that has them
    is loaded (e.g. robots 1, 2, 3, 5 of dataset 3, which lacks ``Robot4_Odometry.dat``); an explicit ``robots``
    list must all have them. Files not required are loaded when present. ``Barcodes.dat`` and
    ``Landmark_Groundtruth.dat`` are always required. Raises :class:`MRCLAMError` naming the folder, the missing
    file(s) and what is available when the folder or a required file is missing, or when no robot qualifies.
    ``corrections``: apply the known corrections of the module docstring (:data:`BARCODE_SWAPS`, yaw rates clipped
    to :data:`MAX_YAW_RATE`), each listed in ``notes``; ``False`` loads the files as they are.
    """
    kinds = readers.require_kinds(require, require_truth)
    folder = readers.folder(path)
    present, missing = readers.robot_files(folder)
    chosen = readers.chosen_robots(folder, robots, kinds, present, missing)
    notes: list[str] = []
    barcode_to_subject = readers.barcodes(folder / "Barcodes.dat")
    landmarks = readers.landmarks(folder / "Landmark_Groundtruth.dat")
    if corrections:
        readers.swap_barcodes(barcode_to_subject, landmarks, notes)
    odometry: dict[int, np.ndarray] = {}
    measurements: dict[int, np.ndarray] = {}
    truth: dict[int, np.ndarray] = {}
    skipped: dict[int, int] = {}
    for r in chosen:
        files = present[r]
        if "odometry" in files:
            odometry[r] = readers.timed_rows(files["odometry"], 3, notes)
            if corrections:
                readers.clip_yaw_rates(files["odometry"], odometry[r], notes)
        if "truth" in files:
            truth[r] = readers.timed_rows(files["truth"], 4, notes)
        if "measurements" in files:
            measurements[r] = readers.measurements(files["measurements"], barcode_to_subject, skipped, notes)
    t_start, t_end = readers.time_span(folder, chosen, odometry, measurements, truth, notes)
    return MRCLAMData(
        name=folder.name,
        path=folder,
        robots=list(chosen),
        odometry=odometry,
        measurements=measurements,
        skipped_barcodes=dict(sorted(skipped.items())),
        truth=truth,
        landmarks=landmarks,
        barcode_to_subject=barcode_to_subject,
        t_start=t_start,
        t_end=t_end,
        missing=missing,
        notes=notes,
    )


# ----------------------------------------------------------------------------------------------------------------
# events


def mrclam_events(
    data: MRCLAMData,
    duration: float | None = None,
    landmarks: bool = True,
    robot_measurements: bool = True,
    range_std: float = DEFAULT_RANGE_STD,
    bearing_std: float = DEFAULT_BEARING_STD,
) -> list[Event]:
    """Time-ordered :class:`Odometry` and :class:`Detection` events of ``data`` over ``[t_start, t_end]``.

    Odometry: consecutive rows ``k, k+1`` of each robot give ``Odometry(robot, t_k, t_{k+1}, v_k, w_k)``, clipped
    to the span, so the first interval starts at ``t_start`` with the last reading at or before it, and the
    intervals of each robot tile the span exactly; zero-length intervals (duplicate time stamps) are dropped.

    Detections: each measurement within the span gives a ``"range_bearing"`` :class:`Detection` with
    ``z = (range [m], bearing [rad])`` and ``cov = diag(range_std**2, bearing_std**2)``; ``target`` is the subject
    id and ``target_is_robot`` is true for subjects 1-5. A detection of a robot that has no odometry here (e.g.
    robot 4 in dataset 3) is still a robot detection: consumers ignore robots they do not estimate.
    ``landmarks``/``robot_measurements`` switch landmark and robot detections on or off.

    ``range_std`` [m] and ``bearing_std`` [rad] default to generic values (0.1 m, 0.035 rad), not fitted to any
    dataset's ground truth; pass your own. The camera's errors are correlated in time, so these white-noise
    covariances over-count repeated readings: :func:`swarmloc.experiments.mrclam.mrclam_stream` replaces them
    (:mod:`swarmloc.sensors.decorrelate`). ``duration`` [s] truncates the span to ``[t_start, t_start + duration]``.
    Events carry absolute Unix times. The list is sorted by stamp (:attr:`~swarmloc.events.Odometry.stamp`): an
    odometry event by ``t0``, since the logged velocities are commands, known when they are issued; a node that
    receives them in this order never has to replay. At equal stamps detections come before odometry (a command
    starting at ``t`` acts after ``t``), then by robot id, then by file order. Detection ``z``/``cov`` arrays are
    read-only (``cov`` is shared by all events).
    """
    if range_std <= 0 or bearing_std <= 0:
        raise ValueError("range_std and bearing_std must be positive")
    t_start = data.t_start
    t_end = data.t_end
    if duration is not None:
        if isinstance(duration, bool) or not (isinstance(duration, numbers.Real) and 0 <= duration < math.inf):
            raise ValueError(f"duration must be a finite number of seconds >= 0, got {duration!r}")
        t_end = min(t_end, t_start + float(duration))

    cov = readonly(np.diag([range_std**2, bearing_std**2]))
    robot_set = set(ROBOT_SUBJECTS)
    odometry: list[Event] = []
    detections: list[Event] = []
    for r in map(int, data.robots):
        odo = data.odometry.get(r)
        if odo is not None and odo.shape[0] >= 2:  # intervals clipped to the span, empty ones dropped
            a, b = np.maximum(odo[:-1, 0], t_start), np.minimum(odo[1:, 0], t_end)
            keep = b > a
            odometry += [Odometry(robot=r, t0=t0, t1=t1, v=v, w=w) for t0, t1, v, w in zip(
                a[keep].tolist(), b[keep].tolist(), odo[:-1, 1][keep].tolist(), odo[:-1, 2][keep].tolist(),
                strict=True)]  # fmt: skip
        m = data.measurements.get(r)
        if m is None or m.shape[0] == 0:
            continue
        is_rob = np.isin(m[:, 1], ROBOT_SUBJECTS)
        keep = (m[:, 0] >= t_start) & (m[:, 0] <= t_end) & (is_rob | landmarks) & (~is_rob | robot_measurements)
        ts, subjects, zs = m[keep, 0].tolist(), m[keep, 1].astype(np.int64).tolist(), m[keep][:, 2:4].copy()
        zs.setflags(write=False)
        detections += [Detection(r, t, Kind.RANGE_BEARING, z, cov, target=s, target_is_robot=s in robot_set)
                       for t, s, z in zip(ts, subjects, zs, strict=True)]  # fmt: skip
    # by stamp (odometry: its start t0), detections before odometry at equal stamps, then robot id and file order
    return sorted([*odometry, *detections], key=lambda e: (e.stamp, isinstance(e, Odometry)))
