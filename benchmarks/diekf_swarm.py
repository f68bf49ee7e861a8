"""``diekf`` for swarms: traffic per robot and second (messages and bytes, sent and received), accuracy and consistency
of the exact filter and of clusters against team size, on teams whose arena grows with them (constant density).

    python benchmarks/diekf_swarm.py                                    # 5,10,20,50 robots, exact and clusters of 5
    python benchmarks/diekf_swarm.py --arena grouped --cluster 2,5,10 --seeds 4       # clusters by proximity
    python benchmarks/diekf_swarm.py --net --robots 5,10 --cluster 5      # networked nodes on 127.0.0.1, threads

In process (default): every robot a node of the in-process runner; each message a node hands the runner is counted
once as sent by its sender and, when delivered, once as received by its receiver; its bytes are those of its
network envelope unsigned (:func:`swarmloc.net.schema.encode`, msgpack; a signed frame adds a fixed tag). A
broadcast is one message per receiver here; over the network it is one publication that each subscriber receives.
RMSE [m] and ANEES/dof against the simulator's truth (:func:`swarmloc.evaluation.metrics.evaluate`), and the RMSE
against the exact filter's on the same scenes (``vs exact``). ``--seeds k``: every row the mean over seeds
``seed..seed+k-1`` (independent scenes), and ``in 95%``: the fraction of (robot, record time) whose ANEES/dof over
the seeds lies within the two-sided 95% chi-square bounds of ``k`` independent NEES
(:func:`swarmloc.evaluation.metrics.over_seeds`; the rest is below them unless ``above`` says otherwise). The exact
filter beyond ``--exact-up-to`` robots (its nodes need ``O(n^3)`` memory in one process) runs as the engine's compiled
replay (``run_engine(src, "diekf", backend="numba")``, equal to the nodes: tests/test_engine_clusters.py): accuracy
only, no traffic.

``--net``: every robot a :class:`~swarmloc.net.process.NetNode` on its own Zenoh session, threads of this process
(as tests/test_net.py's ``thread_team``), on 127.0.0.1; traffic from the nodes' network counters (``sent``,
``received``: point-to-point queries, answers and pushes; ``broadcasts_sent``/``broadcasts_received`` and
``broadcast_bytes``: the team broadcasts), the detections the nodes fused (``fused``), and the progress
announcements of the replay's lock step a robot receives from its teammates (``progress``: its counter
``progress_received``; in clusters a node subscribes to its cluster's and to the robots it detects or is detected
by, :func:`swarmloc.net.lockstep.watched`; ``prog/wall``: the same per second of wall time). ``received`` counts the
broadcasts' heads too, and a head unchanged is announced again every second of wall time (a heartbeat), so a replay
slower than real time receives more of them per second of data: ``recv-hb`` is ``received`` without the heartbeats,
per second of data, and ``hb/wall`` the heartbeats per second of wall time (``--counters``: every network counter,
per robot and second of data). Its beliefs equal the
in-process run's (tests/test_net_diekf.py): ``max |d|`` is the largest difference of a recorded mean or covariance
from the in-process run's, whose RMSE and ANEES/dof the row gives.

Scene (``--arena``, benchmarks/swarm_scene.py): ``bounded`` (default), constant density in what a robot sees, about 2
teammates within its 1.5 m sensor (10 detections/s at 5 Hz) in every team; ``spread``, the arena that grows as
``3 m sqrt(n / 5)`` with the robots free to leave it (the previous scene, whose density is not constant);
``grouped``, the bounded arena with the ids along a Hilbert curve through the start positions, so that a cluster of
``K`` consecutive ids is ``K`` robots that start near each other (clusters formed by proximity at deployment).
``--period p``: the clusters re-form every ``p`` s (``[filter] diekf_reform``,
:mod:`swarmloc.estimators.cluster_reform`; benchmarks/diekf_reform.py is its centralized prototype); networked, a
node hears the broadcasts of its clusters of this period and the next (:mod:`swarmloc.net.hearing`), and its lock
step waits at a boundary for its new mates' pieces.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from swarm_scene import ARENAS, scene  # noqa: E402

from swarmloc.datasets.source import Source  # noqa: E402
from swarmloc.engine import run_engine  # noqa: E402
from swarmloc.estimators import make_team, node_options  # noqa: E402
from swarmloc.evaluation.metrics import evaluate, over_seeds  # noqa: E402
from swarmloc.events import Odometry  # noqa: E402
from swarmloc.messages import Message  # noqa: E402
from swarmloc.net.entry import make_node  # noqa: E402
from swarmloc.net.lockstep import detected_pairs  # noqa: E402
from swarmloc.net.process import NetNode  # noqa: E402
from swarmloc.net.schema import encode  # noqa: E402
from swarmloc.net.team import TeamRun  # noqa: E402
from swarmloc.net.transport import free_ports, open_session  # noqa: E402
from swarmloc.runner import RunResult, run  # noqa: E402


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


def options(src: Source, cluster: int, period: float = 0.0) -> dict[str, Any]:
    """``diekf``'s options: clusters of ``cluster`` re-formed every ``period`` s (0: fixed)."""
    return {
        **node_options("diekf", src.config, src.landmarks),
        "cluster": cluster,
        **({"reform": period} if period else {}),
    }


