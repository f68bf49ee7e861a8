"""Zenoh runtime costs: belief query round trips between processes, and MRCLAM dataset 6 through a live team.

    python benchmarks/network.py            # 2000 queries with 5 and 20 processes; all of MRCLAM 6, expfusion and rdl
    python benchmarks/network.py --quick    # 300 queries, 5 processes; 60 s of MRCLAM 6, expfusion (under a minute)
    python benchmarks/network.py --procs 5 --queries 5000 --window 64 --estimators rdl --out net.json

1. Round trip. ``N - 1`` responder processes (this script, ``--responder``) each open a Zenoh peer on 127.0.0.1
   (their own port, connected to every other one; scouting off) and declare a queryable on
   ``swarmloc/<team>/robot/<r>/query`` that does a node's wire work: ``decode`` (validate) the ``BeliefQuery``,
   ``encode`` a ``BeliefAnswer`` (identity mean, 0.01 I covariance) and reply. The asker (this process, robot 0)
   sends ``--queries`` gets round-robin over the responders with an encoded query and decodes each answer, first
   one at a time (sequential: latency p50 / p99 / max and queries/s), then with ``--window`` gets in flight
   (throughput). Baseline in the same run, between the asker and ONE responder: a bare Zenoh get/reply with raw
   bytes of the same sizes (no encode / decode). The ratio swarmloc / bare is printed (latency above 1 and
   throughput below 1: the schema's cost). Replies are timed on arrival, with Zenoh's default consolidation (what
   a node's ``get`` uses). Path "signed": authenticated senders with an Ed25519 signature per frame
   (:mod:`swarmloc.net.auth`; how every query went before per-pair sessions): the asker signs its query with robot
   0's key, the responder verifies it against the team's roster before decoding, signs its answer, and the asker
   verifies that. Path "mac": the same round trip as the nodes make it now, between members in session
   (:mod:`swarmloc.net.pairing`: every responder answers the handshake, the asker makes a session with each before
   the timing): query and answer MACed with the pair's session key (BLAKE2b), each checked before decoding.
2. MRCLAM dataset 6 through 5 node processes (``swarmloc.experiments.team.run_team``, as ``swarmloc team`` runs
   it) per estimator: data seconds / wall seconds ("x real time"; the team's wall includes starting the processes, the
   slowest node's own run loop excludes it) and each node's CPU seconds per data second (its run loop, from its
   report). Baseline in the same run: the in-process replay (``swarmloc.runner.run``) of the same events.
   A centralized estimator (``cekf``, ``iekf``, ``fej``) runs hosted by the belief server (:mod:`swarmloc.net.central`):
   the 5 robot processes forward their measurements, the server fuses; "slowest node" is then the server (from its
   start to its estimator's end) and the CPU per node is listed for the server and the forwarders apart.

Every process started is stopped (SIGTERM, SIGKILL after 3 s) also on an error or Ctrl-C; networking is on
127.0.0.1 only. Results are printed, and written as JSON with ``--out``.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import itertools
import json
import math
import os
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from _common import add_mrclam, mrclam_root

MRCLAM = mrclam_root() / "MRCLAM_Dataset6"
TEAM = f"netbench{os.getpid()}"
GRACE = 3.0
GET_TIMEOUT = 5.0
CHILD_ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


def bare_key(team: str, robot: int) -> str:
    return f"swarmloc/{team}/bench/{robot}/bare"


def signed_key(team: str, robot: int) -> str:
    return f"swarmloc/{team}/bench/{robot}/signed"


def mac_key(team: str, robot: int) -> str:
    return f"swarmloc/{team}/bench/{robot}/mac"


def answer_body(sender: int, receiver: int, stamp: float, sub: tuple = ()) -> Any:
    from swarmloc.messages import BeliefAnswer, flat

    return BeliefAnswer(sender=sender, receiver=receiver, stamp=stamp, sub=sub, mean=flat(np.eye(3)),
                        cov=flat(0.01 * np.eye(3)))  # fmt: skip


def query_payload(team: str, seq: int, receiver: int) -> bytes:
    from swarmloc.messages import BeliefQuery
    from swarmloc.net.schema import encode

    return encode(team, 0, seq, BeliefQuery(sender=0, receiver=receiver, stamp=1000.0 + seq * 0.01))


def wire_sizes(team: str) -> tuple[int, int]:
    """Bytes of an encoded query and answer (the bare baseline sends raw bytes of these sizes)."""
    from swarmloc.net.schema import encode

    return len(query_payload(team, 10**6, 1)), len(encode(team, 1, 10**6, answer_body(1, 0, 1000.0)))


# ---------------------------------------------------------------------------------------------------- responder
def responder_main(robot: int, team: str, ports: list[int], parent: int, keys: str) -> None:
    """One responder process: serve the swarmloc, the signed and the bare queryable until SIGTERM (or the parent is
    gone); ``keys``: the folder of the team's keys (:class:`~swarmloc.net.auth.TeamKeys`)."""
    from swarmloc.net.auth import TeamKeys, open_envelope
    from swarmloc.net.pairing import attach
    from swarmloc.net.schema import Rejected, decode, encode
    from swarmloc.net.transport import open_session, robot_key

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    roster = frozenset(range(len(ports)))
    seq = itertools.count()
    bare_answer = bytes(wire_sizes(team)[1])
    auth = TeamKeys(range(len(ports)), keys).auth(robot)
    session = open_session([endpoint(ports[robot])], [endpoint(p) for i, p in enumerate(ports) if i != robot])
    attach(auth, session, team, hello=False)  # answers the asker's handshake (the "mac" path)

    def on_query(q: Any) -> None:
        try:
            try:
                env = decode(q.payload.to_bytes() if q.payload is not None else b"", team, roster, to_robot=robot)
            except Rejected as exc:
                q.reply_err(exc.reason.encode())
                return
            m = env.body
            q.reply(q.key_expr, encode(team, robot, next(seq), answer_body(robot, m.sender, m.stamp, m.sub)))
        finally:
            q.drop()

    def on_signed(q: Any, mac: bool = False) -> None:
        try:
            key = str(q.key_expr)
            try:
                payload = q.payload.to_bytes() if q.payload is not None else b""
                env = open_envelope(auth, key, payload, team, roster, to_robot=robot)
            except Rejected as exc:
                q.reply_err(exc.reason.encode())
                return
            m = env.body
            body = encode(team, robot, next(seq), answer_body(robot, m.sender, m.stamp, m.sub))
            q.reply(q.key_expr, auth.seal(key, body, to=m.sender) if mac else auth.signer.seal(key, body))
        finally:
            q.drop()

    def on_bare(q: Any) -> None:
        try:
            if q.payload is not None:
                q.payload.to_bytes()
            q.reply(q.key_expr, bare_answer)
        finally:
            q.drop()

    try:
        decl = [session.declare_queryable(robot_key(team, robot, "query"), handler=on_query),
                session.declare_queryable(signed_key(team, robot), handler=on_signed),
                session.declare_queryable(mac_key(team, robot), handler=lambda q: on_signed(q, mac=True)),
                session.declare_queryable(bare_key(team, robot), handler=on_bare)]  # fmt: skip
        while not stop.wait(1.0):
            if os.getppid() != parent:  # orphaned: the benchmark is gone
                break
        for d in decl:
            d.undeclare()
    finally:
        session.close()


