"""An attacker holding robot 2's valid key, run as its own process with its own Zenoh session (tests/test_net_auth.py).

    python tests/net_attacker.py --listen tcp/127.0.0.1:PORT --team T --keys DIR --robots 0,1,2 --out FILE

It listens on 127.0.0.1 (the team connects to it: ``launch_team(connect_extra=...)``), prints ``ready``, waits until
every robot has announced its progress and the belief server's liveliness token is seen, and then, for ``--rounds``
rounds, sends in robot 1's name what moved robot 0 by 100 m before senders were authenticated: an ``RdlStateQuery`` to
robot 0 and an ``RdlUpdate`` shifted 100 m; also a ``BeliefQuery``, a far-off belief of robot 1 (one at a record time,
one stamped outside the run), robot 1's progress "done", robot 1's report, a query to the belief server, and messages as
the belief server and as the collector. Each is sent signed with robot 2's key under robot 1's name (``key_mismatch``),
with robot 1's key id (``bad_signature``), unsigned, from an id outside the roster, or as robot 2 with robot 1 inside
the envelope; robot 2's own belief on robot 1's key (``not_owner``) and stamped outside the run. Signed as robot 2,
from this process (not robot 2's process of the run: no session vouches for it), what is not refused before is
``other_run``. It replays robot 1's genuine pushes to robot 0 (MACed under their pair's session) as they are
(``replay``), moved to robot 2's inbox (``other_run``: not a session of robot 2's) and, after the roster's
``max_age``, again (``stale``). A queryable it declares ("complete") on robot 1's query key
answers every query to robot 1 with a forged answer (``key_mismatch`` at the asker).

Every inner envelope it forges passes the schema's checks (:func:`swarmloc.net.schema.decode`): only the
signature stops it. It writes what it sent as JSON: per receiver (``robot <id>``, ``collector``, ``server``) and
category, the refusals it expects; and the answers its gets received.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import zenoh
from _attacker import close_when_alone, envelope_of, wait_alive

from swarmloc.messages import BeliefAnswer, BeliefQuery, RdlState, RdlStateQuery, RdlUpdate, flat
from swarmloc.net.auth import COLLECTOR, Roster, Signer, key_id, load_private
from swarmloc.net.schema import SERVER, Belief, Progress, Report, decode, encode
from swarmloc.net.transport import alive_key, open_session, robot_key, server_key

SHIFT = flat(np.array([[1.0, 0.0, 100.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
COV = flat(np.diag([0.01, 0.01, 0.001]))
I3 = flat(np.eye(3))


class Attack:
    def __init__(self, a: argparse.Namespace) -> None:
        self.team = a.team
        self.scope = a.team  # the team's keys: with a run id (swarmloc team), learnt from the progress it sniffs
        self.robots = [int(x) for x in a.robots.split(",")]
        keys = Path(a.keys)
        self.roster = Roster.load(keys / "roster.json")
        stolen = load_private(keys / "robot2.key")
        self.honest = Signer(2, stolen)  # robot 2, as itself
        self.as1 = Signer(1, stolen)  # robot 2's key under robot 1's name
        self.as1_kid1 = Signer(1, stolen)  # ... claiming robot 1's key id
        self.as1_kid1.key_id = key_id(self.roster.keys[1])
        self.as_server, self.as_collector, self.outsider = (
            Signer(SERVER, stolen),
            Signer(COLLECTOR, stolen),
            Signer(9, stolen),
        )
        self.expected: dict[str, Counter] = defaultdict(Counter)
        self.answers: list[str] = []
        self.schema_ok = self.schema_bad = 0
        self.sent: set[bytes] = set()
        self.captured: list[tuple[float, str, bytes]] = []  # (when, key, payload) not replayed yet
        self.replayed: list[tuple[float, str, bytes]] = []
        self.seen_inbox: Counter[int] = Counter()  # genuine pushes to robot 0 seen, by sender
        self.progress: dict[int, float] = {}
        self.lock = threading.Lock()
        self.session = open_session([a.listen], [])
        self.record_times = [float(t) for t in a.record_times.split(",")]

    def key(self, robot: int | str, what: str) -> str:
        return robot_key(self.scope, robot, what)

    def receivers(self, key: str) -> list[str]:
        """Who receives a put on ``key`` (what the team's processes subscribe to)."""
        what, who = key.split("/")[-1], key.split("/")[-2]
        if what in ("inbox", "query") and key.startswith(f"swarmloc/{self.scope}/robot/"):
            return [f"robot {who}"]
        return {"progress": [f"robot {r}" for r in self.robots] + ["collector"], "belief": ["collector", "server"],
                "report": ["collector"]}.get(what, ["server"])  # fmt: skip

    def forge(self, signer: Signer | None, key: str, body, frm: int | None = None, to: int | None = None) -> bytes:
        """``body`` in an envelope from ``frm`` (default: its sender), checked against the schema as the receiver
        would before senders were signed, and sealed by ``signer`` (None: unsigned)."""
        frm = getattr(body, "sender", getattr(body, "robot", 1)) if frm is None else frm
        raw = encode(self.team, frm, 0, body)
        try:
            decode(raw, self.team, set(self.robots), to_robot=to)
            self.schema_ok += 1
        except ValueError:
            self.schema_bad += 1
        return raw if signer is None else signer.seal(key, raw)

    def put(self, key: str, payload: bytes, category: str | None, receivers: list[str] | None = None) -> None:
        self.sent.add(payload)
        self.session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)  # counted: never dropped
        for r in receivers if receivers is not None else self.receivers(key):
            if category is not None:
                self.expected[r][category] += 1

    def get(self, key: str, payload: bytes, category: str) -> None:
        self.sent.add(payload)
        for r in self.receivers(key):
            self.expected[r][category] += 1
        for reply in self.session.get(key, payload=payload, timeout=3.0, target=zenoh.QueryTarget.ALL):
            if reply.ok is not None:
                self.answers.append(f"ok from {key}")
            else:
                self.answers.append(reply.err.payload.to_string()[:80])

    def one_round(self, t: float, rt: float) -> None:
        """Everything forged once: ``t`` a stamp robot 0 has read to, ``rt`` a record time."""
        inbox0, query0 = self.key(0, "inbox"), self.key(0, "query")
        q = RdlStateQuery(sender=1, receiver=0, stamp=t)
        self.get(query0, self.forge(self.as1, query0, q, to=0), "key_mismatch")
        self.get(query0, self.forge(self.as1, query0, BeliefQuery(sender=1, receiver=0, stamp=t), to=0), "key_mismatch")
        u = RdlUpdate(sender=1, receiver=0, stamp=t, x=(100.0, 0.0, 0.0), P=COV)
        for signer, category in ((self.as1, "key_mismatch"), (self.as1_kid1, "bad_signature"), (None, "unsigned"),
                                 (self.outsider, "unknown_sender")):  # fmt: skip
            self.put(inbox0, self.forge(signer, inbox0, u, to=0), category)
        # robot 2's key, signed as robot 2 by this process, not robot 2's process of the run: another run's
        self.put(inbox0, self.forge(self.honest, inbox0, u, to=0), "other_run")
        a = BeliefAnswer(sender=1, receiver=0, stamp=t, seq=-1, mean=SHIFT, cov=COV)
        self.put(inbox0, self.forge(self.as_server, inbox0, a, frm=SERVER, to=0), "key_mismatch")
        self.put(inbox0, self.forge(self.as_collector, inbox0, a, frm=COLLECTOR, to=0), "key_mismatch")
        b1 = self.key(1, "belief")
        self.put(b1, self.forge(self.as1, b1, Belief(robot=1, stamp=rt, rev=99, final=True, mean=SHIFT, cov=COV)),
                 "key_mismatch")  # fmt: skip
        self.put(b1, self.forge(self.as1, b1, Belief(robot=1, stamp=1e6, final=True, mean=SHIFT, cov=COV)),
                 "key_mismatch")  # fmt: skip
        b2 = Belief(robot=2, stamp=rt, rev=99, final=True, mean=SHIFT, cov=COV)
        self.put(b1, self.forge(self.honest, b1, b2), "not_owner")
        own = self.key(2, "belief")  # robot 2's key on its own belief, from a process that is not the run's robot 2
        self.put(own, self.forge(self.honest, own, Belief(robot=2, stamp=-1e6, final=True, mean=SHIFT, cov=COV)),
                 "other_run")  # fmt: skip
        p1 = self.key(1, "progress")
        self.put(p1, self.forge(self.as1, p1, Progress(robot=1, t=math.inf, done=True)), "key_mismatch")
        r1 = self.key(1, "report")
        self.put(r1, self.forge(self.as1, r1, Report(robot=1, stats={"fused": 10**6})), "key_mismatch")
        sq = server_key(self.scope)
        self.get(sq, self.forge(self.as1, sq, BeliefQuery(sender=1, receiver=0, stamp=t)), "key_mismatch")

    def replay(self, stale_after: float | None = None) -> None:
        """Robot 1's pushes to robot 0 captured since the last call: as they are, and moved to robot 2's inbox. With
        ``stale_after`` [s]: those replayed before that are older than that, once more (stale by then)."""
        if stale_after is not None:
            now = time.monotonic()
            for when, key, payload in self.replayed:
                if now - when > stale_after:
                    self.put(key, payload, "stale")
            return
        with self.lock:
            grabbed, self.captured = self.captured, []
        for _, key, payload in grabbed:
            self.put(key, payload, "replay")
            self.put(self.key(2, "inbox"), payload, "other_run")  # MACed for robot 0: no session of robot 2
        self.replayed += grabbed

    def on_query(self, q) -> None:
        """A teammate's query to robot 1: answered, forged, in robot 1's name (robot 2's key)."""
        try:
            raw = q.payload.to_bytes()
            asker = int.from_bytes(raw[4:8], "big", signed=True)
            env = decode(envelope_of(raw), self.team, set(self.robots))
            m = env.body
            kind = RdlState if isinstance(m, RdlStateQuery) else BeliefAnswer
            fields = dict(x=(100.0, 0.0, 0.0), P=COV, sigma=I3) if kind is RdlState else dict(mean=SHIFT, cov=COV)
            body = kind(sender=1, receiver=m.sender, stamp=m.stamp, sub=m.sub, **fields)
            q.reply(q.key_expr, self.forge(self.as1, str(q.key_expr), body))
            with self.lock:
                self.expected[f"robot {asker}"]["key_mismatch"] += 1
        except Exception as exc:  # noqa: BLE001
            print(f"attacker: query not answered: {exc}", file=sys.stderr)
        finally:
            q.drop()

    def on_sample(self, x) -> None:
        what = str(x.key_expr).split("/")
        raw = x.payload.to_bytes()
        if what[-1] == "progress" and raw[:3] == b"SLS":
            r = int(what[-2])
            with self.lock:
                self.progress[r] = time.monotonic()
                self.scope = "/".join(what[1:-3])  # swarmloc/<scope>/robot/<r>/progress
        elif what[-1] == "inbox" and raw not in self.sent:
            sender = int.from_bytes(raw[4:8], "big", signed=True)
            with self.lock:
                self.seen_inbox[sender] += 1
                if sender == 1:
                    self.captured.append((time.monotonic(), str(x.key_expr), raw))


