"""Simulated point landmarks: a seeded map, and range-bearing detections of it from a simulation's truth.

Added on top of a :class:`~swarmloc.sim.simulator.SimResult` without touching the simulator, so that a team's
trajectories, odometry and robot-to-robot detections stay exactly those of the same seed without landmarks.

* **Map** (:func:`place_landmarks`): ``n`` landmarks on a jittered grid over a box ``(xmin, xmax, ymin, ymax)``
  [m]: the box is cut into ``cols x rows`` cells (``cols / rows`` about the box's aspect ratio, ``cols * rows >=
  n``), ``n`` of them are drawn at random and each holds one landmark uniform in the cell. Ids ``first_id,
  first_id + 1, ...`` (default 100: never a robot id of a simulated team). The map is given to nodes as MRCLAM's
  is: ``id -> (x, y, std_x, std_y)`` [m] (:data:`swarmloc.node.inputs.Landmarks`), ``std`` = ``map_std``
  (default 0: the simulated map is exact).
* **Detections** (:func:`landmark_detections`, :class:`LandmarkSensor`): at ``rate`` Hz (on the odometry grid,
  where the truth is known), every robot ``i`` detects every landmark ``l`` whose position in ``i``'s frame
  ``p = R_i^T (l - t_i)`` has ``min_range <= |p| <= max_range`` and ``|atan2(p_y, p_x)| <= fov / 2``:
  ``z = (|p| + n_r, wrap(atan2(p_y, p_x) + n_b))``, ``n ~ N(0, diag(sigma_range^2, sigma_bearing^2))``, as
  ``Detection(i, t, "range_bearing", z, cov, target=l, target_is_robot=False)`` (the form of MRCLAM's landmark
  detections, :func:`swarmloc.datasets.mrclam.mrclam_events`).
* **Random numbers**: ``SeedSequence([seed, LANDMARK_STREAM])`` spawns a map stream and a noise stream, apart from
  the simulator's streams (``SeedSequence(seed)`` and its children), so adding landmarks changes no other event.
  The noise is drawn for every (time, robot, landmark) whether seen or not: the same seed gives the same noise on a
  detection whatever the range or field of view.

Angles wrapped to (-pi, pi]; times [s]; lengths [m].
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from swarmloc.arrays import readonly
from swarmloc.events import Detection, Event, Kind, sim_order
from swarmloc.lie import wrap_angle
from swarmloc.sim.simulator import SimResult, in_view, seen_from

__all__ = [
    "LANDMARK_STREAM",
    "LandmarkSensor",
    "add_landmarks",
    "landmark_detections",
    "landmark_streams",
    "merge_events",
    "place_landmarks",
]

LANDMARK_STREAM = 0x4C4D4B
"""Second entropy word of the landmarks' ``SeedSequence([seed, LANDMARK_STREAM])`` (apart from the simulator's)."""

Box = tuple[float, float, float, float]
"""``(xmin, xmax, ymin, ymax)`` [m]."""


@dataclass(frozen=True)
class LandmarkSensor:
    """Range-bearing sensor of point landmarks: ``rate`` [Hz] (a divisor of the odometry rate), ``min_range`` and
    ``max_range`` [m], ``fov`` [rad] (total width about the robot's x axis; ``2 pi``: all round), noise std
    ``sigma_range`` [m] and ``sigma_bearing`` [rad]."""

    rate: float = 2.0
    min_range: float = 0.1
    max_range: float = 4.0
    fov: float = 2 * math.pi
    sigma_range: float = 0.05
    sigma_bearing: float = float(np.deg2rad(2.0))

    def __post_init__(self) -> None:
        if not (self.rate > 0 and 0 <= self.min_range < self.max_range and self.fov > 0):
            raise ValueError(f"LandmarkSensor: need rate > 0, 0 <= min_range < max_range, fov > 0; got {self}")
        if self.sigma_range < 0 or self.sigma_bearing < 0:
            raise ValueError(f"LandmarkSensor: noise std must be >= 0; got {self}")

    def cov(self) -> np.ndarray:
        """``diag(sigma_range^2, sigma_bearing^2)``."""
        return np.diag([self.sigma_range**2, self.sigma_bearing**2])

    def noiseless(self) -> LandmarkSensor:
        return replace(self, sigma_range=0.0, sigma_bearing=0.0)


def landmark_streams(seed: int) -> tuple[np.random.SeedSequence, np.random.SeedSequence]:
    """The map and noise seed sequences of ``seed`` (independent of the simulator's ``SeedSequence(seed)``)."""
    a, b = np.random.SeedSequence([int(seed), LANDMARK_STREAM]).spawn(2)
    return a, b


def place_landmarks(
    n: int,
    bounds: Box,
    seed: int | np.random.SeedSequence = 0,
    *,
    first_id: int = 100,
    map_std: float = 0.0,
) -> dict[int, tuple[float, float, float, float]]:
    """``n`` landmarks on a jittered grid over ``bounds`` (see the module docstring): ``id -> (x, y, std, std)``."""
    xmin, xmax, ymin, ymax = (float(b) for b in bounds)
    if n < 0 or not (xmax > xmin and ymax > ymin):
        raise ValueError(f"place_landmarks: need n >= 0 and a non-empty box, got n={n}, bounds={bounds}")
    if map_std < 0:
        raise ValueError(f"place_landmarks: map_std must be >= 0, got {map_std}")
    if n == 0:
        return {}
    w, h = xmax - xmin, ymax - ymin
    cols = max(1, min(n, math.ceil(math.sqrt(n * w / h))))
    rows = math.ceil(n / cols)
    rng = np.random.default_rng(seed)
    cells = rng.permutation(cols * rows)[:n]
    u = rng.uniform(size=(n, 2))
    x = xmin + (cells % cols + u[:, 0]) * (w / cols)
    y = ymin + (cells // cols + u[:, 1]) * (h / rows)
    s = float(map_std)
    return {first_id + k: (float(x[k]), float(y[k]), s, s) for k in range(n)}


def landmark_detections(
    sim: SimResult,
    landmarks: Mapping[int, Sequence[float]],
    sensor: LandmarkSensor | None = None,
    seed: int | np.random.SeedSequence = 0,
) -> list[Detection]:
    """Range-bearing detections of ``landmarks`` (``id -> (x, y, ...)``) by every robot of ``sim`` from its truth,
    sorted by (time, observer, landmark id); ``seed`` seeds the noise (see the module docstring)."""
    sensor = LandmarkSensor() if sensor is None else sensor
    T = float(sim.times[1] - sim.times[0]) if sim.times.size > 1 else 0.0
    step = int(round(1.0 / (sensor.rate * T))) if T > 0 else 0
    if step < 1 or abs(step * T * sensor.rate - 1.0) > 1e-9:
        raise ValueError(f"landmark_detections: rate {sensor.rate:g} Hz must divide the odometry rate {1 / T:g} Hz")
    if not landmarks:
        return []
    ids = sorted(landmarks)
    L = np.array([[float(landmarks[i][0]), float(landmarks[i][1])] for i in ids])  # (m, 2)
    ks = np.arange(step, sim.times.size, step)
    P = sim.truth[ks]  # (S, n_rob, 3)
    dx = L[:, 0] - P[..., 0][..., None]  # (S, n_rob, m)
    dy = L[:, 1] - P[..., 1][..., None]
    mx, my, rng_, bearing = seen_from(P[..., 2][..., None], dx, dy)
    seen = (rng_ >= sensor.min_range) & in_view(rng_, bearing, sensor.max_range, sensor.fov)
    noise = np.random.default_rng(seed).standard_normal((*mx.shape, 2)) * [sensor.sigma_range, sensor.sigma_bearing]
    z = readonly(np.stack([rng_ + noise[..., 0], wrap_angle(bearing + noise[..., 1])], axis=-1))
    cov = readonly(sensor.cov())
    out = []
    for a, r, l_ in zip(*np.nonzero(seen), strict=True):
        out.append(
            Detection(
                sim.robot_ids[r], float(sim.times[ks[a]]), Kind.RANGE_BEARING, z[a, r, l_], cov,
                target=ids[l_], target_is_robot=False,
            )
        )  # fmt: skip
    return out


def merge_events(events: Sequence[Event], extra: Sequence[Event]) -> list[Event]:
    """``events`` (in the simulator's order) with ``extra`` (sorted by time) merged in: ``events`` keep their order,
    and each extra detection at time ``t`` comes after every detection at ``t`` and before the truth at ``t``."""
    return list(heapq.merge(events, extra, key=sim_order))


def add_landmarks(
    sim: SimResult,
    n: int = 6,
    sensor: LandmarkSensor | None = None,
    seed: int = 0,
    *,
    bounds: Box | None = None,
    margin: float = 1.0,
    map_std: float = 0.0,
) -> tuple[SimResult, dict[int, tuple[float, float, float, float]]]:
    """``sim`` with ``n`` landmarks placed (:func:`place_landmarks` over ``bounds``; default the box the team's true
    positions cover, grown by ``margin`` [m]) and their detections merged into its events; returns
    ``(sim with the detections, landmarks)``. Both are deterministic in ``seed`` (:func:`landmark_streams`)."""
    if bounds is None:
        xy = sim.truth[..., :2].reshape(-1, 2)
        lo, hi = xy.min(axis=0) - margin, xy.max(axis=0) + margin
        bounds = (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))
    map_ss, noise_ss = landmark_streams(seed)
    landmarks = place_landmarks(n, bounds, map_ss, map_std=map_std)
    dets = landmark_detections(sim, landmarks, sensor, noise_ss)
    return replace(sim, events=merge_events(sim.events, dets)), landmarks
