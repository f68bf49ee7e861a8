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
rotation vector). With ``detection="rbe3"`` it measures instead the range, azimuth and elevation of the teammate's
position in its body frame, ``"bearing3"`` the azimuth and elevation only (:mod:`swarmloc.sensors.models3`):
additive noise ``N(0, diag(sigma_range^2, sigma_angle^2, sigma_angle^2))``, azimuth wrapped to (-pi, pi]; a noisy
elevation past +-90 deg is reported as the same direction (``pi - e``, azimuth + pi). The noise is drawn from the same
stream as the relative poses' (6 numbers per detection), so the three kinds share trajectories, odometry and
initial beliefs for a seed. ``landmarks > 0`` adds that many known 3-D point landmarks (ids 100, 101, ...; uniform
in the box the team's true positions cover grown by 1 m; the map ``id -> (x, y, z, 0, 0, 0)`` is exact), each
detected by ``"rbe3"`` at ``landmark_rate`` within ``landmark_range``, from their own random stream (the team's
events stay those of the seed without landmarks). Initial beliefs are drawn consistently: ``mean = g_true
exp(-y)``, ``y ~ N(0, Sigma0)`` (``Sigma0 = diag(init_pos^2 I3, init_rot^2 I3)``), so the truth is a sample of the
belief; ``init_rot`` large is the "large rotational uncertainty" case. Everything is deterministic in ``seed``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from swarmloc.events import Detection, Event, Kind, MeasurementKind, Truth, twist_odometry
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE3, wrap_angle
from swarmloc.motion.twist3 import TwistNoise
from swarmloc.sensors.models3 import pose3_vector

__all__ = ["DETECTIONS3", "LANDMARK_FIRST_ID", "Sim3Config", "Sim3Result", "measure3", "simulate3d"]

DETECTIONS3 = (Kind.POSE3, Kind.RBE3, Kind.BEARING3)
"""What a robot of :func:`simulate3d` measures of a teammate."""

LANDMARK_FIRST_ID = 100
"""Id of the first simulated 3-D landmark."""

LANDMARK_STREAM = 3
"""``SeedSequence([seed, LANDMARK_STREAM])`` draws the landmarks' map and detection noise."""


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
    detection: MeasurementKind = Kind.POSE3
    sigma_range: float = 0.05
    sigma_angle: float = float(np.deg2rad(1.0))
    landmarks: int = 0
    landmark_rate: float = 2.0
    landmark_range: float = 8.0

    def __post_init__(self) -> None:
        if self.detection not in DETECTIONS3:
            raise ValueError(f"Sim3Config: detection must be one of {DETECTIONS3}, got {self.detection!r}")
        if not (isinstance(self.landmarks, int) and self.landmarks >= 0):
            raise ValueError(f"Sim3Config: landmarks must be an integer >= 0, got {self.landmarks!r}")
        if not (isinstance(self.robots, int) and self.robots >= 1):
            raise ValueError(f"Sim3Config: robots must be a positive integer, got {self.robots!r}")
        for name in ("duration", "odom_rate", "sensor_rate", "max_range", "sigma_pos", "sigma_rot", "init_pos",
                     "init_rot", "truth_rate", "sigma_range", "sigma_angle", "landmark_rate",
                     "landmark_range"):  # fmt: skip
            val = getattr(self, name)
            if not (isinstance(val, int | float) and np.isfinite(val) and val > 0):
                raise ValueError(f"Sim3Config: {name} must be a finite number > 0, got {val!r}")
        if not (isinstance(self.substeps, int) and self.substeps >= 1):
            raise ValueError(f"Sim3Config: substeps must be an integer >= 1, got {self.substeps!r}")

    def initial_cov(self) -> np.ndarray:
        return np.diag([self.init_pos**2] * 3 + [self.init_rot**2] * 3)

    def sensor_cov(self) -> np.ndarray:
        """Covariance of a teammate detection of kind :attr:`detection`."""
        if self.detection == Kind.RBE3:
            return self.rbe_cov()
        if self.detection == Kind.BEARING3:
            return np.diag([self.sigma_angle**2] * 2)
        return np.diag([self.sigma_pos**2] * 3 + [self.sigma_rot**2] * 3)

    def rbe_cov(self) -> np.ndarray:
        """Covariance of a range-bearing-elevation detection (of a teammate or a landmark)."""
        return np.diag([self.sigma_range**2] + [self.sigma_angle**2] * 2)


@dataclass
class Sim3Result:
    """A 3-D simulation: events (odometry, detections, truth; sorted by stamp), initial beliefs, truth on the
    odometry grid ``times (T,)`` / ``poses (T, robots, 4, 4)``, and its configuration."""

    events: list[Event]
    initial: dict[int, GroupGaussian]
    times: np.ndarray
    poses: np.ndarray
    config: Sim3Config
    landmarks: dict[int, tuple[float, ...]] = field(default_factory=dict)
    """Known 3-D landmarks ``id -> (x, y, z, std_x, std_y, std_z)`` [m] (empty without landmarks)."""

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


def measure3(kind: str, gi: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The noise-free measurement of ``kind`` of ``target`` (a pose ``(4, 4)`` or, for ``"rbe3"`` / ``"bearing3"``,
    a point ``(3,)``) by the robot at pose ``gi (4, 4)``: computed from the homogeneous transform ``gi^-1``, apart
    from the filters' models (:mod:`swarmloc.sensors.models3`)."""
    if kind == Kind.POSE3:
        return pose3_vector(SE3.between(gi, target, validate=False))
    target = np.asarray(target, dtype=float)
    q = np.append(target if target.shape == (3,) else target[:3, 3], 1.0)
    x, y, z = (np.linalg.inv(gi) @ q)[:3]
    rbe = np.array([np.sqrt(x * x + y * y + z * z), np.arctan2(y, x), np.arctan2(z, np.sqrt(x * x + y * y))])
    return rbe if kind == Kind.RBE3 else rbe[1:]


def _noisy(kind: str, clean: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``clean + n`` of a ``"rbe3"`` / ``"bearing3"`` value: azimuth wrapped, an elevation past +-pi/2 folded."""
    z = clean + n
    el = z[-1]
    if abs(el) > np.pi / 2:
        z[-1] = np.sign(el) * np.pi - el
        z[-2] += np.pi
    z[-2] = wrap_angle(z[-2])
    return z


def _landmarks(cfg: Sim3Config, g: np.ndarray, times: np.ndarray, seed: int) -> tuple[dict, list]:
    """The landmarks' map and their ``"rbe3"`` detections ``(stamp, 1, robot, Detection)``."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, LANDMARK_STREAM]))
    lo, hi = g[:, :, :3, 3].min(axis=(0, 1)) - 1.0, g[:, :, :3, 3].max(axis=(0, 1)) + 1.0
    pts = lo + (hi - lo) * rng.uniform(size=(cfg.landmarks, 3))
    lms = {LANDMARK_FIRST_ID + k: (*map(float, p), 0.0, 0.0, 0.0) for k, p in enumerate(pts)}
    R3 = cfg.rbe_cov()
    sd = np.sqrt(np.diag(R3))
    out: list = []
    every = max(1, int(round(cfg.odom_rate / cfg.landmark_rate)))
    for k in range(every, times.size, every):
        for i in range(g.shape[1]):
            noise = rng.standard_normal((cfg.landmarks, 3)) * sd  # drawn whether seen or not
            for m, p in enumerate(pts):
                clean = measure3(Kind.RBE3, g[k, i], p)
                if clean[0] > cfg.landmark_range:
                    continue
                z = _noisy(Kind.RBE3, clean, noise[m])
                d = Detection(i, float(times[k]), Kind.RBE3, z, R3.copy(), target=LANDMARK_FIRST_ID + m,
                              target_is_robot=False)  # fmt: skip
                out.append((times[k], 1, i, d))
    return lms, out


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
                n6 = rng.standard_normal(6)
                if cfg.detection == Kind.POSE3:
                    z = pose3_vector(m @ SE3.exp(Ls @ n6, validate=False))
                else:
                    clean = measure3(cfg.detection, g[k, i], g[k, j])
                    z = _noisy(cfg.detection, clean, (Ls @ n6[: Ls.shape[0]])[: clean.size])
                events.append((times[k], 1, i, Detection(i, float(times[k]), cfg.detection, z, R6.copy(), target=j)))
    from swarmloc.datasets.tum import pose7

    tevery = max(1, int(round(cfg.odom_rate / cfg.truth_rate)))
    for k in range(0, steps + 1, tevery):
        for r in range(n):
            events.append((times[k], 2, r, Truth(r, float(times[k]), pose7(g[k, r]))))
    lms: dict[int, tuple[float, ...]] = {}
    if cfg.landmarks:
        lms, seen = _landmarks(cfg, g, times, seed)
        events += seen
    events.sort(key=lambda e: (e[0], e[1], e[2]))
    S0 = cfg.initial_cov()
    L0 = np.linalg.cholesky(S0)
    initial = {r: GroupGaussian(SE3, g[0, r] @ SE3.exp(-(L0 @ rng.standard_normal(6))), S0) for r in range(n)}
    return Sim3Result([e[3] for e in events], initial, times, g, cfg, lms)