def in_process(src: Source, n: int, cluster: int, duration: float, engine: bool = False,
               period: float = 0.0) -> tuple[dict, RunResult]:  # fmt: skip
    """One run of the nodes in process (``engine``: the exact filter as the engine's replay, no traffic): traffic and
    fused detections per robot and second, RMSE, ANEES/dof and CPU [s]; and the run."""
    traffic: Counter[str] = Counter()
    t = time.process_time()
    if engine:
        res = run_engine(src, "diekf", backend="numba", **options(src, cluster))
    else:
        nodes = make_team("diekf", src.initial, **options(src, cluster, period))
        for node in nodes:
            counted(node, traffic)
        res = run(nodes, src.events, src.record_times(), truth=src.truth)
    cpu = time.process_time() - t
    team = evaluate(res)["team"]
    per = {k: traffic[k] / n / duration if traffic else math.nan for k in ("sent", "recv", "sent_bytes", "recv_bytes")}
    return {"rmse": team["pos_rmse"], "anees": team["anees"], "cpu": cpu, "fused": res.stats["fused"] / n / duration,
            **per}, res  # fmt: skip


def over(seeds: list[int], n: int, cluster: int, duration: float, arena: str, engine: bool = False,
         period: float = 0.0) -> dict:  # fmt: skip
    """:func:`in_process` on the scenes of ``seeds``: each figure's mean over them, ``rmses`` per seed, and the
    fractions of (robot, record time) whose ANEES/dof over the seeds is within or above their 95% bounds."""
    rows, results = [], []
    for seed in seeds:
        row, res = in_process(scene(n, duration, seed, arena), n, cluster, duration, engine, period)
        rows.append(row)
        results.append(res)
    mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
    inside = above = total = 0
    if len(seeds) > 1:
        for r in sorted(results[0].tracks):
            o = over_seeds(results, r)
            above += int((o["anees"] > o["anees_hi"]).sum())
            inside += int(((o["anees"] >= o["anees_lo"]) & (o["anees"] <= o["anees_hi"])).sum())
            total += o["anees"].size
    return {**mean, "rmses": [r["rmse"] for r in rows], "in": inside / max(total, 1), "above": above / max(total, 1)}


