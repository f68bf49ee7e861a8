"""Who may write a robot's live inputs: ``zenoh:`` inputs signed by the robot, ``ros2:`` inputs heard on loopback only.

A stranger that reached the team's network once moved a robot by writing its inputs: one unsigned end of stream and
robot 1 read none of its 120 odometry intervals; odometry intervals at +5 m/s racing the genuine ones got every
genuine one refused as overlapping. Here a stranger *process* without a key (``tests/live_attacker.py``: Zenoh,
JSON and rosbags only) sends all three attacks (injected detections, the odometry race, the end) to every robot:

* to three ``swarmloc node --source zenoh:`` processes and to three ``LiveNode(inputs="zenoh")`` (the Python API):
  none accepted, every frame refused and counted by category in each node's report (``input_auth_unsigned``,
  ``input_auth_key_mismatch`` for frames forged with a key of its own), the final beliefs equal the in-process
  run on the genuine inputs (the clean run) to 1e-9; an attacker holding robot 2's valid key writing robots 0 and
  1's inputs is refused ``not_owner``, counted;
* from another host (a network namespace joined by a veth pair, ``tests/_netns.py``) to three ``swarmloc node
  --source ros2:`` processes whose team sessions listen on that link: it reaches the team (it sees the nodes'
  liveliness tokens), but none of its ROS 2 messages reaches an input (they are read on loopback only), the input
  endpoints refuse its connections, and the beliefs equal the replay of the genuine messages.

Also: replays, stale and future stamps, frames in the team's signing context and oversize frames are refused with
their categories; a refused frame does not count towards the stream's end; the same attacks against an input that
does not protect them (``zenoh:`` without a roster, ``ros2:`` on a reachable session) are taken (they are real).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import msgspec
import pytest
from _netns import stranger_host
from _ros_input import decoded_events
from test_live import SIM, max_diff, owner, reference, wait_for

from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.live import LiveNode
from swarmloc.live.ros_input import RosInput, detection_cdr, odometry_cdr
from swarmloc.live.source import INPUT_LISTEN, check_loopback, input_endpoints, live_inputs
from swarmloc.live.zenoh_input import InputPublisher, ZenohInput, input_key
from swarmloc.net.auth import INPUT_CONTEXT, Auth, AuthRejected, Signer, TeamKeys, Verifier, load_private, open_envelope
from swarmloc.net.feed import LiveFeed
from swarmloc.net.schema import Belief
from swarmloc.net.transport import alive_key, free_ports, open_session, robot_key

pytestmark = [pytest.mark.network, pytest.mark.slow]

HERE = Path(__file__).resolve().parent
ATTACKER = HERE / "live_attacker.py"
PY = [sys.executable, "-m", "swarmloc.cli"]


@pytest.fixture
def keys(tmp_path):
    k = TeamKeys([0, 1, 2], tmp_path / "keys")
    yield k
    k.close()


def attack(mode: str, connect: list[str], robots, src, *extra: str, run=subprocess.run) -> dict:  # noqa: ANN001
    """Run the attacker process (its own session); its JSON summary."""
    cmd = [sys.executable, str(ATTACKER), mode, "--connect", ",".join(connect), "--robots",
           ",".join(map(str, robots)), "--t0", repr(src.t_start), "--t1", repr(src.t_end), *extra]  # fmt: skip
    out = run(cmd, capture_output=True, text=True, timeout=90)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def input_counts(net: dict) -> dict:
    """A report's refusals of inputs (input layer and feed), the zero ones left out."""
    kept = ("input_seen", "input_accepted")
    return {k: v for k, v in net.items() if k.startswith(("input_", "feed_")) and k not in kept and v}


@contextmanager
def processes() -> Iterator[list[subprocess.Popen]]:
    """A list to start processes into; those still running at the end are killed."""
    procs: list[subprocess.Popen] = []
    try:
        yield procs
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()


def start_node(robot: int, team: str, source: str, out: Path, listen: str, connect: str, *extra: str):  # noqa: ANN201
    """``swarmloc node`` for ``robot`` of the 3-robot, 4 s ``sim:random`` team (seed 1, ``rdl``) from ``source``."""
    cmd = PY + ["node", "--robot", str(robot), "--team", team, "--source", source, "--robots", "3", "--duration", "4",
                "--seed", "1", "--estimator", "rdl", "--max-wall", "90", "--out", str(out), "--listen", listen,
                "--connect", connect, *extra]  # fmt: skip
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def all_exit_0(procs: list[subprocess.Popen], timeout: float = 120.0) -> None:
    outs = [p.communicate(timeout=timeout) for p in procs]
    assert [p.returncode for p in procs] == [0] * len(procs), [o[1][-800:] for o in outs]


