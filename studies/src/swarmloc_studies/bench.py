"""``swarmloc-studies bench``: how fast swarmloc runs on this machine, every figure measured in the same run.

Five sections (each a function, called by :func:`run_bench`; ``--sections`` picks them, a-d by default):

a. **Fusion step** (:func:`fusion_comparison`): robot-updates per second of one SE(2) step, a prediction and
   ``neighbours`` (3) relative-pose updates per robot (distributed EKF: the neighbour's covariance as noise, Joseph
   form), for a plain per-robot loop over ``filterpy``'s ``ExtendedKalmanFilter`` and for the batched engine's step
   (:func:`swarmloc.engine.fusion_step`, each installed backend of :data:`BACKENDS`); ratios to filterpy. Each
   engine row is the median of ``runs`` (10) runs of the step (:func:`engine_runs`), with their minimum and maximum
   and the load average around them: on a shared machine one run says little.
b. **Machine** (:func:`machine_rates`): memory bandwidth of a large numpy copy [GB/s, read + write] and the float64
   matmul rate [GFLOP/s] (all BLAS threads, and one thread in a fresh process); the fusion step's achieved
   fraction of each, from the estimated work of one robot-update (:data:`BYTES_PER_UPDATE`,
   :data:`FLOPS_PER_UPDATE`).
c. **Swarms** (:func:`swarm_scaling`): :func:`swarmloc.engine.swarm_run` for swarms of 100, 1,000 and 10,000 robots
   (1,000 steps of 0.1 s): wall time (simulation and estimation), peak memory (each run in a fresh process, so that
   its peak is its own), cost per robot-step against the team size and against the measurements per robot
   (neighbours 1, 3, 6), with the slopes of straight lines fitted in log-log (0: the cost per robot does not grow).
d. **MRCLAM replay** (:func:`mrclam_replay`): dataset 6 through the in-process runner, ``x`` real time per
   estimator (replayed seconds / wall seconds of the event loop, as ``swarmloc evaluate mrclam`` reports it),
   landmarks on and off.
e. **Accelerator** (:func:`swarmloc_studies.accelerator.accelerator_rates`, only when asked): the fusion step
   on jax's default device, the engine's ``"jax"`` and ``"jax32"`` backends against the same step in plain JAX
   (float64 and float32) and the numba engine, at 1e4, 1e5 and 1e6 robots.

Times are wall-clock seconds on a machine that may be shared: best (or median, as each section says) of a few
repeats. ``--quick`` (:data:`QUICK`) shrinks every section (under a minute); the default (:data:`FULL`) takes
several minutes. The engine (:mod:`swarmloc.engine`) and ``filterpy`` (extra ``bench``) are imported when needed; a
section that lacks one says so instead of failing.
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing as mp
import os
import platform
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.experiments.progress import Tick, no_tick, steps

REPLAY_ESTIMATORS = ("dr", "dekf", "cekf", "expfusion", "ci", "rdl", "diekf")
ENGINE_REPLAY = ("dekf", "cekf", "iekf", "rdl", "diekf")
"""Estimators section d also replays through the engine's compiled loop (numba): a row ``<name>/engine`` each."""
MRCLAM_ENV = "SWARMLOC_MRCLAM"
"""Environment variable: a folder holding ``MRCLAM_Dataset6`` (or the dataset folder itself)."""

BYTES_PER_UPDATE = 216 + 3 * 384
"""Least memory traffic of one robot-update with 3 neighbours [bytes], float64: the prediction reads ``x (3)``,
``P (9)`` and ``(v, w, dt)`` and writes ``x, P`` (27 numbers, 216 B); each relative-pose update reads the robot's
``x, P``, the neighbour's ``x, P``, ``z (3)`` and ``R (9)`` and writes ``x, P`` (48 numbers, 384 B). Real traffic
is higher (temporaries), so the achieved fraction is an upper bound."""

