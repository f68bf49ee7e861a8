"""Which of particles, roughening and a regularised summary makes multi-robot MCL consistent?

    python benchmarks/mcl_consistency.py [--seeds 1,2,3] [--duration 60] [--mrclam-duration 300] [--out FILE.md]

Runs ``mcl`` in process with every variant (particles 200 / 500 / 2000; roughening K = 0 / 0.2 (Gordon et al.
1993); the regularised summary off / on) on the simulated team ``sim:random`` (4 robots, no landmarks, one run per
seed) and on MRCLAM dataset 6 (first ``--mrclam-duration`` s, landmarks on), the latter also with the robot-robot
detections left out (``use_relative=False``: landmarks only), which separates what the particles do from what the
mutual detections treated as independent do. ``dekf`` on the same runs is the reference: a Gaussian filter with
the same double counting and no particles. Prints pos RMSE [m] and ANEES/dof per variant.
"""

from __future__ import annotations

import argparse
import itertools
import os
import platform
import time
from pathlib import Path

import numpy as np
from _common import add_mrclam

from swarmloc.estimators import make_team, node_options
from swarmloc.evaluation.metrics import evaluate
from swarmloc.experiments.sources import load_source
from swarmloc.runner import run


def score(src, est: str, **opts) -> dict[str, float]:
    nodes = make_team(est, src.initial, **{**node_options(est, src.config, src.landmarks), **opts})
    team = evaluate(run(nodes, src.events, src.record_times(), src.truth, name=est))["team"]
    return {"rmse": float(team["pos_rmse"]), "anees": float(team["anees"])}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of each simulated run")
    add_mrclam(ap)
    ap.add_argument("--mrclam-duration", type=float, default=300.0)
    ap.add_argument("--particles", default="200,500,2000")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    t_start = time.perf_counter()
    sims = [load_source("sim:random", robots=4, duration=a.duration, seed=int(s)) for s in a.seeds.split(",")]
    mr = load_source(f"mrclam:{a.mrclam / 'MRCLAM_Dataset6'}", duration=a.mrclam_duration)
    cases = {"sim:random (mutual only)": (sims, {}), "MRCLAM 6 (landmarks + mutual)": ([mr], {}),
             "MRCLAM 6 (landmarks only)": ([mr], {"use_relative": False})}  # fmt: skip
    variants = [("dekf", {})] + [
        ("mcl", {"particles": n, "roughen": k, "regularise": r})
        for n, k, r in itertools.product([int(x) for x in a.particles.split(",")], (0.0, 0.2), (False, True))
    ]
    lines = ["| variant | " + " | ".join(f"{c}: RMSE [m] / ANEES" for c in cases) + " |", "|---" * 4 + "|"]
    for est, opts in variants:
        cells = []
        for srcs, extra in cases.values():
            rows = [score(s, est, **opts, **extra) for s in srcs]
            cells.append(f"{np.mean([r['rmse'] for r in rows]):.3f} / {np.mean([r['anees'] for r in rows]):.2f}")
        name = (
            est
            if not opts
            else f"mcl N={opts['particles']} K={opts['roughen']:g} reg={'on' if opts['regularise'] else 'off'}"
        )
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
        print(lines[-1], flush=True)
    lines.append(f"\n{platform.machine()}, {os.cpu_count()} cores, {time.perf_counter() - t_start:.0f} s; seeds "
                 f"{a.seeds}, sim {a.duration:g} s, MRCLAM 6 first {a.mrclam_duration:g} s")  # fmt: skip
    md = "\n".join(lines) + "\n"
    print(md)
    if a.out:
        a.out.write_text(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
