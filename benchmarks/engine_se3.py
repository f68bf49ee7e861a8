"""Throughput of the batched engine's step on SE(3) teams against SE(2) teams, numpy backend, in one run.

One step: predict every robot over 0.1 s with its command, then fuse ``--neighbours`` relative-pose detections per
robot (its nearest robots; ``"pose3"`` on SE(3), ``"pose"`` on SE(2)), Gauss-Seidel levels included, no gate (every
update is computed). One robot-update = one prediction + its neighbours' updates; reported: robots / median step
time. Same swarm size, neighbours and estimator on both groups.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/engine_se3.py --robots 1000,10000
"""

from __future__ import annotations

import argparse
import json
import math
import time
from typing import Any

import numpy as np

from swarmloc.engine import Detections, Engine
from swarmloc.engine.codes import POSE, POSE3
from swarmloc.engine.swarm import neighbour_pairs
from swarmloc.lie import SE2, SE3
from swarmloc.motion import UnicycleNoise
from swarmloc.motion.twist3 import TwistNoise
from swarmloc.sensors.models3 import pose3_vector


def _team(n: int, group: str, k: int, rng: np.random.Generator) -> tuple[Any, ...]:
    """Initial beliefs, detections of the ``k`` nearest robots (canonical order) and commands of ``n`` robots."""
    side = math.sqrt(n) * 2.0
    if group == "SE3":
        xyz = np.column_stack([rng.uniform(0, side, (n, 2)), rng.uniform(0, 10.0, n)])
        g = SE3.exp(np.column_stack([xyz, rng.normal(0, 0.2, (n, 2)), rng.uniform(-np.pi, np.pi, n)]))
        g[:, :3, 3] = xyz
        cov = np.broadcast_to(np.diag([1e-2] * 3 + [1e-3] * 3), (n, 6, 6)).copy()
        obs, tgt = neighbour_pairs(xyz, k, math.inf)
        z = pose3_vector(SE3.between(g[obs], g[tgt])) + rng.normal(0, 0.01, (obs.size, 6))
        R = np.broadcast_to(np.diag([0.05**2] * 3 + [np.deg2rad(2.0) ** 2] * 3), (obs.size, 6, 6))
        det = Detections(obs, tgt, np.full(obs.size, POSE3), z, R)
        v = np.column_stack([rng.uniform(0.2, 0.8, n), rng.normal(0, 0.05, (n, 2))])
        w = np.column_stack([rng.normal(0, 0.05, (n, 2)), rng.uniform(-0.5, 0.5, n)])
        return g, cov, det.canonical(), v, w, TwistNoise(q_lin0=4e-4, q_ang0=1e-4)
    xyt = np.column_stack([rng.uniform(0, side, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    g = SE2.from_xytheta(xyt)
    cov = np.broadcast_to(np.diag([1e-2, 1e-2, 1e-3]), (n, 3, 3)).copy()
    obs, tgt = neighbour_pairs(xyt[:, :2], k, math.inf)
    z = SE2.to_xytheta(SE2.between(g[obs], g[tgt])) + rng.normal(0, 0.01, (obs.size, 3))
    R = np.broadcast_to(np.diag([0.05**2, 0.05**2, np.deg2rad(2.0) ** 2]), (obs.size, 3, 3))
    det = Detections(obs, tgt, np.full(obs.size, POSE), z, R)
    return g, cov, det.canonical(), rng.uniform(0.2, 0.8, n), rng.uniform(-0.5, 0.5, n), UnicycleNoise()


def step_rate(n: int, group: str, estimator: str, neighbours: int, repeats: int, seed: int) -> dict[str, Any]:
    """Median step time [s] and robot-updates per second of ``estimator`` on ``n`` robots of ``group``."""
    g, cov, det, v, w, noise = _team(n, group, neighbours, np.random.default_rng(seed))
    eng = Engine(estimator, g, cov, noise=noise, gate=None)
    robots = np.arange(n)
    eng.step(0.0, det, (robots, v, w), presorted=True)
    times = []
    for k in range(1, repeats + 1):
        t0 = time.perf_counter()
        eng.step(0.1 * k, det, (robots, v, w), presorted=True)
        times.append(time.perf_counter() - t0)
    step = float(np.median(times))
    fused = eng.counts["fused"] / eng.counts["detections"]
    return {"group": group, "estimator": estimator, "n": n, "step_s": step, "robot_updates_per_s": n / step,
            "levels": eng.last_levels, "fused_fraction": fused}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default="1000,10000")
    ap.add_argument("--estimators", default="expfusion,dekf,ci")
    ap.add_argument("--neighbours", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    rows = []
    for n in (int(x) for x in a.robots.split(",")):
        for est in a.estimators.split(","):
            for group in ("SE2", "SE3"):
                rows.append(step_rate(n, group, est, a.neighbours, a.repeats, seed=0))
                r = rows[-1]
                if not a.json:
                    print(f"{est:9s} {group} n={n:6d}  step {r['step_s'] * 1e3:9.1f} ms  "
                          f"{r['robot_updates_per_s']:10.0f} robot-updates/s  levels {r['levels']}  "
                          f"fused {r['fused_fraction']:.2f}", flush=True)  # fmt: skip
    if a.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