FLOPS_PER_UPDATE = 80 + 3 * 660
"""Floating-point operations of one robot-update with 3 neighbours (3-state Cartesian EKF, 3-dim measurement):
prediction about 80 (arc, ``Phi P Phi^T`` as a shear, rotated ``Q``); each update about 660: model and Jacobians
40, ``S = H P H^T + H_k P_k H_k^T + R`` 200, ``S^-1`` 50, ``K`` 90, mean 18, Joseph form
``(I - K H) P (I - K H)^T + K R K^T`` and symmetrization 260. Counted as multiplications plus additions."""


@dataclass(frozen=True)
class BenchConfig:
    """Sizes of every section (see the module docstring); :data:`QUICK` and :data:`FULL` are the presets."""

    engine_n: int = 10_000
    filterpy_n: int = 1_000
    neighbours: int = 3
    repeats: int = 5
    runs: int = 10
    copy_mb: int = 256
    matmul_n: int = 2048
    swarm_sizes: tuple[int, ...] = (100, 1_000, 10_000)
    swarm_steps: int = 1_000
    neighbour_sweep: tuple[int, ...] = (1, 3, 6)
    sweep_n: int = 1_000
    isolate: bool = True
    replay_duration: float | None = None
    replay_rounds: int = 1
    estimators: tuple[str, ...] = REPLAY_ESTIMATORS
    landmarks: tuple[bool, ...] = (True, False)
    accelerator_sizes: tuple[int, ...] = (10_000, 100_000, 1_000_000)


FULL = BenchConfig()
QUICK = BenchConfig(
    engine_n=2_000, filterpy_n=200, repeats=3, runs=3, copy_mb=64, matmul_n=1024, swarm_sizes=(100, 1_000),
    swarm_steps=100, sweep_n=300, isolate=False, replay_duration=60.0, accelerator_sizes=(1_000, 10_000),
)  # fmt: skip


def _engine() -> Any:
    """:mod:`swarmloc.engine`, or None when it is not there."""
    try:
        from swarmloc import engine
    except ImportError:
        return None
    return engine if hasattr(engine, "fusion_step") and hasattr(engine, "swarm_run") else None


ENGINE_MISSING = "swarmloc.engine (fusion_step, swarm_run) is not available in this installation"

BACKENDS = ("numpy", "numba", "jax")
"""Engine backends the fusion step is measured with (those installed); swarms run on the fastest of numpy and
numba (:func:`swarm_backend`): jax compiles once per batch size, which a swarm's changing detection counts defeat."""


def backend_available(backend: str) -> bool:
    """Whether the optional package behind an engine backend imports."""
    import importlib.util

    return backend == "numpy" or importlib.util.find_spec(backend) is not None


def swarm_backend() -> str:
    """``"numba"`` where it is installed, else ``"numpy"``."""
    return "numba" if backend_available("numba") else "numpy"


