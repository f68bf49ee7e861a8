"""Per-pair sessions (:mod:`swarmloc.net.pairing`, :mod:`swarmloc.net.macframe`): frames bound to this run, MACed
between the members of a pair, a key held by two processes reported, re-asks bounded.

Before: nodes started by hand without a run id, with the same roster, accepted all 334 signed frames of robot 1
captured from the run before (none refused; a robot moved 0.29 m); a second process signing with robot 2's key got
the real robot 2's frames refused as replays, robot 2 was declared lost and a query storm from that process moved
robot 0 by 2.09 m; one query was asked 22,662 times while a fake liveliness token lasted; and signed belief queries
cost two Ed25519 signatures and two verifications each (p99 above 1 ms at 20 processes).

The offline tests build sessions without Zenoh; the live ones give every member its own Zenoh session on
127.0.0.1 (its own process in the attacker tests: ``tests/net_replay_attacker.py``, ``tests/net_twin_attacker.py``).
Every wait is bounded and every process started is stopped.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from _attacker import attacker_process

from swarmloc.datasets.tum import read_tum
from swarmloc.estimators import make_team, node_options
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.messages import BeliefQuery
from swarmloc.net import faults, outbound
from swarmloc.net.auth import (
    HEADER,
    HEADER_V1,
    MAGIC_V1,
    Auth,
    AuthRejected,
    Roster,
    Signer,
    load_private,
    make_team_keys,
    new_key,
)
from swarmloc.net.entry import make_node
from swarmloc.net.macframe import MAC_HEADER, TAG_SIZE
from swarmloc.net.pairing import Pairing, attach
from swarmloc.net.process import NetNode
from swarmloc.net.schema import Progress, encode
from swarmloc.net.transport import free_ports, open_session, robot_key
from swarmloc.runner import run

pytestmark = pytest.mark.network

TEAM = "p"
INBOX0 = robot_key(TEAM, 0, "inbox")
PROGRESS1 = robot_key(TEAM, 1, "progress")
REPLAY_ATTACKER = Path(__file__).with_name("net_replay_attacker.py")
TWIN_ATTACKER = Path(__file__).with_name("net_twin_attacker.py")


@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[int, Path]]:
    return make_team_keys(tmp_path_factory.mktemp("keys"), [0, 1, 2])


def auth(keys, member: int) -> Auth:
    return Auth.load(keys[1][member], keys[0], member)


def pair(a: Pairing, b: Pairing) -> None:
    """Put ``a`` and ``b`` in session (what the handshake does once both are vouched for)."""
    a.install(b.member, b.incarnation, b.eph)
    b.install(a.member, a.incarnation, a.eph)


def category(a: Auth, key: str, data: bytes, publication: bool = False) -> str:
    with pytest.raises(AuthRejected) as exc:
        a.open(key, data, publication)
    return exc.value.category


# ------------------------------------------------------------------------------------------------ offline
def test_a_maced_frame_opens_only_under_its_session_from_its_peer(keys):
    """Robot 1's push to robot 0 is MACed under their session: 48 bytes of framing (the signed frame has 104), it
    opens at robot 0; any byte changed, or the frame moved to another key, breaks the MAC; robot 2 holds no such
    session (``other_run``); opened twice it is a replay; robot 0's own frame played back to it is refused
    (``key_mismatch``); stamped beyond ``max_age_s`` either way it is ``stale`` / ``future``."""
    a0, a1, a2 = auth(keys, 0), auth(keys, 1), auth(keys, 2)
    p0, p1, p2 = Pairing(a0, TEAM), Pairing(a1, TEAM), Pairing(a2, TEAM)
    pair(p0, p1)
    pair(p1, p2)
    payload = encode(TEAM, 1, 0, Progress(robot=1, t=1.0))
    data = a1.seal(INBOX0, payload)
    assert data[:4] == b"SLM1" and len(data) == len(payload) + MAC_HEADER.size + TAG_SIZE == len(payload) + 48
    signed = a1.signer.seal(INBOX0, payload)
    assert len(signed) == len(payload) + HEADER.size + 64 == len(payload) + 104
    for at in (5, 9, 20, MAC_HEADER.size + 3, len(data) - 1):
        bad = bytearray(data)
        bad[at] ^= 0x01
        assert category(a0, INBOX0, bytes(bad)) in ("bad_signature", "unknown_sender"), at
    bad = bytearray(data)
    bad[30] ^= 0x01  # the session id
    assert category(a0, INBOX0, bytes(bad)) == "other_run"
    assert category(a0, robot_key(TEAM, 2, "inbox"), data) == "bad_signature"  # moved to another key
    assert category(a2, robot_key(TEAM, 0, "inbox"), data) == "other_run"  # robot 2: not its session
    assert a0.open(INBOX0, data) == (1, payload)
    assert category(a0, INBOX0, data) == "replay"
    own = a0.seal(robot_key(TEAM, 1, "inbox"), encode(TEAM, 0, 0, Progress(robot=0, t=1.0)))
    assert category(a0, robot_key(TEAM, 1, "inbox"), own) == "key_mismatch"  # its own frame, played back
    now = a0.verifier.clock()
    for shift, why in ((31e9, "stale"), (-31e9, "future")):
        a0.verifier.clock = lambda s=shift: now + int(s)
        assert category(a0, INBOX0, a1.seal(INBOX0, payload)) == why
    a0.verifier.clock = time.time_ns
    assert a0.open(INBOX0, a1.seal(INBOX0, payload))[0] == 1


def test_a_signed_frame_is_taken_only_from_its_senders_process_of_this_run(keys):
    """With sessions, a signed publication opens only from the process of its sender that the session vouched for:
    another process of robot 1 (a run before, replayed: ``other_run``), a version 1 frame that names no run
    (``other_run``), a member this process has no session with, on another thread (``no_session``); a restarted
    robot 1, once in session, is taken, and its former process's frames, MACed or signed, are ``other_run``."""
    a0, a1 = auth(keys, 0), auth(keys, 1)
    p0, p1 = Pairing(a0, TEAM), Pairing(a1, TEAM)
    pair(p0, p1)
    body = encode(TEAM, 1, 0, Progress(robot=1, t=1.0))
    old_push = a1.seal(INBOX0, body)
    old_progress = a1.seal(PROGRESS1, body)
    assert old_progress[:4] == b"SLS2"
    assert a0.open(PROGRESS1, old_progress, publication=True) == (1, body)
    before = Signer(1, load_private(keys[1][1]))  # another process of robot 1 (the run before)
    assert category(a0, PROGRESS1, before.seal(PROGRESS1, body), True) == "other_run"
    v1 = HEADER_V1.pack(MAGIC_V1, 1, 1, time.time_ns(), before.key_id) + body
    v1 += load_private(keys[1][1]).sign(b"swarmloc-signed-v1\0" + PROGRESS1.encode() + b"\0" + v1)
    assert category(a0, PROGRESS1, v1, True) == "other_run"
    assert Auth(Roster.load(keys[0])).open(PROGRESS1, v1, True) == (1, body)  # without sessions: read as before
    got: list[str] = []
    t = threading.Thread(target=lambda: got.append(category(a0, robot_key(TEAM, 2, "progress"),
                                                             auth(keys, 2).seal(robot_key(TEAM, 2, "progress"), body),
                                                             True)))  # fmt: skip
    t.start()
    t.join(10)
    assert got == ["no_session"]
    a1_new = auth(keys, 1)  # robot 1 restarted: a new process, in session with robot 0
    p1_new = Pairing(a1_new, TEAM)
    pair(p0, p1_new)
    assert a0.open(INBOX0, a1_new.seal(INBOX0, body)) == (1, body)
    assert a0.open(PROGRESS1, a1_new.seal(PROGRESS1, body), True) == (1, body)
    assert category(a0, INBOX0, old_push) == "other_run"
    assert category(a0, PROGRESS1, a1.signer.seal(PROGRESS1, body), True) == "other_run"
    assert p0.snapshot()["sessions_renewed"] == 1


