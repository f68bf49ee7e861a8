"""A simulated 3-D team: quadrotor-like robots on SE(3) with body-twist odometry and relative-pose sensors.

Each robot flies a smooth, bounded path: a body twist ``h(t)`` with forward speed ``speed (1 + 0.2 sin)``, small
lateral and vertical speeds, a yaw rate ``yaw_rate (1 + 0.5 sin)`` (so it circles) and small roll and pitch
rates (the tilts of a quadrotor), with random phases per robot. Truth integrates the SDE
``(g^-1 dg)^v = h dt + H dw`` (``H H^T = noise.Q(h)``) by Euler-Maruyama on the group, ``substeps`` per odometry
interval; the odometry reports the commanded twist ``h`` over each interval (:func:`swarmloc.events.twist_odometry`),
so the filters' increment model (:func:`swarmloc.motion.twist3.twist_increment`) is the true one up to the
first-order linearization in the noise.

At ``sensor_rate`` every robot measures the pose of each teammate within ``max_range`` (``"pose3"``:
``m = (g_i^-1 g_k) exp(n)``, ``n ~ N(0, diag(sigma_pos^2 I3, sigma_rot^2 I3))``, reported as translation and
rotation vector). Initial beliefs are drawn consistently: ``mean = g_true exp(-y)``, ``y ~ N(0, Sigma0)``
(``Sigma0 = diag(init_pos^2 I3, init_rot^2 I3)``), so the truth is a sample of the belief; ``init_rot`` large is
the "large rotational uncertainty" case. Everything is deterministic in ``seed``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from swarmloc.events import Detection, Event, Odometry, Truth, twist_odometry
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE3
from swarmloc.motion.twist3 import TwistNoise
from swarmloc.sensors.models3 import pose3_vector

__all__ = ["Sim3Config", "Sim3Result", "simulate3d"]


@dataclass(frozen=True)
class Sim3Config:
    """Parameters of :func:`simulate3d` (SI units: m, rad, s)."""

    robots: int = 4
    duration: float = 60.0
    odom_rate: float = 10.0
    substeps: int = 10
    noise: TwistNoise = field(default_factory=lambda: TwistNoise(q_lin0=4e-4, q_ang0=1e-4))
    speed: float = 0.5
    yaw_rate: float = 0.25
    sensor_rate: float = 2.0
    max_range: float = 12.0
    sigma_pos: float = 0.05
    sigma_rot: float = float(np.deg2rad(2.0))
    init_pos: float = 0.1
    init_rot: float = float(np.deg2rad(3.0))
    truth_rate: float = 2.0

    def __post_init__(self) -> None:
        if not (isinstance(self.robots, int) and self.robots >= 1):
            raise ValueError(f"Sim3Config: robots must be a positive integer, got {self.robots!r}")
        for name in ("duration", "odom_rate", "sensor_rate", "max_range", "sigma_pos", "sigma_rot", "init_pos",
                     "init_rot", "truth_rate"):  # fmt: skip
            val = getattr(self, name)
            if not (isinstance(val, int | float) and np.isfinite(val) and val > 0):
                raise ValueError(f"Sim3Config: {name} must be a finite number > 0, got {val!r}")
        if not (isinstance(self.substeps, int) and self.substeps >= 1):
            raise ValueError(f"Sim3Config: substeps must be an integer >= 1, got {self.substeps!r}")

    def initial_cov(self) -> np.ndarray:
        return np.diag([self.init_pos**2] * 3 + [self.init_rot**2] * 3)

    def sensor_cov(self) -> np.ndarray:
        return np.diag([self.sigma_pos**2] * 3 + [self.sigma_rot**2] * 3)


@dataclass
class Sim3Result:
    """A 3-D simulation: events (odometry, detections, truth; sorted by stamp), initial beliefs, truth on the
    odometry grid ``times (T,)`` / ``poses (T, robots, 4, 4)``, and its configuration."""

    events: list[Event]
    initial: dict[int, GroupGaussian]
    times: np.ndarray
    poses: np.ndarray
    config: Sim3Config

    @property
    def noise(self) -> TwistNoise:
        return self.config.noise

    def truth(self, robot: int, times: np.ndarray) -> np.ndarray:
        """Truth ``(len(times), 7)`` ``(x, y, z, qx, qy, qz, qw)`` at times on the odometry grid (ValueError off it)."""
        from swarmloc.datasets.tum import pose7

        if not 0 <= robot < self.poses.shape[1]:
            raise ValueError(f"no ground truth for robot {robot}")
        tq = np.atleast_1d(np.asarray(times, dtype=float))
        k = np.rint((tq - self.times[0]) * self.config.odom_rate).astype(int)
        if np.any(k < 0) or np.any(k >= self.times.size) or not np.allclose(self.times[np.clip(k, 0, None)], tq):
            raise ValueError("truth: time outside the simulation's grid")
        return pose7(self.poses[k, robot])


def _twists(rng: np.random.Generator, cfg: Sim3Config, t: np.ndarray) -> np.ndarray:
    """Commanded body twists ``(T, 6)`` of one robot at times ``t``."""
    ph = rng.uniform(0, 2 * np.pi, 6)
    f = rng.uniform(0.05, 0.15, 6) * 2 * np.pi
    s = np.sin(f[None, :] * t[:, None] + ph[None, :])
    h = np.empty((t.size, 6))
    h[:, 0] = cfg.speed * (1 + 0.2 * s[:, 0])
    h[:, 1] = 0.1 * cfg.speed * s[:, 1]
    h[:, 2] = 0.3 * cfg.speed * s[:, 2]
    h[:, 3] = 0.05 * s[:, 3]
    h[:, 4] = 0.05 * s[:, 4]
    h[:, 5] = cfg.yaw_rate * (1 + 0.5 * s[:, 5])
    return h


def simulate3d(cfg: Sim3Config | None = None, seed: int = 0) -> Sim3Result:
    """Simulate a 3-D team (module doc); deterministic in ``seed``."""
    cfg = Sim3Config() if cfg is None else cfg
    rng = np.random.default_rng(seed)
    n, dt = cfg.robots, 1.0 / cfg.odom_rate
    steps = int(round(cfg.duration * cfg.odom_rate))
    times = np.arange(steps + 1) * dt
    g = np.empty((steps + 1, n, 4, 4))
    for r in range(n):  # starts on a circle of radius 2 m, 2-4 m high, random yaw, level
        a = 2 * np.pi * r / n
        yaw = rng.uniform(-np.pi, np.pi)
        g[0, r] = SE3.exp(np.zeros(6))
        g[0, r, :3, :3] = SE3.exp(np.array([0, 0, 0, 0, 0, yaw]))[:3, :3]
        g[0, r, :3, 3] = [2 * np.cos(a), 2 * np.sin(a), rng.uniform(2.0, 4.0)]
    H = np.stack([_twists(rng, cfg, times[:-1]) for _ in range(n)], axis=1)  # (steps, n, 6)
    d = dt / cfg.substeps
    for k in range(steps):
        cur = g[k].copy()
        for r in range(n):
            L = np.linalg.cholesky(cfg.noise.Q(H[k, r]))
            xi = H[k, r] * d + np.sqrt(d) * (L @ rng.standard_normal((cfg.substeps, 6)).T).T
            for j in range(cfg.substeps):
                cur[r] = cur[r] @ SE3.exp(xi[j], validate=False)
        g[k + 1] = SE3.normalize(cur)
    events: list[tuple[float, int, int, Event]] = []
    for k in range(steps):
        for r in range(n):
            events.append((times[k], 0, r, twist_odometry(r, times[k], times[k + 1], H[k, r])))
    R6 = cfg.sensor_cov()
    Ls = np.linalg.cholesky(R6)
    every = max(1, int(round(cfg.odom_rate / cfg.sensor_rate)))
    for k in range(every, steps + 1, every):
        for i in range(n):
            for j in range(n):
                if i == j:
                    continue
                m = SE3.between(g[k, i], g[k, j], validate=False)
                if np.linalg.norm(m[:3, 3]) > cfg.max_range:
                    continue
                meas = m @ SE3.exp(Ls @ rng.standard_normal(6), validate=False)
                z = pose3_vector(meas)
                events.append((times[k], 1, i, Detection(i, float(times[k]), "pose3", z, R6.copy(), target=j)))
    from swarmloc.datasets.tum import pose7

    tevery = max(1, int(round(cfg.odom_rate / cfg.truth_rate)))
    for k in range(0, steps + 1, tevery):
        for r in range(n):
            events.append((times[k], 2, r, Truth(r, float(times[k]), pose7(g[k, r]))))
    events.sort(key=lambda e: (e[0], e[1], e[2]))
    S0 = cfg.initial_cov()
    L0 = np.linalg.cholesky(S0)
    initial = {r: GroupGaussian(SE3, g[0, r] @ SE3.exp(-(L0 @ rng.standard_normal(6))), S0) for r in range(n)}
    return Sim3Result([e[3] for e in events], initial, times, g, cfg)


def is_odometry(e: Event) -> bool:
    return isinstance(e, Odometry)
