"""Ready-made scenarios: the thesis' ROS/Gazebo experiments (sec. 5.2.2) and random teams for tests.

The thesis does not state the Gazebo process noise. Because the odometry reports the commanded wheel speeds
(see :mod:`swarmloc.sim.simulator`), the wheel diffusion ``D`` sets both the dead-reckoning error and how far the
two robots' true paths drift apart (and so whether they stay within the 1.5 m sensor range). The default
:data:`THESIS_ROS_D` is documented there; pass ``D`` to change it.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TypedDict, Unpack

import numpy as np

from swarmloc.motion.diffdrive import DiffDrive
from swarmloc.sim.simulator import (
    AbsoluteSensor,
    RelativeSensor,
    SimConfig,
    SimResult,
    WheelSchedule,
    check_size,
    simulate,
)

THESIS_ROS_D = 5e-4
"""Default wheel-speed diffusion [rad^2/s] for the thesis' Gazebo scenarios (not given in the thesis).

Heading diffusion ``2 D r^2/l^2 = 2.7e-5`` rad^2/s (std ~2.8 deg after 90 s); over 40 seeds the largest
dead-reckoning position error in the 90 s run averages ~0.2 m and the two robots stay within the 1.5 m sensor range
the whole time; in the 500 s run they are in range ~96% of the time on average (min ~78%). Larger ``D`` makes them
drift out of range (``D = 2e-3``: 96% / 82%)."""

THESIS_START = {1: (1.0, 1.0, float(np.deg2rad(30.0))), 2: (1.0, 2.0, float(np.deg2rad(30.0)))}
"""Known initial poses ``(x, y, theta)`` of robots 1 and 2 (thesis sec. 5.2.2)."""


def thesis_schedule(
    drive: DiffDrive, speed: float = 0.4, straight_time: float = 15.0, arc_radius: float = 2.0
) -> WheelSchedule:
    """Straight at ``speed`` [m/s] for ``straight_time`` [s], then a left arc of radius ``arc_radius`` [m]."""
    return WheelSchedule.from_unicycle([0.0, straight_time], [speed, speed], [0.0, speed / arc_radius], drive)


def thesis_two_robot(
    noise_std: float = 0.01,
    seed: int = 0,
    duration: float = 90.0,
    *,
    D: float = THESIS_ROS_D,
    sigma_theta: float | None = None,
    speed: float = 0.4,
    straight_time: float = 15.0,
    arc_radius: float = 2.0,
    odom_rate: float = 10.0,
    sensor_rate: float = 10.0,
    zero_noise: bool = False,
    absolute: AbsoluteSensor | None = None,
) -> SimResult:
    """Thesis sec. 5.2.2: robot 1 at ``[1, 1, 30 deg]``, robot 2 at ``[1, 2, 30 deg]`` (ids 1 and 2).

    Both drive straight at ``speed`` = 0.4 m/s for ``straight_time`` = 15 s, then along a left arc of radius
    ``arc_radius`` = 2 m (yaw rate 0.2 rad/s) until ``duration``; mutual relative-pose measurements within 1.5 m,
    full circle, at ``sensor_rate`` Hz, position noise std ``noise_std`` (thesis: 0.01, 0.05, 0.1 m) and heading
    noise std ``sigma_theta`` (default ``2 * noise_std`` rad, an assumption: the thesis gives none). Identical
    commands keep the noise-free robots exactly 1 m apart. Odometry at ``odom_rate`` Hz; ``absolute``: fixes, if any.
    """
    sensor = RelativeSensor(
        rate=sensor_rate,
        max_range=1.5,
        fov=2 * np.pi,
        sigma_xy=noise_std,
        sigma_theta=2 * noise_std if sigma_theta is None else sigma_theta,
    )
    drive = DiffDrive(r=0.033, l=0.2, D=D)
    cfg = SimConfig(duration=duration, drive=drive, odom_rate=odom_rate, sensor=sensor, absolute=absolute,
                    zero_noise=zero_noise)  # fmt: skip
    sched = thesis_schedule(drive, speed, straight_time, arc_radius)
    return simulate(THESIS_START, {1: sched, 2: sched}, cfg, seed)


class ThesisOptions(TypedDict, total=False):
    """The keyword options of :func:`thesis_two_robot` that :func:`thesis_ground_truth_neighbour` passes on."""

    D: float
    sigma_theta: float | None
    speed: float
    straight_time: float
    arc_radius: float
    odom_rate: float
    sensor_rate: float
    zero_noise: bool


def thesis_ground_truth_neighbour(
    noise_std: float = 0.05,
    seed: int = 0,
    duration: float = 500.0,
    *,
    fix_sigma_xy: float = 1e-3,
    fix_sigma_theta: float = 1e-3,
    fix_rate: float = 10.0,
    **options: Unpack[ThesisOptions],
) -> SimResult:
    """Thesis Figs 5.22-5.23: as :func:`thesis_two_robot` but ~500 s, and robot 2 is the 'ground-truth neighbour'.

    Robot 2 receives absolute fixes (``Detection(kind="absolute")``, std ``fix_sigma_xy`` [m] and
    ``fix_sigma_theta`` [rad], at ``fix_rate`` Hz); an estimator reproducing the thesis uses them as robot 2's
    belief (the thesis passes robot 2's ground truth to robot 1's localizer).
    """
    fixes = AbsoluteSensor(robots=(2,), rate=fix_rate, sigma_xy=fix_sigma_xy, sigma_theta=fix_sigma_theta)
    return thesis_two_robot(noise_std, seed, duration, absolute=fixes, **options)


def random_team(
    n_robots: int = 4,
    duration: float = 30.0,
    seed: int = 0,
    *,
    area: float = 2.0,
    D: float = 0.01,
    speed_range: tuple[float, float] = (0.05, 0.3),
    max_turn_rate: float = 0.5,
    segment: tuple[float, float] = (2.0, 5.0),
    sensor: RelativeSensor | None = None,
    absolute: AbsoluteSensor | None = None,
    odom_rate: float = 10.0,
    zero_noise: bool = False,
) -> SimResult:
    """A team of ``n_robots`` (ids ``0..n-1``) with random starts in ``[0, area]^2`` and random piecewise-constant
    commands: every ``U(segment)`` s a new forward speed ``U(speed_range)`` [m/s] and yaw rate
    ``U(-max_turn_rate, max_turn_rate)`` [rad/s]. Default sensor: :class:`RelativeSensor` (1.5 m, full circle,
    10 Hz, 0.05 m / 1 deg). The layout and the simulation noise both derive from ``seed``.
    """
    check_size(n_robots, duration, 1.0 / SimConfig.dt)  # before the commands are drawn
    layout_ss, sim_ss = np.random.SeedSequence(seed).spawn(2)
    rng = np.random.default_rng(layout_ss)
    drive = DiffDrive(D=D)
    starts = {}
    cmds = {}
    for i in range(n_robots):
        starts[i] = (rng.uniform(0, area), rng.uniform(0, area), rng.uniform(-np.pi, np.pi))
        times = [0.0]
        while times[-1] < duration:
            times.append(times[-1] + rng.uniform(*segment))
        v = rng.uniform(*speed_range, size=len(times))
        w = rng.uniform(-max_turn_rate, max_turn_rate, size=len(times))
        cmds[i] = WheelSchedule.from_unicycle(times, v, w, drive)
    cfg = SimConfig(
        duration=duration,
        drive=drive,
        odom_rate=odom_rate,
        sensor=RelativeSensor() if sensor is None else sensor,
        absolute=absolute,
        zero_noise=zero_noise,
    )
    return simulate(starts, cmds, cfg, int(sim_ss.generate_state(1)[0]))


def cooperative_positioning(
    n_a: int = 2,
    n_b: int = 2,
    phases: int = 8,
    phase_s: float = 5.0,
    speed: float = 0.2,
    seed: int = 0,
    D: float = 5e-3,
    sensor: RelativeSensor | None = None,
) -> SimResult:
    """Kurazume, Nagata and Hirose's cooperative positioning (lecture slide 13): move-and-stop in two groups.

    Robots ``0..n_a-1`` form group A, the next ``n_b`` group B; they start side by side facing +x, B 0.5 m ahead of
    A, 0.5 m apart across. In phase ``k`` (``phase_s`` seconds each) group B moves straight ahead at ``speed``
    [m/s] while A stands still when ``k`` is even, and the other way round when ``k`` is odd; at the end of each
    phase every robot of the group that moved measures its relative pose to every robot of the group that stood
    still (``sensor``: default 5 cm / 1 deg, no range limit). Odometry runs throughout; ``D`` is the wheel-speed
    diffusion (the thesis' model: a standing robot's true pose diffuses too). Only those detections are kept.
    """
    if n_a < 1 or n_b < 1 or phases < 1:
        raise ValueError("cooperative_positioning: n_a, n_b and phases must be >= 1")
    from swarmloc.events import Detection

    drive = DiffDrive(D=D)
    n = n_a + n_b
    group_a = set(range(n_a))
    starts = {i: (0.0 if i in group_a else 0.5, 0.5 * (i if i in group_a else i - n_a), 0.0) for i in range(n)}
    times = [k * phase_s for k in range(phases)]
    cmds = {}
    for i in range(n):
        moving = [(k % 2 == 0) != (i in group_a) for k in range(phases)]
        v = [speed if mv else 0.0 for mv in moving]
        cmds[i] = WheelSchedule.from_unicycle(times, v, [0.0] * phases, drive)
    base = RelativeSensor(rate=1.0 / phase_s, max_range=1e6) if sensor is None else sensor
    cfg = SimConfig(duration=phases * phase_s, drive=drive, odom_rate=10.0, sensor=base)
    sim = simulate(starts, cmds, cfg, seed)
    ends = np.arange(1, phases + 1) * phase_s

    def keep(e: object) -> bool:
        if not isinstance(e, Detection):
            return True
        k = int(np.argmin(np.abs(ends - e.t)))
        if abs(ends[k] - e.t) > 1e-6 or e.target is None:
            return False
        moved_a = k % 2 == 1  # phase k: B moves when k is even
        return (e.observer in group_a) == moved_a and (e.target in group_a) != moved_a

    return replace(sim, events=[e for e in sim.events if keep(e)])