class Finals:
    """Final beliefs published on the team's network, opened with the roster (thread-safe)."""

    def __init__(self, session, team: str, robots, roster) -> None:  # noqa: ANN001
        self.auth, self.team, self.robots = Auth(roster), team, robots
        self.beliefs: dict = {}
        self._lock = threading.Lock()
        self.sub = session.declare_subscriber(robot_key(team, "*", "belief"), handler=self.on)

    def on(self, sample) -> None:  # noqa: ANN001
        with self._lock:
            b = open_envelope(self.auth, str(sample.key_expr), sample.payload.to_bytes(), self.team, self.robots,
                              server_ok=False, publication=True).body  # fmt: skip
            if isinstance(b, Belief) and b.final:
                self.beliefs[(b.robot, b.stamp)] = b

    def at(self, times) -> dict:  # noqa: ANN001
        with self._lock:
            return {k: b for k, b in self.beliefs.items() if k[1] in set(times)}


def stream(pubs: dict, src, speed: float = 4.0) -> None:  # noqa: ANN001
    """Every genuine input of ``src`` once it is known, ``speed`` times real time, then each robot's end."""
    known = sorted((e.t, i, e) for i, e in enumerate(src.events) if isinstance(e, Odometry | Detection))
    w0 = time.monotonic()
    for t, _, e in known:
        time.sleep(max(0.0, w0 + (t - src.t_start) / speed - time.monotonic()))
        pubs[owner(e)].push(e)
    for p in pubs.values():
        p.end()


# ------------------------------------------------------------------------------------------------ the frames
def test_inputs_are_signed_in_a_context_of_their_own(keys):
    """A frame signed for the team does not open as an input, nor an input as a team frame: the driver's inputs and
    the node's team frames, signed with one key in two processes, never share a replay window."""
    roster, key1 = keys.roster, load_private(keys.files[1])
    team, inputs = Signer(1, key1), Signer(1, key1).for_context(INPUT_CONTEXT)
    k = input_key("lab", 1, "odom")
    assert Verifier(roster, context=INPUT_CONTEXT).open(k, inputs.seal(k, b"{}"), publication=True) == (1, b"{}")
    for verifier, frame in ((Verifier(roster, context=INPUT_CONTEXT), team.seal(k, b"{}")),
                            (Verifier(roster), inputs.seal(k, b"{}"))):  # fmt: skip
        with pytest.raises(AuthRejected) as exc:
            verifier.open(k, frame, publication=True)
        assert exc.value.category == "bad_signature"
    with pytest.raises(ValueError, match="robot 1's own key"):
        InputPublisher(None, "lab", 1, auth=keys.auth(2))


