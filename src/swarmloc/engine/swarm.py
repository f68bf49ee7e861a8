"""Large swarms: a vectorized simulator with k-nearest-neighbour sensing, :func:`swarm_run` and :func:`fusion_step`.

The swarm simulator draws ``n`` unicycles at a constant density (``density`` robots per square metre) with random
piecewise-constant commands, integrates the truth with the odometry's own process noise and, at every step, lets
each robot measure the relative pose of its ``neighbours`` nearest robots within ``max_range`` (a
``scipy.spatial.cKDTree`` query per step: ``O(n log n)``, no list of pairs). Nothing is kept per step beyond the
current arrays, so memory is ``O(n)``. The engine (:class:`~swarmloc.engine.Engine`) estimates the swarm on the
fly with the same semantics as the nodes: each step's detection groups (Gauss-Seidel levels), then the commands.

Timings depend on BLAS threads only through the kernel path (``np.linalg`` on 3x3 stacks); set
``OPENBLAS_NUM_THREADS=1`` for reproducible figures.
"""

from __future__ import annotations

import math
import resource
import time
import tracemalloc
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from swarmloc.engine.core import Detections, Engine
from swarmloc.events import Kind
from swarmloc.lie import SE2, wrap_angle
from swarmloc.motion import UnicycleNoise
from swarmloc.motion.sde import compose_exp_xyt

SWARM_NOISE = UnicycleNoise(q_v0=1e-4, q_lat0=1e-5, q_w0=1e-3)
"""Process noise of the swarm's odometry (per second: ``1e-4`` m^2 forward, ``1e-5`` m^2 lateral, ``1e-3`` rad^2)."""