def networked(src: Source, n: int, cluster: int, duration: float, max_wall: float,
              period: float = 0.0) -> dict[str, Any]:  # fmt: skip
    """Every robot a NetNode on its own Zenoh session, threads of this process (tests/test_net.py's thread_team);
    its figures, and the in-process run's RMSE, ANEES/dof and the networked beliefs' largest difference from it."""
    f = dataclasses.replace(src.config.filter, diekf_cluster=cluster, diekf_reform=period if cluster else 0.0)
    cfg = dataclasses.replace(src.config, filter=f)
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(n)]
    sessions, nets = [], []
    reports: dict[int, Any] = {}
    beliefs = TeamRun()  # the best belief per robot and record time
    detected = detected_pairs(src.events)
    t0 = time.perf_counter()
    try:
        for i, r in enumerate(src.robots):
            s = open_session([eps[i]], [e for e in eps if e != eps[i]])
            sessions.append(s)
            ev = src.own_events(r)
            node = make_node("diekf", r, src.initial[r], cfg, src.landmarks, team=src.robots)
            node.start(min(e.t0 if isinstance(e, Odometry) else e.stamp for e in ev))
            node.plan(src.events)
            nets.append(NetNode(node, ev, session=s, team=f"swarm{os.getpid()}", roster=src.robots,
                                record_times=src.record_times(), detected=detected,
                                on_belief=beliefs.keep))  # fmt: skip
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
    wall = time.perf_counter() - t0
    net: Counter[str] = Counter()
    fused = pieces = 0
    for rep in reports.values():
        net.update(rep.net)
        fused += rep.stats.get("fused", 0)
        pieces += rep.stats.get("pieces_received", 0)
    k = n * duration
    ref, res = in_process(src, n, cluster, duration, period=period if cluster else 0.0)
    return {
        "wall": wall, "reports": len(reports), "fused": fused / k, "progress": net["progress_received"] / k,
        "prog_wall": net["progress_received"] / n / wall, "hb_wall": net["broadcast_heads_repeated"] / n / wall,
        "recv_data": (net["received"] - net["broadcast_heads_repeated"]) / k,
        "sent": net["sent"] / k, "recv": net["received"] / k, "bc_sent": net["broadcasts_sent"] / k,
        "bc_recv": net["broadcasts_received"] / k, "bc_bytes": net["broadcast_bytes"] / k,
        "rmse": ref["rmse"], "anees": ref["anees"], "diff": largest_difference(beliefs, res), "pieces": pieces,
        "ref_pieces": res.stats.get("pieces_received", 0),
        "counters": {c: v / k for c, v in sorted(net.items()) if isinstance(v, int | float)},
    }  # fmt: skip