def main() -> None:
    p = argparse.ArgumentParser()
    for name in ("--listen", "--team", "--keys", "--robots", "--out", "--record-times"):
        p.add_argument(name, required=True)
    p.add_argument("--rounds", type=int, default=8)
    p.add_argument("--wait", type=float, default=60.0)
    a = p.parse_args()
    atk = Attack(a)
    s = atk.session
    # the keys of a run of swarmloc team carry its run id (swarmloc/<team>/run/<id>/...): sniffed from the progress
    progress = f"swarmloc/{atk.team}/**/robot/*/progress"
    decl = [s.declare_subscriber(progress, atk.on_sample, allowed_origin=zenoh.Locality.REMOTE)]
    print("ready", flush=True)
    end = time.monotonic() + a.wait
    while len(atk.progress) < len(atk.robots) and time.monotonic() < end:
        time.sleep(0.05)
    server_seen = wait_alive(s, alive_key(atk.scope, "server"), end)  # (a CI run lost a round to the server without)
    decl.append(s.declare_subscriber(atk.key(0, "inbox"), atk.on_sample, allowed_origin=zenoh.Locality.REMOTE))
    started = time.monotonic()
    fake = s.declare_queryable(atk.key(1, "query"), atk.on_query, complete=True)
    t = atk.record_times[len(atk.record_times) // 3]
    for i in range(a.rounds):  # about 3 s
        atk.one_round(t, atk.record_times[i % len(atk.record_times)])
        atk.replay()
        time.sleep(0.3)
    while time.monotonic() < end:  # replaying what robot 1 pushes to robot 0 (once it has observed it) ...
        atk.replay()
        if atk.replayed and time.monotonic() > atk.replayed[0][0] + atk.roster.max_age + 0.6:
            break  # ... until the first one replayed is stale
        time.sleep(0.05)
    atk.replay(stale_after=atk.roster.max_age + 0.5)
    fake.undeclare()
    time.sleep(0.5)
    for d in decl:
        d.undeclare()
    out = {"expected": {k: dict(v) for k, v in atk.expected.items()}, "answers": atk.answers,
           "schema_ok": atk.schema_ok, "schema_bad": atk.schema_bad, "seen_inbox": atk.seen_inbox,
           "server_seen": server_seen, "seconds": time.monotonic() - started}  # fmt: skip
    Path(a.out).write_text(json.dumps(out, indent=1))
    close_when_alone(s)


if __name__ == "__main__":
    main()
