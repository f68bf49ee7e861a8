"""Simulator: a team of differential-drive robots, wheel-encoder odometry, relative and absolute sensors.

Generative model (everything an estimator needs to match it):

* **Time grid.** Odometry intervals of ``T = 1/odom_rate`` s; each is split into ``n_sub = round(T/dt)`` internal
  steps of ``dt_f = T/n_sub`` (about ``config.dt``). Times are ``k/f`` with ``f = odom_rate * n_sub`` and integer
  ``k``, so events of different kinds at the same instant have bit-identical times.
* **Commands.** Each robot's commanded wheel speeds ``(w1, w2)`` [rad/s] are sampled from its schedule at the start
  of every odometry interval and held (zero-order hold at the odometry rate, like the thesis' 15 Hz controller).
* **Truth.** The SDE ``(g^-1 dg)^v = h dt + H dw`` (thesis 4.12/5.1, :class:`~swarmloc.motion.DiffDrive`), i.e.
  each wheel turns at its commanded speed plus white noise of intensity ``D``, integrated by the geometric
  Euler-Maruyama scheme ``g <- g exp((h dt_f + H dw)^)``, ``dw ~ N(0, dt_f I)``.
* **Odometry.** The encoders report the *commanded* wheel speeds of the interval, converted by eq. (5.14):
  ``Odometry(robot, t0, t1, v, w)``. The truth therefore deviates from the odometry by exactly the SDE's
  diffusion: the matching process model is ``mean = exp(T (v, 0, w)^)``, covariance (5.4) with
  ``Q = H H^T = D diag(r^2/2, 0, 2 r^2/l^2)`` per second (``SimResult.config.drive.diffusion()``,
  :meth:`SimResult.unicycle_noise`; up to the O(dt_f) Euler-Maruyama discretization).
* **Relative sensor** (:class:`RelativeSensor`), at ``rate`` Hz, for every ordered pair observer ``i`` /
  target ``j != i`` whose true relative position ``p = R_i^T (t_j - t_i)`` has ``|p| <= max_range`` and
  ``|atan2(p_y, p_x)| <= fov/2`` (candidates from a ``scipy.spatial.cKDTree`` query per time, no all-pairs list):

  - ``kind="pose"``: ``z = xytheta(m_true exp(n^))``, ``m_true = g_i^-1 g_j``, ``n ~ N(0, diag(s_xy^2, s_xy^2,
    s_theta^2))`` (right perturbation: ``n`` is in the target's frame); ``cov`` is that diagonal matrix;
  - ``kind="range_bearing"``: ``z = (|p| + n_r, wrap(bearing + n_b))``, ``cov = diag(s_r^2, s_b^2)``.
* **Absolute fixes** (:class:`AbsoluteSensor`), GPS-like, for chosen robots at ``rate`` Hz:
  ``z = (x, y, theta) + n`` (additive in Cartesian coordinates, ``theta`` wrapped), ``n ~ N(0, cov)``,
  ``Detection(kind="absolute", observer=robot, target=None)``.
* **Truth events** ``Truth(robot, t, (x, y, theta))`` at ``t = 0`` and every ``truth_every``-th odometry time.

Angles are wrapped to (-pi, pi]. Random numbers: ``SeedSequence(seed)`` spawns independent streams for the motion
noise, the relative sensor and the absolute sensor, so changing a sensor does not change the trajectories. Same
seed and configuration give identical events. Events are sorted by time; at equal times odometry (by robot),
then detections (by observer, kind, target; absolute fixes last), then truth (by robot).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from swarmloc.arrays import readonly
from swarmloc.events import Detection, Event, Kind, Odometry, Truth
from swarmloc.lie import SE2, wrap_angle
from swarmloc.motion.diffdrive import DiffDrive
from swarmloc.motion.sde import compose_exp_xyt
from swarmloc.motion.unicycle import UnicycleNoise

WheelCommand = Callable[[float], "tuple[float, float] | np.ndarray"]


@dataclass(frozen=True)
class WheelSchedule:
    """Piecewise-constant wheel speeds: ``speeds[k] = (w1, w2)`` [rad/s] from ``times[k]`` [s] on.

    Before ``times[0]`` the first speeds apply. Callable on scalars or arrays of times (returns ``(..., 2)``).
    """

    times: tuple[float, ...]
    speeds: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        if len(self.times) != len(self.speeds) or not self.times:
            raise ValueError("WheelSchedule: times and speeds must be non-empty and of equal length")
        if np.any(np.diff(self.times) < 0):
            raise ValueError("WheelSchedule: times must be non-decreasing")

    def __call__(self, t: np.ndarray | float) -> np.ndarray:
        idx = np.searchsorted(np.asarray(self.times), np.asarray(t, dtype=float), side="right") - 1
        return np.asarray(self.speeds, dtype=float)[np.clip(idx, 0, None)]

    @classmethod
    def from_unicycle(
        cls,
        times: Sequence[float] | np.ndarray,
        v: Sequence[float] | np.ndarray,
        w: Sequence[float] | np.ndarray,
        drive: DiffDrive,
    ) -> WheelSchedule:
        """Schedule from forward speeds ``v`` [m/s] and yaw rates ``w`` [rad/s] (eq. 5.14 inverted)."""
        w1, w2 = drive.from_unicycle(np.asarray(v, dtype=float), np.asarray(w, dtype=float))
        return cls(tuple(float(x) for x in times), tuple((float(a), float(b)) for a, b in zip(w1, w2, strict=True)))


@dataclass(frozen=True)
class RelativeSensor:
    """Exteroceptive robot-to-robot sensor (thesis 5.2: laser, 1.5 m, full circle).

    ``rate`` [Hz]; ``max_range`` [m]; ``fov`` [rad], total width centred on the observer's x axis (``2 pi``: full
    circle); ``sigma_xy`` [m] and ``sigma_theta`` [rad]: std of the pose noise (exponential coordinates, right
    perturbation); ``kinds``: any of ``"pose"``, ``"range_bearing"``; ``sigma_range`` [m], ``sigma_bearing`` [rad].
    """

    rate: float = 10.0
    max_range: float = 1.5
    fov: float = 2 * np.pi
    sigma_xy: float = 0.05
    sigma_theta: float = float(np.deg2rad(1.0))
    kinds: tuple[str, ...] = (Kind.POSE,)
    sigma_range: float = 0.05
    sigma_bearing: float = float(np.deg2rad(1.0))

    def __post_init__(self) -> None:
        bad = set(self.kinds) - {Kind.POSE, Kind.RANGE_BEARING}
        if bad:
            raise ValueError(f"RelativeSensor: unsupported kinds {sorted(bad)} (use 'pose', 'range_bearing')")

    def pose_cov(self) -> np.ndarray:
        """``diag(sigma_xy^2, sigma_xy^2, sigma_theta^2)``."""
        return np.diag([self.sigma_xy**2, self.sigma_xy**2, self.sigma_theta**2])

    def range_bearing_cov(self) -> np.ndarray:
        """``diag(sigma_range^2, sigma_bearing^2)``."""
        return np.diag([self.sigma_range**2, self.sigma_bearing**2])

    def noiseless(self) -> RelativeSensor:
        return replace(self, sigma_xy=0.0, sigma_theta=0.0, sigma_range=0.0, sigma_bearing=0.0)


@dataclass(frozen=True)
class AbsoluteSensor:
    """GPS-like world-pose fixes for ``robots`` at ``rate`` [Hz], additive noise ``diag(s_xy^2, s_xy^2, s_th^2)``."""

    robots: tuple[int, ...]
    rate: float = 1.0
    sigma_xy: float = 0.01
    sigma_theta: float = 0.01

    def cov(self) -> np.ndarray:
        return np.diag([self.sigma_xy**2, self.sigma_xy**2, self.sigma_theta**2])

    def noiseless(self) -> AbsoluteSensor:
        return replace(self, sigma_xy=0.0, sigma_theta=0.0)


@dataclass(frozen=True)
class SimConfig:
    """Simulation settings: ``duration`` [s], robot model ``drive``, internal step ``dt`` [s], ``odom_rate`` [Hz],
    a ``Truth`` event every ``truth_every`` odometry events, sensors, and ``zero_noise`` (forces ``D = 0`` and all
    sensor sigmas to 0)."""

    duration: float
    drive: DiffDrive = field(default_factory=DiffDrive)
    dt: float = 0.01
    odom_rate: float = 10.0
    truth_every: int = 1
    sensor: RelativeSensor | None = field(default_factory=RelativeSensor)
    absolute: AbsoluteSensor | None = None
    zero_noise: bool = False

    def effective(self) -> SimConfig:
        """The configuration actually simulated (noise removed when ``zero_noise``)."""
        if not self.zero_noise:
            return self
        return replace(
            self,
            drive=replace(self.drive, D=0.0),
            sensor=None if self.sensor is None else self.sensor.noiseless(),
            absolute=None if self.absolute is None else self.absolute.noiseless(),
        )


@dataclass
class SimResult:
    """Output of :func:`simulate`.

    ``events``: time-sorted list; ``initial_poses``: robot id -> known initial ``(x, y, theta)``;
    ``times`` ``(K+1,)``: odometry grid including 0; ``truth`` ``(K+1, n_robots, 3)``: true poses on that grid
    (columns in ``robot_ids`` order); ``config``: the effective configuration; ``seed``: :func:`simulate`'s seed
    (its ``SeedSequence``'s fourth child seeds the initial beliefs' errors of
    :func:`~swarmloc.sim.source.sim_source`).
    """

    events: list[Event]
    initial_poses: dict[int, np.ndarray]
    robot_ids: tuple[int, ...]
    times: np.ndarray
    truth: np.ndarray
    config: SimConfig
    seed: int | None = 0

    def unicycle_noise(self) -> UnicycleNoise:
        """The same process noise as a :class:`~swarmloc.motion.UnicycleNoise` (for ``odometry_increment``)."""
        return UnicycleNoise.from_diff_drive(self.config.drive)

    def initial_pose_matrices(self) -> dict[int, np.ndarray]:
        return {k: SE2.from_xytheta(p) for k, p in self.initial_poses.items()}


def _steps(period: float, dt_f: float, what: str) -> int:
    n = int(round(period / dt_f))
    if n < 1 or abs(n * dt_f - period) > 1e-9 * max(1.0, period):
        raise ValueError(f"simulate: {what} period {period:g} s is not a multiple of the internal step {dt_f:g} s")
    return n


def _commands(cmds: Sequence[WheelCommand], t: np.ndarray) -> np.ndarray:
    """Wheel speeds ``(len(t), n_robots, 2)`` at the interval start times ``t``."""
    out = np.empty((len(t), len(cmds), 2))
    for r, c in enumerate(cmds):
        if isinstance(c, WheelSchedule):
            out[:, r] = c(t)
        else:
            out[:, r] = np.array([np.asarray(c(float(tk)), dtype=float).reshape(2) for tk in t])
    return out


def _pairs_within(xy: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ordered pairs ``(s, i, j)``, ``i != j``, of points ``xy[s]`` ``(S, n, 2)`` [m] that may lie within ``r`` [m]:
    a k-d tree query per time with a slightly larger radius (the caller applies its exact test), sorted by
    ``(s, i, j)``. No list of all ``n (n - 1)`` pairs unless ``r`` is infinite."""
    n = xy.shape[1]
    if not np.isfinite(r):
        i, j = np.nonzero(~np.eye(n, dtype=bool))
        s = np.repeat(np.arange(xy.shape[0]), i.size)
        return s, np.tile(i, xy.shape[0]), np.tile(j, xy.shape[0])
    from scipy.spatial import cKDTree

    reach = r * (1 + 1e-9) + 1e-12
    parts = []
    for k in range(xy.shape[0]):
        ij = cKDTree(xy[k]).query_pairs(reach, output_type="ndarray")
        if ij.size:
            both = np.concatenate([ij, ij[:, ::-1]])
            parts.append(np.column_stack([np.full(both.shape[0], k), both]))
    if not parts:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty
    sij = np.concatenate(parts).astype(np.int64)
    sij = sij[np.lexsort((sij[:, 2], sij[:, 1], sij[:, 0]))]
    return sij[:, 0], sij[:, 1], sij[:, 2]


