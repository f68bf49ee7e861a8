"""An attacker on a ``diekf`` team's broadcasts, holding robot 2's valid key, run as its own process with its own
Zenoh session (tests/test_net_auth.py).

    python tests/net_diekf_attacker.py --listen tcp/127.0.0.1:PORT --team T --keys DIR --robots 0,1,2 --out FILE

It listens on 127.0.0.1 (the team connects to it), prints ``ready``, sniffs the run's key scope from the robots'
progress, and then, for ``--rounds`` rounds, publishes on robot 1's broadcast key a team update in robot 1's name
that would move every teammate's copy of robot 1 by 100 m: signed with robot 2's key under robot 1's name
(``key_mismatch``), with robot 1's key id (``bad_signature``), unsigned (``unsigned``), from an id outside the
roster (``unknown_sender``), and robot 2's own broadcast on robot 1's key (``not_owner``). It also publishes again,
as they are, robot 1's genuine broadcasts it has captured (``replay``). It writes, as JSON, how many of each it
sent (every robot subscribes to every broadcast key but its own).
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import zenoh
from _attacker import close_when_alone

from swarmloc.messages import TeamUpdate, flat
from swarmloc.net.auth import Roster, Signer, key_id, load_private
from swarmloc.net.schema import Broadcast, encode
from swarmloc.net.transport import open_session, robot_key

COV = flat(np.diag([0.01, 0.01, 0.001]))


def forged_update(sender: int, t: float) -> TeamUpdate:
    """A landmark-style update of ``sender``'s pose that pulls it 100 m along x (``H = [I 0]``, ``nu = S^-1 r``)."""
    Hi = flat(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    return TeamUpdate(sender=sender, receiver=-1, stamp=t, sub=(0.0,), target=sender, m=2, Hi=Hi, Hj=(0.0,) * 6,
                      Sinv=flat(np.eye(2)), nu=(100.0, 0.0), Pii=COV, Pjj=COV)  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser()
    for name in ("--listen", "--team", "--keys", "--robots", "--out"):
        p.add_argument(name, required=True)
    p.add_argument("--rounds", type=int, default=8)
    p.add_argument("--wait", type=float, default=60.0)
    a = p.parse_args()
    robots = [int(x) for x in a.robots.split(",")]
    keys = Path(a.keys)
    roster = Roster.load(keys / "roster.json")
    stolen = load_private(keys / "robot2.key")
    honest, as1, as1_kid1, outsider = Signer(2, stolen), Signer(1, stolen), Signer(1, stolen), Signer(9, stolen)
    as1_kid1.key_id = key_id(roster.keys[1])
    lock = threading.Lock()
    scope: list[str] = []
    seen: set[int] = set()
    captured: list[tuple[str, bytes]] = []
    sent: Counter[str] = Counter()
    mine: set[bytes] = set()

    def on_progress(x) -> None:
        what = str(x.key_expr).split("/")
        with lock:
            seen.add(int(what[-2]))
            if not scope:
                scope.append("/".join(what[1:-3]))  # swarmloc/<scope>/robot/<r>/progress

    def on_broadcast(x) -> None:
        raw = x.payload.to_bytes()
        if raw not in mine:
            with lock:
                captured.append((str(x.key_expr), raw))

    s = open_session([a.listen], [])
    decl = [s.declare_subscriber(f"swarmloc/{a.team}/**/robot/*/progress", on_progress,
                                 allowed_origin=zenoh.Locality.REMOTE)]  # fmt: skip
    print("ready", flush=True)
    end = time.monotonic() + a.wait
    while len(seen) < len(robots) and time.monotonic() < end:
        time.sleep(0.05)
    b1 = robot_key(scope[0], 1, "broadcast")
    decl.append(s.declare_subscriber(b1, on_broadcast, allowed_origin=zenoh.Locality.REMOTE))

    def put(payload: bytes, category: str) -> None:
        mine.add(payload)
        s.put(b1, payload, congestion_control=zenoh.CongestionControl.BLOCK)  # counted: never dropped
        sent[category] += 1

    for i in range(a.rounds):
        time.sleep(0.3)
        t = time.time()  # any stamp: the signature stops it before the stamp is read
        body = Broadcast(robot=1, n=10**6 + i, update=forged_update(1, t))
        raw = encode(a.team, 1, 0, body)
        put(as1.seal(b1, raw), "key_mismatch")
        put(as1_kid1.seal(b1, raw), "bad_signature")
        put(raw, "unsigned")
        put(outsider.seal(b1, encode(a.team, 9, 0, Broadcast(robot=9, n=i, update=forged_update(9, t)))),
            "unknown_sender")  # fmt: skip
        put(honest.seal(b1, encode(a.team, 2, 0, Broadcast(robot=2, n=10**6 + i, update=forged_update(2, t)))),
            "not_owner")  # fmt: skip
        with lock:
            grabbed, captured[:] = list(captured), []
        for _, payload in grabbed:
            put(payload, "replay")
    while not sent["replay"] and time.monotonic() < end:  # at least one genuine broadcast replayed
        with lock:
            grabbed, captured[:] = list(captured), []
        for _, payload in grabbed[:3]:
            put(payload, "replay")
        time.sleep(0.05)
    time.sleep(0.5)
    for d in decl:
        d.undeclare()
    Path(a.out).write_text(json.dumps({"sent": dict(sent)}, indent=1))
    close_when_alone(s)


if __name__ == "__main__":
    main()