# ------------------------------------------------------------------------------------------------ b. machine
def machine_rates(copy_mb: int = 256, matmul_n: int = 2048, repeats: int = 3, single_thread: bool = True) -> dict:
    """Memory bandwidth [GB/s] of copying ``copy_mb`` MB of float64 (bytes read + written / best time) and float64
    matmul rate [GFLOP/s] (``2 n^3`` / best time) with the BLAS threads as configured and, with ``single_thread``,
    with one thread (in a fresh process started with ``OPENBLAS_NUM_THREADS=1`` and the like)."""
    n = max(1, copy_mb * 2**20 // 8)
    src = np.ones(n)
    dst = np.empty_like(src)
    np.copyto(dst, src)
    best = math.inf
    for _ in range(max(1, repeats)):
        t = time.perf_counter()
        np.copyto(dst, src)
        best = min(best, time.perf_counter() - t)
    out: dict[str, Any] = {
        "copy_mb": copy_mb,
        "bandwidth_gb_s": 2 * n * 8 / best / 1e9,
        "matmul_n": matmul_n,
        "gflops": _matmul_gflops(matmul_n, repeats),
        "cpu_count": os.cpu_count(),
        "blas_threads_env": os.environ.get("OPENBLAS_NUM_THREADS") or os.environ.get("OMP_NUM_THREADS") or "default",
    }
    del src, dst
    if single_thread:
        out["gflops_one_thread"] = _in_fresh_process(_matmul_gflops, matmul_n, repeats, one_thread=True)
    return out


def _matmul_gflops(n: int, repeats: int) -> float:
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((n, n)), rng.standard_normal((n, n))
    a @ b
    best = math.inf
    for _ in range(max(1, repeats)):
        t = time.perf_counter()
        a @ b
        best = min(best, time.perf_counter() - t)
    return 2.0 * n**3 / best / 1e9


_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")


@contextlib.contextmanager
def _env(one_thread: bool) -> Iterator[None]:
    old = {k: os.environ.get(k) for k in _THREAD_VARS}
    if one_thread:
        os.environ.update(dict.fromkeys(_THREAD_VARS, "1"))
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _in_fresh_process(fn: Callable[..., Any], *args: Any, one_thread: bool = False) -> Any:
    """``fn(*args)`` in a new interpreter (spawned: its own memory peak, its own BLAS threads)."""
    with _env(one_thread), ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn")) as ex:
        return ex.submit(fn, *args).result()


# ------------------------------------------------------------------------------------------------ a. fusion step
def _swarm_geometry(n: int, neighbours: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses ``(n, 3)`` in a square of ``n`` m^2, the ``neighbours`` nearest robots of each ``(n, k)``, and each
    robot's measured relative pose of them ``(n, k, 3)`` (5 cm, 1 deg noise)."""
    from scipy.spatial import cKDTree

    from swarmloc.lie import wrap_angle

    rng = np.random.default_rng(seed)
    side = math.sqrt(n)
    pose = np.column_stack([rng.uniform(0, side, (n, 2)), rng.uniform(-math.pi, math.pi, n)])
    k = min(neighbours, n - 1)
    _, idx = cKDTree(pose[:, :2]).query(pose[:, :2], k=k + 1)
    nb = idx.reshape(n, k + 1)[:, 1:]
    d = pose[nb, :2] - pose[:, None, :2]
    c, s = np.cos(pose[:, 2])[:, None], np.sin(pose[:, 2])[:, None]
    rel = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1],
                    wrap_angle(pose[nb, 2] - pose[:, None, 2])], axis=-1)  # fmt: skip
    rel += rng.standard_normal(rel.shape) * np.array([0.05, 0.05, math.radians(1.0)])
    return pose, nb, rel