def test_the_session_key_binds_both_members_keys_and_both_processes(keys, tmp_path):
    """Both sides derive one key and session id; another process of either gives another; so does a roster with
    another Ed25519 key for the peer; an X25519 key of a small order (a zero shared secret) is refused."""
    p0, p1 = Pairing(auth(keys, 0), TEAM), Pairing(auth(keys, 1), TEAM)
    k01 = p0.derive(1, p1.eph)
    assert k01 == p1.derive(0, p0.eph) and len(k01[0]) == 32 and len(k01[1]) == 8
    p1b = Pairing(auth(keys, 1), TEAM)
    assert p0.derive(1, p1b.eph)[0] != k01[0] and p0.derive(1, p1b.eph)[1] != k01[1]
    roster = Roster.load(keys[0])
    other = Roster({**roster.keys, 1: new_key(tmp_path / "other1.key")})
    p0_other = Pairing(Auth(other, Signer(0, load_private(keys[1][0]))), TEAM)
    p0_other._eph, p0_other.eph = p0._eph, p0.eph  # the same X25519 key: only robot 1's Ed25519 key differs
    assert p0_other.derive(1, p1.eph) != k01
    with pytest.raises(ValueError):
        p0.derive(1, bytes(32))


def test_a_query_asked_again_is_bounded_by_count_and_rate(monkeypatch):
    """A teammate's token without a process behind it: each get ends at once, unanswered. Before, the query was
    asked again at once every time, as long as ``lost_timeout`` lasted (22,662 asks). Now, beyond
    ``answer_retries``, the ``k``-th ask waits ``k`` spacings after the first (on the node's timers), and the asks
    stop at ``answer_retries + ceil(lost_timeout / spacing) + 1``; then the node gets its "not found" answer."""
    clock = SimpleNamespace(t=100.0)
    for module in (outbound, faults):  # the asks' times, and the timers' (FaultySender's)
        monkeypatch.setattr(module, "time", SimpleNamespace(monotonic=lambda: clock.t))
    asks: list[float] = []

    class EndsAtOnce:  # a get that nobody answers (the test ends it at once)
        def get(self, key, **kw) -> None:
            asks.append(clock.t)

    src = load_source("sim:random", robots=3, duration=4.0, seed=0)
    node = make_node("rdl", 0, src.initial[0], src.config, src.landmarks)
    node.start(src.t_start)
    net = NetNode(node, src.own_events(0), session=EndsAtOnce(), team=TEAM, roster=src.robots,
                  record_times=src.record_times(), answer_timeout=2.0, lost_timeout=10.0, answer_retries=2)  # fmt: skip
    net.wiring.pub["belief"] = SimpleNamespace(put=lambda *a, **k: None)  # never opened: beliefs go nowhere
    fed: list = []
    step = net.node.step
    net.node.step = lambda item: fed.append(item) or step(item)
    net.lockstep.alive.add(1)
    net.outbound.ask(BeliefQuery(sender=0, receiver=1, stamp=net.node.present))
    while not fed and clock.t < 200.0:
        for qid in list(net.outbound.outstanding):  # every get ends at once, with no reply
            net.inbound.handle("reply_end", qid)
        net.outbound.sends.run_timers()
        clock.t += 0.01
    spacing = 0.25  # answer_timeout 2 s, within the spacing's bounds (0.05, 0.25)
    bound = 2 + math.ceil(10.0 / spacing) + 1
    assert len(asks) <= bound and len(asks) >= 10.0 / spacing, len(asks)
    gaps = np.diff(asks[3:])
    assert gaps.min() >= spacing - 0.011, gaps.min()
    assert [(a.found, a.seq) for a in fed] == [(False, -2)] and f"({len(asks)} asks)" in fed[0].reason
    assert net.counts["asked_again_later"] >= len(asks) - 3


