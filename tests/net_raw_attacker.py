"""An attacker holding robot 2's valid key against a server-hosted estimator (tests/test_net_central.py), run as its
own process with its own Zenoh session:

    python tests/net_raw_attacker.py --listen tcp/127.0.0.1:PORT --team T --keys DIR --out FILE

It listens on 127.0.0.1 (the team connects to it: ``launch_team(connect_extra=...)``), prints ``ready``, learns the
run's keys from the robots' progress, waits for the belief server's liveliness token, and then, for ``--rounds`` rounds,
forwards in robot 1's name a detection of robot 0 100 m off (as forward 0, a duplicate, and as forward 10^6, past a
gap): signed with robot 2's key under robot 1's name (``key_mismatch``), as robot 2 on robot 1's raw key
(``not_owner``), unsigned (``unsigned``), as robot 2 with robot 1 inside the envelope, and as robot 2 on its own key
with robot 1's forward inside: signed by this process, which is not robot 2's process of the run (no session vouches
for it), both ``other_run`` (before runs were bound, ``sender_mismatch`` and a refusal of the schema). Every forward
it forges passes the schema's checks of its body. It writes the refusals it expects at the server, by category, as
JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import Counter
from pathlib import Path

import numpy as np
import zenoh
from _attacker import close_when_alone, wait_alive

from swarmloc.messages import flat
from swarmloc.net.auth import Roster, Signer, load_private
from swarmloc.net.schema import Raw, RawDetection, decode, encode
from swarmloc.net.transport import alive_key, open_session, robot_key


def main() -> None:
    p = argparse.ArgumentParser()
    for name in ("--listen", "--team", "--keys", "--out"):
        p.add_argument(name, required=True)
    p.add_argument("--rounds", type=int, default=6)
    p.add_argument("--wait", type=float, default=60.0)
    a = p.parse_args()
    keys = Path(a.keys)
    roster = Roster.load(keys / "roster.json")
    stolen = load_private(keys / "robot2.key")
    honest, as1 = Signer(2, stolen), Signer(1, stolen)
    session = open_session([a.listen], [])
    seen: dict[int, str] = {}

    def on_progress(x: zenoh.Sample) -> None:
        parts = str(x.key_expr).split("/")
        seen[int(parts[-2])] = "/".join(parts[1:-3])  # swarmloc/<scope>/robot/<r>/progress

    sub = session.declare_subscriber(f"swarmloc/{a.team}/**/robot/*/progress", on_progress,
                                     allowed_origin=zenoh.Locality.REMOTE)  # fmt: skip
    print("ready", flush=True)
    end = time.monotonic() + a.wait
    while len(seen) < len(roster.robots) and time.monotonic() < end:
        time.sleep(0.02)
    scope = next(iter(seen.values()))
    server_seen = wait_alive(session, alive_key(scope, "server"), end)
    raw1, raw2 = robot_key(scope, 1, "raw"), robot_key(scope, 2, "raw")
    far = RawDetection(1.0, "pose", (100.0, 0.0, 0.0), flat(np.diag([0.01, 0.01, 0.001])), 0, True)
    expected: Counter[str] = Counter()
    schema_ok = 0
    for i in range(a.rounds):
        for n in (0, 10**6):
            body = Raw(robot=1, n=n, first=0.0, upto=math.inf, odometry=0, detections=1, items=(far,))
            env1, env2 = encode(a.team, 1, 0, body), encode(a.team, 2, 0, body)
            decode(env1, a.team, set(roster.robots))  # the body passes the schema: only the signature stops it
            schema_ok += 1
            for key, payload, category in (
                (raw1, as1.seal(raw1, env1), "key_mismatch"),
                (raw1, honest.seal(raw1, env1), "sender_mismatch_or_not_owner"),
                (raw1, env1, "unsigned"),
                (raw2, honest.seal(raw2, env1), "other_run"),
                (raw2, honest.seal(raw2, env2), "other_run"),
            ):
                session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)  # counted: never dropped
                expected[category] += 1
        time.sleep(0.2 if i else 0.05)
    expected["not_owner"] = expected.pop("sender_mismatch_or_not_owner")  # robot 2 on robot 1's key: not_owner
    time.sleep(0.5)
    sub.undeclare()
    Path(a.out).write_text(
        json.dumps({"expected": expected, "schema_ok": schema_ok, "scope": scope, "server_seen": server_seen}, indent=1)
    )
    close_when_alone(session)


if __name__ == "__main__":
    main()
