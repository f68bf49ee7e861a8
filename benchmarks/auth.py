"""The per-message cost of authenticated senders: Ed25519 sign + verify vs the schema's encode + decode.

    python benchmarks/auth.py               # 20,000 messages per kind, best of 5 repeats
    python benchmarks/auth.py --n 2000 --repeats 3 --out auth.json

For each kind of message a node sends (a belief answer, an rdl state, an rdl update, a progress announcement, a
published belief), in one process and one run: the baseline is what every message cost before, the schema's
``encode`` on the sender and ``decode`` (MessagePack plus validation: SE(2) mean, SPD covariance...) on the receiver;
the signed path adds :meth:`swarmloc.net.auth.Signer.seal` on the sender and :meth:`swarmloc.net.auth.Verifier.open`
(key id, signature, stamp, replay window) on the receiver. Printed per message in microseconds, the ratio signed /
unsigned, and the bytes on the wire (the signed frame adds 104: a 40-byte header and a 64-byte signature). Each
timing is the best of ``--repeats`` loops over ``--n`` messages (every frame opened once: the replay window refuses a
second opening). Beside it, the MACed frame that members in a per-pair session send each other
(:mod:`swarmloc.net.pairing`, :mod:`swarmloc.net.macframe`; it adds 48 bytes: a 32-byte header and a 16-byte keyed
BLAKE2b tag): sealing and opening it (session, MAC, stamp, replay window), in isolation. The network itself (a
Zenoh put or get on 127.0.0.1: ~50-100 us, ``benchmarks/network.py``) is not in it.

In context (``--team``, on by default): a simulated team of 3 (``--estimator``, ``--duration`` s) run as three
:class:`~swarmloc.net.process.NetNode` threads of this process, each on its own Zenoh session on 127.0.0.1, as fast as
lockstep allows, after a warm-up run, alternately without and with authentication (``--rounds`` each; the best of
each kept): wall and CPU seconds of the
process (Zenoh's threads included), the messages each robot verified, and the ratios signed / unsigned.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import platform
import tempfile
import time
from collections.abc import Callable

import numpy as np

from swarmloc.messages import BeliefAnswer, RdlState, RdlUpdate, flat
from swarmloc.net.auth import Auth, Roster, Signer, Verifier, load_private, make_team_keys
from swarmloc.net.pairing import Pairing
from swarmloc.net.schema import Belief, Progress, decode, encode

TEAM = "bench"
KEY = f"swarmloc/{TEAM}/robot/0/inbox"
I3 = flat(np.eye(3))
COV = flat(np.diag([0.01, 0.01, 0.001]))
MESSAGES = {
    "BeliefAnswer": BeliefAnswer(sender=1, receiver=0, stamp=12.5, seq=0, mean=I3, cov=COV),
    "RdlState": RdlState(sender=1, receiver=0, stamp=12.5, x=(1.0, 2.0, 0.3), P=COV, sigma=I3),
    "RdlUpdate": RdlUpdate(sender=1, receiver=0, stamp=12.5, x=(1.0, 2.0, 0.3), P=COV),
    "Progress": Progress(robot=1, t=12.5),
    "Belief": Belief(robot=1, stamp=12.5, final=True, mean=I3, cov=COV),
}


def best(fn: Callable[[], None], repeats: int, n: int) -> float:
    """Best of ``repeats`` calls of ``fn`` (a loop over ``n`` messages), in microseconds per message."""
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return min(out) / n * 1e6


def measure(name: str, body, signer: Signer, roster: Roster, n: int, repeats: int, pair: tuple) -> dict:
    """One message's costs; ``pair``: robot 1's and robot 0's :class:`Pairing`, in session with each other."""
    to = 0 if not isinstance(body, Progress | Belief) else None
    raw = encode(TEAM, 1, 0, body)
    t_enc = best(lambda: [encode(TEAM, 1, i, body) for i in range(n)], repeats, n)
    t_dec = best(lambda: [decode(raw, TEAM, {0, 1, 2}, to_robot=to) for _ in range(n)], repeats, n)
    t_seal = best(lambda: [signer.seal(KEY, raw) for _ in range(n)], repeats, n)
    opens = []
    for _ in range(repeats):  # fresh frames for every loop: each may be opened once
        frames = [signer.seal(KEY, raw) for _ in range(n)]
        v = Verifier(roster)
        t = time.perf_counter()
        for f in frames:
            v.open(KEY, f)
        opens.append((time.perf_counter() - t) / n * 1e6)
    t_open = min(opens)
    one, zero = pair
    t_mac = best(lambda: [one.seal(KEY, raw, to=0) for _ in range(n)], repeats, n)
    macs = []
    for _ in range(repeats):
        maced = [one.seal(KEY, raw, to=0) for _ in range(n)]
        t = time.perf_counter()
        for f in maced:
            zero.open(KEY, f)
        macs.append((time.perf_counter() - t) / n * 1e6)
    t_mac_open = min(macs)
    unsigned, signed = t_enc + t_dec, t_enc + t_seal + t_open + t_dec
    maced_us = t_enc + t_mac + t_mac_open + t_dec
    return {"message": name, "bytes": len(raw), "bytes_signed": len(frames[0]), "encode_us": t_enc,
            "decode_us": t_dec, "seal_us": t_seal, "open_us": t_open, "unsigned_us": unsigned, "signed_us": signed,
            "ratio": signed / unsigned, "bytes_maced": len(maced[0]), "mac_seal_us": t_mac, "mac_open_us": t_mac_open,
            "maced_us": maced_us, "mac_ratio": maced_us / unsigned}  # fmt: skip