def _draws_at(rng: np.random.Generator, S: int, n_pairs: int, d: int, s: np.ndarray, pair: np.ndarray) -> np.ndarray:
    """Rows ``[s, pair]`` of ``rng.standard_normal((S, n_pairs, d))`` (``s`` sorted), drawn a block of times at a
    time: the generator fills arrays in order, so the numbers are those of the one big draw, in bounded memory."""
    out = np.empty((s.size, d))
    block = max(1, (1 << 22) // max(1, n_pairs * d))
    for s0 in range(0, S, block):
        b = min(block, S - s0)
        draw = rng.standard_normal((b, n_pairs, d))
        lo, hi = np.searchsorted(s, [s0, s0 + b])
        out[lo:hi] = draw[s[lo:hi] - s0, pair[lo:hi]]
    return out


MAX_SIM_STEPS = 50_000_000
"""Most robot-steps (robots x internal steps) one simulation takes: its arrays hold about 0.2 kB per robot-step,
so at most about 10 GB; 50 robots for one hour at the default 100 steps/s is 18 million."""


def check_size(n_robots: int, duration: float, steps_per_s: float) -> None:
    """ValueError, before anything is allocated, unless ``duration`` [s] is finite and positive, ``n_robots`` a
    positive integer, and ``n_robots x duration x steps_per_s`` at most :data:`MAX_SIM_STEPS`."""
    if not (isinstance(n_robots, int) and n_robots >= 1):
        raise ValueError(f"simulate: robots must be a positive integer, got {n_robots!r}")
    if not (isinstance(duration, int | float) and np.isfinite(duration) and duration > 0):
        raise ValueError(f"simulate: duration must be a finite number of seconds > 0, got {duration!r}")
    steps = n_robots * duration * steps_per_s
    if steps > MAX_SIM_STEPS:
        raise ValueError(
            f"simulate: {n_robots} robot(s) x {duration:g} s x {steps_per_s:g} steps/s = {steps:.3g} robot-steps, more "
            f"than {MAX_SIM_STEPS} (the bound on a simulation's memory): simulate fewer robots or a shorter span"
        )


def _true_paths(
    p0: np.ndarray, W: np.ndarray, drive: DiffDrive, n_sub: int, dt_f: float, ss_motion: np.random.SeedSequence
) -> np.ndarray:
    """True poses ``(N + 1, n_rob, 3)`` (theta unwrapped) at every internal step from ``p0`` under the wheel speeds
    ``W`` ``(n_int, n_rob, 2)``, each held ``n_sub`` steps of ``dt_f`` s, with the wheels' noise when ``D > 0``
    (vectorized, no time loop)."""
    n_rob = p0.shape[0]
    h = drive.twist(W[..., 0], W[..., 1])  # (n_int, n_rob, 3)
    xi = np.repeat(h, n_sub, axis=0) * dt_f  # (N, n_rob, 3)
    if drive.D > 0:
        rng_m = np.random.default_rng(ss_motion)
        dw = np.sqrt(dt_f) * rng_m.standard_normal((xi.shape[0], n_rob, 2))
        xi = xi + np.einsum("...k,ik->...i", dw, drive.H())
    # local increments exp(xi) in the current body frame, then one cumulative sum
    dx, dy, da = compose_exp_xyt(np.zeros(xi.shape[:-1]), np.zeros(xi.shape[:-1]), np.zeros(xi.shape[:-1]), xi)
    th = p0[:, 2] + np.concatenate([np.zeros((1, n_rob)), np.cumsum(da, axis=0)])  # (N+1, n_rob)
    c, s = np.cos(th[:-1]), np.sin(th[:-1])
    steps = np.stack([c * dx - s * dy, s * dx + c * dy], axis=-1)
    pos = p0[:, :2] + np.concatenate([np.zeros((1, n_rob, 2)), np.cumsum(steps, axis=0)])  # (N+1, n_rob, 2)
    return np.concatenate([pos, th[..., None]], axis=-1)


def seen_from(
    theta: np.ndarray, dx: np.ndarray, dy: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A target at world offset ``(dx, dy)`` [m] from an observer of heading ``theta`` [rad] (broadcast): its
    position ``(mx, my)`` [m] in the observer's frame, its range [m] and its bearing [rad]."""
    c, s = np.cos(theta), np.sin(theta)
    mx, my = c * dx + s * dy, -s * dx + c * dy
    return mx, my, np.hypot(mx, my), np.arctan2(my, mx)


def in_view(range_: np.ndarray, bearing: np.ndarray, max_range: float, fov: float) -> np.ndarray:
    """Within ``max_range`` [m] and ``fov / 2`` [rad] of the observer's x axis (``1e-12`` rad of slack, so that a
    full circle ``fov = 2 pi`` keeps a bearing of ``+-pi``)."""
    return (range_ <= max_range) & (np.abs(bearing) <= fov / 2 + 1e-12)


def _relative_detections(
    truth_all: np.ndarray, ids: tuple[int, ...], sen: RelativeSensor, n_s: int, f: float,
    ss_rel: np.random.SeedSequence,
) -> list[tuple[int, int, tuple, Event]]:  # fmt: skip
    """The relative sensor's detections every ``n_s`` internal steps (``f`` per second) of the true poses
    ``truth_all``, keyed ``(step, 1, (observer, kind, target), event)``."""
    n_rob = len(ids)
    ks = np.arange(n_s, truth_all.shape[0], n_s)
    P = truth_all[ks]  # (S, n_rob, 3)
    s_, obs, tgt = _pairs_within(P[..., :2], sen.max_range)  # candidates, sorted by (s, observer, target)
    gi, gj = P[s_, obs], P[s_, tgt]
    mx, my, rng_, bearing = seen_from(gi[..., 2], gj[..., 0] - gi[..., 0], gj[..., 1] - gi[..., 1])
    mth = gj[..., 2] - gi[..., 2]
    seen = in_view(rng_, bearing, sen.max_range, sen.fov)
    s_, obs, tgt, mx, my, mth, rng_, bearing = (a[seen] for a in (s_, obs, tgt, mx, my, mth, rng_, bearing))
    # the noise of ordered pair p = (observer, target) at sensor time s is element [s, p] of one
    # (S, n_rob (n_rob - 1), 3) draw and then one (S, n_rob (n_rob - 1), 2) draw, as always (same numbers)
    pair = obs * (n_rob - 1) + tgt - (tgt > obs)
    rng_s = np.random.default_rng(ss_rel)
    n_pose = _draws_at(rng_s, len(ks), n_rob * (n_rob - 1), 3, s_, pair) * np.sqrt(np.diag(sen.pose_cov()))
    n_rb = _draws_at(rng_s, len(ks), n_rob * (n_rob - 1), 2, s_, pair) * np.sqrt(np.diag(sen.range_bearing_cov()))
    zx, zy, zth = compose_exp_xyt(mx, my, mth, n_pose)
    z_pose = np.stack([zx, zy, wrap_angle(zth)], axis=-1)
    z_rb = np.stack([rng_ + n_rb[..., 0], wrap_angle(bearing + n_rb[..., 1])], axis=-1)
    cov_pose, cov_rb = readonly(sen.pose_cov()), readonly(sen.range_bearing_cov())
    keyed: list[tuple[int, int, tuple, Event]] = []
    for q in range(s_.size):
        k = int(ks[s_[q]])
        t = k / f
        oi, ti = int(obs[q]), int(tgt[q])
        o, g = ids[oi], ids[ti]
        if Kind.POSE in sen.kinds:
            ev = Detection(o, t, Kind.POSE, readonly(z_pose[q]), cov_pose, target=g)
            keyed.append((k, 1, (oi, 0, ti), ev))
        if Kind.RANGE_BEARING in sen.kinds:
            ev = Detection(o, t, Kind.RANGE_BEARING, readonly(z_rb[q]), cov_rb, target=g)
            keyed.append((k, 1, (oi, 1, ti), ev))
    return keyed


def _absolute_fixes(
    truth_all: np.ndarray, ids: tuple[int, ...], ab: AbsoluteSensor, n_a: int, f: float,
    ss_abs: np.random.SeedSequence,
) -> list[tuple[int, int, tuple, Event]]:  # fmt: skip
    """Absolute fixes of ``ab``'s robots every ``n_a`` internal steps (``f`` per second) of the true poses
    ``truth_all``, keyed ``(step, 1, (n_rob + robot index, 2, 0), event)``."""
    ka = np.arange(n_a, truth_all.shape[0], n_a)
    cols = [ids.index(r) for r in ab.robots]
    rng_a = np.random.default_rng(ss_abs)
    noise = rng_a.standard_normal((len(ka), len(cols), 3)) * np.sqrt(np.diag(ab.cov()))
    z = truth_all[ka][:, cols] + noise
    z[..., 2] = wrap_angle(z[..., 2])
    cov_a = readonly(ab.cov())
    keyed: list[tuple[int, int, tuple, Event]] = []
    for a_, k in enumerate(ka):
        for c_, col in enumerate(cols):
            ev = Detection(ids[col], int(k) / f, Kind.ABSOLUTE, readonly(z[a_, c_]), cov_a, target=None)
            keyed.append((int(k), 1, (len(ids) + col, 2, 0), ev))
    return keyed


def simulate(
    initial_poses: Mapping[int, Sequence[float]] | Sequence[Sequence[float]],
    commands: Mapping[int, WheelCommand] | Sequence[WheelCommand],
    config: SimConfig,
    seed: int | None = 0,
) -> SimResult:
    """Simulate a team (see the module docstring for the exact model).

    ``initial_poses``: robot id -> ``(x, y, theta)`` (a sequence means ids ``0..n-1``); ``commands``: the same ids
    -> wheel-speed schedule (a :class:`WheelSchedule` or any callable ``t -> (w1, w2)``); ``seed`` for
    ``np.random.default_rng``-style seeding.
    """
    if not isinstance(initial_poses, Mapping):
        initial_poses = dict(enumerate(initial_poses))
    if not isinstance(commands, Mapping):
        commands = dict(enumerate(commands))
    ids = tuple(sorted(initial_poses))
    if set(commands) != set(ids):
        raise ValueError(f"simulate: commands for {sorted(commands)} but robots {list(ids)}")
    cfg = config.effective()
    n_rob = len(ids)
    T = 1.0 / cfg.odom_rate
    n_sub = max(1, int(round(T / cfg.dt)))
    f = cfg.odom_rate * n_sub  # internal steps per second
    dt_f = 1.0 / f
    check_size(n_rob, cfg.duration, f)
    n_int = int(round(cfg.duration * cfg.odom_rate))
    N = n_int * n_sub
    ss_motion, ss_rel, ss_abs = np.random.SeedSequence(seed).spawn(3)
    if abs(n_int / cfg.odom_rate - cfg.duration) > 1e-9 * max(1.0, cfg.duration):
        raise ValueError(f"simulate: duration {cfg.duration:g} s is not a multiple of the odometry period {T:g} s")
    sen, ab = cfg.sensor, cfg.absolute
    n_s = _steps(1.0 / sen.rate, dt_f, "sensor") if sen is not None else 0
    n_a = _steps(1.0 / ab.rate, dt_f, "absolute-fix") if ab is not None else 0

    p0 = np.array([np.asarray(initial_poses[i], dtype=float) for i in ids]).reshape(n_rob, 3)
    W = _commands([commands[i] for i in ids], np.arange(n_int) * n_sub / f)  # (n_int, n_rob, 2)
    v_cmd, w_cmd = cfg.drive.to_unicycle(W[..., 0], W[..., 1])  # (n_int, n_rob)
    truth_all = _true_paths(p0, W, cfg.drive, n_sub, dt_f, ss_motion)  # (N + 1, n_rob, 3)

    # keyed events: (step index, category, sub-order, event)
    keyed: list[tuple[int, int, tuple, Event]] = []
    for j in range(n_int):
        k1 = (j + 1) * n_sub
        t0, t1 = j * n_sub / f, k1 / f
        for r, rid in enumerate(ids):
            keyed.append((k1, 0, (r,), Odometry(rid, t0, t1, float(v_cmd[j, r]), float(w_cmd[j, r]))))
    if sen is not None and n_rob > 1:
        keyed += _relative_detections(truth_all, ids, sen, n_s, f, ss_rel)
    if ab is not None and ab.robots:
        unknown = set(ab.robots) - set(ids)
        if unknown:
            raise ValueError(f"simulate: absolute fixes requested for unknown robots {sorted(unknown)}")
        keyed += _absolute_fixes(truth_all, ids, ab, n_a, f, ss_abs)

    # ---------------------------------------------------------------- truth events
    k_truth = np.arange(0, N + 1, n_sub * cfg.truth_every)
    wrapped = truth_all.copy()
    wrapped[..., 2] = wrap_angle(wrapped[..., 2])
    for k in k_truth:
        for r, rid in enumerate(ids):
            keyed.append((int(k), 2, (r,), Truth(rid, int(k) / f, readonly(wrapped[k, r]))))

    keyed.sort(key=lambda e: (e[0], e[1], e[2]))
    return SimResult(
        events=[e[3] for e in keyed],
        initial_poses={rid: readonly(p0[r]) for r, rid in enumerate(ids)},
        robot_ids=ids,
        times=np.arange(n_int + 1) * n_sub / f,
        truth=wrapped[::n_sub],
        config=cfg,
        seed=seed,
    )