# ------------------------------------------------------------------------------------------------ live, in-process
def sessions(n: int, extra: int = 0) -> tuple[list[str], list]:
    """``n`` Zenoh peers on 127.0.0.1 connected to each other (and ``extra`` more endpoints for later ones)."""
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(n + extra)]
    return eps, [open_session([eps[i]], [e for j, e in enumerate(eps) if j != i]) for i in range(n)]


def reach(session, members, timeout: float = 10.0) -> None:
    """Wait (bounded) until a get from ``session`` on each of ``members``' hello keys finds its queryable."""
    from swarmloc.net.pairing import member_key
    from swarmloc.net.transport import hello_key

    queriers = [session.declare_querier(hello_key(TEAM, member_key(m))) for m in members]
    end = time.monotonic() + timeout
    try:
        while not all(q.matching_status.matching for q in queriers):
            assert time.monotonic() < end, f"hello keys of {members} not reachable"
            time.sleep(0.02)
    finally:
        for q in queriers:
            q.undeclare()


def test_the_handshake_pairs_every_member_and_a_restarted_member_rejoins(keys, caplog):
    """Robots 0 and 1 start, robot 2 later: each process says hello to those up and confirms a session with each,
    so all three pairs are in session (both ways, each naming the other's process) with one side's initiative;
    what they send each other is MACed, their publications signed and taken. Robot 1 restarts (a new process): its
    start renews its sessions (the old process no longer answers the probe), its frames open, the old process's
    frames are ``other_run``."""
    eps, zs = sessions(3, extra=1)
    try:
        a = [auth(keys, r) for r in range(3)]
        attach(a[0], zs[0], TEAM)
        reach(zs[1], [0])
        attach(a[1], zs[1], TEAM)
        reach(zs[2], [0, 1])
        attach(a[2], zs[2], TEAM)
        for r in range(3):
            s = {m: a[r].sessions.session(m) for m in range(3) if m != r}
            assert all(s[m] is not None and s[m].incarnation == a[m].signer.incarnation for m in s), (r, s)
        push = a[1].seal(INBOX0, b"\x00")
        assert push[:4] == b"SLM1" and a[0].open(INBOX0, push) == (1, b"\x00")
        progress = a[1].seal(PROGRESS1, b"\x01")
        assert progress[:4] == b"SLS2" and a[2].open(PROGRESS1, progress, True) == (1, b"\x01")
        old = a[1].seal(INBOX0, b"\x02")
        a[1].sessions.close()
        zs[1].close()
        zs[1] = open_session([eps[3]], [eps[0], eps[2]])
        reach(zs[1], [0, 2])
        new1 = auth(keys, 1)
        with caplog.at_level(logging.INFO, logger="swarmloc.net.pairing"):
            attach(new1, zs[1], TEAM)
        for r in (0, 2):
            assert a[r].sessions.session(1).incarnation == new1.signer.incarnation
            assert a[r].session_counts()["sessions_renewed"] == 1
        assert new1.session_counts()["sessions"] == 2
        assert f"robot 1 has a new process ({new1.signer.incarnation.hex()}" in caplog.text
        assert a[0].open(INBOX0, new1.seal(INBOX0, b"\x03")) == (1, b"\x03")
        assert category(a[0], INBOX0, old) == "other_run"
        assert category(a[2], PROGRESS1, progress, True) == "other_run"
        assert category(a[2], PROGRESS1, a[1].signer.seal(PROGRESS1, b"\x04"), True) == "other_run"
    finally:
        for s in zs:
            s.close()