def largest_difference(beliefs: TeamRun, res: RunResult) -> float:
    """The largest difference of a networked belief's mean or covariance from the in-process run's (inf: not the
    same record times)."""
    d = 0.0
    got = beliefs.tracks()
    for r, tr in res.tracks.items():
        a = got.get(r)
        if a is None or not np.array_equal(a.times, tr.times):
            return math.inf
        d = max(d, float(np.abs(a.mean - tr.mean).max()), float(np.abs(a.cov - tr.cov).max()))
    return d


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", default="5,10,20,50")
    ap.add_argument("--cluster", default="5", help="cluster sizes besides the exact filter (comma-separated)")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--exact-up-to", type=int, default=20, help="largest team whose exact filter runs as nodes")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--seeds", type=int, default=1, help="this many seeds from --seed, every row their mean")
    ap.add_argument("--arena", choices=ARENAS, default="bounded", help="benchmarks/swarm_scene.py")
    ap.add_argument("--period", type=float, default=0.0, help="in process: the clusters re-form every this many s")
    ap.add_argument("--net", action="store_true", help="networked nodes (threads, 127.0.0.1): traffic only")
    ap.add_argument("--max-wall", type=float, default=600.0)
    ap.add_argument("--counters", action="store_true", help="--net: also every network counter, per robot and s")
    args = ap.parse_args()
    sizes = [int(x) for x in args.robots.split(",")]
    settings = [0] + [int(c) for c in args.cluster.split(",") if c]
    seeds = list(range(args.seed, args.seed + args.seeds))
    how = "networked (threads, 127.0.0.1)" if args.net else "in process"
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}; sim:random "
          f"({args.arena} arena), seeds {seeds[0]}-{seeds[-1]}, {args.duration:g} s; {how}; per robot and second "
          "of data, the mean over the seeds")  # fmt: skip
    if args.net:
        print(f"{'robots':>6} {'filter':>10} {'fused':>6} {'sent':>7} {'recv':>7} {'bc sent':>7} {'bc recv':>7} "
              f"{'bc B/s':>8} {'progress':>8} {'prog/wall':>9} {'recv-hb':>7} {'hb/wall':>7} {'wall s':>7} "
              f"{'RMSE [m]':>9} {'ANEES/dof':>9} "
              f"{'max |d|':>8}")  # fmt: skip
    else:
        print(f"{'robots':>6} {'filter':>14} {'fused':>6} {'msg sent':>8} {'msg recv':>8} {'B sent':>8} "
              f"{'B recv':>8} {'RMSE [m]':>9} {'vs exact':>8} {'ANEES/dof':>9} {'in 95%':>6} {'cpu s':>6}")  # fmt: skip
    for n in sizes:
        exact = math.nan
        for c in settings:
            name = "exact" if c == 0 else f"K={c}" + (f"/{args.period:g}s" if args.period else "")
            if args.net:
                if c == 0 and n > args.exact_up_to:
                    continue
                rs = [networked(scene(n, args.duration, s, args.arena), n, c, args.duration, args.max_wall,
                                args.period) for s in seeds]  # fmt: skip
                r = {k: float(np.mean([x[k] for x in rs])) for k in rs[0] if k != "counters"}
                r["diff"] = max(x["diff"] for x in rs)
                print(f"{n:>6} {name:>10} {r['fused']:>6.1f} {r['sent']:>7.1f} {r['recv']:>7.1f} {r['bc_sent']:>7.1f} "
                      f"{r['bc_recv']:>7.1f} {r['bc_bytes']:>8.0f} {r['progress']:>8.1f} {r['prog_wall']:>9.1f} "
                      f"{r['recv_data']:>7.1f} {r['hb_wall']:>7.1f} "
                      f"{r['wall']:>7.1f} {r['rmse']:>9.4f} {r['anees']:>9.2f} {r['diff']:>8.1e}"
                      + ("" if r["reports"] == n else f"  ({r['reports']} of {n} reports)"), flush=True)  # fmt: skip
                if args.counters:
                    keys = sorted(set().union(*(x["counters"] for x in rs)))
                    means = {c: float(np.mean([x["counters"].get(c, 0.0) for x in rs])) for c in keys}
                    print("        " + ", ".join(f"{c} {v:.1f}" for c, v in means.items() if v), flush=True)
                continue
            engine = c == 0 and n > args.exact_up_to
            r = over(seeds, n, c, args.duration, args.arena, engine, args.period if c else 0.0)
            if c == 0:
                exact = r["rmse"]
                name += " (engine)" if engine else ""
            vs = f"{100 * (r['rmse'] / exact - 1):+.0f}%" if c else "-"
            inside = f"{r['in']:.2f}" if len(seeds) > 1 else "-"
            cols = (("sent", 1), ("recv", 1), ("sent_bytes", 0), ("recv_bytes", 0))
            traffic = " ".join(f"{r[k]:>8.{p}f}" if r[k] == r[k] else f"{'-':>8}" for k, p in cols)
            print(f"{n:>6} {name:>14} {r['fused']:>6.1f} {traffic} {r['rmse']:>9.4f} {vs:>8} {r['anees']:>9.2f} "
                  f"{inside:>6} {r['cpu']:>6.1f}" + (f"  (above: {r['above']:.2f})" if r["above"] else ""),
                  flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