# ---------------------------------------------------------------------------------------------------- processes
def tail(path: Path, n: int = 2000) -> str:
    try:
        return path.read_text(errors="replace")[-n:]
    except OSError:
        return ""


# ---------------------------------------------------------------------------------------------------- round trips
def round_trips(
    session: Any,
    targets: list[tuple[str, Callable[[int], bytes]]],
    check: Callable[[bytes, str], bool],
    n: int,
    window: int,
) -> dict[str, float]:
    """``n`` gets round-robin over ``targets`` (key, payload for query ``i``), ``window`` in flight (1: each waits
    for its reply). A reply counts once ``check`` accepts its payload (and key). Latencies in ms, throughput in
    queries/s."""
    import zenoh

    lat = np.full(n, np.nan)
    lock = threading.Lock()
    slots = threading.Semaphore(window)
    counts = {"lost": 0, "rejected": 0}

    def one(i: int) -> threading.Event:
        key, make = targets[i % len(targets)]
        done = threading.Event()

        def finish(t: float | None, why: str = "") -> None:
            with lock:
                if done.is_set():
                    return
                if t is None:
                    counts[why] += 1
                else:
                    lat[i] = t
                done.set()
            slots.release()

        def on_reply(reply: Any) -> None:
            ok = reply.ok
            if ok is not None and check(ok.payload.to_bytes(), str(ok.key_expr)):
                finish(time.perf_counter() - t0)
            else:
                finish(None, "rejected")

        slots.acquire()
        t0 = time.perf_counter()
        payload = make(i)  # encoding the query is part of the round trip
        session.get(key, payload=payload, timeout=GET_TIMEOUT,
                    handler=zenoh.handlers.Callback(on_reply, lambda: finish(None, "lost")))  # fmt: skip
        return done

    start = time.perf_counter()
    for i in range(n):
        ev = one(i)
        if window == 1:
            ev.wait(GET_TIMEOUT + 5.0)  # the reply callback sets it: no busy waiting (Zenoh's threads need the GIL)
    for _ in range(window):  # every get answered or ended
        slots.acquire(timeout=GET_TIMEOUT + 5.0)
    elapsed = time.perf_counter() - start
    ok = lat[~np.isnan(lat)] * 1e3
    pct = (lambda q: float(np.percentile(ok, q))) if ok.size else (lambda q: math.nan)
    return {"p50_ms": pct(50), "p99_ms": pct(99), "max_ms": float(ok.max()) if ok.size else math.nan,
            "qps": ok.size / elapsed, "answered": int(ok.size), "lost": counts["lost"], "rejected": counts["rejected"],
            "n": n}  # fmt: skip