def filterpy_fusion(n: int, neighbours: int = 3, repeats: int = 3, seed: int = 0) -> dict:
    """Robot-updates per second of a per-robot loop over ``filterpy.kalman.ExtendedKalmanFilter``: for every robot
    one prediction (``F = Phi``, ``Q`` and the arc of :func:`swarmloc.kernels.cartesian.increment`) and
    ``neighbours`` relative-pose updates (:func:`swarmloc.sensors.models.relative_pose`, the neighbour's covariance
    added to the noise as the distributed EKF does, angle residuals wrapped). Median over ``repeats`` steps."""
    from filterpy.kalman import ExtendedKalmanFilter

    from swarmloc.engine.swarm import wall_times
    from swarmloc.kernels import cartesian as C
    from swarmloc.lie import wrap_angle
    from swarmloc.motion import UnicycleNoise
    from swarmloc.sensors import models

    noise = UnicycleNoise(q_v0=1e-4, q_lat0=1e-5, q_w0=1e-3)
    pose, nb, rel = _swarm_geometry(n, neighbours, seed)
    rng = np.random.default_rng(seed + 1)
    v, w = rng.uniform(0.0, 0.5, n), rng.uniform(-0.5, 0.5, n)
    R = np.diag([0.05**2, 0.05**2, math.radians(1.0) ** 2])

    class _EKF(ExtendedKalmanFilter):
        def predict_x(self, u: Any = 0) -> None:  # the arc (filterpy's default is F x)
            self.x = self.x_next

    def residual(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        r = a - b
        r[2] = wrap_angle(r[2])
        return r

    filters = []
    for i in range(n):
        f = _EKF(dim_x=3, dim_z=3)
        f.x = pose[i].copy()
        f.P = np.eye(3) * 1e-4
        filters.append(f)

    def step() -> None:
        xs = [f.x.copy() for f in filters]
        Ps = [f.P.copy() for f in filters]
        for i, f in enumerate(filters):
            f.x_next, f.F, f.Q = C.increment(f.x, float(v[i]), float(w[i]), 0.1, noise)
            f.predict()
            for j in range(nb.shape[1]):
                k = int(nb[i, j])
                h, Hi, Hk = models.relative_pose(f.x, xs[k])
                f.update(rel[i, j], lambda x, H=Hi: H, lambda x, h=h: h, R=R + Hk @ Ps[k] @ Hk.T, residual=residual)

    times = wall_times(step, repeats)
    med = float(np.median(times))
    return {"n": n, "neighbours": int(nb.shape[1]), "step_s": med, "robot_updates_per_s": n / med,
            "best_robot_updates_per_s": n / min(times)}  # fmt: skip


def engine_runs(n: int, backend: str, neighbours: int = 3, repeats: int = 5, runs: int = 10,
                landmarks: int = 0) -> dict:  # fmt: skip
    """:func:`~swarmloc.engine.fusion_step` run ``runs`` times (each the median of ``repeats`` steps): the first
    run's other figures with ``robot_updates_per_s`` and ``robot_updates_per_cpu_s`` the medians over the runs
    (``step_s``: ``n`` over that median), ``min_robot_updates_per_s`` and ``max_robot_updates_per_s``,
    ``best_robot_updates_per_s`` over all steps, ``runs``, and ``load_1min``: the 1-minute load average before and
    after the runs (``os.getloadavg``; absent where the platform has none)."""
    from swarmloc.engine import fusion_step

    load0 = _load()
    rs = [fusion_step(n, backend=backend, neighbours=neighbours, repeats=repeats, landmarks=landmarks)
          for _ in range(max(1, runs))]  # fmt: skip
    out: dict[str, Any] = {k: v for k, v in rs[0].items() if isinstance(v, int | float | str)}
    rates = [r["robot_updates_per_s"] for r in rs]
    med = float(np.median(rates))
    out.update(runs=len(rs), robot_updates_per_s=med, step_s=n / med, min_robot_updates_per_s=min(rates),
               max_robot_updates_per_s=max(rates),
               best_robot_updates_per_s=max(r["best_robot_updates_per_s"] for r in rs),
               robot_updates_per_cpu_s=float(np.median([r["robot_updates_per_cpu_s"] for r in rs])))  # fmt: skip
    load1 = _load()
    if load0 is not None and load1 is not None:
        out["load_1min"] = (load0, load1)
    return out


def _load() -> float | None:
    """The 1-minute load average (None where the platform has none)."""
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):
        return None


def fusion_comparison(
    engine_n: int = 10_000, filterpy_n: int = 1_000, neighbours: int = 3, repeats: int = 5,
    machine: dict | None = None, tick: Tick = no_tick, runs: int = 10,
) -> dict:  # fmt: skip
    """Section a (and the fractions of section b when ``machine`` is given): the engine's
    :func:`~swarmloc.engine.fusion_step` (:func:`engine_runs`: the median of ``runs`` runs) and
    :func:`filterpy_fusion`, robot-updates/s and their ratio; also the step with one map landmark per robot on the
    fastest installed CPU backend (numba, else numpy)."""
    out: dict[str, Any] = {"neighbours": neighbours}
    try:
        out["filterpy"] = filterpy_fusion(filterpy_n, neighbours, max(1, min(repeats, 3)))
    except ImportError:
        out["filterpy"] = {"skipped": "filterpy is not installed (pip install filterpy)"}
    tick("fusion step: filterpy")
    eng = _engine()
    if eng is None:
        out["engine"] = {"skipped": ENGINE_MISSING}
    else:
        out["backends"] = {}
        for backend in BACKENDS:
            if backend != "numpy" and not backend_available(backend):
                out["backends"][backend] = {"skipped": f"{backend} is not installed"}
                continue
            if backend == "jax":  # compiled once per batch size: a first, untimed call
                eng.fusion_step(engine_n, backend=backend, neighbours=neighbours, repeats=1)
            out["backends"][backend] = engine_runs(engine_n, backend, neighbours, repeats, runs)
        out["engine"] = out["backends"]["numpy"]
        rates = {b: r["robot_updates_per_s"] for b, r in out["backends"].items() if "robot_updates_per_s" in r}
        out["best_backend"] = max(rates, key=rates.__getitem__)
        lm = engine_runs(engine_n, swarm_backend(), neighbours, repeats, runs, landmarks=1)
        out["backends"][f"{swarm_backend()}, 1 landmark"] = lm
    tick("fusion step: engine")
    fp, en = out["filterpy"].get("robot_updates_per_s"), out["engine"].get("robot_updates_per_s")
    if fp and en:
        out["engine_over_filterpy"] = en / fp
        for r in out.get("backends", {}).values():
            if "robot_updates_per_s" in r:
                r["over_filterpy"] = r["robot_updates_per_s"] / fp
    if en and machine:
        out["bytes_per_update"] = BYTES_PER_UPDATE
        out["flops_per_update"] = FLOPS_PER_UPDATE
        out["achieved_gb_s"] = en * BYTES_PER_UPDATE / 1e9
        out["achieved_gflops"] = en * FLOPS_PER_UPDATE / 1e9
        out["fraction_of_bandwidth"] = out["achieved_gb_s"] / machine["bandwidth_gb_s"]
        out["fraction_of_flops"] = out["achieved_gflops"] / machine["gflops"]
        if machine.get("gflops_one_thread"):
            out["fraction_of_flops_one_thread"] = out["achieved_gflops"] / machine["gflops_one_thread"]
    return out


