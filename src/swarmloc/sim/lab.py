"""The chapter's map-building experiment as a simulation: robots H1 and H2 driving axis-aligned legs.

Song, Tsai and Chiu Huang (2010), sec. 5: two robots that only turn in place between the headings 0, 90, 180 and
270 deg, and record their true positions at the points of Tables 3 (H1) and 4 (H2) of experiment 2 [cm]. We drive
each robot through those points in order, each leg as at most two straight runs along the axes (x first, or y first
where x first would cross an obstacle of :func:`~swarmloc.sim.walls.chapter_lab`), turning in place in between.
"""

from __future__ import annotations

import numpy as np

from swarmloc.motion.diffdrive import DiffDrive
from swarmloc.sim.simulator import RelativeSensor, SimConfig, SimResult, WheelSchedule, simulate

__all__ = ["H1_POINTS", "H2_POINTS", "axis_schedule", "chapter_team"]

H1_POINTS = ((0.40, -0.10), (0.33, 1.15), (1.00, 0.31), (-0.14, 0.35), (-0.76, 2.25), (-0.05, 0.70), (-0.12, -0.70))
"""True positions A-G of H1 in experiment 2 (Table 3), metres."""
H2_POINTS = ((-0.28, -1.00), (1.03, -0.91), (0.58, -0.92), (0.34, 0.94), (0.38, 0.40))
"""True positions A-E of H2 in experiment 2 (Table 4), metres."""
H1_Y_FIRST = (3,)
"""Legs of H1 (by index of their start point) driven y first: (-0.14, 0.35) -> (-0.76, 2.25) would cross the table."""


def _quantize(amount: float, rate: float, period: float) -> tuple[int, float]:
    """Duration in periods and the speed that covers ``amount`` in it at about ``rate`` (per second)."""
    n = max(1, int(round(abs(amount) / rate / period)))
    return n, amount / (n * period)


def axis_schedule(
    points: tuple[tuple[float, float], ...],
    drive: DiffDrive,
    y_first: tuple[int, ...] = (),
    speed: float = 0.15,
    turn_rate: float = 0.5,
    period: float = 0.1,
) -> tuple[tuple[float, float, float], WheelSchedule, float]:
    """Start pose, wheel schedule and duration [s] through ``points`` [m] along the axes.

    Each leg is an x run then a y run (y then x for the leg indices in ``y_first``), at about ``speed`` [m/s],
    with in-place turns at about ``turn_rate`` [rad/s]; durations are multiples of ``period`` [s] (the odometry
    period) and speeds are adjusted so that a noise-free robot lands exactly on each point."""
    runs: list[tuple[float, float]] = []  # (dx, dy) axis-aligned runs
    for k, (p, q) in enumerate(zip(points[:-1], points[1:], strict=True)):
        dx, dy = q[0] - p[0], q[1] - p[1]
        legs = [(0.0, dy), (dx, 0.0)] if k in y_first else [(dx, 0.0), (0.0, dy)]
        runs += [leg for leg in legs if abs(leg[0]) + abs(leg[1]) > 1e-9]
    heads = [float(np.arctan2(dy, dx)) for dx, dy in runs]
    n = 0
    changes: list[tuple[int, float, float]] = []  # (tick, v, w): a command from a tick (odometry periods) on
    for i, (dx, dy) in enumerate(runs):
        if i > 0:
            turn = float(np.angle(np.exp(1j * (heads[i] - heads[i - 1]))))
            if abs(turn) > 1e-9:
                k, rate = _quantize(turn, turn_rate, period)
                changes.append((n, 0.0, rate))
                n += k
        k, sp = _quantize(float(np.hypot(dx, dy)), speed, period)
        changes.append((n, sp, 0.0))
        n += k
    changes.append((n, 0.0, 0.0))  # stop at the last point
    ticks, v, w = zip(*changes, strict=True)
    start = (points[0][0], points[0][1], heads[0])
    times = [(i - 0.5) * period for i in ticks]  # half a period early: immune to the rounding of i * period
    return start, WheelSchedule.from_unicycle(times, v, w, drive), n * period


def chapter_team(
    seed: int = 0,
    *,
    D: float = 0.005,
    sensor: RelativeSensor | None = None,
    speed: float = 0.15,
) -> SimResult:
    """Robots H1 (id 1) and H2 (id 2) through the points of Tables 3 and 4 (experiment 2), until both have
    arrived (H2 then stands still). ``D``: wheel-speed diffusion [rad^2/s] (default: dead reckoning drifts
    about 10-20 cm over H1's 10 m, as in Tables 2-3); ``sensor``: the robot-to-robot sensor (default: the
    chapter's stereo camera read as 120 deg, 3 m, 3 cm, 2 deg, 2 Hz)."""
    drive = DiffDrive(D=D)
    s1, c1, d1 = axis_schedule(H1_POINTS, drive, H1_Y_FIRST, speed)
    s2, c2, d2 = axis_schedule(H2_POINTS, drive, (), speed)
    sensor = (
        RelativeSensor(
            rate=2.0, max_range=3.0, fov=float(np.deg2rad(120)), sigma_xy=0.03, sigma_theta=float(np.deg2rad(2.0))
        )  # fmt: skip
        if sensor is None
        else sensor
    )
    cfg = SimConfig(duration=max(d1, d2), drive=drive, odom_rate=10.0, sensor=sensor)
    return simulate({1: s1, 2: s2}, {1: c1, 2: c2}, cfg, seed)
