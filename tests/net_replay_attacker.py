"""An attacker that records robot 1's frames in one run of a team and replays them in the next run of the same
team, run as its own process with its own Zenoh session (tests/test_net_pairing.py).

    python tests/net_replay_attacker.py --listen tcp/127.0.0.1:PORT --team T --robots 0,1,2 --out FILE

The two runs are started by hand without a run id, with the same roster: every key expression is the same in both
(``swarmloc/<team>/robot/<id>/...``), so a frame recorded in the first run is, on the wire, a frame of the second.
It listens on 127.0.0.1 (the nodes connect to it), prints ``ready``, and records every frame robot 1 puts (its
pushes to the inboxes, its progress, beliefs and report) and every query robot 1 sends to robots 0 and 2 (through
a queryable of its own on their query keys, which never answers). Once robot 1's report of the first run has come,
it waits for the second run: every robot announcing progress from a process it has not seen (another incarnation,
bytes 32..40 of a signed frame); then it replays everything recorded, once, as it was (puts as puts, queries as
gets), and writes as JSON what it recorded, what each node received of it (a node subscribes to its inbox, to its
query key and to its teammates' progress), and the answers its gets received.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from collections import Counter
from pathlib import Path

import zenoh
from _attacker import close_when_alone

from swarmloc.net.transport import open_session


def main() -> None:
    p = argparse.ArgumentParser()
    for name in ("--listen", "--team", "--robots", "--out"):
        p.add_argument(name, required=True)
    p.add_argument("--wait", type=float, default=120.0)
    a = p.parse_args()
    robots = [int(x) for x in a.robots.split(",")]
    lock = threading.Lock()
    puts: list[tuple[str, bytes]] = []
    gets: list[tuple[str, bytes]] = []
    runs: list[dict[int, bytes]] = [{}]  # per run: robot -> the incarnation of its process
    ended = threading.Event()

    def on_put(x) -> None:
        key, raw = str(x.key_expr), x.payload.to_bytes()
        what = key.split("/")
        sender = int.from_bytes(raw[4:8], "big", signed=True) if len(raw) >= 8 else None
        with lock:
            if what[-1] == "progress" and raw[:4] == b"SLS2":
                r = int(what[-2])
                inc = raw[32:40]
                if ended.is_set():  # the second run: robots whose process is new
                    if all(inc != run.get(r) for run in runs[:-1]):
                        runs[-1][r] = inc
                else:
                    runs[0][r] = inc
            if not ended.is_set() and sender == 1 and raw[:3] in (b"SLS", b"SLM"):
                puts.append((key, raw))
                if what[-1] == "report":
                    ended.set()
                    runs.append({})

    def on_query(q) -> None:
        try:
            raw = q.payload.to_bytes() if q.payload is not None else b""
            if not ended.is_set() and raw[4:8] == (1).to_bytes(4, "big"):
                with lock:
                    gets.append((str(q.key_expr), raw))
        finally:
            q.drop()

    s = open_session([a.listen], [])
    decl = [s.declare_subscriber(f"swarmloc/{a.team}/robot/*/*", on_put, allowed_origin=zenoh.Locality.REMOTE)]
    decl += [s.declare_queryable(f"swarmloc/{a.team}/robot/{r}/query", on_query) for r in robots if r != 1]
    print("ready", flush=True)
    end = time.monotonic() + a.wait
    while not ended.wait(0.05) and time.monotonic() < end:
        pass
    for d in decl[1:]:  # the second run's queries are the team's own
        d.undeclare()
    while time.monotonic() < end:
        with lock:
            if len(runs) > 1 and len(runs[-1]) == len(robots):
                break
        time.sleep(0.02)
    received: Counter[str] = Counter()
    answers: Counter[str] = Counter()
    with lock:
        recorded_puts, recorded_gets = list(puts), list(gets)
        second_run = len(runs) > 1 and len(runs[-1]) == len(robots)
    for key, raw in recorded_puts if second_run else []:
        s.put(key, raw, congestion_control=zenoh.CongestionControl.BLOCK)  # counted: never dropped
        what = key.split("/")
        if what[-1] == "inbox":
            received[f"robot {what[-2]}"] += 1
        elif what[-1] == "progress":
            for r in robots:  # every node subscribes to its teammates' progress (this process is a remote one)
                received[f"robot {r}"] += 1
    for key, raw in recorded_gets if second_run else []:
        received[f"robot {key.split('/')[-2]}"] += 1
        for reply in s.get(key, payload=raw, timeout=3.0, target=zenoh.QueryTarget.ALL):
            answers["ok" if reply.ok is not None else "error"] += 1
    time.sleep(0.5)
    decl[0].undeclare()
    kinds = Counter(k.split("/")[-1] for k, _ in recorded_puts) + Counter("query" for _ in recorded_gets)
    out = {"second_run": second_run, "recorded": dict(kinds), "received": dict(received), "answers": dict(answers),
           "incarnations": [{str(r): i.hex() for r, i in run.items()} for run in runs]}  # fmt: skip
    Path(a.out).write_text(json.dumps(out, indent=1))
    close_when_alone(s)


if __name__ == "__main__":
    main()
