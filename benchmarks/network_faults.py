"""Fault table of the live team runtime: team RMSE, ANEES and message counts under injected network faults.

    python benchmarks/network_faults.py [--estimator rdl] [--robots 3] [--duration 30] [--out FILE.md]

Every row starts a fresh team of node processes on 127.0.0.1 (``swarmloc.experiments.team.run_team``) on the same
simulated team (``sim:random``, seed 0), with message loss x delay (plus duplicates 5% and reordering 10% once
delayed), then a node killed and restarted from the belief server, then a late joiner. The first row (no faults) is
the baseline.
Counts are summed over the nodes' reports: ``lost``/``dup`` injected, ``dropped`` messages rejected on receipt
(stale, duplicate, outdated update, malformed), ``replayed`` history entries re-applied because of late input,
``no reply`` queries that timed out (asked of the server or answered "not found"). NaN: any non-finite belief.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np

from swarmloc.evaluation.metrics import evaluate
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result

LINK = [(loss, delay) for loss in (0.0, 0.1, 0.3, 0.5) for delay in (0.0, 0.2, 1.0)]


def row(src, spec: str, est: str, faults: str, robots: int, duration: float, waits: dict[str, float]) -> dict:
    t = time.perf_counter()
    tr = run_team(src=src, source=spec, robots=robots, duration=duration, estimator=est, faults=faults,
                  max_wall=600, team=f"faults{os.getpid()}", **waits)  # fmt: skip
    res = team_result(tr, src, est)
    ev = evaluate(res)["team"]
    s = res.stats
    finite = all(np.isfinite(tr_.mean).all() and np.isfinite(tr_.cov).all() for tr_ in res.tracks.values())
    return {
        "faults": faults or "none",
        "pos_rmse": ev["pos_rmse"],
        "anees": ev["anees"],
        "fused": s["fused"],
        "unknown": s["unknown"],
        "rejected_det": s["rejected"],
        "lost": s.get("net_lost", 0),
        "dup": s.get("net_duplicated", 0),
        "dropped": s.get("messages_rejected", 0) + s.get("net_rejected", 0),
        "replayed": s.get("replayed", 0),
        "no_reply": s.get("net_no_reply", 0),
        "nan": not finite,
        "exit_ok": all(c == 0 for c in tr.exit_codes.values() if c is not None),
        "wall_s": time.perf_counter() - t,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--estimator", default="rdl")
    ap.add_argument("--robots", type=int, default=3)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--answer-timeout", type=float, default=0.5, help="seconds a node waits for a reply to a query")
    ap.add_argument("--hold-timeout", type=float, default=0.25, help="seconds a node holds a query to let it settle")
    ap.add_argument("--update-timeout", type=float, default=0.5, help="seconds a node waits for an rdl update")
    ap.add_argument("--out", default=None, help="also write the Markdown table here")
    a = ap.parse_args(argv)
    spec = "sim:random"
    src = load_source(spec, robots=a.robots, duration=a.duration, seed=0)
    specs = [""] + [f"loss={lo:g},delay={de:g}" + (",dup=0.05,reorder=0.1" if de else "") for lo, de in LINK[1:]]
    specs += [f"kill=1@{a.duration / 3:g}", f"late=2@{a.duration / 4:g}"]
    rows = []
    for f in specs:
        waits = {"answer_timeout": a.answer_timeout, "hold_timeout": a.hold_timeout, "update_timeout": a.update_timeout}
        r = row(src, spec, a.estimator, f, a.robots, a.duration, waits)
        rows.append(r)
        msg = f"{r['faults']:<40} rmse {r['pos_rmse']:.3f} anees {r['anees']:.2f} ({r['wall_s']:.0f} s)"
        print(msg, file=sys.stderr)
    lines = [
        f"Fault table: `python benchmarks/network_faults.py --estimator {a.estimator} --robots {a.robots} "
        f"--duration {a.duration:g}` ({spec}, seed 0; {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores; answer, hold and update timeouts {a.answer_timeout:g}, {a.hold_timeout:g} and "
        f"{a.update_timeout:g} s)",
        "",
        "| faults | team pos RMSE [m] | ANEES/dof | fused | unknown | rejected det. | lost | dup | dropped msgs "
        "| replayed | no reply | NaN | clean exit |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['faults']} | {r['pos_rmse']:.3f} | {r['anees']:.2f} | {r['fused']} | {r['unknown']} | "
            f"{r['rejected_det']} | {r['lost']} | {r['dup']} | {r['dropped']} | {r['replayed']} | {r['no_reply']} | "
            f"{'yes' if r['nan'] else 'no'} | {'yes' if r['exit_ok'] else 'NO'} |"
        )
    text = "\n".join(lines)
    print(text)
    if a.out:
        with open(a.out, "w") as fh:
            fh.write(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
