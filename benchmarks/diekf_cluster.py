"""``diekf`` with clusters against the exact filter: cost per detection and per robot against team size, and the
accuracy and consistency paid for it.

    python benchmarks/diekf_cluster.py                                   # 5..80 robots, clusters of 5, 10 s
    python benchmarks/diekf_cluster.py --robots 5,10,20 --cluster 3,5 --duration 20 --exact-up-to 10
    python benchmarks/diekf_cluster.py --engine --spread --robots 10,100,1000,3000 --exact-up-to 100

``--engine``: the engine's compiled replay (``run_engine(src, "diekf", backend="numba", cluster=K)``, equal to the
nodes: tests/test_engine_clusters.py) instead of the in-process nodes, timed as the wall of its replay (after an
untimed run on a small team that compiles numba's loop). ``--spread``: the arena grows with the team (side ``3 m
sqrt(n / 5)``) but the robots may leave it, so a robot of a small team still sees fewer teammates; ``--bounded``:
constant density in what a robot sees (benchmarks/swarm_scene.py); without either, ``sim:random``'s 3 m arena.

``sim:random`` teams (seed 1), every robot a node of the in-process runner; CPU time of the run
(``time.process_time``, one process, one thread: ``OPENBLAS_NUM_THREADS=1`` is set before numpy loads). The exact
filter (``cluster 0``) costs ``O(n^2)`` per robot and detection, so it runs only up to ``--exact-up-to`` robots.
In ``sim:random`` a robot sees more teammates in a larger team (the arena does not grow), so the cost is given per
fused detection (``ms/detection``: the whole team's CPU per detection, every cluster mate's replica update
included) besides per robot and second of data; the log-log slope of the former against team size is printed
per setting (0: flat).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from swarm_scene import scene  # noqa: E402

from swarmloc.engine import run_engine  # noqa: E402
from swarmloc.estimators import make_team, node_options  # noqa: E402
from swarmloc.evaluation.metrics import evaluate  # noqa: E402
from swarmloc.runner import run  # noqa: E402


def measure(n: int, cluster: int, duration: float, seed: int, engine: bool = False, arena: str = "fixed") -> dict:
    src = scene(n, duration, seed, arena)
    options = {**node_options("diekf", src.config, src.landmarks), "cluster": cluster}
    if engine:  # the replay's own wall (RunResult.wall_time), after a run that compiles
        run_engine(scene(min(n, 6), 2.0, seed, arena), "diekf", backend="numba", **options)
        res = run_engine(src, "diekf", backend="numba", **options)
        cpu = res.wall_time
    else:
        nodes = make_team("diekf", src.initial, **options)
        t = time.process_time()
        res = run(nodes, src.events, src.record_times(), truth=src.truth)
        cpu = time.process_time() - t
    team = evaluate(res)["team"]
    fused = res.stats["fused"]
    return {
        "n": n, "cluster": cluster, "fused": fused, "det_per_robot_s": fused / n / duration,
        "ms_per_detection": 1e3 * cpu / max(fused, 1), "ms_per_robot_s": 1e3 * cpu / n / duration,
        "rmse": team["pos_rmse"], "anees": team["anees"], "accounted": res.accounted(),
    }  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", default="5,10,20,40,80")
    ap.add_argument("--cluster", default="5", help="cluster sizes to run besides the exact filter (comma-separated)")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--exact-up-to", type=int, default=20, help="largest team the exact filter runs (default 20)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--engine", action="store_true", help="the engine's compiled replay instead of the nodes")
    ap.add_argument("--spread", action="store_true", help="the arena grows with the team, robots free to leave it")
    ap.add_argument("--bounded", action="store_true", help="constant density: swarm_scene.py's bounded arena")
    args = ap.parse_args()
    sizes = [int(x) for x in args.robots.split(",")]
    arena = "bounded" if args.bounded else "spread" if args.spread else "fixed"
    clusters = [0] + [int(x) for x in args.cluster.split(",") if x]
    print(
        f"machine: {platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}; "
        f"sim:random ({arena} arena) seed {args.seed}, {args.duration:g} s; "
        + ("engine (numba), wall of the replay" if args.engine else "nodes in process, CPU time")
    )
    print(f"{'robots':>6} {'cluster':>8} {'det/robot/s':>11} {'ms/detection':>12} {'ms/robot/s':>10} "
          f"{'RMSE [m]':>9} {'ANEES/dof':>9}")  # fmt: skip
    rows: dict[int, list[dict]] = {c: [] for c in clusters}
    for n in sizes:
        for c in clusters:
            if c == 0 and n > args.exact_up_to:
                continue
            r = measure(n, c, args.duration, args.seed, args.engine, arena)
            rows[c].append(r)
            name = "exact" if c == 0 else str(c)
            print(f"{n:>6} {name:>8} {r['det_per_robot_s']:>11.1f} {r['ms_per_detection']:>12.3f} "
                  f"{r['ms_per_robot_s']:>10.2f} {r['rmse']:>9.4f} {r['anees']:>9.2f}"
                  + ("" if r["accounted"] else "  (not every detection accounted!)"), flush=True)  # fmt: skip
    for c, rs in rows.items():
        if len(rs) >= 2:
            x = np.log([r["n"] for r in rs])
            y = np.log([r["ms_per_detection"] for r in rs])
            slope = float(np.polyfit(x, y, 1)[0])
            name = "exact" if c == 0 else f"clusters of {c}"
            print(f"  {name}: log-log slope of ms/detection against team size {slope:+.2f}"
                  f" ({rs[0]['n']}..{rs[-1]['n']} robots)")  # fmt: skip
    if not math.isfinite(sum(r["rmse"] for rs in rows.values() for r in rs)):
        raise SystemExit("a run gave a non-finite error")


if __name__ == "__main__":
    main()
