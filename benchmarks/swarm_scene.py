"""The swarm benchmarks' scenes (benchmarks/diekf_cluster.py, benchmarks/diekf_swarm.py): ``sim:random`` teams of
``n`` robots (seed ``seed``), a 5 Hz robot sensor of 1.5 m (full circle), in one of four arenas:

* ``"fixed"``: ``sim:random``'s own 3 m square (a robot sees more teammates in a larger team);
* ``"spread"``: a square of side ``3 m sqrt(n / 5)``, robots free to drive out of it. Not of constant density in
  what a robot sees: over 10 s about half the robots of a 10-robot team leave their 4.2 m square (0.05-0.3 m/s),
  and a sensor near its edge sees less of the team, so a robot detects 5.8 teammates/s at 10 robots, 15.8 at 50
  (seed 1; over seeds 1-8 10.3 and 16.0; 19.6 in the unbounded plane at that density);
* ``"bounded"``: constant density in what a robot sees. The robots stay in the square (:func:`bounded_commands`)
  and its side is :func:`arena_side`: the side at which a robot at a uniformly random place has on average
  :data:`NEIGHBOURS` teammates within the sensor's range, the square's edge and the robot itself counted. So a
  robot detects about ``5 Hz x NEIGHBOURS`` = 10 teammates/s in every team (over seeds 1-8, 10 s: 9.0, 9.6, 9.0,
  9.9 at 5, 10, 20, 50 robots; one seed of a small team varies far more, 5.7-14.2 at 5 robots);
* ``"grouped"``: the bounded arena with the ids along a Hilbert curve through the start positions
  (:func:`hilbert_index`), so that ``diekf``'s clusters (consecutive ids) are robots that start near each other.

A square, not a torus: across a torus' seam the measured relative poses would not be those of the world frame the
filters estimate in.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from swarmloc.datasets.source import Source
from swarmloc.experiments.sources import load_source
from swarmloc.motion.diffdrive import DiffDrive
from swarmloc.sim import RelativeSensor, SimConfig, WheelSchedule, random_team, simulate
from swarmloc.sim.source import sim_source

ARENAS = ("fixed", "spread", "bounded", "grouped")
RATE = 5.0
"""The robot sensor's rate [Hz] in every arena."""
RANGE = 1.5
"""The robot sensor's range [m] (``RelativeSensor``'s default, the thesis' laser), full circle."""
NEIGHBOURS = 2.0
"""``"bounded"``: teammates within range of a robot at a uniformly random place in the square, on average."""


def seen_fraction(side: float, r: float = RANGE, grid: int = 200) -> float:
    """The probability that two robots at independent uniform places in a square of side ``side`` [m] are within
    ``r`` [m] of each other: ``(1 / side^4) integral over |d| <= r of (side - |d_x|)+ (side - |d_y|)+ dd`` (midpoint
    rule in polar coordinates, ``grid`` x ``2 grid`` points; for ``r <= side / 2`` it is ``(pi r^2 - 8 r^3 / (3 side)
    + r^4 / (2 side^2)) / side^2``, the mean area of the sensor's disc inside the square over the square's)."""
    rho = (np.arange(grid) + 0.5) * r / grid
    phi = (np.arange(2 * grid) + 0.5) * np.pi / grid
    cx, sy = np.abs(np.cos(phi))[None, :] * rho[:, None], np.abs(np.sin(phi))[None, :] * rho[:, None]
    f = np.clip(side - cx, 0.0, None) * np.clip(side - sy, 0.0, None) * rho[:, None]
    return float(f.sum() * (r / grid) * (np.pi / grid) / side**4)


@functools.cache
def arena_side(n: int, neighbours: float = NEIGHBOURS, r: float = RANGE) -> float:
    """The side [m] of the square in which a robot at a uniformly random place has on average ``neighbours`` of its
    ``n - 1`` teammates (uniform in the square) within range ``r`` [m]: ``(n - 1) seen_fraction(side) =
    neighbours``, the square's edge counted (bisection; ``ValueError`` when ``n - 1 <= neighbours``)."""
    if n - 1 <= neighbours:
        raise ValueError(f"arena_side: {n} robots cannot see {neighbours} teammates each on average")
    lo, hi = r / 100, 2 * r * math.sqrt(n)  # (n - 1) seen_fraction: above neighbours at lo, below at hi
    for _ in range(40):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if (n - 1) * seen_fraction(mid, r) >= neighbours else (lo, mid)
    return lo


