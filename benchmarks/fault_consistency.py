"""Consistency under faults: ANEES/dof of every networked estimator under link faults, over fault seeds.

    python benchmarks/fault_consistency.py [--estimators dr,expfusion,dekf,ci,rdl,irdl,mcl] [--faults
        loss=0.2,delay=0.5] [--seeds 1,2,3] [--robots 3] [--duration 30] [--out FILE.md]

For each estimator: the in-process run without faults on the same simulated team (``sim:random``, seed 0; the
estimator's own consistency, for reference) and one live team of node processes on 127.0.0.1 per fault seed
(``--faults ...,seed=K``), with the fault table's waits. The verdict is whether the mean ANEES/dof over the seeds
lies in ``[0.5, 2]``; an estimator outside that band without faults as well (a filter that ignores correlations by
design) is marked so.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np

from swarmloc.estimators import make_team, node_options
from swarmloc.evaluation.metrics import evaluate
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.runner import run

BAND = (0.5, 2.0)
NETWORKED = "dr,expfusion,dekf,ci,rdl,irdl,mcl"


def in_process(src, est: str) -> dict:
    nodes = make_team(est, src.initial, **node_options(est, src.config, src.landmarks))
    return evaluate(run(nodes, src.events, src.record_times(), src.truth, name=est))["team"]


def networked(src, spec: str, est: str, faults: str, robots: int, duration: float, waits: dict) -> dict:
    tr = run_team(src=src, source=spec, robots=robots, duration=duration, estimator=est, faults=faults,
                  max_wall=600, team=f"consistency{os.getpid()}", **waits)  # fmt: skip
    return evaluate(team_result(tr, src, est))["team"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--estimators", default=NETWORKED, help="comma-separated networked estimators")
    ap.add_argument("--faults", default="loss=0.2,delay=0.5", help="link faults (a seed is added per run)")
    ap.add_argument("--seeds", default="1,2,3", help="comma-separated fault seeds")
    ap.add_argument("--robots", type=int, default=3)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--answer-timeout", type=float, default=0.5)
    ap.add_argument("--hold-timeout", type=float, default=0.25)
    ap.add_argument("--update-timeout", type=float, default=0.5)
    ap.add_argument("--out", default=None, help="also write the Markdown table here")
    a = ap.parse_args(argv)
    spec = "sim:random"
    src = load_source(spec, robots=a.robots, duration=a.duration, seed=0)
    seeds = [int(s) for s in a.seeds.split(",")]
    waits = {"answer_timeout": a.answer_timeout, "hold_timeout": a.hold_timeout, "update_timeout": a.update_timeout}
    t0 = time.perf_counter()
    rows = []
    for est in a.estimators.split(","):
        ref = in_process(src, est)
        runs = []
        for sd in seeds:
            r = networked(src, spec, est, f"{a.faults},seed={sd}", a.robots, a.duration, waits)
            runs.append(r)
            print(f"{est:<10} seed {sd}: rmse {r['pos_rmse']:.3f} anees {r['anees']:.2f}", file=sys.stderr)
        anees = np.array([r["anees"] for r in runs])
        inside = BAND[0] <= anees.mean() <= BAND[1]
        ref_inside = BAND[0] <= ref["anees"] <= BAND[1]
        verdict = "inside" if inside else ("outside (also without faults)" if not ref_inside else "OUTSIDE")
        rows.append((est, ref, runs, anees.mean(), verdict))
    lines = [
        f"Consistency under faults: `python benchmarks/fault_consistency.py --estimators {a.estimators} --faults "
        f"{a.faults} --seeds {a.seeds}` ({spec} seed 0, {a.robots} robots, {a.duration:g} s; "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores; waits {a.answer_timeout:g}/"
        f"{a.hold_timeout:g}/{a.update_timeout:g} s; {(time.perf_counter() - t0) / 60:.0f} min)",
        "",
        "| estimator | no faults, in-process: RMSE [m] / ANEES | "
        + " | ".join(f"seed {s}" for s in seeds)
        + " | mean ANEES | in [0.5, 2] |",
        "|---|---|" + "---|" * len(seeds) + "---|---|",
    ]
    for est, ref, runs, mean, verdict in rows:
        cells = " | ".join(f"{r['pos_rmse']:.3f} / {r['anees']:.2f}" for r in runs)
        lines.append(f"| {est} | {ref['pos_rmse']:.3f} / {ref['anees']:.2f} | {cells} | {mean:.2f} | {verdict} |")
    text = "\n".join(lines)
    print(text)
    if a.out:
        with open(a.out, "w") as fh:
            fh.write(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