# ------------------------------------------------------------------------------------------------ c. swarms
def _vm_hwm() -> int | None:
    """Peak resident memory of this process's address space [bytes] (``VmHWM``; Linux), None elsewhere. Unlike
    ``ru_maxrss`` it is not inherited from the parent of a spawned process."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def _reset_hwm() -> bool:
    """Reset ``VmHWM`` to the current resident memory (Linux ``clear_refs``); False where not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        return False
    return True


def _swarm_job(n: int, steps: int, neighbours: int, seed: int, backend: str = "numpy") -> dict:
    reset = _reset_hwm()
    r = _engine().swarm_run(n, steps, estimator="dekf", backend=backend, seed=seed, neighbours=neighbours)
    out = {k: v for k, v in r.items() if isinstance(v, int | float | str)}
    out["backend"] = backend
    hwm = _vm_hwm()
    if hwm is not None:  # this run's peak (reset before it), not the process's since it started
        out["peak_mem_bytes"] = hwm
        out["peak_mem_source"] = "VmHWM reset before the run" if reset else "VmHWM"
    return out


def loglog_slope(x: Sequence[float], y: Sequence[float]) -> float:
    """Slope of the least-squares line through ``(log x, log y)`` (NaN with fewer than two points)."""
    if len(x) < 2:
        return math.nan
    return float(np.polyfit(np.log(np.asarray(x, float)), np.log(np.asarray(y, float)), 1)[0])


def swarm_scaling(
    sizes: Sequence[int] = (100, 1_000, 10_000), steps: int = 1_000, neighbour_sweep: Sequence[int] = (1, 3, 6),
    sweep_n: int = 1_000, neighbours: int = 3, isolate: bool = True, tick: Tick = no_tick,
) -> dict:  # fmt: skip
    """Section c: :func:`swarmloc.engine.swarm_run` (distributed EKF, :func:`swarm_backend`) over ``sizes`` with
    ``neighbours``, and over ``neighbour_sweep`` at ``sweep_n`` robots. ``us_per_robot_step``: estimation wall
    time per robot and step [us]; slopes of its log against log team size and log neighbours.
    ``peak_mem_bytes``: peak resident memory of the process during the run (interpreter and libraries included;
    Linux ``VmHWM``, reset before the run where the kernel allows). ``isolate``: each run in a fresh process."""
    if _engine() is None:
        for _ in [*sizes, *neighbour_sweep]:
            tick("swarms: skipped")
        return {"skipped": ENGINE_MISSING}

    def job(n: int, k: int) -> dict:
        b = swarm_backend()
        r = _in_fresh_process(_swarm_job, n, steps, k, 0, b) if isolate else _swarm_job(n, steps, k, 0, b)
        r["us_per_robot_step"] = 1e6 * r["wall_est_s"] / max(r["robot_updates"], 1)
        r["us_per_robot_step_total"] = 1e6 * (r["wall_est_s"] + r["wall_sim_s"]) / max(r["robot_updates"], 1)
        tick(f"swarm {n} robots, {k} neighbours")
        return r

    by_size = [job(n, neighbours) for n in sizes]
    by_nb = [r for r in by_size if r["n"] == sweep_n and r["neighbours"] in neighbour_sweep]
    done = {r["neighbours"] for r in by_nb}
    by_nb += [job(sweep_n, k) for k in neighbour_sweep if k not in done]
    by_nb.sort(key=lambda r: r["neighbours"])
    sizes_, nbs = [r["n"] for r in by_size], [r["neighbours"] for r in by_nb]
    return {
        "steps": steps,
        "isolated": isolate,
        "by_size": by_size,
        "by_neighbours": by_nb,
        "slope_cost_per_robot_vs_size": loglog_slope(sizes_, [r["us_per_robot_step"] for r in by_size]),
        "slope_wall_vs_size": loglog_slope(sizes_, [r["wall_est_s"] for r in by_size]),
        "slope_cost_per_robot_vs_neighbours": loglog_slope(nbs, [r["us_per_robot_step"] for r in by_nb]),
    }