def test_a_key_in_two_processes_is_reported_and_the_first_one_kept(keys, caplog):
    """A second process with robot 2's key says hello while robot 2 runs: every member holding a session with robot
    2 probes it, the first process answers, so the second is a twin: counted (``twins``), logged once naming both
    processes, refused a session (``sessions_refused`` on its side), and every frame it signs is refused (``twin``)
    while robot 2's own frames are still taken. Robot 2 hears the twin's hello (``twins_of_self``). A member that
    starts after both (here the collector) gets two answers from robot 2 and keeps the process started first."""
    from swarmloc.net.auth import COLLECTOR

    eps, zs = sessions(4, extra=1)
    try:
        a = [auth(keys, r) for r in range(3)]
        for r in range(3):
            reach(zs[r], range(r))
            attach(a[r], zs[r], TEAM)
        reach(zs[3], range(3))
        twin = auth(keys, 2)
        with caplog.at_level(logging.WARNING, logger="swarmloc.net.pairing"):
            attach(twin, zs[3], TEAM)
        real, fake = a[2].signer.incarnation.hex(), twin.signer.incarnation.hex()
        for r in (0, 1):
            assert a[r].session_counts()["twins"] == 1 and a[r].sessions.session(2).incarnation.hex() == real
            line = next(x for x in caplog.messages if x.startswith(f"robot {r}: two processes hold the key of robot 2"))
            assert re.search(f"process {real} .*, kept, and process {fake} .*, refused", line), line
        assert twin.session_counts()["sessions_refused"] == 2 and not twin.session_counts().get("sessions")
        assert a[2].session_counts()["twins_of_self"] == 1
        k2 = robot_key(TEAM, 2, "progress")
        for r in (0, 1):
            assert category(a[r], k2, twin.seal(k2, b"\x05"), True) == "twin"
            assert a[r].open(k2, a[2].seal(k2, b"\x06"), True) == (2, b"\x06")
        assert twin.seal(INBOX0, b"\x07")[:4] == b"SLS2"  # no session: it can only sign, and that is refused
        assert category(a[0], INBOX0, twin.seal(INBOX0, b"\x07")) == "twin"
        zc = open_session([eps[4]], eps[:4])
        reach(zc, range(3))
        try:
            collector = Auth.load(keys[1][COLLECTOR], keys[0], COLLECTOR)
            attach(collector, zc, TEAM)
            assert collector.sessions.session(2).incarnation.hex() == real
            assert collector.session_counts()["twins"] == 1
        finally:
            zc.close()
    finally:
        for s in zs:
            s.close()


