"""``diekf``'s broadcast traffic per robot per second against team size, through a live team of node processes.

    python benchmarks/diekf_traffic.py                          # 3, 5 and 10 robots, 20 s of sim:random each
    python benchmarks/diekf_traffic.py --robots 3,5 --duration 10 --out traffic.json

Each row starts a team of ``n`` node processes on 127.0.0.1 (``swarmloc.experiments.team.run_team``, as
``swarmloc team --estimator diekf`` runs it; signed messages) on the simulated team ``sim:random`` (seed 0), without
faults, and sums the nodes' reports. Per robot and per data second: broadcasts published (one per fused or settled
detection, a revision is one more), their heads, and the bytes published (signed frames: envelope + 96 bytes);
"received" is what each robot takes in from its ``n - 1`` teammates (Zenoh sends a publication once per
subscriber). Pairwise traffic (queries and their answers) is the same as ``rdl``'s and is left out. The last
column checks that the run equals the in-process one (``swarmloc.runner.run``; max abs difference of every
recorded mean and covariance).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from swarmloc.estimators import make_team, node_options
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.runner import run


def max_diff(res, ref) -> float:
    d = 0.0
    for r, tr in ref.tracks.items():
        a = res.tracks.get(r)
        if a is None or a.times.size != tr.times.size:
            return float("inf")
        d = max(d, float(np.abs(a.mean - tr.mean).max()), float(np.abs(a.cov - tr.cov).max()))
    return d


def row(n: int, duration: float, timeout: float) -> dict:
    src = load_source("sim:random", robots=n, duration=duration, seed=0)
    t = time.perf_counter()
    tr = run_team(src=src, source="sim:random", robots=n, duration=duration, seed=0, estimator="diekf",
                  team=f"traffic{os.getpid()}", max_wall=timeout)  # fmt: skip
    wall = time.perf_counter() - t
    res = team_result(tr, src, "diekf")
    s = res.stats
    ref = run(make_team("diekf", src.initial, **node_options("diekf", src.config, src.landmarks)), src.events,
              src.record_times(), truth=src.truth)  # fmt: skip
    per = n * duration  # robot-seconds of data
    sent, heads = s.get("net_broadcasts_sent", 0), s.get("net_broadcast_heads_sent", 0)
    b_bytes, h_bytes = s.get("net_broadcast_bytes", 0), s.get("net_broadcast_head_bytes", 0)
    return {
        "robots": n,
        "duration_s": duration,
        "fused": s.get("fused", 0),
        "broadcasts_per_robot_s": sent / per,
        "heads_per_robot_s": heads / per,
        "bytes_per_broadcast": b_bytes / sent if sent else 0.0,
        "published_bytes_per_robot_s": (b_bytes + h_bytes) / per,
        "received_msgs_per_robot_s": (sent + heads) * (n - 1) / per,
        "received_bytes_per_robot_s": (b_bytes + h_bytes) * (n - 1) / per,
        "applied": s.get("net_broadcasts_applied", 0),
        "expected_applied": sent * (n - 1),
        "repairs": s.get("net_repair_requests", 0),
        "wall_s": wall,
        "max_diff_vs_in_process": max_diff(res, ref),
        "exit_ok": all(c == 0 for c in tr.exit_codes.values()),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", default="3,5,10", help="team sizes (default 3,5,10)")
    ap.add_argument("--duration", type=float, default=20.0, help="seconds of sim:random per row (default 20)")
    ap.add_argument("--timeout", type=float, default=600.0, help="time limit per team [s]")
    ap.add_argument("--out", default=None, help="write the rows as JSON here")
    a = ap.parse_args(argv)
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")
    rows = []
    hdr = ("robots | broadcasts/robot/s | heads/robot/s | bytes/broadcast | published B/robot/s | received msgs/robot/s"
           " | received B/robot/s | applied / expected | repairs | wall [s] | max diff vs in-process")  # fmt: skip
    print(hdr)
    for n in [int(x) for x in a.robots.split(",")]:
        r = row(n, a.duration, a.timeout)
        rows.append(r)
        print(f"{n} | {r['broadcasts_per_robot_s']:.2f} | {r['heads_per_robot_s']:.2f} | "
              f"{r['bytes_per_broadcast']:.0f} | {r['published_bytes_per_robot_s']:.0f} | "
              f"{r['received_msgs_per_robot_s']:.1f} | "
              f"{r['received_bytes_per_robot_s']:.0f} | {r['applied']} / {r['expected_applied']} | {r['repairs']} | "
              f"{r['wall_s']:.1f} | {r['max_diff_vs_in_process']:.1e}" + ("" if r["exit_ok"] else " (a node failed)"),
              flush=True)  # fmt: skip
    if a.out:
        with open(a.out, "w") as f:
            json.dump(rows, f, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