# ------------------------------------------------------------------------------------------------ d. replay
def find_mrclam(path: str | Path | None = None) -> Path | None:
    """``MRCLAM_Dataset6``: ``path`` (the dataset or a folder holding it), else :data:`MRCLAM_ENV`, else None."""
    for cand in (path, os.environ.get(MRCLAM_ENV)):
        if cand:
            p = Path(cand)
            for d in (p, p / "MRCLAM_Dataset6"):
                if d.is_dir() and (d / "Robot1_Odometry.dat").exists():
                    return d
    return None


def mrclam_replay(
    path: str | Path, duration: float | None = None, estimators: Sequence[str] = REPLAY_ESTIMATORS,
    landmarks: Sequence[bool] = (True, False), rounds: int = 1, tick: Tick = no_tick,
) -> dict:  # fmt: skip
    """Section d: every estimator on the MRCLAM dataset at ``path`` (first ``duration`` s, default all), with and
    without landmarks, through :func:`swarmloc.experiments.evaluate.evaluate_stream` (the events built once per setting,
    as ``swarmloc evaluate mrclam`` builds them). ``x_real_time``: replayed seconds / best wall time of the event loop
    over ``rounds``. With an estimator of :data:`ENGINE_REPLAY`, also a row ``<name>/engine``: the same run through
    the batched engine's compiled replay (numba; :func:`swarmloc.experiments.mrclam.engine_replay`, whole call).
    Both rows run ``diekf`` with its process noise fixed (``diekf_adaptive = false``): the engine's replay does not
    scale it, so the rows time one filter."""
    from swarmloc.config import DEFAULTS

    fixed = DEFAULTS.with_filter(diekf_adaptive=False)
    from swarmloc.datasets.mrclam import load_mrclam
    from swarmloc.experiments import mrclam as M
    from swarmloc.experiments.evaluate import evaluate_stream

    data = load_mrclam(path)
    t_end = data.t_end if duration is None else min(data.t_end, data.t_start + duration)
    out: dict[str, Any] = {"dataset": data.name, "duration_s": float(t_end - data.t_start), "rounds": rounds}
    for lm in landmarks:
        key = "landmarks_on" if lm else "landmarks_off"
        if hasattr(M, "mrclam_stream"):
            events, _ = M.mrclam_stream(data, DEFAULTS, duration, lm)
        else:  # an installation without the camera model
            s = DEFAULTS.sensors
            events = M.mrclam_events(data, duration=duration, landmarks=lm, range_std=s.range_std,
                                     bearing_std=s.bearing_std)  # fmt: skip
        rows: dict[str, Any] = {}
        for name in estimators:
            best = math.inf
            for _ in range(max(1, rounds)):
                rep, _ = evaluate_stream(
                    events, M.initial_beliefs(data, DEFAULTS), t_start=data.t_start, t_end=t_end,
                    truth=data.truth_at if data.has_truth else None, landmarks=data.landmarks, estimators=[name],
                    config=fixed,
                )  # fmt: skip
                best = min(best, rep["estimators"][name]["wall_time_s"])
            team = rep["estimators"][name].get("team") or {}
            rows[name] = {"wall_s": best, "x_real_time": out["duration_s"] / best, "pos_rmse_m": team.get("pos_rmse"),
                          "anees": team.get("anees")}  # fmt: skip
            tick(f"replay {name}, landmarks {'on' if lm else 'off'}")
        for name in ENGINE_REPLAY:  # the same filter through the engine's compiled replay, every call timed whole
            eng = M.engine_replay(data, events, t_end, lm, rounds, fixed, name) if name in estimators else None
            if eng is not None:
                rows[f"{name}/engine"] = eng
                tick(f"replay {name}/engine, landmarks {'on' if lm else 'off'}")
        out[key] = {"events": len(events), "estimators": rows}
    return out