def bench_queries(procs: int, queries: int, window: int, ready_timeout: float) -> dict[str, Any]:
    """One asker (this process) and ``procs - 1`` responder processes; the swarmloc, signed, mac and bare paths."""
    from swarmloc.net.auth import TeamKeys, open_envelope
    from swarmloc.net.pairing import attach
    from swarmloc.net.schema import Rejected, decode, encode
    from swarmloc.net.team import stop_all
    from swarmloc.net.transport import free_ports, open_session, robot_key

    team = f"{TEAM}_{procs}"
    ports = free_ports(procs)
    responders = list(range(1, procs))
    roster = frozenset(range(procs))
    q_size, a_size = wire_sizes(team)
    bare_query = bytes(q_size)
    children: list[subprocess.Popen] = []
    session = None
    with tempfile.TemporaryDirectory() as tmp:
        logs = {r: Path(tmp) / f"responder{r}.log" for r in responders}
        keys = TeamKeys(range(procs), Path(tmp) / "keys")
        auth = keys.auth(0)
        try:
            for r in responders:
                with open(logs[r], "wb") as out:
                    children.append(subprocess.Popen(
                        [sys.executable, __file__, "--responder", str(r), "--team", team,
                         "--ports", ",".join(map(str, ports)), "--parent", str(os.getpid()), "--keys",
                         str(keys.folder)],
                        stdout=out, stderr=subprocess.STDOUT, env=CHILD_ENV, start_new_session=True,
                    ))  # fmt: skip
            session = open_session([endpoint(ports[0])], [endpoint(p) for p in ports[1:]])

            def dead() -> None:
                for r, p in zip(responders, children, strict=True):
                    if p.poll() is not None:
                        raise RuntimeError(f"responder {r} exited with {p.returncode}:\n{tail(logs[r])}")

            t0 = time.monotonic()
            while len(list(session.info.peers_zid())) < len(responders):
                dead()
                if time.monotonic() - t0 > ready_timeout:
                    raise RuntimeError(f"only {len(list(session.info.peers_zid()))} of {len(responders)} responders "
                                       f"reachable after {ready_timeout:.0f} s")  # fmt: skip
                time.sleep(0.05)
            connect_s = time.monotonic() - t0
            attach(auth, session, team)  # a session with every responder (those not up yet: below, one by one)
            for r in responders:
                while not auth.sessions.ensure(r):  # a handshake at most every second while one is missing
                    dead()
                    if time.monotonic() - t0 > ready_timeout:
                        raise RuntimeError(f"no session with responder {r} after {ready_timeout:.0f} s")
                    time.sleep(0.05)

            def check(b: bytes, key: str) -> bool:
                try:
                    decode(b, team, roster, to_robot=0)
                except Rejected:
                    return False
                return True

            def check_signed(b: bytes, key: str) -> bool:
                try:
                    open_envelope(auth, key, b, team, roster, to_robot=0)
                except Rejected:
                    return False
                return True

            def signed_query(r: int, mac: bool = False) -> bytes:
                from swarmloc.messages import BeliefQuery

                q = encode(team, 0, 0, BeliefQuery(sender=0, receiver=r, stamp=1000.0 + next(seqs) * 0.01))
                return auth.seal(mac_key(team, r), q, to=r) if mac else auth.signer.seal(signed_key(team, r), q)

            seqs = itertools.count()
            swarm = [
                (robot_key(team, r, "query"), lambda i, r=r: query_payload(team, next(seqs), r)) for r in responders
            ]
            signed = [(signed_key(team, r), lambda i, r=r: signed_query(r)) for r in responders]
            mac = [(mac_key(team, r), lambda i, r=r: signed_query(r, mac=True)) for r in responders]
            bare = [(bare_key(team, responders[0]), lambda i: bare_query)]
            yes = lambda b, k: True  # noqa: E731
            # the queryables are declared once every responder answers every path (bounded)
            targets = [(t, check) for t in swarm] + [(t, check_signed) for t in signed + mac] + [(bare[0], yes)]
            for target, chk in targets:
                while math.isnan(round_trips(session, [target], chk, 1, 1)["p50_ms"]):
                    dead()
                    if time.monotonic() - t0 > ready_timeout:
                        raise RuntimeError(f"no answer on {target[0]} after {ready_timeout:.0f} s")
                    time.sleep(0.05)
            warm = min(200, queries)
            round_trips(session, swarm, check, warm, 1)
            round_trips(session, signed, check_signed, warm, 1)
            round_trips(session, mac, check_signed, warm, 1)
            round_trips(session, bare, yes, warm, 1)
            rows: dict[str, Any] = {"procs": procs, "connect_s": connect_s, "query_bytes": q_size,
                                    "answer_bytes": a_size}  # fmt: skip
            for mode, w in (("sequential", 1), (f"window {window}", window)):
                rows[mode] = {
                    "bare": round_trips(session, bare, yes, queries, w),
                    "swarmloc": round_trips(session, swarm, check, queries, w),
                    "signed": round_trips(session, signed, check_signed, queries, w),
                    "mac": round_trips(session, mac, check_signed, queries, w),
                }
            return rows
        finally:
            if session is not None:
                session.close()
            stop_all(children, grace=GRACE)
            keys.close()


