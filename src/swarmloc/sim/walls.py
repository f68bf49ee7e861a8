"""Range sensing: a 2-D world of wall segments and a simulated range finder per robot.

* :class:`Walls`: segments ``(W, 2, 2)`` [m] (``[w, 0]`` and ``[w, 1]`` are the end points); :func:`office_walls`
  (an office floor: a corridor, rooms and doors) and :func:`chapter_lab` (the experiment area of Song, Tsai and
  Chiu Huang, *Multi-robot cooperative sensing and localization*, 2010, as read from their Tables 2-4; see there).
* :class:`RangeFinder`: ``n_beams`` beams evenly over ``fov`` centred on the robot's x axis, returns beyond
  ``max_range`` missing (NaN), additive Gaussian range noise of std ``sigma`` [m]; walls and the other robots
  (discs of radius ``robot_radius``) occlude.
* :func:`cast_rays`: batched ray / segment and ray / disc intersection (numpy, chunked over rays).
* :func:`scan_team`: every robot's scan at the odometry times of a :class:`~swarmloc.sim.SimResult` (its true
  poses), at ``finder.rate`` Hz.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from swarmloc.arrays import readonly
from swarmloc.sim.simulator import SimResult

__all__ = ["RangeFinder", "Scans", "Walls", "cast_rays", "chapter_lab", "office_walls", "scan_team"]


@dataclass(frozen=True)
class Walls:
    """Wall segments ``segments`` ``(W, 2, 2)`` [m] in the world frame."""

    segments: np.ndarray

    def __post_init__(self) -> None:
        s = np.array(self.segments, dtype=float)
        if s.ndim != 3 or s.shape[1:] != (2, 2) or s.shape[0] == 0:
            raise ValueError(f"Walls: segments must have shape (W, 2, 2) with W >= 1, got {s.shape}")
        if not np.isfinite(s).all():
            raise ValueError("Walls: segments must be finite")
        if (np.linalg.norm(s[:, 1] - s[:, 0], axis=-1) <= 0).any():
            raise ValueError("Walls: a segment has zero length")
        object.__setattr__(self, "segments", readonly(s))

    @classmethod
    def from_polylines(cls, *lines: Sequence[tuple[float, float]]) -> Walls:
        """Walls along polylines of ``(x, y)`` vertices [m] (each consecutive pair is one segment)."""
        segs = [(a, b) for pl in lines for a, b in zip(pl[:-1], pl[1:], strict=True)]
        return cls(np.array(segs, dtype=float))


def office_walls() -> Walls:
    """An office floor of 10 m x 6 m: a corridor ``1 m`` wide along ``y in [2.5, 3.5]``, three rooms below and two
    above, each with a 0.9 m door onto the corridor (27 segments)."""
    outer = [(0, 0), (10, 0), (10, 6), (0, 6), (0, 0)]
    below = [[(0, 2.5), (1.0, 2.5)], [(1.9, 2.5), (4.3, 2.5)], [(5.2, 2.5), (7.6, 2.5)], [(8.5, 2.5), (10, 2.5)]]
    above = [[(0, 3.5), (2.0, 3.5)], [(2.9, 3.5), (6.5, 3.5)], [(7.4, 3.5), (10, 3.5)]]
    rooms = [[(3.3, 0), (3.3, 2.5)], [(6.6, 0), (6.6, 2.5)], [(5.0, 3.5), (5.0, 6)]]
    desk = [(8.0, 4.5), (9.0, 4.5), (9.0, 5.2), (8.0, 5.2), (8.0, 4.5)]
    return Walls.from_polylines(outer, *below, *above, *rooms, desk)


def chapter_lab() -> Walls:
    """The chapter's experiment area (sec. 5, Figs 7-10), as well as it can be read.

    The figures are missing from the text, so the walls are *read from the tables*: every recorded true position
    of H1 and H2 (Tables 2-4, in cm) lies in ``x in [-76, 103]``, ``y in [-100, 253]``; the robots move only along
    the axes (headings 0, 90, 180, 270 deg). We take an axis-aligned room ``x in [-1.2, 1.5]``, ``y in [-1.4, 2.8]``
    [m] (the recorded positions with about 0.4 m of clearance for a robot of radius 0.2 m) and two box-shaped
    obstacles that none of the recorded positions or the axis-aligned legs between them cross (a table at the left,
    ``[-0.9, -0.45] x [0.6, 1.6]``, a cabinet at the right, ``[0.7, 1.1] x [1.5, 2.2]``). The obstacles are our
    assumption, there to give the map walls that are not the room's outline.
    """
    room = [(-1.2, -1.4), (1.5, -1.4), (1.5, 2.8), (-1.2, 2.8), (-1.2, -1.4)]
    table = [(-0.9, 0.6), (-0.45, 0.6), (-0.45, 1.6), (-0.9, 1.6), (-0.9, 0.6)]
    cabinet = [(0.7, 1.5), (1.1, 1.5), (1.1, 2.2), (0.7, 2.2), (0.7, 1.5)]
    return Walls.from_polylines(room, table, cabinet)


@dataclass(frozen=True)
class RangeFinder:
    """A planar range finder: ``n_beams`` over ``fov`` [rad] centred on the robot's heading, ``max_range`` [m],
    range noise std ``sigma`` [m], ``rate`` [Hz]; other robots are discs of radius ``robot_radius`` [m].

    Defaults: a stereo-camera-like sensor (the chapter's robots carry stereo vision): 61 beams over 120 deg, 3 m,
    1 cm noise, 2 Hz."""

    n_beams: int = 61
    fov: float = float(np.deg2rad(120.0))
    max_range: float = 3.0
    sigma: float = 0.01
    rate: float = 2.0
    robot_radius: float = 0.2

    def __post_init__(self) -> None:
        if not (isinstance(self.n_beams, int) and self.n_beams >= 2):
            raise ValueError(f"RangeFinder: n_beams must be an integer >= 2, got {self.n_beams!r}")
        if not (0 < self.fov <= 2 * np.pi and self.max_range > 0 and self.sigma >= 0 and self.rate > 0):
            raise ValueError("RangeFinder: need 0 < fov <= 2 pi, max_range > 0, sigma >= 0, rate > 0")

    @property
    def angles(self) -> np.ndarray:
        """Beam angles [rad] in the robot frame, ``(n_beams,)``."""
        if np.isclose(self.fov, 2 * np.pi):
            return -np.pi + 2 * np.pi * np.arange(self.n_beams) / self.n_beams
        return np.linspace(-self.fov / 2, self.fov / 2, self.n_beams)


def cast_rays(
    origins: np.ndarray,
    directions: np.ndarray,
    walls: np.ndarray,
    discs: np.ndarray | None = None,
    radius: float = 0.0,
    chunk: int = 4096,
) -> np.ndarray:
    """Distance [m] along each ray to the first wall or disc it meets (``inf`` when none), ``(R,)``.

    ``origins`` and unit ``directions`` ``(R, 2)``; ``walls`` ``(W, 2, 2)``; ``discs`` ``(R, K, 2)``: per ray the
    centres of the discs (radius ``radius``) that may occlude it (NaN rows: none). Ray ``o + t d`` meets segment
    ``a + u (b - a)`` at ``t = cross(a - o, e) / cross(d, e)``, ``u = cross(a - o, d) / cross(d, e)``, ``e = b - a``,
    when ``t > 0`` and ``0 <= u <= 1``.
    """
    o = np.asarray(origins, dtype=float)
    d = np.asarray(directions, dtype=float)
    a = walls[:, 0]
    e = walls[:, 1] - walls[:, 0]
    out = np.empty(o.shape[0])
    for s in range(0, o.shape[0], chunk):
        oo, dd = o[s : s + chunk, None, :], d[s : s + chunk, None, :]
        ao = a[None] - oo
        den = dd[..., 0] * e[None, :, 1] - dd[..., 1] * e[None, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (ao[..., 0] * e[None, :, 1] - ao[..., 1] * e[None, :, 0]) / den
            u = (ao[..., 0] * dd[..., 1] - ao[..., 1] * dd[..., 0]) / den
        hit = (np.abs(den) > 1e-12) & (t > 1e-9) & (u >= 0) & (u <= 1)
        best = np.where(hit, t, np.inf).min(axis=1)
        if discs is not None and discs.shape[1]:
            c = discs[s : s + chunk] - oo  # (r, K, 2)
            along = np.einsum("rkj,rkj->rk", c, np.broadcast_to(dd, c.shape))
            perp2 = np.einsum("rkj,rkj->rk", c, c) - along**2
            with np.errstate(invalid="ignore"):
                tc = along - np.sqrt(radius**2 - perp2)
            ok = np.isfinite(tc) & (tc > 0)
            best = np.minimum(best, np.where(ok, tc, np.inf).min(axis=1))
        out[s : s + chunk] = best
    return out


@dataclass(frozen=True)
class Scans:
    """Scans of a team: ``times`` ``(S,)`` [s], ``robot_ids``, beam ``angles`` ``(B,)`` [rad, robot frame],
    ``ranges`` ``(S, N, B)`` [m] (NaN: no return within range), the true poses ``poses`` ``(S, N, 3)`` they were
    taken from, and the finder's ``sigma`` [m]."""

    times: np.ndarray
    robot_ids: tuple[int, ...]
    angles: np.ndarray
    ranges: np.ndarray
    true_ranges: np.ndarray
    poses: np.ndarray
    sigma: float

    def true_hits(self) -> np.ndarray:
        """World points ``(k, 2)`` [m] that the beams truly hit (what of the walls was seen)."""
        th = self.poses[..., 2:3] + self.angles
        x = self.poses[..., 0:1] + self.true_ranges * np.cos(th)
        y = self.poses[..., 1:2] + self.true_ranges * np.sin(th)
        ok = np.isfinite(self.true_ranges)
        return np.stack([x[ok], y[ok]], axis=-1)


def scan_team(
    sim: SimResult,
    walls: Walls,
    finder: RangeFinder | None = None,
    seed: int | None = 0,
    drop_teammates: bool = True,
) -> Scans:
    """Every robot's scan every ``1 / finder.rate`` s (on the simulation's odometry grid, from ``t = 0``), from its
    true pose; occlusion by walls and by the other robots. With ``drop_teammates`` a return from another robot is
    removed (NaN), as the chapter's robots recognize their teammates in the image; otherwise it stays (a robot's
    round body then yields short spurious segments). Deterministic in ``seed``."""
    finder = RangeFinder() if finder is None else finder
    step = int(round(1.0 / (finder.rate * (sim.times[1] - sim.times[0]))))
    if step < 1:
        raise ValueError("scan_team: the finder's rate is faster than the simulation's odometry")
    idx = np.arange(0, sim.times.size, step)
    P = sim.truth[idx]  # (S, N, 3)
    S, N, _ = P.shape
    ang = finder.angles
    B = ang.size
    heading = P[..., 2:3] + ang  # (S, N, B)
    dirs = np.stack([np.cos(heading), np.sin(heading)], axis=-1).reshape(-1, 2)
    origins = np.broadcast_to(P[:, :, None, :2], (S, N, B, 2)).reshape(-1, 2)
    others = np.where(~np.eye(N, dtype=bool)[None, :, :, None], P[:, None, :, :2], np.nan)  # (S, N, N, 2)
    discs = np.broadcast_to(others[:, :, None], (S, N, B, N, 2)).reshape(-1, N, 2)
    true = cast_rays(origins, dirs, walls.segments, discs, finder.robot_radius).reshape(S, N, B)
    teammate = true < cast_rays(origins, dirs, walls.segments).reshape(S, N, B)
    rng = np.random.default_rng(seed)
    r = true + finder.sigma * rng.standard_normal(true.shape)
    r[~(r <= finder.max_range) | (r <= 0)] = np.nan
    true[~(true <= finder.max_range) | teammate] = np.nan
    if drop_teammates:
        r[teammate] = np.nan
    return Scans(sim.times[idx], sim.robot_ids, ang, r, true, P, finder.sigma)