def test_signed_inputs_refuse_strangers_replays_and_old_frames_by_category(keys):
    """One ZenohInput with the roster: the robot's own frames are taken; unsigned JSON, robot 2's key, a replayed
    frame, stamps 60 s old or ahead, a team-context frame and an oversize one are refused by category, in
    ``ZenohInput.reasons`` and in the feed's summary (the node's report); none counts towards the end's count."""
    p = free_ports(2)
    a = open_session([f"tcp/127.0.0.1:{p[0]}"])
    b = open_session([f"tcp/127.0.0.1:{p[1]}"], [f"tcp/127.0.0.1:{p[0]}"])
    try:
        feed = LiveFeed(1, 0.0)
        zi = ZenohInput(a, feed, "lab", keys.roster)
        zi.open()
        pub = InputPublisher(b, "lab", 1, auth=keys.auth(1))
        raw = {w: b.declare_publisher(input_key("lab", 1, w)) for w in ("odom", "det", "progress")}
        captured: list[bytes] = []
        spy = b.declare_subscriber(input_key("lab", 1, "odom"), handler=lambda s: captured.append(s.payload.to_bytes()))
        assert pub.wait_matched(10.0)
        wait_for(lambda: all(x.matching_status.matching for x in raw.values()), 10.0, "the input's subscription")
        pub.push(Odometry(1, 0.0, 0.1, 0.2, 0.0))
        wait_for(lambda: zi.counts["pushed"] == 1 and captured, 10.0, "the genuine odometry")
        odom, end = msgspec.json.encode({"t0": 0.1, "t1": 0.2, "v": 5.0, "w": 0.0}), b'{"end": true}'
        ko, kp = input_key("lab", 1, "odom"), input_key("lab", 1, "progress")
        robot2 = keys.auth(2).signer.for_context(INPUT_CONTEXT)
        old, ahead = (Signer(1, load_private(keys.files[1]), lambda d=d: time.time_ns() + d, INPUT_CONTEXT)
                      for d in (-60 * 10**9, 60 * 10**9))  # fmt: skip
        frames = {  # category -> (input, frame)
            "auth_unsigned": [("odom", odom), ("progress", end)],
            "auth_not_owner": [("odom", robot2.seal(ko, odom)), ("progress", robot2.seal(kp, end))],
            "auth_replay": [("odom", captured[0])],
            "auth_stale": [("odom", old.seal(ko, odom))],
            "auth_future": [("odom", ahead.seal(ko, odom))],
            "auth_bad_signature": [("odom", keys.auth(1).seal(ko, odom))],  # the team's context, on an input key
            "too_large": [("odom", b"SLS1" + bytes(9000))],
        }
        pub.sent += 1  # the end announces one more input than the one sent: the end waits for it
        pub.end()
        for fs in frames.values():
            for what, f in fs:
                raw[what].put(f)
        want = {k: len(v) for k, v in frames.items()}
        wait_for(lambda: zi.counts["rejected"] == sum(want.values()), 10.0, "every refusal")
        assert dict(zi.reasons) == want
        assert feed.watermark < math.inf and feed.ending  # the end still waits: no refused frame counted towards it
        assert feed.counts["accepted"] == 1 and not feed.reasons
        summary = feed.summary()
        assert {k: v for k, v in summary.items() if k.startswith("input_auth") or k == "input_too_large"} == {
            f"input_{k}": v for k, v in want.items()
        }
        pub.push(Odometry(1, 0.1, 0.2, 0.2, 0.0))
        wait_for(lambda: feed.watermark == math.inf, 10.0, "the end, once the genuine input came")
        assert summary["input_seen"] == 1 and feed.summary()["input_seen"] == 2
        spy.undeclare()
        zi.close()
        pub.close()
    finally:
        b.close()
        a.close()


@pytest.mark.parametrize("mode", ["zenoh", "ros2"])
def test_an_unprotected_input_takes_the_strangers_inputs(mode):
    """The control: the attacker process's inputs reach an input that does not protect them (``zenoh:`` without a
    roster, ``--no-auth``; ``ros2:`` on a session the attacker can reach): its detections and racing odometry are
    accepted and its end closes the stream. (The tests above: the same attacks, all refused.)"""
    src = load_source("sim:random", **SIM)
    p = free_ports(1)
    a = open_session([f"tcp/127.0.0.1:{p[0]}"])
    try:
        feed = LiveFeed(1, src.t_start)
        sub = ZenohInput(a, feed, "lab") if mode == "zenoh" else RosInput(a, feed, team="lab")
        sub.open()
        token = a.liveliness().declare_token(alive_key("lab", 1))  # what the ros2 attacker waits for
        extra = ["--scope", "lab"] if mode == "zenoh" else ["--team", "lab"]
        got = attack(mode, [f"tcp/127.0.0.1:{p[0]}"], [1], src, *extra)
        sent = got["sent"]["unsigned"]["1"] if mode == "zenoh" else got["sent"]["1"]
        wait_for(lambda: sub.counts["received"] == sent, 10.0, "the attacker's inputs")
        # every input but the end reached the feed (some detections may be stale: the keys are not ordered with each
        # other), the racing odometry was accepted, the end took effect
        assert feed.counts["accepted"] + feed.counts["refused"] == sent - 1 and not sub.reasons
        assert feed.counts["odometry"] > 0 and feed.watermark == math.inf
        token.undeclare()
        sub.close()
    finally:
        a.close()