# ---------------------------------------------------------------------------------------------------- MRCLAM
def bench_mrclam(path: Path, duration: float | None, estimators: list[str], timeout: float) -> dict[str, Any]:
    from swarmloc.estimators import make_team, node_options
    from swarmloc.experiments.sources import load_source
    from swarmloc.experiments.team import run_team
    from swarmloc.net.entry import hosted_class
    from swarmloc.net.schema import SERVER
    from swarmloc.runner import run

    spec = f"mrclam:{path}"
    src = load_source(spec, duration=duration)
    data_s = float(src.t_end - src.t_start)
    out: dict[str, Any] = {"data_s": data_s, "robots": list(src.robots), "estimators": {}}
    for est in estimators:
        nodes = make_team(est, src.initial, **node_options(est, src.config, src.landmarks))
        w0, c0 = time.perf_counter(), time.process_time()
        run(nodes, src.events, src.record_times())
        wall_in, cpu_in = time.perf_counter() - w0, time.process_time() - c0
        print(f"  {est}: in-process {wall_in:.2f} s; live team ...", file=sys.stderr)
        tr = run_team(src=src, source=spec, duration=duration, estimator=est, team=f"{TEAM}_{est}", max_wall=timeout)
        cpu = {r: rep.cpu_s / data_s for r, rep in sorted(tr.reports.items()) if r >= 0}
        server = tr.reports.get(SERVER)  # a hosted estimator's: the server's wall and CPU to its estimator's end
        node_wall = max((rep.wall_s for rep in tr.reports.values()), default=math.nan)
        problems = []
        if tr.counts.get("timed_out"):
            problems.append(f"timed out after {timeout:.0f} s")
        hosted = hosted_class(est) is not None
        if len(cpu) != len(src.robots) or (hosted and server is None):
            problems.append(f"{len(tr.reports)} of {len(src.robots) + hosted} reports")
        bad = {n: c for n, c in tr.exit_codes.items() if c != 0}
        if bad:
            problems.append(f"exit codes {bad}")
        out["estimators"][est] = {
            "inprocess_wall_s": wall_in, "inprocess_x_real": data_s / wall_in,
            "inprocess_cpu_per_data_s": cpu_in / data_s,
            "team_wall_s": tr.wall_s, "team_x_real": data_s / tr.wall_s, "slowest_node_wall_s": node_wall,
            "node_x_real": data_s / node_wall, "node_cpu_per_data_s": {str(r): v for r, v in cpu.items()},
            "team_cpu_per_data_s": sum(cpu.values()) + (server.cpu_s / data_s if server else 0.0),
            "server_cpu_per_data_s": server.cpu_s / data_s if server else None,
            "server_wall_s": server.wall_s if server else None, "problems": problems,
        }  # fmt: skip
    return out


