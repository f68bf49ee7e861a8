"""A flooder without any key, run as its own process with its own Zenoh session (tests/test_net_flood.py). It imports
no swarmloc: only eclipse-zenoh, and the signed frame's layout as ``docs/network.md`` states it.

    python tests/net_flood_attacker.py --listen tcp/127.0.0.1:PORT --team T --robots 0,1,2 --seconds 20 --out FILE

It listens on 127.0.0.1 (the team connects to it), prints ``ready``, sniffs the run's key scope and each robot's key
id from the robots' progress frames, then for ``--seconds`` s puts, in turns, on every robot's inbox:

- ``big``: frames just under the signature's size bound (1 MiB) claiming robot 1, and
- many small ones: ``unsigned`` (no signed frame), ``unknown_sender`` (a sender outside the roster),
  ``key_mismatch`` (a roster robot's id with a key id that is not its), ``bad_signature`` (a roster robot's id and
  key id, the signature random): each claiming robots 0, 1, 2 in turn;

and small ``bad_signature`` frames in robot 1's name on robot 1's progress key (every teammate and the collector
hear them). Every put waits for room (``CongestionControl.BLOCK``), so that each frame counted here reaches its
receivers. It writes, as JSON, how many of each kind it put where, and when it flooded (``span``: Unix times), and
keeps its session open until every peer has left (at most ``--wait`` s): a session closed at once discards what a
loaded receiver has not read yet (measured: 20,000 small puts to a subscriber slower than the sender, 6,716 received
when the sender closed at once, all of them when it stayed open).
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import threading
import time
from collections import Counter

import zenoh

HEADER = struct.Struct(">4siQq8s")  # magic, sender, seq, stamp [ns], key id (docs/network.md: the signed frame)
MAGIC = b"SLS1"
MAX_SIGNED = 1 << 20


def frame(sender: int, kid: bytes, body: bytes) -> bytes:
    """A signed frame's layout with a random signature."""
    return HEADER.pack(MAGIC, sender, time.time_ns(), time.time_ns(), kid) + body + os.urandom(64)


def main() -> None:
    p = argparse.ArgumentParser()
    for name in ("--listen", "--team", "--robots", "--out"):
        p.add_argument(name, required=True)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--wait", type=float, default=60.0)
    a = p.parse_args()
    robots = [int(x) for x in a.robots.split(",")]
    lock = threading.Lock()
    scope: list[str] = []
    kids: dict[int, bytes] = {}

    def on_progress(x) -> None:
        parts, raw = str(x.key_expr).split("/"), x.payload.to_bytes()
        with lock:
            if raw[:4] in (MAGIC, b"SLS2") and len(raw) >= HEADER.size:  # version 2 adds the incarnation after
                _, sender, _, _, kid = HEADER.unpack_from(raw)
                kids.setdefault(sender, kid)
            if not scope:
                scope.append("/".join(parts[1:-3]))  # swarmloc/<scope>/robot/<r>/progress

    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("scouting/gossip/enabled", "false")
    cfg.insert_json5("listen/endpoints", json.dumps([a.listen]))
    s = zenoh.open(cfg)
    sub = s.declare_subscriber(f"swarmloc/{a.team}/**/robot/*/progress", on_progress)
    print("ready", flush=True)
    end = time.monotonic() + a.wait
    while time.monotonic() < end:
        with lock:
            if scope and all(r in kids for r in robots):
                break
        time.sleep(0.05)
    sub.undeclare()
    sent: dict[str, Counter[str]] = {}
    t0 = time.time()
    if scope and all(r in kids for r in robots):
        sent = flood(s, f"swarmloc/{scope[0]}", robots, kids, a.seconds)
    t1 = time.time()
    with open(a.out, "w") as f:
        json.dump({"scope": scope[:1], "sent": sent, "span": [t0, t1]}, f)
    end = time.monotonic() + a.wait
    while list(s.info.peers_zid()) and time.monotonic() < end:  # the team reads what is in flight, then leaves
        time.sleep(0.05)
    s.close()


def flood(s, prefix: str, robots: list[int], kids: dict[int, bytes], seconds: float) -> dict[str, Counter[str]]:
    block = zenoh.CongestionControl.BLOCK
    big = frame(1, kids[1], os.urandom(MAX_SIGNED - HEADER.size - 64 - 16))
    pubs = {r: s.declare_publisher(f"{prefix}/robot/{r}/inbox", congestion_control=block) for r in robots}
    progress = s.declare_publisher(f"{prefix}/robot/1/progress", congestion_control=block)
    body = b"\x85\xa1v\x02" + os.urandom(120)  # the start of a MessagePack map, then noise
    sent: dict[str, Counter[str]] = {f"robot {r}": Counter() for r in robots}
    sent["progress of robot 1"] = Counter()
    end, k = time.monotonic() + seconds, 0
    while time.monotonic() < end:
        k += 1
        for r in robots:
            c, pub, claim = sent[f"robot {r}"], pubs[r], robots[k % len(robots)]
            if k % 50 == 0:
                pub.put(big)
                c["big"] += 1
            for what, data in (
                ("unsigned", b"\x00" * 64 + body),
                ("unknown_sender", frame(9, kids[claim], body)),
                ("key_mismatch", frame(claim, os.urandom(8), body)),
                ("bad_signature", frame(claim, kids[claim], body)),
            ):
                pub.put(data)
                c[what] += 1
        progress.put(frame(1, kids[1], body))
        sent["progress of robot 1"]["bad_signature"] += 1
    for pub in [*pubs.values(), progress]:
        pub.undeclare()
    return {k: dict(v) for k, v in sent.items()}


if __name__ == "__main__":
    main()
