"""A second process holding robot 2's key while robot 2 runs, with a query storm, run as its own process with its
own Zenoh session (tests/test_net_pairing.py).

    python tests/net_twin_attacker.py --listen tcp/127.0.0.1:PORT --team T --keys DIR --robots 0,1,2 --out FILE

It listens on 127.0.0.1 (the team connects to it), prints ``ready``, sniffs the run's key scope from the robots'
progress and, once every robot has announced progress, joins the team as robot 2 would (it is robot 2's key
after all): it answers the per-pair handshake and says hello to every member (:func:`swarmloc.net.pairing.attach`),
declares robot 2's liveliness token and a queryable on robot 2's query key that answers every query with a state
or belief 100 m off. Then it storms robot 0 with ``--queries`` queries as robot 2 (state and belief queries at the
stamps robot 0 has read), pushes robot 0 pairwise updates 100 m off, announces robot 2's progress "done" and
publishes robot 2's beliefs 100 m off, all sealed with robot 2's key as robot 2's process would (signed: nobody
gave it a session). It writes as JSON its process (incarnation), its handshake counters, what each member
received of it (per receiver: robots, ``collector``), and the answers its gets received.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import zenoh
from _attacker import close_when_alone, envelope_of, team_scope_of

from swarmloc.messages import BeliefAnswer, BeliefQuery, RdlState, RdlStateQuery, RdlUpdate, flat
from swarmloc.net.auth import Auth
from swarmloc.net.pairing import attach
from swarmloc.net.schema import Belief, Progress, decode, encode
from swarmloc.net.transport import alive_key, open_session, robot_key

SHIFT = flat(np.array([[1.0, 0.0, 100.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
COV = flat(np.diag([0.01, 0.01, 0.001]))
I3 = flat(np.eye(3))


def arguments() -> argparse.Namespace:
    p = argparse.ArgumentParser()
    for name in ("--listen", "--team", "--keys", "--robots", "--out", "--record-times"):
        p.add_argument(name, required=True)
    p.add_argument("--queries", type=int, default=2000)
    p.add_argument("--wait", type=float, default=60.0)
    return p.parse_args()


def main() -> None:
    a = arguments()
    robots = [int(x) for x in a.robots.split(",")]
    record_times = [float(t) for t in a.record_times.split(",")]
    keys = Path(a.keys)
    auth = Auth.load(keys / "robot2.key", keys / "roster.json", 2)
    lock = threading.Lock()
    received: Counter[str] = Counter()
    answers: Counter[str] = Counter()

    def on_query(q) -> None:
        """A teammate's query to robot 2, answered 100 m off (in robot 2's name: its key)."""
        try:
            raw = q.payload.to_bytes()
            m = decode(envelope_of(raw), a.team, set(robots)).body
            kind = RdlState if isinstance(m, RdlStateQuery) else BeliefAnswer
            fields = dict(x=(100.0, 0.0, 0.0), P=COV, sigma=I3) if kind is RdlState else dict(mean=SHIFT, cov=COV)
            body = kind(sender=2, receiver=m.sender, stamp=m.stamp, sub=m.sub, **fields)
            q.reply(q.key_expr, auth.seal(str(q.key_expr), encode(a.team, 2, 0, body), to=m.sender))
            with lock:
                received[f"robot {m.sender}"] += 1
        except Exception as exc:  # noqa: BLE001
            print(f"twin: query not answered: {exc}", file=sys.stderr)
        finally:
            q.drop()

    s = open_session([a.listen], [])
    print("ready", flush=True)
    sc = team_scope_of(s, a.team, robots, time.monotonic() + a.wait)
    attach(auth, s, sc)  # robot 2's handshake, from a second process
    token = s.liveliness().declare_token(alive_key(sc, 2))
    decl = [s.declare_queryable(robot_key(sc, 2, "query"), on_query, complete=True)]

    def send(key: str, body, receivers: list[str]) -> None:
        s.put(key, auth.seal(key, encode(a.team, 2, 0, body)), congestion_control=zenoh.CongestionControl.BLOCK)
        for r in receivers:
            received[r] += 1

    t = record_times[len(record_times) // 4]
    q0 = robot_key(sc, 0, "query")
    started = time.monotonic()
    for i in range(a.queries):  # the storm
        m = (RdlStateQuery if i % 2 else BeliefQuery)(sender=2, receiver=0, stamp=t + 0.01 * (i % 50))
        for reply in s.get(q0, payload=auth.seal(q0, encode(a.team, 2, 0, m)), timeout=3.0,
                           target=zenoh.QueryTarget.ALL):  # fmt: skip
            answers["ok" if reply.ok is not None else "error"] += 1
        with lock:
            received["robot 0"] += 1
        if i % 200 == 0:
            everyone = [f"robot {r}" for r in robots] + ["collector"]
            with lock:
                send(robot_key(sc, 2, "progress"), Progress(robot=2, t=math.inf, done=True), everyone)
                send(robot_key(sc, 0, "inbox"), RdlUpdate(sender=2, receiver=0, stamp=t, x=(100.0, 0.0, 0.0), P=COV),
                     ["robot 0"])  # fmt: skip
                b = Belief(robot=2, stamp=record_times[i // 200 % len(record_times)], rev=9, final=True, mean=SHIFT,
                           cov=COV)  # fmt: skip
                send(robot_key(sc, 2, "belief"), b, ["collector"])
    seconds = time.monotonic() - started
    time.sleep(1.0)  # the teammates' queries to robot 2 meanwhile
    token.undeclare()
    for d in decl:
        d.undeclare()
    auth.sessions.close()
    out = {"incarnation": auth.signer.incarnation.hex(), "counts": auth.session_counts(),
           "received": dict(received), "answers": dict(answers), "storm_s": seconds}  # fmt: skip
    Path(a.out).write_text(json.dumps(out, indent=1))
    close_when_alone(s)


if __name__ == "__main__":
    main()