# ---------------------------------------------------------------------------------------------------- output
def machine() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith(("model name", "hardware", "cpu model")):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        zenoh_v = importlib.metadata.version("eclipse-zenoh")
    except importlib.metadata.PackageNotFoundError:
        zenoh_v = "?"
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "zenoh": zenoh_v,
            "system": f"{platform.system()} {platform.release()} {platform.machine()}"}  # fmt: skip


def print_queries(res: list[dict[str, Any]], queries: int, window: int) -> None:
    print(f"\nbelief query round trip over Zenoh on 127.0.0.1, {queries} queries per row after a warm-up; "
          f"window {window}: gets in flight\nswarmloc: round-robin over the N-1 responders, encode + decode both ways, "
          "unauthenticated; signed: + an Ed25519 signature and its check both ways; mac: + the pair's session MAC "
          "both ways (what nodes in session send); bare: raw bytes to ONE responder")  # fmt: skip
    print(
        f"{'procs':>5} {'mode':<11} {'path':<9} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'queries/s':>10} {'lost':>5}"
    )
    for r in res:
        for mode in ("sequential", f"window {window}"):
            for path in ("bare", "swarmloc", "signed", "mac"):
                m = r[mode][path]
                print(f"{r['procs']:>5} {mode:<11} {path:<9} {m['p50_ms']:8.3f} {m['p99_ms']:8.3f} {m['max_ms']:8.2f} "
                      f"{m['qps']:10.0f} {m['lost'] + m['rejected']:5d}")  # fmt: skip
            for path in ("swarmloc", "signed", "mac"):
                s, b = r[mode][path], r[mode]["bare"]
                print(f"{'':>5} {'':<11} {'ratio':<9} {s['p50_ms'] / b['p50_ms']:7.2f}x "
                      f"{s['p99_ms'] / b['p99_ms']:7.2f}x {s['max_ms'] / b['max_ms']:7.2f}x {s['qps'] / b['qps']:9.2f}x"
                      f"   ({path} / bare)")  # fmt: skip
    sizes = res[0]
    print(
        f"query {sizes['query_bytes']} B, answer {sizes['answer_bytes']} B; all responders reachable after "
        + ", ".join(f"{r['connect_s']:.1f} s ({r['procs']} procs)" for r in res)
    )
    for r in res:  # the 1, 5 and 15 min load averages before and after each run (another program's load shows here)
        before, after = r["load"]
        print(f"load average with {r['procs']} procs: before {before[0]:.2f} {before[1]:.2f} {before[2]:.2f}, "
              f"after {after[0]:.2f} {after[1]:.2f} {after[2]:.2f} ({os.cpu_count()} cores)")  # fmt: skip