class Swarm:
    """Truth, commands and sensing of ``n`` robots (rows ``0..n-1``), stepped in place.

    Poses ``pose (n, 3)`` ``(x [m], y [m], theta [rad])`` in a square of side ``sqrt(n / density)`` [m]; commands
    ``v (n,)`` [m/s] in ``speed`` and ``w (n,)`` [rad/s] in ``+-max_turn``, each redrawn with probability ``dt /
    segment`` per step (a robot outside the square turns back towards its centre).
    """

    def __init__(
        self,
        n: int,
        *,
        seed: int = 0,
        density: float = 1.0,
        speed: tuple[float, float] = (0.05, 0.3),
        max_turn: float = 0.5,
        segment: float = 3.0,
        noise: UnicycleNoise = SWARM_NOISE,
    ) -> None:
        self.n = n
        self.rng = np.random.default_rng(seed)
        self.side = math.sqrt(n / density)
        self.speed, self.max_turn, self.segment, self.noise = speed, max_turn, segment, noise
        r = self.rng
        self.pose = np.column_stack(
            [r.uniform(0, self.side, n), r.uniform(0, self.side, n), r.uniform(-np.pi, np.pi, n)]
        )
        self.v = r.uniform(*speed, n)
        self.w = r.uniform(-max_turn, max_turn, n)

    def commands(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Commands ``(v, w)`` for the next ``dt`` [s] (some redrawn, robots outside the square steered back)."""
        r, n = self.rng, self.n
        new = r.random(n) < dt / self.segment
        k = int(new.sum())
        self.v[new] = r.uniform(*self.speed, k)
        self.w[new] = r.uniform(-self.max_turn, self.max_turn, k)
        x, y, th = self.pose.T
        out = (x < 0) | (x > self.side) | (y < 0) | (y > self.side)
        if out.any():
            c = 0.5 * self.side
            home = np.arctan2(c - y[out], c - x[out])
            self.w[out] = np.clip(2.0 * wrap_angle(home - th[out]), -self.max_turn, self.max_turn)
        return self.v.copy(), self.w.copy()

    def move(self, v: np.ndarray, w: np.ndarray, dt: float) -> None:
        """Truth over ``dt`` [s]: ``g <- g exp((v dt, 0, w dt) + n)``, ``n ~ N(0, Q(v, w) dt)`` (one Euler step)."""
        q_fwd, q_lat, q_yaw = self.noise.diag(v, w)
        std = np.sqrt(np.column_stack(np.broadcast_arrays(q_fwd, q_lat, q_yaw)) * dt)
        xi = np.column_stack([v * dt, np.zeros(self.n), w * dt]) + std * self.rng.standard_normal((self.n, 3))
        x, y, th = compose_exp_xyt(self.pose[:, 0], self.pose[:, 1], self.pose[:, 2], xi)
        self.pose = np.column_stack([x, y, wrap_angle(th)])

    def sense(
        self, k: int, max_range: float, cov: np.ndarray, pairs: tuple[np.ndarray, np.ndarray] | None = None
    ) -> Detections:
        """Relative poses of each robot's ``k`` nearest neighbours within ``max_range`` [m] (or of the given
        ``(observer, target)`` pairs), noise ``N(0, cov)`` in exponential coordinates (right perturbation), sorted
        canonically (by observer, then target)."""
        if pairs is None:
            obs, tgt = neighbour_pairs(self.pose[:, :2], k, max_range)
        else:
            obs, tgt = pairs
        gi, gj = self.pose[obs], self.pose[tgt]
        c, s = np.cos(gi[:, 2]), np.sin(gi[:, 2])
        dx, dy = gj[:, 0] - gi[:, 0], gj[:, 1] - gi[:, 1]
        n = self.rng.standard_normal((obs.size, 3)) * np.sqrt(np.diag(cov))
        zx, zy, zth = compose_exp_xyt(c * dx + s * dy, -s * dx + c * dy, gj[:, 2] - gi[:, 2], n)
        z = np.column_stack([zx, zy, wrap_angle(zth)])
        return Detections.poses(obs, tgt, z, cov)


def neighbour_pairs(xy: np.ndarray, k: int, max_range: float) -> tuple[np.ndarray, np.ndarray]:
    """``(observer, target)`` rows of the ``k`` nearest other points within ``max_range`` [m] of every point of
    ``xy (n, 2)`` [m], sorted by observer then target (one ``cKDTree.query``)."""
    n = xy.shape[0]
    tree = cKDTree(xy, balanced_tree=False, compact_nodes=False)  # faster to build; same answers
    _, idx = tree.query(xy, k=k + 1, distance_upper_bound=max_range, workers=-1)
    idx = idx.reshape(n, k + 1)
    ok = (idx < n) & (idx != np.arange(n)[:, None])
    ok &= np.cumsum(ok, axis=1) <= k
    idx = np.sort(np.where(ok, idx, n), axis=1)
    obs, col = np.nonzero(idx < n)
    return obs, idx[obs, col]


def _peak_rss() -> int:
    """Peak resident memory of this process so far [bytes] (Linux reports kilobytes)."""
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


def swarm_run(
    n_robots: int,
    steps: int,
    *,
    estimator: str = "dekf",
    backend: str = "numpy",
    seed: int = 0,
    neighbours: int = 3,
    dt: float = 0.1,
    max_range: float = 1.5,
    density: float = 1.0,
    gate: float | None = 0.997,
    trace_memory: bool = False,
) -> dict[str, Any]:
    """Simulate a swarm of ``n_robots`` for ``steps`` steps of ``dt`` [s] and estimate it with the engine.

    Each robot gets its odometry every step and measures the relative pose (5 cm, 1 deg) of its ``neighbours``
    nearest robots within ``max_range`` [m]; initial beliefs at the truth with 1 cm / 0.01 rad std. Returns
    ``wall_sim_s`` / ``wall_est_s`` (seconds simulating / estimating; ``cpu_s``: CPU seconds of the process over
    both, all threads: on a shared machine the wall time also counts waiting), ``robot_updates`` (robot-steps estimated:
    one prediction and that robot's detection group), ``detections``, outcome counts, the Gauss-Seidel levels
    per step (mean, max), the final position RMSE [m] and ``peak_mem_bytes``: the process's peak resident memory
    (``ru_maxrss``: includes the interpreter and everything before the call) or, with ``trace_memory``, the peak
    of allocations traced by ``tracemalloc`` during the run (slower).
    """
    if trace_memory:
        tracemalloc.start()
    sw = Swarm(n_robots, seed=seed, density=density, noise=SWARM_NOISE)
    cov0 = np.diag([1e-4, 1e-4, 1e-4])
    meas_cov = np.diag([0.05**2, 0.05**2, np.deg2rad(1.0) ** 2])
    eng = Engine(
        estimator,
        SE2.from_xytheta(sw.pose),
        np.broadcast_to(cov0, (n_robots, 3, 3)).copy(),
        noise=SWARM_NOISE,
        gate=gate,
        backend=backend,
    )
    robots = np.arange(n_robots)
    wall_sim = wall_est = 0.0
    cpu0 = time.process_time()
    level_sum = level_max = n_det = 0
    for k in range(steps):
        t = k * dt
        t_a = time.perf_counter()
        v, w = sw.commands(dt)
        det = sw.sense(neighbours, max_range, meas_cov)
        t_b = time.perf_counter()
        eng.step(t, det, (robots, v, w), presorted=True)
        t_c = time.perf_counter()
        sw.move(v, w, dt)
        wall_sim += (t_b - t_a) + (time.perf_counter() - t_c)
        wall_est += t_c - t_b
        n_det += len(det)
        level_sum += eng.last_levels
        level_max = max(level_max, eng.last_levels)
    cpu = time.process_time() - cpu0
    mean, _ = eng.belief(steps * dt)
    err = SE2.to_xytheta(mean)[:, :2] - sw.pose[:, :2]
    if trace_memory:
        peak, source = tracemalloc.get_traced_memory()[1], "tracemalloc"
        tracemalloc.stop()
    else:
        peak, source = _peak_rss(), "ru_maxrss"
    return {
        "n": n_robots,
        "steps": steps,
        "estimator": estimator,
        "backend": backend,
        "neighbours": neighbours,
        "dt": dt,
        "wall_sim_s": wall_sim,
        "wall_est_s": wall_est,
        "wall_total_s": wall_sim + wall_est,
        "cpu_s": cpu,
        "robot_updates": n_robots * steps,
        "robot_updates_per_s": n_robots * steps / wall_est if wall_est > 0 else math.inf,
        "detections": n_det,
        "fused": eng.counts["fused"],
        "gated": eng.counts["gated"],
        "rejected": eng.counts["rejected"],
        "levels_mean": level_sum / max(steps, 1),
        "levels_max": level_max,
        "pos_rmse_m": float(np.sqrt(np.mean(np.sum(err * err, axis=1)))),
        "peak_mem_bytes": peak,
        "peak_mem_source": source,
    }


def _step_scene(n: int, neighbours: int, seed: int) -> tuple[Swarm, Detections, np.ndarray, np.ndarray]:
    """The swarm, its detections (each robot sees its ``neighbours`` nearest robots) and commands of one step."""
    sw = Swarm(n, seed=seed)
    meas_cov = np.diag([0.05**2, 0.05**2, np.deg2rad(1.0) ** 2])
    det = sw.sense(neighbours, math.inf, meas_cov, neighbour_pairs(sw.pose[:, :2], neighbours, math.inf))
    v, w = sw.commands(0.1)
    return sw, det, v, w


def _landmark_scene(sw: Swarm, k: int, seed: int) -> tuple[dict[int, tuple[float, float, float, float]], Detections]:
    """A map of one landmark per 25 robots spread over the swarm's square (std 5 cm) and each robot's range-bearing
    detections of its ``k`` nearest landmarks (noise 5 cm and 1 degree), as the engine takes them."""
    from swarmloc.engine.codes import landmark_code
    from swarmloc.sensors.models import KIND_ORDER

    rng = np.random.default_rng([seed, 25])
    m = max(k, sw.n // 25)
    xy = rng.uniform(0, sw.side, (m, 2))
    lmap = {i: (float(xy[i, 0]), float(xy[i, 1]), 0.05, 0.05) for i in range(m)}
    _, near = cKDTree(xy).query(sw.pose[:, :2], k=k)
    near = near.reshape(sw.n, k)
    obs = np.repeat(np.arange(sw.n), k)
    d = xy[near.ravel()] - sw.pose[obs, :2]
    c, s = np.cos(sw.pose[obs, 2]), np.sin(sw.pose[obs, 2])
    z = np.zeros((obs.size, 3))
    z[:, 0] = np.hypot(d[:, 0], d[:, 1]) + rng.normal(scale=0.05, size=obs.size)
    z[:, 1] = wrap_angle(np.arctan2(-s * d[:, 0] + c * d[:, 1], c * d[:, 0] + s * d[:, 1])
                         + rng.normal(scale=np.deg2rad(1.0), size=obs.size))  # fmt: skip
    R = np.zeros((obs.size, 3, 3))
    R[:, 0, 0], R[:, 1, 1] = 0.05**2, np.deg2rad(1.0) ** 2
    tgt = landmark_code(0) - near.ravel()  # landmark_code(k) = landmark_code(0) - k
    return lmap, Detections(obs, tgt, np.full(obs.size, KIND_ORDER[Kind.RANGE_BEARING]), z, R)


def fusion_step(
    n: int, *, backend: str = "numpy", neighbours: int = 3, repeats: int = 5, seed: int = 0, landmarks: int = 0
) -> dict[str, Any]:
    """Micro-benchmark of one engine step of the distributed EKF (Cartesian, ``"dekf"``, fast path) for ``n``
    robots: predict every robot and fuse ``neighbours`` relative-pose detections per robot (its nearest robots, no
    range limit, no gate: every update is computed), Gauss-Seidel levels included; with ``landmarks``, also that
    many range-bearing detections of map landmarks per robot (:func:`_landmark_scene`), one robot-update then
    counting them too.

    Returns ``robot_updates_per_s`` (``n`` / median step time; one robot-update = one prediction + its
    ``neighbours`` updates), ``best_robot_updates_per_s``, ``step_s`` (median), ``robot_updates_per_cpu_s`` (``n``
    / median CPU seconds of a step, all threads: what an idle machine would give per core), ``levels`` and
    ``kernel_robot_updates_per_s``: the same arithmetic on all robots at once without scheduling (one
    prediction and ``neighbours`` batched update calls, relative poses only: the kernels' ceiling).
    """
    sw, det, v, w = _step_scene(n, neighbours, seed)
    lmap, every = None, det
    if landmarks > 0:
        lmap, seen = _landmark_scene(sw, landmarks, seed)
        every = Detections.concat(det, seen).canonical()
    eng = Engine("dekf", SE2.from_xytheta(sw.pose), np.broadcast_to(np.diag([1e-4, 1e-4, 1e-4]), (n, 3, 3)).copy(),
                 noise=SWARM_NOISE, gate=None, backend=backend, landmarks=lmap)  # fmt: skip
    robots = np.arange(n)
    for k in (0, 1):  # warm-up: jax compiles the updates at the first stamp, the prediction at the second
        eng.step(0.1 * k, every, (robots, v, w), presorted=True)
    times, cpus = [], []
    for k in range(2, max(1, repeats) + 2):
        t0, c0 = time.perf_counter(), time.process_time()
        eng.step(0.1 * k, every, (robots, v, w), presorted=True)
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    levels = eng.last_levels

    ops = eng.ops
    if ops is None:
        raise ValueError(f"fusion_step: the engine has no fast path on backend {backend!r}")
    x, P = eng.a.copy(), eng.b.copy()
    z = det.z.reshape(n, neighbours, 3)
    R = det.R.reshape(n, neighbours, 3, 3)
    tgt = det.target.reshape(n, neighbours)
    dt = np.full(n, 0.1)

    def kernels() -> None:
        xs, Ps = ops.predict(x, P, v, w, dt)
        for j in range(neighbours):
            xs, Ps, *_ = ops.pose_update(xs, Ps, x[tgt[:, j]], P[tgt[:, j]], z[:, j], R[:, j])

    kernels()
    ktimes = wall_times(kernels, repeats)
    step = float(np.median(times))
    return {
        "n": n,
        "backend": backend,
        "neighbours": neighbours,
        "landmarks": landmarks,
        "estimator": "dekf (Cartesian EKF, structure-of-arrays kernels)",
        "step_s": step,
        "robot_updates_per_s": n / step,
        "best_robot_updates_per_s": n / min(times),
        "cpu_step_s": float(np.median(cpus)),
        "robot_updates_per_cpu_s": n / float(np.median(cpus)),
        "levels": levels,
        "kernel_robot_updates_per_s": n / float(np.median(ktimes)),
    }


def wall_times(call: Callable[[], object], repeats: int) -> list[float]:
    """Wall-clock seconds (``time.perf_counter``) of each of ``max(1, repeats)`` calls of ``call``."""
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return times


def _ready(step: Callable[..., Any], args: Sequence[object]) -> None:
    """``step(*args)`` run and waited for: each array it returns computed on its device (jax dispatches
    asynchronously; what ``jax.block_until_ready`` does, typed)."""
    for out in step(*args):
        out.block_until_ready()


def device_step(
    n: int, *, dtype: str = "float64", neighbours: int = 3, repeats: int = 5, seed: int = 0
) -> dict[str, Any]:
    """The step of :func:`fusion_step`'s scene (same swarm, detections and commands) as one jitted JAX function on
    arrays kept on jax's default device (:func:`swarmloc.engine.backends.jax_team_step`: no scheduling, no host
    copies) in ``dtype`` (``"float64"`` or ``"float32"``): the device's ceiling for this step.

    Returns ``robot_updates_per_s`` (``n`` / median step time), ``step_s``, ``compile_s`` (the first call, compile
    included), ``device`` and ``dtype``. Needs jax.
    """
    import jax

    from swarmloc.engine.backends import jax_team_step

    if dtype not in ("float64", "float32"):
        raise ValueError(f"device_step: dtype must be 'float64' or 'float32', not {dtype!r}")
    sw, det, v, w = _step_scene(n, neighbours, seed)
    f = jax_team_step(SWARM_NOISE)
    host = (sw.pose, np.broadcast_to(1e-4 * np.eye(3), (n, 3, 3)), v, w, np.full(n, 0.1),
            det.z.reshape(n, neighbours, 3), det.R.reshape(n, neighbours, 3, 3))  # fmt: skip
    args = [jax.device_put(np.asarray(a, dtype=dtype)) for a in host]
    args.append(jax.device_put(det.target.reshape(n, neighbours)))
    t0 = time.perf_counter()
    _ready(f, args)
    compile_s = time.perf_counter() - t0
    times = wall_times(lambda: _ready(f, args), repeats)
    step = float(np.median(times))
    dev = args[0].devices() if hasattr(args[0], "devices") else jax.devices()
    return {"n": n, "dtype": dtype, "neighbours": neighbours, "device": str(next(iter(dev))), "step_s": step,
            "robot_updates_per_s": n / step, "compile_s": compile_s}  # fmt: skip