def team_run(src, est: str, auth: bool, folder: str) -> dict:
    """The team of ``src`` as NetNode threads on Zenoh sessions on 127.0.0.1 (with ``auth``: keys of ``folder``)."""
    import threading

    from swarmloc.events import Odometry
    from swarmloc.net.entry import make_node
    from swarmloc.net.process import NetNode
    from swarmloc.net.transport import free_ports, open_session

    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(len(src.robots))]
    sessions, nets, opened = [], [], []
    roster_file = f"{folder}/roster.json"
    try:
        for i, r in enumerate(src.robots):
            sessions.append(open_session([eps[i]], [e for e in eps if e != eps[i]]))
            ev = src.own_events(r)
            node = make_node(est, r, src.initial[r], src.config, src.landmarks)
            node.start(min(e.t0 if isinstance(e, Odometry) else e.stamp for e in ev))
            a = Auth.load(f"{folder}/robot{r}.key", roster_file, r) if auth else None
            if a is not None:  # count what each robot verifies
                v, count = a.verifier, [0]
                opened.append(count)
                a.open = lambda k, d, p=False, v=v, c=count: (c.__setitem__(0, c[0] + 1), v.open(k, d, p))[1]
            nets.append(NetNode(node, ev, session=sessions[-1], team=f"authbench{auth:d}", roster=src.robots,
                                record_times=src.record_times(), auth=a))  # fmt: skip
        wall, cpu = time.perf_counter(), time.process_time()
        threads = [threading.Thread(target=n.run, kwargs={"max_wall": 300}) for n in nets]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        fused = sum(n.node.stats()["fused"] for n in nets)
        return {"auth": auth, "wall_s": wall, "cpu_s": cpu, "verified": [c[0] for c in opened], "fused": fused}
    finally:
        for s in sessions:
            s.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--n", type=int, default=20_000, help="messages per loop (default 20000)")
    p.add_argument("--repeats", type=int, default=5, help="loops per timing; the best is kept (default 5)")
    p.add_argument("--out", default=None, help="write the results as JSON")
    p.add_argument("--no-team", dest="team", action="store_false", help="only the per-message costs")
    p.add_argument("--estimator", default="rdl", help="the team's estimator (default rdl)")
    p.add_argument("--duration", type=float, default=60.0, help="seconds of the simulated team (default 60)")
    p.add_argument("--rounds", type=int, default=2, help="team runs without and with authentication, each (default 2)")
    a = p.parse_args()
    folder = tempfile.TemporaryDirectory()
    roster_file, files = make_team_keys(folder.name, [0, 1, 2])
    roster = Roster.load(roster_file)
    signer = Signer(1, load_private(files[1]))
    Auth(roster, signer)  # the key is robot 1's in the roster
    one = Pairing(Auth(roster, Signer(1, load_private(files[1]))), TEAM)  # per-pair sessions, without Zenoh
    zero = Pairing(Auth(roster, Signer(0, load_private(files[0]))), TEAM)
    one.install(0, zero.incarnation, zero.eph)
    zero.install(1, one.incarnation, one.eph)
    rows = [measure(name, body, signer, roster, a.n, a.repeats, (one, zero)) for name, body in MESSAGES.items()]
    print(f"{'message':<13} {'bytes':>11} {'encode':>7} {'decode':>7} {'sign':>7} {'verify':>7} "
          f"{'unsigned':>9} {'signed':>8} {'ratio':>6}   (microseconds per message)")  # fmt: skip
    for r in rows:
        print(f"{r['message']:<13} {r['bytes']:>4} -> {r['bytes_signed']:<4} {r['encode_us']:>7.2f} "
              f"{r['decode_us']:>7.2f} {r['seal_us']:>7.2f} {r['open_us']:>7.2f} {r['unsigned_us']:>9.2f} "
              f"{r['signed_us']:>8.2f} {r['ratio']:>6.1f}")  # fmt: skip
    print(f"\n{'message':<13} {'bytes':>11} {'MAC':>7} {'check':>7} {'unsigned':>9} {'maced':>8} {'ratio':>6}   "
          "(per-pair session: MACed frame, microseconds per message)")  # fmt: skip
    for r in rows:
        print(
            f"{r['message']:<13} {r['bytes']:>4} -> {r['bytes_maced']:<4} {r['mac_seal_us']:>7.2f} "
            f"{r['mac_open_us']:>7.2f} {r['unsigned_us']:>9.2f} {r['maced_us']:>8.2f} {r['mac_ratio']:>6.1f}"
        )
    env = {"python": platform.python_version(), "machine": platform.machine(), "processor": platform.processor(),
           "cryptography": importlib.metadata.version("cryptography"),
           "msgspec": importlib.metadata.version("msgspec"), "n": a.n, "repeats": a.repeats}  # fmt: skip
    print(json.dumps(env))
    teams = []
    if a.team:
        from swarmloc.experiments.sources import load_source

        src = load_source("sim:random", robots=3, duration=a.duration, seed=1)
        team_run(src, a.estimator, True, folder.name)  # warm-up, not counted
        for _ in range(a.rounds):
            for auth in (False, True):
                teams.append(team_run(src, a.estimator, auth, folder.name))
        plain = [t for t in teams if not t["auth"]]
        signed = [t for t in teams if t["auth"]]
        assert len({t["fused"] for t in teams}) == 1, "the runs differ"
        w0, w1 = min(t["wall_s"] for t in plain), min(t["wall_s"] for t in signed)
        c0, c1 = min(t["cpu_s"] for t in plain), min(t["cpu_s"] for t in signed)
        per = (c1 - c0) / max(sum(signed[0]["verified"]), 1) * 1e6
        print(f"team of 3 ({a.estimator}, {a.duration:g} s simulated, best of {a.rounds}): wall {w0:.2f} s unsigned, "
              f"{w1:.2f} s signed ({w1 / w0:.2f}x); CPU {c0:.2f} s, {c1:.2f} s ({c1 / c0:.2f}x); messages verified "
              f"per robot {signed[0]['verified']}; extra CPU per verified message {per:.0f} us")  # fmt: skip
    folder.cleanup()
    if a.out:
        with open(a.out, "w") as f:
            json.dump({"env": env, "rows": rows, "teams": teams}, f, indent=2)


if __name__ == "__main__":
    main()