def test_input_endpoints_are_loopback_only():
    for ok in ("tcp/127.0.0.1:7448", "tcp/[::1]:7448", "udp/127.0.0.5:9", "unixsock-stream//tmp/in.sock"):
        assert check_loopback(ok, "--input-listen") == ok
    for bad in ("tcp/0.0.0.0:7448", "tcp/[::]:7448", "tcp/10.231.0.1:7448", "tcp/localhost:7448", "tcp/127.0.0.1"):
        with pytest.raises(ValueError, match="--input-connect"):
            check_loopback(bad, "--input-connect")
    assert input_endpoints() == ([INPUT_LISTEN], [])
    assert input_endpoints((), ["tcp/127.0.0.1:7447"]) == ([], ["tcp/127.0.0.1:7447"])
    with pytest.raises(ValueError, match="are for ros2"):
        live_inputs("zenoh", team="lab", input_listen=["tcp/127.0.0.1:1"])
    cmd = ["node", "--robot", "1", "--team", "lab", "--source", "ros2:sim:random", "--no-auth", "--input-listen",
           "tcp/0.0.0.0:7448"]  # fmt: skip
    out = subprocess.run(PY + cmd, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--input-listen: 'tcp/0.0.0.0:7448' is not a loopback endpoint" in out.stderr


# ------------------------------------------------------------------------------------------------ zenoh: end to end
def test_a_stranger_moves_no_zenoh_input_of_signed_node_processes(tmp_path, keys):
    """Three ``swarmloc node --source zenoh:`` processes with keys; a keyless attacker process sends each robot its
    three attacks unsigned and forged (signed with a key of its own), before the genuine inputs (signed by each
    robot's key in the test's process, the robots' drivers) stream at 4x real time."""
    src = load_source("sim:random", **SIM)
    team = f"zauth{os.getpid()}"
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(4)]
    out = tmp_path / "out"
    sender = open_session([eps[3]], eps[:3])
    finals = Finals(sender, team, src.robots, keys.roster)
    try:
        with processes() as procs:
            for i, r in enumerate(src.robots):
                others = ",".join(e for e in eps[:3] if e != eps[i])
                procs.append(start_node(r, team, "zenoh:sim:random", out, eps[i], others, *keys.args(r)))
            pubs = {r: InputPublisher(sender, team, r, auth=keys.auth(r)) for r in src.robots}
            assert all(p.wait_matched(30.0) for p in pubs.values()), "the nodes' input subscriptions do not match"
            got = attack("zenoh", eps[:3], src.robots, src, "--scope", team, "--forge")
            stream(pubs, src)
            all_exit_0(procs)
    finally:
        finals.sub.undeclare()
        sender.close()
    for r in src.robots:
        net = json.loads((out / f"robot{r}.json").read_text())["net"]
        print(f"robot {r}: attacker sent {got['sent']}; refused {input_counts(net)}")
        assert net["input_accepted"] == net["input_seen"] == len(src.own_events(r))
        assert input_counts(net) == {"input_auth_unsigned": got["sent"]["unsigned"][str(r)],
                                     "input_auth_key_mismatch": got["sent"]["forged"][str(r)]}  # fmt: skip
    d = max_diff(finals.at(src.record_times()), reference(src, src.events))
    print(f"zenoh: inputs under attack: max difference to the clean in-process run {d:.3g}")
    assert d <= 1e-9