def test_a_receiver_makes_the_session_a_frame_needs_on_its_own_thread(keys):
    """Two processes that missed each other's hello (both attached before the other answered): the first signed
    frame robot 0's own thread opens from robot 1 makes the session at once, and is taken; a frame of a member
    with no process up waits for nothing longer than the hello and is refused ``no_session``."""
    eps, zs = sessions(2)
    try:
        a0, a1 = auth(keys, 0), auth(keys, 1)
        attach(a0, zs[0], TEAM, hello=False)
        attach(a1, zs[1], TEAM, hello=False)
        reach(zs[0], [1])
        reach(zs[1], [0])
        assert a0.sessions.session(1) is None
        assert a0.open(PROGRESS1, a1.seal(PROGRESS1, b"\x01"), True) == (1, b"\x01")
        assert a0.sessions.session(1) is not None and a1.sessions.session(0) is not None
        assert a1.seal(INBOX0, b"\x02")[:4] == b"SLM1"
        t0 = time.monotonic()
        k2 = robot_key(TEAM, 2, "progress")
        assert category(a0, k2, auth(keys, 2).signer.seal(k2, b"\x03"), True) == "no_session"
        assert time.monotonic() - t0 < 3.0
    finally:
        for s in zs:
            s.close()


# ------------------------------------------------------------------------------------------------ live, processes
def reference(src, est: str):
    nodes = make_team(est, src.initial, **node_options(est, src.config, src.landmarks))
    return run(nodes, src.events, src.record_times(), truth=src.truth)