def print_mrclam(res: dict[str, Any]) -> None:
    print(f"\nMRCLAM dataset 6, {res['data_s']:.0f} s of data, {len(res['robots'])} node processes (run_team) "
          "against the in-process replay in the same run; x real = data s / wall s")  # fmt: skip
    print(f"{'estimator':<10} {'in-process':>11} {'team':>10} {'team/in-proc':>12} {'slowest node':>13} "
          f"{'CPU s / data s: node mean':>26} {'max':>6} {'team':>6} {'in-proc':>8}")  # fmt: skip
    for est, e in res["estimators"].items():
        cpu = list(e["node_cpu_per_data_s"].values())
        mean, mx = (float(np.mean(cpu)), max(cpu)) if cpu else (math.nan, math.nan)
        print(f"{est:<10} {e['inprocess_x_real']:6.1f}x real {e['team_x_real']:5.1f}x real "
              f"{e['team_x_real'] / e['inprocess_x_real']:11.3f}x {e['node_x_real']:7.1f}x real {mean:26.4f} {mx:6.4f} "
              f"{e['team_cpu_per_data_s']:6.4f} {e['inprocess_cpu_per_data_s']:8.4f}")  # fmt: skip
        if e.get("server_cpu_per_data_s") is not None:
            print(f"{'':<10} hosted by the server: the node columns are the forwarding robots'; the server took "
                  f"{e['server_cpu_per_data_s']:.4f} CPU s / data s ({res['data_s'] / e['server_wall_s']:.1f}x real "
                  "from its start to its estimator's end)")  # fmt: skip
        if e["problems"]:
            print(f"  WARNING {est}: " + "; ".join(e["problems"]))
    print("team: the launcher's wall, starting and stopping the processes included; slowest node: its run loop only")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--procs", default="5,20", help="processes per round-trip run, asker included (default 5,20)")
    ap.add_argument("--queries", type=int, default=2000, help="queries per row (default 2000)")
    ap.add_argument("--window", type=int, default=32, help="gets in flight for the throughput rows (default 32)")
    add_mrclam(ap, default=MRCLAM, help=f"MRCLAM dataset 6 folder (default {MRCLAM})")
    ap.add_argument("--duration", type=float, default=None, help="seconds of the dataset (default: all)")
    ap.add_argument("--estimators", default="expfusion,rdl", help="distributed estimators (default expfusion,rdl)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="time limit per live team run [s]")
    ap.add_argument("--ready-timeout", type=float, default=60.0, help="limit for the responders to be reachable [s]")
    ap.add_argument("--skip", choices=["queries", "mrclam"], action="append", default=[], help="leave a part out")
    ap.add_argument("--quick", action="store_true", help="300 queries, 5 procs, 60 s of MRCLAM, one estimator")
    ap.add_argument("--out", type=Path, help="also write the results as JSON here")
    ap.add_argument("--responder", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--team", help=argparse.SUPPRESS)
    ap.add_argument("--ports", help=argparse.SUPPRESS)
    ap.add_argument("--parent", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--keys", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.responder is not None:
        responder_main(args.responder, args.team, [int(p) for p in args.ports.split(",")], args.parent, args.keys)
        return
    # SIGTERM unwinds like Ctrl-C, so that every process started is stopped (the finally blocks run)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGTERM))
    estimators = [e for e in args.estimators.split(",") if e]
    procs = [int(p) for p in args.procs.split(",") if p]
    if args.quick:
        args.queries, procs, args.duration, estimators = 300, [5], 60.0, estimators[:1]
    if any(p < 2 for p in procs) or args.queries < 1 or args.window < 1:
        sys.exit("--procs must be at least 2, --queries and --window at least 1")
    if "mrclam" not in args.skip and not args.mrclam.is_dir():
        sys.exit(f"MRCLAM dataset 6 not found at {args.mrclam} (give --mrclam or set SWARMLOC_MRCLAM)")

    mach = machine()
    results: dict[str, Any] = {"machine": mach, "queries": args.queries, "window": args.window, "round_trip": [],
                               "mrclam": None}  # fmt: skip
    if "queries" not in args.skip:
        for n in procs:
            print(f"round trips with {n} processes ...", file=sys.stderr)
            load0 = os.getloadavg()
            results["round_trip"].append(bench_queries(n, args.queries, args.window, args.ready_timeout))
            results["round_trip"][-1]["load"] = [load0, os.getloadavg()]  # the machine may be shared: say so
    if "mrclam" not in args.skip:
        print(f"MRCLAM through {','.join(estimators)} ...", file=sys.stderr)
        results["mrclam"] = bench_mrclam(args.mrclam, args.duration, estimators, args.timeout)

    print(f"machine: {mach['cpu']}, {mach['cores']} cores, {mach['system']}, python {mach['python']}, "
          f"zenoh {mach['zenoh']} (eclipse-zenoh)")  # fmt: skip
    if results["round_trip"]:
        print_queries(results["round_trip"], args.queries, args.window)
    if results["mrclam"] is not None:
        print_mrclam(results["mrclam"])
    if args.out is not None:
        args.out.write_text(json.dumps(results, indent=2, default=float) + "\n")
        print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