# ------------------------------------------------------------------------------------------------ all
SECTIONS = "abcd"
"""Sections run by default; ``e`` (the accelerator, :mod:`swarmloc_studies.accelerator`) runs when asked."""


def _work_items(cfg: BenchConfig, replay: bool, sections: str = SECTIONS) -> int:
    swarms = len(cfg.swarm_sizes) + len([k for k in cfg.neighbour_sweep if not (
        k == cfg.neighbours and cfg.sweep_n in cfg.swarm_sizes)])  # fmt: skip
    replays = len(cfg.estimators) + len(set(ENGINE_REPLAY) & set(cfg.estimators))  # the engine rows too
    counts = {"b": 1, "a": 2, "c": swarms, "d": replays * len(cfg.landmarks) if replay else 0,
              "e": 5 * len(cfg.accelerator_sizes)}  # fmt: skip
    return sum(counts[k] for k in sections)


def run_bench(
    cfg: BenchConfig = FULL, mrclam: str | Path | None = None, progress: bool = False, sections: str = SECTIONS
) -> dict:
    """The ``sections`` (letters of ``abcde``; a needs b's rates for its fractions and runs b with it) with the
    sizes of ``cfg``; section d when the dataset is found (:func:`find_mrclam`)."""
    bad = sorted(set(sections) - set("abcde"))
    if bad or not sections:
        raise ValueError(f"bench: sections are letters of 'abcde', not {sections!r}")
    if "a" in sections and "b" not in sections:
        sections += "b"
    ds = find_mrclam(mrclam) if "d" in sections else None
    machine = {"platform": platform.platform(), "python": platform.python_version(), "numpy": np.__version__}
    res: dict[str, Any] = {"machine": {**machine, "cpu_count": os.cpu_count()}, "config": asdict(cfg)}
    with steps(progress, _work_items(cfg, ds is not None, sections), "bench") as tick:
        if "b" in sections:
            m = machine_rates(cfg.copy_mb, cfg.matmul_n)
            res["machine"].update(m)
            tick("machine: bandwidth and FLOP rate")
        if "a" in sections:
            res["fusion_step"] = fusion_comparison(cfg.engine_n, cfg.filterpy_n, cfg.neighbours, cfg.repeats, m,
                                                   tick, cfg.runs)  # fmt: skip
        if "c" in sections:
            res["swarms"] = swarm_scaling(cfg.swarm_sizes, cfg.swarm_steps, cfg.neighbour_sweep, cfg.sweep_n,
                                          cfg.neighbours, cfg.isolate, tick)  # fmt: skip
        if "d" in sections and ds is None:
            res["mrclam"] = {"skipped": f"MRCLAM_Dataset6 not found (pass --mrclam or set {MRCLAM_ENV})"}
        elif "d" in sections and ds is not None:
            res["mrclam"] = mrclam_replay(ds, cfg.replay_duration, cfg.estimators, cfg.landmarks, cfg.replay_rounds,
                                          tick)  # fmt: skip
        if "e" in sections:
            from swarmloc_studies.accelerator import accelerator_rates

            res["accelerator"] = accelerator_rates(cfg.accelerator_sizes, cfg.neighbours, cfg.repeats, tick)
    return res