def hand_started_run(team: str, keys_dir: Path, out: Path, extra_connect: str) -> dict[int, dict]:
    """Three ``swarmloc node`` processes of ``team`` started by hand (no run id: the keys are the team's alone),
    ``rdl`` on 20 s of ``sim:random`` at twice real time; their reports, once all have ended (bounded)."""
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(3)]
    procs = []
    try:
        for r in range(3):
            connect = ",".join([e for i, e in enumerate(eps) if i != r] + [extra_connect])
            cmd = [sys.executable, "-m", "swarmloc.cli", "node", "--team", team, "--robot", str(r), "--source",
                   "sim:random", "--duration", "20", "--seed", "1", "--estimator", "rdl", "--speed", "2", "--key",
                   str(keys_dir / f"robot{r}.key"), "--roster", str(keys_dir / "roster.json"), "--listen", eps[r],
                   "--connect", connect, "--out", str(out), "--max-wall", "150"]  # fmt: skip
            log = open(out.parent / f"{out.name}-robot{r}.log", "wb")  # noqa: SIM115 - closed with the process
            procs.append((subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT), log))
        for p, log in procs:
            p.wait(timeout=200)
            log.close()
    finally:
        for p, log in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
            log.close()
    assert [p.returncode for p, _ in procs] == [0, 0, 0], [(out.parent / f"{out.name}-robot{r}.log").read_text()[-1500:]
                                                           for r in range(3)]  # fmt: skip
    return {r: json.loads((out / f"robot{r}.json").read_text()) for r in range(3)}


def test_frames_recorded_in_a_run_are_refused_in_the_next_run_of_the_same_team(tmp_path):
    """Two runs of a team started by hand with one roster and no run id (every key expression the same), the
    roster's ``max_age_s`` 600 s (so that no replay is refused for its age: only the run binding can refuse it).
    An attacker process records robot 1's frames in the first run (its pushes, MACed for robots 0 and 2; its
    queries, MACed; its progress, beliefs and report, signed) and replays every one in the second run, once every
    robot's new process announces progress. Before, all 334 were accepted and a robot moved 0.29 m. Now none is:
    each node counts exactly what reached it as ``auth_other_run`` (and nothing else), no replayed query is
    answered, and the second run's beliefs equal the first's (and the in-process run's)."""
    src = load_source("sim:random", robots=3, duration=20.0, seed=1)
    team = f"replay{os.getpid()}"
    make_team_keys(tmp_path / "keys", src.robots, max_age=600.0)
    ep = f"tcp/127.0.0.1:{free_ports(1)[0]}"
    out = tmp_path / "attacker.json"
    args = ["--listen", ep, "--team", team, "--robots", "0,1,2", "--out", str(out)]
    with attacker_process(REPLAY_ATTACKER, args, wait=120):
        first = hand_started_run(team, tmp_path / "keys", tmp_path / "run1", ep)
        second = hand_started_run(team, tmp_path / "keys", tmp_path / "run2", ep)
    got = json.loads(out.read_text())
    assert got["second_run"], got
    recorded = got["recorded"]
    assert recorded["inbox"] > 20 and recorded["progress"] > 20 and recorded["query"] > 20, recorded
    assert sum(recorded.values()) >= 100
    assert not got["answers"].get("ok") and got["answers"].get("error") == recorded["query"]
    for r in range(3):
        auth = {k: v for k, v in second[r]["net"].items() if k.startswith("auth_")}
        assert auth == {"auth_other_run": got["received"][f"robot {r}"]}, (r, auth, got["received"])
        assert not {k: v for k, v in first[r]["net"].items() if k.startswith("auth_")}, first[r]["net"]
        assert second[r]["net"]["sessions"] == 2 and not second[r]["net"].get("peers_lost")
    ref = reference(src, "rdl")
    for r in range(3):
        t1, xyt1 = read_tum(tmp_path / "run1" / f"robot{r}.tum")
        t2, xyt2 = read_tum(tmp_path / "run2" / f"robot{r}.tum")
        np.testing.assert_array_equal(t1, t2)
        assert np.abs(xyt2 - xyt1).max() <= 1e-9, r
        np.testing.assert_array_equal(t2, ref.tracks[r].times)
        assert np.abs(xyt2[:, :2] - ref.tracks[r].mean[:, :2]).max() <= 1e-8  # the file's 9 decimals


