"""Association of anonymous detections in the centralized EKF: tags vs nearest vs joint, against clutter.

    python benchmarks/association.py                        # 6 robots, 60 s, seeds 0-2, clutter 0, 1, 3 per scan
    python benchmarks/association.py --robots 10 --seeds 5 --clutter 0,2

Each seed's simulated team (``sim:random``) is run by ``cekf`` on its tagged detections (``tags``, the reference)
and on the same detections made anonymous with detection probability ``--p-detect`` and Poisson clutter per scan
(:func:`swarmloc.sim.anonymous.anonymize`) with ``nearest`` and ``joint``. Printed per setting, summed or averaged
over the seeds: association accuracy (detections given their true identity, clutter refused as clutter, over all
detections), team position RMSE [m], ANEES per dof, and the fused / rejected counts.
"""

from __future__ import annotations

import argparse
import platform

import numpy as np

from swarmloc.estimators import make_team, node_options
from swarmloc.evaluation.metrics import evaluate
from swarmloc.experiments.sources import load_source
from swarmloc.runner import run
from swarmloc.sim.anonymous import anonymize


def one(src, events, policy: str) -> dict:
    opts = node_options("cekf", src.config, src.landmarks, src.t_start)
    extra = {} if policy == "tags" else {"association": policy}
    res = run(make_team("cekf", src.initial, **opts, **extra), events, src.record_times(), src.truth)
    right = sum(v for k, v in res.reasons.items() if "association right" in k or "(right)" in k)
    team = evaluate(res)["team"]
    return {"right": right, "n": res.stats["detections"], "rmse": team["pos_rmse"], "anees": team["anees"],
            "fused": res.stats["fused"], "rejected": res.stats["rejected"]}  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", type=int, default=6)
    p.add_argument("--duration", type=float, default=60.0)
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--clutter", default="0,1,3", help="mean false detections per scan, comma-separated")
    p.add_argument("--p-detect", type=float, default=0.9)
    a = p.parse_args()
    print(f"# {a.robots} robots, {a.duration:g} s, seeds 0-{a.seeds - 1}, p_detect {a.p_detect}; "
          f"{platform.machine()}, python {platform.python_version()}")  # fmt: skip
    print("| clutter/scan | policy | accuracy | team pos RMSE [m] | ANEES/dof | fused | rejected |")
    print("|---|---|---|---|---|---|---|")
    for clutter in [float(c) for c in a.clutter.split(",")]:
        rows: dict[str, list[dict]] = {"tags": [], "nearest": [], "joint": []}
        for seed in range(a.seeds):
            src = load_source("sim:random", robots=a.robots, duration=a.duration, seed=seed)
            anon = anonymize(src.events, p_detect=a.p_detect, clutter=clutter, seed=seed)
            rows["tags"].append(one(src, src.events, "tags"))
            for policy in ("nearest", "joint"):
                rows[policy].append(one(src, anon, policy))
        for policy, rs in rows.items():
            acc = "-" if policy == "tags" else f"{sum(r['right'] for r in rs) / sum(r['n'] for r in rs):.3f}"
            print(f"| {clutter:g} | {policy} | {acc} | {np.mean([r['rmse'] for r in rs]):.3f} | "
                  f"{np.mean([r['anees'] for r in rs]):.2f} | {sum(r['fused'] for r in rs)} | "
                  f"{sum(r['rejected'] for r in rs)} |")  # fmt: skip


if __name__ == "__main__":
    main()
