"""The compiled replays (``cekf``, ``iekf``, ``diekf``, ``rdl``) with JAX against numba's loops, measured in one run:
MRCLAM replay in x real time per estimator, dataset and landmark setting, and a Monte Carlo sweep (simulated teams,
one seed per run) in runs per second: numba one run after another, JAX all runs in one vmapped call.

    OPENBLAS_NUM_THREADS=1 python benchmarks/joint_jax.py                                # datasets 6 and 9, sweeps
    python benchmarks/joint_jax.py --datasets 6 --duration 120 --batches 1,4 --rounds 1  # a quick check
    python benchmarks/joint_jax.py --estimators diekf --cluster 2                       # diekf in clusters of 2

Timed: each ``run_engine`` call whole (input checks, packing, the replay, the tracks), best of ``--rounds`` after an
untimed call that compiles (its time printed as ``first``); the sweep's replays only (inputs packed beforehand),
best of ``--rounds``. The device is jax's default one (``jax.devices()[0]``).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from swarmloc.engine import joint_inputs, run_engine  # noqa: E402
from swarmloc.experiments.sources import load_source  # noqa: E402


def _best(fn, rounds: int) -> tuple[float, float, object]:  # noqa: ANN001
    """``(first call's wall, best of rounds after it, last result)``."""
    t = time.perf_counter()
    out = fn()
    first, best = time.perf_counter() - t, math.inf
    for _ in range(rounds):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return first, best, out


def _name(estimator: str, cluster: int) -> str:
    return f"{estimator} (clusters of {cluster})" if cluster and estimator == "diekf" else estimator


def replay_rows(folder: Path, datasets: list[str], estimators: list[str], duration: float | None, rounds: int,
                cluster: int = 0) -> None:  # fmt: skip
    print(
        "| dataset | landmarks | estimator | numba x real time | jax x real time | jax / numba | jax first call [s] "
        "| max mean difference [m] |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for d in datasets:
        src = load_source(f"mrclam:{folder / f'MRCLAM_Dataset{d}'}", duration=duration)
        span = src.t_end - src.t_start
        for lm in (True, False):
            for est in estimators:
                row = {}
                for backend in ("numba", "jax"):

                    def call(b=backend, src=src, est=est, lm=lm):  # noqa: ANN001, ANN202
                        extra = {"cluster": cluster} if cluster and est == "diekf" else {}
                        return run_engine(src, est, backend=b, use_landmarks=lm, **extra)

                    row[backend] = _best(call, rounds)
                a, b = row["numba"][2].tracks, row["jax"][2].tracks
                diff = max(float(np.abs(a[r].mean[:, :2] - b[r].mean[:, :2]).max(initial=0.0)) for r in a)
                xn, xj = span / row["numba"][1], span / row["jax"][1]
                print(
                    f"| {d} ({span:.0f} s) | {'on' if lm else 'off'} | {_name(est, cluster)} | {xn:.0f}x | {xj:.0f}x "
                    f"| {xj / xn:.3f} | {row['jax'][0]:.1f} | {diff:.1e} |",
                    flush=True,
                )


def sweep_rows(batches: list[int], robots: int, duration: float, rounds: int, cluster: int = 0) -> None:
    from swarmloc.engine.jax_clusters import replay_clusters_batch, replay_clusters_jax
    from swarmloc.engine.jax_joint import replay_joint_batch, replay_joint_jax
    from swarmloc.engine.jax_pairs import replay_rdl_batch, replay_rdl_jax
    from swarmloc.engine.joint import replay_joint
    from swarmloc.engine.joint_clusters import replay_clusters
    from swarmloc.engine.pairs import replay_rdl

    print(f"\nMonte Carlo sweep: sim:random, {robots} robots, {duration:g} s each, one seed per run")
    print(
        "| estimator | runs | numba, one after another [runs/s] | jax, one vmapped call [runs/s] | jax / numba "
        "| jax first call [s] |"
    )
    print("|---|---|---|---|---|---|")
    forms = {"diekf": (replay_joint, replay_joint_jax, replay_joint_batch, {"invariant": True}),
             "rdl": (replay_rdl, replay_rdl_jax, replay_rdl_batch, {})}  # fmt: skip
    if cluster:  # diekf in clusters: the cluster size is the replays' sixth argument

        def size(f):  # noqa: ANN001, ANN202
            return lambda *a, **kw: f(*a, cluster, **kw)

        forms["diekf"] = (size(replay_clusters), size(replay_clusters_jax), size(replay_clusters_batch), {})
    for est, (numba, one, many, extra) in forms.items():
        for b in batches:
            runs = [joint_inputs(load_source("sim:random", robots=robots, duration=duration, seed=s), est)
                    for s in range(b)]  # fmt: skip
            kw = {**runs[0].options, **extra}

            def numba_all(runs=runs, kw=kw, numba=numba) -> None:  # noqa: ANN001
                for r in runs:
                    numba(r.timeline, r.x, r.P, r.t0, r.noise, **kw)

            def jax_all(runs=runs, kw=kw, one=one, many=many) -> None:  # noqa: ANN001
                if len(runs) == 1:
                    one(runs[0].timeline, runs[0].x, runs[0].P, runs[0].t0, runs[0].noise, **kw)
                    return
                many([r.timeline for r in runs], np.stack([r.x for r in runs]), np.stack([r.P for r in runs]),
                     [r.t0 for r in runs], runs[0].noise, **kw)  # fmt: skip

            _, tn, _ = _best(numba_all, rounds)
            first, tj, _ = _best(jax_all, rounds)
            name = _name(est, cluster)
            print(f"| {name} | {b} | {b / tn:.1f} | {b / tj:.1f} | {tn / tj:.3f} | {first:.1f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    default = os.environ.get("SWARMLOC_MRCLAM", str(Path(__file__).resolve().parents[2] / "shared/data/mrclam"))
    ap.add_argument("--mrclam", default=default, help="folder holding MRCLAM_Dataset<k>")
    ap.add_argument("--datasets", default="6,9")
    ap.add_argument("--estimators", default="cekf,iekf,diekf,rdl")
    ap.add_argument("--duration", type=float, default=None, help="first seconds of each dataset (default all)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--batches", default="1,8,32", help="Monte Carlo runs per call, comma-separated ('' for none)")
    ap.add_argument("--sweep-robots", type=int, default=5)
    ap.add_argument("--sweep-duration", type=float, default=60.0)
    ap.add_argument("--cluster", type=int, default=0, help="diekf in clusters of this many robots (0: exact)")
    args = ap.parse_args()
    import jax

    from swarmloc.engine.jax_stamp import import_jax

    import_jax()
    print(f"device: {jax.devices()[0]} (jax {jax.__version__}), {os.cpu_count()} CPUs\n")
    if args.datasets:
        replay_rows(Path(args.mrclam), args.datasets.split(","), args.estimators.split(","), args.duration,
                    args.rounds, args.cluster)  # fmt: skip
    if args.batches:
        sweep_rows([int(b) for b in args.batches.split(",")], args.sweep_robots, args.sweep_duration, args.rounds,
                   args.cluster)  # fmt: skip


if __name__ == "__main__":
    main()