def _arc(x: float, y: float, th: float, v: float, w: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The unicycle's poses after ``t`` [s] at ``v`` [m/s] and yaw rate ``w`` [rad/s] from ``(x, y, th)``."""
    if abs(w) < 1e-9:
        return x + v * t * math.cos(th), y + v * t * math.sin(th), th + 0.0 * t
    return x + v / w * (np.sin(th + w * t) - math.sin(th)), y - v / w * (np.cos(th + w * t) - math.cos(th)), th + w * t


def bounded_commands(rng: np.random.Generator, start: tuple[float, float, float], duration: float, side: float,
                     tries: int = 20) -> tuple[list[float], list[float], list[float]]:  # fmt: skip
    """``random_team``'s commands (segments of ``U(2, 5)`` s at ``U(0.05, 0.3)`` m/s and ``U(-0.5, 0.5)`` rad/s) for a
    robot that stays in ``[0, side]^2``: a segment whose noise-free path leaves the square is drawn again (up to
    ``tries`` times), else the robot turns in place towards the square's centre at 0.5 rad/s. Returns the segments'
    start times [s], forward speeds and yaw rates (the wheels' noise moves the true path a few cm off)."""
    x, y, th = start
    times, vs, ws = [0.0], [], []
    while True:
        for _ in range(tries):
            dt, v, w = rng.uniform(2.0, 5.0), rng.uniform(0.05, 0.3), rng.uniform(-0.5, 0.5)
            px, py, _ = _arc(x, y, th, v, w, np.linspace(0.0, dt, 16))
            if min(px.min(), py.min()) >= 0.0 and max(px.max(), py.max()) <= side:
                break
        else:
            a = math.remainder(math.atan2(side / 2 - y, side / 2 - x) - th, 2 * math.pi)
            dt, v, w = max(abs(a) / 0.5, 0.1), 0.0, math.copysign(0.5, a)
        vs.append(v)
        ws.append(w)
        px, py, pth = _arc(x, y, th, v, w, np.array([dt]))
        x, y, th = float(px[0]), float(py[0]), float(pth[0])
        if times[-1] + dt >= duration:
            return times, vs, ws
        times.append(times[-1] + dt)


def hilbert_index(x: float, y: float, side: float, order: int = 10) -> int:
    """The index of the point ``(x, y)`` of ``[0, side]^2`` along a Hilbert curve of ``4^order`` cells (close indices:
    close points)."""
    m = 1 << order
    cx, cy = (min(int(v / side * m), m - 1) for v in (x, y))
    d, s = 0, m // 2
    while s > 0:
        rx, ry = int(cx & s > 0), int(cy & s > 0)
        d += s * s * ((3 * rx) ^ ry)
        if ry == 0:
            if rx == 1:
                cx, cy = m - 1 - cx, m - 1 - cy
            cx, cy = cy, cx
        s //= 2
    return d


def bounded_team(n: int, duration: float, seed: int, side: float, grouped: bool = False, D: float = 0.01) -> Source:
    """``n`` robots (ids ``0..n-1``) at uniform random poses in ``[0, side]^2`` driving :func:`bounded_commands`;
    the layout and the simulation noise derive from ``seed`` as in ``random_team``. ``grouped``: the same poses
    with the ids in the order of a Hilbert curve through them (:func:`hilbert_index`), so that the robots of a
    cluster (consecutive ids) start near each other; the commands are drawn after the ids are given."""
    layout_ss, sim_ss = np.random.SeedSequence(seed).spawn(2)
    rng = np.random.default_rng(layout_ss)
    drive = DiffDrive(D=D)
    poses = [(rng.uniform(0, side), rng.uniform(0, side), rng.uniform(-np.pi, np.pi)) for _ in range(n)]
    if grouped:
        poses.sort(key=lambda p: hilbert_index(p[0], p[1], side))
    starts, cmds = dict(enumerate(poses)), {}
    for i in range(n):
        cmds[i] = WheelSchedule.from_unicycle(*bounded_commands(rng, starts[i], duration, side), drive)
    cfg = SimConfig(duration=duration, drive=drive, odom_rate=10.0, sensor=RelativeSensor(rate=RATE, max_range=RANGE))
    return sim_source(simulate(starts, cmds, cfg, int(sim_ss.generate_state(1)[0])), "sim:random (bounded)")


def scene(n: int, duration: float, seed: int, arena: str) -> Source:
    """``sim:random`` with ``n`` robots in ``arena`` (one of :data:`ARENAS`, module docstring)."""
    if arena == "fixed":
        return load_source("sim:random", robots=n, duration=duration, seed=seed)
    if arena == "spread":
        sensor = RelativeSensor(rate=RATE, max_range=RANGE)
        return sim_source(random_team(n, duration, seed=seed, area=3.0 * math.sqrt(n / 5), sensor=sensor),
                          "sim:random (spread)")  # fmt: skip
    if arena in ("bounded", "grouped"):
        return bounded_team(n, duration, seed, arena_side(n), grouped=arena == "grouped")
    raise ValueError(f"scene: arena must be one of {ARENAS}, got {arena!r}")