def test_a_stranger_and_robot_2s_key_move_no_input_of_live_nodes(keys):
    """The Python API's transport: three ``LiveNode(inputs="zenoh")`` with keys; the keyless attacker process (unsigned
    and forged frames to every robot) and an attacker process holding robot 2's valid key (robots 0 and 1's inputs,
    signed as robot 2: ``not_owner``) run before the genuine signed inputs stream."""
    src = load_source("sim:random", **SIM)
    team = f"zapi{os.getpid()}"
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(4)]
    sender = open_session([eps[3]], eps[:3])
    finals = Finals(sender, team, src.robots, keys.roster)
    same = dict(team=team, roster=src.robots, t0=src.t_start, config=src.config, inputs="zenoh")
    nodes = {
        r: LiveNode(
            r, src.initial[r], auth=keys.auth(r), listen=[eps[i]], connect=[e for e in eps[:3] if e != eps[i]], **same
        )
        for i, r in enumerate(src.robots)
    }
    try:
        pubs = {r: InputPublisher(sender, team, r, auth=keys.auth(r)) for r in src.robots}
        assert all(p.wait_matched(20.0) for p in pubs.values()), "the nodes' input subscriptions do not match"
        stranger = attack("zenoh", eps[:3], src.robots, src, "--scope", team, "--forge")
        insider = attack("zenoh", eps[:3], [0, 1], src, "--scope", team, "--key", str(keys.files[2]), "--member", "2")
        stream(pubs, src)
        reports = {r: n.close(timeout=60) for r, n in nodes.items()}
    finally:
        for n in nodes.values():
            n.close(timeout=1)
        finals.sub.undeclare()
        sender.close()
    for r, rep in reports.items():
        want = {"input_auth_unsigned": stranger["sent"]["unsigned"][str(r)],
                "input_auth_key_mismatch": stranger["sent"]["forged"][str(r)]}  # fmt: skip
        if r in (0, 1):
            want["input_auth_not_owner"] = insider["sent"]["member"][str(r)]
        print(f"robot {r}: refused {input_counts(rep.net)}")
        assert rep.net["input_accepted"] == rep.net["input_seen"] == len(src.own_events(r))
        assert input_counts(rep.net) == want
        assert rep.net.get("rejected", 0) == 0  # the team's own frames (same keys, other processes) all taken
    d = max_diff(finals.at(src.record_times()), reference(src, src.events))
    print(f"LiveNode: inputs under attack: max difference to the clean in-process run {d:.3g}")
    assert d <= 1e-9


# ------------------------------------------------------------------------------------------------ ros2: off-host
def test_a_stranger_off_host_moves_no_ros2_input(tmp_path, keys):
    """Three ``swarmloc node --source ros2:`` processes whose team sessions also listen on a veth link to a second
    host (a network namespace); a keyless stranger there connects to the team, sees the nodes' liveliness tokens and
    publishes the three attacks on every robot's rmw_zenoh input keys before the genuine ROS 2 publisher process
    (on this host, connected to the nodes' loopback input endpoints) streams: nothing of it arrives."""
    src = load_source("sim:random", **SIM)
    team = f"rauth{os.getpid()}"
    out = tmp_path / "out"
    with stranger_host() as ns, processes() as procs:
        local = [f"tcp/127.0.0.1:{p}" for p in free_ports(4)]
        shared = [f"tcp/{ns.here}:{p}" for p in free_ports(3, host=ns.here)]
        inputs = [f"tcp/127.0.0.2:{p}" for p in free_ports(3, host="127.0.0.2")]  # no race with 127.0.0.1's connections
        watch = open_session([local[3]], local[:3])
        finals = Finals(watch, team, src.robots, keys.roster)
        try:
            for i, r in enumerate(src.robots):
                others = ",".join(e for e in local[:3] if e != local[i])
                procs.append(start_node(r, team, "ros2:sim:random", out, f"{local[i]},{shared[i]}", others,
                                        "--input-listen", inputs[i], *keys.args(r)))  # fmt: skip
            probes = ",".join(f"{ns.here}:{e.rsplit(':', 1)[1]}" for e in inputs)
            got = attack("ros2", shared, src.robots, src, "--team", team, "--probe", probes, run=ns.run)
            pub = subprocess.Popen([sys.executable, str(HERE / "live_publisher.py"), "--connect", ",".join(inputs),
                                    "--team", team, "--speed", "2", "--duration", "4", "--seed", "1"],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
            procs.append(pub)
            all_exit_0(procs)
        finally:
            finals.sub.undeclare()
            watch.close()
    print(f"ros2 stranger: {got}")
    assert got["alive"] == src.robots  # it reached the team's network
    assert not got["matched"] and sum(got["sent"].values()) > 0  # ... where nobody subscribes to the inputs
    assert all("ConnectionRefused" in v for v in got["probes"].values()), got["probes"]
    events = []
    for r in src.robots:
        net = json.loads((out / f"robot{r}.json").read_text())["net"]
        assert net["input_accepted"] == net["input_seen"] == len(src.own_events(r)), net
        assert input_counts(net) == {}
        own = src.own_events(r)
        odom = [odometry_cdr(e.t1, e.v, e.w) for e in own if isinstance(e, Odometry)]
        events += decoded_events(r, src.t_start, odom, [detection_cdr(e) for e in own if isinstance(e, Detection)])
    d = max_diff(finals.at(src.record_times()), reference(src, events))
    print(f"ros2: a stranger off-host: max difference to the clean replay {d:.3g}")
    assert d <= 1e-9