def test_a_second_process_with_robot_2s_key_and_its_query_storm_change_nothing(tmp_path):
    """A team of 3 (``rdl``, ``swarmloc team``: robots, collector) and a second process holding robot 2's key
    (``tests/net_twin_attacker.py``) that joins as robot 2 while robot 2 runs: it says hello to every member,
    declares robot 2's token and a queryable on robot 2's query key answering 100 m off, storms robot 0 with 2000
    queries, pushes updates and announces robot 2 done. Before, robot 2's own frames were refused as replays,
    robot 2 was declared lost and robot 0 moved 2.09 m. Now every member that holds a session with robot 2 reports
    the twin (``twins`` 1, a log line naming both processes), robot 2 reports another process of its key, every
    frame of the twin is refused as ``twin`` where it arrives (counted exactly), no query of its storm is answered,
    nobody is declared lost, and every robot's beliefs equal the in-process run to 1e-9."""
    src = load_source("sim:random", robots=3, duration=20.0, seed=1)
    team = f"twin{os.getpid()}"
    make_team_keys(tmp_path / "keys", src.robots)
    ep = f"tcp/127.0.0.1:{free_ports(1)[0]}"
    out = tmp_path / "twin.json"
    rts = ",".join(repr(float(t)) for t in src.record_times())
    args = ["--listen", ep, "--team", team, "--keys", str(tmp_path / "keys"), "--robots", "0,1,2", "--out", str(out),
            "--record-times", rts]  # fmt: skip
    with attacker_process(TWIN_ATTACKER, args, wait=120):
        tr = run_team(src=src, source="sim:random", robots=3, duration=20.0, seed=1, estimator="rdl", team=team,
                      speed=1.0, max_wall=150, connect_extra=[ep], keys_dir=tmp_path / "keys",
                      log_dir=tmp_path / "logs")  # fmt: skip
    got = json.loads(out.read_text())
    twin = got["incarnation"]
    assert got["counts"]["sessions_refused"] == 3 and not got["counts"].get("sessions"), got["counts"]
    assert got["answers"] == {"error": 2000}, got["answers"]
    assert all(c == 0 for c in tr.exit_codes.values()), tr.exit_codes
    for r in src.robots:
        net = tr.reports[r].net
        assert {k: v for k, v in net.items() if k.startswith("auth_")} == {"auth_twin": got["received"][f"robot {r}"]}
        assert not net.get("peers_lost") and not net.get("peers_left"), net
        log_text = (tmp_path / "logs" / f"robot{r}.log").read_text()
        if r == 2:
            assert net["twins_of_self"] == 1 and f"another process holds this member's key: process {twin}" in log_text
        else:
            assert net["twins"] == 1
            assert re.search(f"two processes hold the key of robot 2: process [0-9a-f]{{16}} .*, kept, and process "
                             f"{twin} .*, refused", log_text), log_text[-3000:]  # fmt: skip
    assert tr.counts["collector_twins"] == 1
    assert {k: v for k, v in tr.counts.items() if k.startswith("collector_auth_")} == {
        "collector_auth_twin": got["received"]["collector"]}  # fmt: skip
    res = team_result(tr, src, "rdl")
    ref = reference(src, "rdl")
    assert res.stats["reports"] == 3 and res.stats["recorded_provisional_only"] == 0
    for r, t in ref.tracks.items():
        np.testing.assert_array_equal(res.tracks[r].times, t.times)
        assert np.abs(res.tracks[r].mean - t.mean).max() <= 1e-9 and np.abs(res.tracks[r].cov - t.cov).max() <= 1e-9
