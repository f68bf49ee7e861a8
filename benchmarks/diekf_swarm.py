"""``diekf`` for swarms: traffic per robot and second (messages and bytes, sent and received), accuracy and consistency
of the exact filter and of clusters against team size, on teams whose arena grows with them (constant density).

    python benchmarks/diekf_swarm.py                                    # 5,10,20,50 robots, exact and clusters of 5
    python benchmarks/diekf_swarm.py --robots 10,20,50 --cluster 2,5 --duration 15
    python benchmarks/diekf_swarm.py --net --robots 5,10 --cluster 5      # networked nodes on 127.0.0.1, threads

In process (default): every robot a node of the in-process runner; each message a node hands the runner is counted
once as sent by its sender and, when delivered, once as received by its receiver; its bytes are those of its
network envelope unsigned (:func:`swarmloc.net.schema.encode`, msgpack; a signed frame adds a fixed tag). A
broadcast is one message per receiver here; over the network it is one publication that each subscriber receives.
RMSE [m] and ANEES/dof against the simulator's truth (:func:`swarmloc.evaluation.metrics.evaluate`).

``--net``: every robot a :class:`~swarmloc.net.process.NetNode` on its own Zenoh session, threads of this process
(as tests/test_net.py's ``thread_team``), on 127.0.0.1; traffic from the nodes' network counters (``sent``,
``received``: point-to-point queries, answers and pushes; ``broadcasts_sent``/``broadcasts_received`` and
``broadcast_bytes``: the team broadcasts). Its beliefs equal the in-process run's (tests/test_net_diekf.py), so
accuracy is given by the in-process rows.

Scene: ``sim:random`` in an arena of side ``3 m sqrt(n / 5)`` (benchmarks/diekf_cluster.py's ``--spread``), seed 1.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from typing import Any  # noqa: E402

from diekf_cluster import scene  # noqa: E402

from swarmloc.datasets.source import Source  # noqa: E402
from swarmloc.estimators import make_team, node_options  # noqa: E402
from swarmloc.evaluation.metrics import evaluate, over_seeds  # noqa: E402
from swarmloc.events import Odometry  # noqa: E402
from swarmloc.messages import Message  # noqa: E402
from swarmloc.net.entry import make_node  # noqa: E402
from swarmloc.net.process import NetNode  # noqa: E402
from swarmloc.net.schema import encode  # noqa: E402
from swarmloc.net.transport import free_ports, open_session  # noqa: E402
from swarmloc.runner import run  # noqa: E402


def counted(node: Any, traffic: Counter[str]) -> None:
    """Count what ``node`` is handed and hands on (messages and envelope bytes), per robot."""
    step = node.step

    def counting(item: Any) -> list[Message]:
        if isinstance(item, Message):
            traffic["recv"] += 1
            traffic["recv_bytes"] += len(encode("t", item.sender, 0, item))
        out = step(item)
        for m in out or ():
            traffic["sent"] += 1
            traffic["sent_bytes"] += len(encode("t", m.sender, 0, m))
        return out

    node.step = counting


def options(src: Source, cluster: int) -> dict[str, Any]:
    return {**node_options("diekf", src.config, src.landmarks), "cluster": cluster}


def in_process(src: Source, n: int, cluster: int, duration: float) -> dict[str, Any]:
    nodes = make_team("diekf", src.initial, **options(src, cluster))
    traffic: Counter[str] = Counter()
    for node in nodes:
        counted(node, traffic)
    t = time.process_time()
    res = run(nodes, src.events, src.record_times(), truth=src.truth)
    cpu = time.process_time() - t
    team = evaluate(res)["team"]
    per = {k: v / n / duration for k, v in traffic.items()}
    return {"rmse": team["pos_rmse"], "anees": team["anees"], "cpu": cpu, "fused": res.stats["fused"] / n / duration,
            **per}  # fmt: skip


def monte_carlo(n: int, cluster: int, duration: float, seeds: list[int]) -> dict[str, Any]:
    """The in-process run on ``len(seeds)`` independent scenes: ANEES/dof and RMSE averaged over seeds, and the
    fraction of (robot, record time) whose ANEES/dof over the seeds lies within, below or above the two-sided 95%
    chi-square bounds of ``len(seeds)`` independent NEES (:func:`swarmloc.evaluation.metrics.over_seeds`)."""
    results, rows = [], []
    for seed in seeds:
        src = scene(n, duration, seed, True)
        nodes = make_team("diekf", src.initial, **options(src, cluster))
        results.append(run(nodes, src.events, src.record_times(), truth=src.truth))
        rows.append(evaluate(results[-1])["team"])
    inside = below = above = total = 0
    for r in sorted(results[0].tracks):
        o = over_seeds(results, r)
        a = o["anees"]
        below += int((a < o["anees_lo"]).sum())
        above += int((a > o["anees_hi"]).sum())
        inside += int(((a >= o["anees_lo"]) & (a <= o["anees_hi"])).sum())
        total += a.size
    return {
        "rmse": float(sum(t["pos_rmse"] for t in rows) / len(rows)), "anees": float(sum(t["anees"] for t in rows) /
        len(rows)), "in": inside / total, "below": below / total, "above": above / total,
    }  # fmt: skip


def networked(src: Source, n: int, cluster: int, duration: float, max_wall: float) -> dict[str, Any]:
    """Every robot a NetNode on its own Zenoh session, threads of this process (tests/test_net.py's thread_team)."""
    f = dataclasses.replace(src.config.filter, diekf_cluster=cluster)
    cfg = dataclasses.replace(src.config, filter=f)
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(n)]
    sessions, nets = [], []
    reports: dict[int, Any] = {}
    t0 = time.perf_counter()
    try:
        for i, r in enumerate(src.robots):
            s = open_session([eps[i]], [e for e in eps if e != eps[i]])
            sessions.append(s)
            ev = src.own_events(r)
            node = make_node("diekf", r, src.initial[r], cfg, src.landmarks, team=src.robots)
            node.start(min(e.t0 if isinstance(e, Odometry) else e.stamp for e in ev))
            nets.append(NetNode(node, ev, session=s, team=f"swarm{os.getpid()}", roster=src.robots,
                                record_times=src.record_times()))  # fmt: skip
        threads = [threading.Thread(target=lambda m=m: reports.__setitem__(m.robot, m.run(max_wall=max_wall)))
                   for m in nets]  # fmt: skip
        for t in threads:
            t.start()
        for t in threads:
            t.join(max_wall + 30)
    finally:
        for m in nets:
            m.stop()
        for s in sessions:
            s.close()
    net: Counter[str] = Counter()
    for rep in reports.values():
        net.update(rep.net)
    k = n * duration
    return {
        "wall": time.perf_counter() - t0, "reports": len(reports),
        "sent": net["sent"] / k, "recv": net["received"] / k, "bc_sent": net["broadcasts_sent"] / k,
        "bc_recv": net["broadcasts_received"] / k, "bc_bytes": net["broadcast_bytes"] / k,
    }  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", default="5,10,20,50")
    ap.add_argument("--cluster", default="5", help="cluster sizes besides the exact filter (comma-separated)")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--exact-up-to", type=int, default=50, help="largest team the exact filter runs")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--net", action="store_true", help="networked nodes (threads, 127.0.0.1): traffic only")
    ap.add_argument("--max-wall", type=float, default=600.0)
    ap.add_argument("--seeds", type=int, default=0, help="Monte Carlo: this many seeds from --seed (in process)")
    args = ap.parse_args()
    sizes = [int(x) for x in args.robots.split(",")]
    settings = [0] + [int(c) for c in args.cluster.split(",") if c]
    how = "networked (threads, 127.0.0.1)" if args.net else "in process"
    print(f"sim:random spread, seed {args.seed}, {args.duration:g} s; {how}; per robot and second of data")
    if args.seeds:
        print(f"Monte Carlo over {args.seeds} seeds: mean RMSE, mean ANEES/dof, fraction of (robot, time) whose "
              "ANEES/dof over the seeds is within / below / above the 95% chi-square bounds")  # fmt: skip
        print(f"{'robots':>6} {'filter':>10} {'RMSE [m]':>9} {'ANEES/dof':>9} {'in':>6} {'below':>6} {'above':>6}")
    elif args.net:
        print(f"{'robots':>6} {'filter':>10} {'sent':>7} {'recv':>7} {'bc sent':>7} {'bc recv':>7} {'bc B/s':>8} "
              f"{'wall s':>7}")  # fmt: skip
    else:
        print(f"{'robots':>6} {'filter':>10} {'fused':>6} {'msg sent':>8} {'msg recv':>8} {'B sent':>8} "
              f"{'B recv':>8} {'RMSE [m]':>9} {'ANEES/dof':>9} {'cpu s':>6}")  # fmt: skip
    for n in sizes:
        src = scene(n, args.duration, args.seed, True)
        for c in settings:
            if c == 0 and n > args.exact_up_to:
                continue
            name = "exact" if c == 0 else f"K={c}"
            if args.seeds:
                r = monte_carlo(n, c, args.duration, list(range(args.seed, args.seed + args.seeds)))
                print(f"{n:>6} {name:>10} {r['rmse']:>9.4f} {r['anees']:>9.2f} {r['in']:>6.2f} {r['below']:>6.2f} "
                      f"{r['above']:>6.2f}", flush=True)  # fmt: skip
            elif args.net:
                r = networked(src, n, c, args.duration, args.max_wall)
                print(f"{n:>6} {name:>10} {r['sent']:>7.1f} {r['recv']:>7.1f} {r['bc_sent']:>7.1f} "
                      f"{r['bc_recv']:>7.1f} {r['bc_bytes']:>8.0f} {r['wall']:>7.1f}"
                      + ("" if r["reports"] == n else f"  ({r['reports']} of {n} reports)"), flush=True)  # fmt: skip
            else:
                r = in_process(src, n, c, args.duration)
                print(f"{n:>6} {name:>10} {r['fused']:>6.1f} {r['sent']:>8.1f} {r['recv']:>8.1f} "
                      f"{r['sent_bytes']:>8.0f} {r['recv_bytes']:>8.0f} {r['rmse']:>9.4f} {r['anees']:>9.2f} "
                      f"{r['cpu']:>6.1f}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
