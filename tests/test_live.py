"""Live inputs (issue 18): a robot's odometry and detections streamed as they happen into the networked node.

The acceptance test: a publisher *process* streams a simulated 3-robot team's odometry and detections as CDR ROS 2
messages in rmw_zenoh's layout, in real time (2x); three ``swarmloc node --source ros2:...`` processes localize from
them live; their final beliefs equal the in-process replay of the same decoded messages to 1e-6. Also: the Python
API (three LiveNodes) equals the in-process run; the feed refuses stale, future, overlapping and non-finite inputs
with their reasons; malformed CDR and JSON inputs are counted, never crash; the rmw_zenoh liveliness token keys
round-trip and a liveliness subscriber on 127.0.0.1 sees them. Zenoh peers on 127.0.0.1 only, bounded in time.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from _ros_input import decoded_events

from swarmloc.estimators import make_team, node_options
from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.live import LiveNode
from swarmloc.live.ros_input import RosInput, RosInputPublisher, detection_cdr, odometry_cdr
from swarmloc.live.zenoh_input import InputPublisher, ZenohInput, decode_input, encode_event, input_key
from swarmloc.net.auth import open_envelope
from swarmloc.net.feed import LiveFeed
from swarmloc.net.rosgraph import Entity, entity_key, parse_entity_key, qos_key
from swarmloc.net.schema import Belief, Report
from swarmloc.net.team import TeamRun
from swarmloc.net.transport import free_ports, open_session, robot_key
from swarmloc.runner import run

pytestmark = pytest.mark.network


HERE = Path(__file__).resolve().parent
SIM = dict(robots=3, duration=4.0, seed=1)


def reference(src, events, est: str = "rdl"):
    nodes = make_team(est, src.initial, **node_options(est, src.config, src.landmarks))
    return run(nodes, sorted(events, key=lambda e: e.stamp), src.record_times())


def max_diff(beliefs: dict, ref) -> float:
    """Largest difference of the final beliefs (mean as x, y, theta; covariance) to ``ref``'s tracks."""
    tr = TeamRun.__new__(TeamRun)
    tr.beliefs = {}
    for b in beliefs.values():
        tr.keep(b)
    got = tr.tracks()
    assert sorted(got) == sorted(ref.tracks)
    d = 0.0
    for r, want in ref.tracks.items():
        np.testing.assert_array_equal(got[r].times, want.times)
        d = max(d, float(np.abs(got[r].mean - want.mean).max()), float(np.abs(got[r].cov - want.cov).max()))
    return d


def owner(e) -> int:
    return e.robot if isinstance(e, Odometry) else e.observer


def wait_for(cond, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.02)


# ------------------------------------------------------------------------------------------------ ROS 2 graph
def test_liveliness_key_builds_and_parses_back_in_rmw_zenohs_layout():
    e = Entity(0, "q1w2e3r4t5y6", 1, 32, "MP", "/", "/", "talker", "/chatter", "std_msgs::msg::dds_::String_",
               "RIHS01_abc", qos_key())  # fmt: skip
    key = entity_key(e)
    # @ros2_lv/<domainid>/<zid>/<nid>/<id>/<entity>/<enclave>/<namespace>/<nodename>/<topic>/<type>/<hash>/<qos>
    assert (
        key
        == "@ros2_lv/0/q1w2e3r4t5y6/1/32/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/RIHS01_abc/:2:,10:,:,:,,"
    )
    assert parse_entity_key(key) == e
    node = Entity(3, "ab", 7, 7, "NN", "/", "/swarmloc/lab", "robot1")
    assert entity_key(node) == "@ros2_lv/3/ab/7/7/NN/%/%swarmloc%lab/robot1"
    assert parse_entity_key(entity_key(node)) == node
    assert qos_key(depth=42, durability=1) == "::,:,:,:,,"  # rmw_zenoh's defaults leave every field empty
    for bad in ("@ros2_lv/0/ab/1/1/NN/%/%", "@ros2_lv/0/ab/1/1/XX/%/%/n", "@ros2_lv/x/ab/1/1/NN/%/%/n",
                "@ros2_lv/0/ab/1/1/MP/%/%/n"):  # fmt: skip
        with pytest.raises(ValueError):
            parse_entity_key(bad)
    with pytest.raises(ValueError, match="node name"):
        entity_key(Entity(0, "ab", 1, 1, "NN", "/", "/", "1robot"))


def test_a_liveliness_subscriber_on_localhost_sees_the_nodes_tokens():
    p = free_ports(2)
    a = open_session([f"tcp/127.0.0.1:{p[0]}"])
    b = open_session([f"tcp/127.0.0.1:{p[1]}"], [f"tcp/127.0.0.1:{p[0]}"])
    try:
        seen: list[str] = []
        sub = b.liveliness().declare_subscriber("@ros2_lv/5/**", history=True, handler=lambda s: seen.append(
            str(s.key_expr)))  # fmt: skip
        feed = LiveFeed(1, 0.0)
        ri = RosInput(a, feed, team="lab", domain=5)
        ri.open()
        wait_for(lambda: len(seen) >= 4, 10.0, "the tokens of a node and its 3 subscriptions")
        ents = [parse_entity_key(k) for k in seen]
        assert {e.kind for e in ents} == {"NN", "MS"}
        assert {e.topic for e in ents if e.kind == "MS"} == {f"/swarmloc/lab/robot1/{w}" for w in
                                                             ("odom", "detections", "input_progress")}  # fmt: skip
        assert all(e.zid == str(a.info.zid()) and e.node == "robot1_input" and e.domain == 5 for e in ents)
        ri.close()
        sub.undeclare()
    finally:
        b.close()
        a.close()


# ------------------------------------------------------------------------------------------------ the feed
def test_the_feed_refuses_stale_future_overlapping_and_bad_inputs_with_their_reason():
    f = LiveFeed(1, 10.0, window=0.2, max_ahead=5.0)
    det = lambda t, obs=1: Detection(obs, t, "pose", np.zeros(3), np.eye(3) * 0.01, 2)  # noqa: E731
    assert f.push(Odometry(1, 10.0, 10.1, 0.2, 0.0))
    assert f.push(det(10.05))
    assert not f.push(Odometry(1, 10.05, 10.2, 0.2, 0.0))  # starts before the previous one ended
    assert not f.push(det(9.0))  # before the node's start
    assert not f.push(det(10.1 + 5.5))  # far in the future
    assert not f.push(det(10.3, obs=2))  # another robot's
    assert not f.push(Odometry(1, 10.1, 10.2, math.nan, 0.0))
    for k in range(2, 10):
        assert f.push(Odometry(1, 10.0 + k / 10 - 0.1, 10.0 + k / 10, 0.2, 0.0))
    taken, w = f.take()  # released: stamped before min(latest - window, odometry end) = 10.7
    assert w == pytest.approx(10.7) and [round(e.stamp, 2) for e in taken][:3] == [10.0, 10.05, 10.1]
    assert all(e.stamp < w for e in taken)
    assert not f.push(det(10.5))  # the driver may have read past it
    f.end()
    assert not f.push(det(11.0))
    assert dict(f.reasons) == {"overlap": 1, "stale": 2, "future": 1, "not_own": 1, "bad_value": 1, "ended": 1}
    rest, w = f.take()
    assert w == math.inf and f.exhausted and len(taken) + len(rest) == f.counts["accepted"] == 10


def test_an_end_with_a_count_waits_for_the_inputs_still_on_their_way():
    """The end of a stream may overtake its last inputs (other keys): with the count sent, they are still taken."""
    f = LiveFeed(0, 0.0)
    assert f.push(Odometry(0, 0.0, 0.1, 0.2, 0.0))
    f.end(count=3)
    assert not f.exhausted and f.watermark < 0.1
    f.dropped()  # a malformed one, refused by the input layer, counts
    assert not f.exhausted
    assert f.push(Detection(0, 0.1, "pose", np.zeros(3), np.eye(3) * 0.01, 1))  # late, but announced: taken
    assert f.take()[1] == math.inf and f.exhausted and not f.push(Odometry(0, 0.1, 0.2, 0.2, 0.0))
    g = LiveFeed(0, 0.0)
    g.end(count=2, grace=0.0)  # nothing more comes: the grace ends it, the shortfall counted
    assert g.exhausted and g.counts["missing"] == 2


def test_the_api_turns_velocities_and_wheel_travel_into_odometry_and_refuses_what_is_wrong():
    node = LiveNode(0, ((0.0, 0.0, 0.0), np.eye(3) * 0.01), team="unit", roster=[0, 1], t0=5.0, start=False)
    try:
        assert node.velocity(5.1, 0.3, 0.1)  # [5.0, 5.1]
        assert node.wheels(5.3, 0.05, 0.07, track=0.4)  # [5.1, 5.3]: v = 0.06 / 0.2, w = 0.02 / 0.4 / 0.2
        assert node.detection(5.2, (1.0, 0.0, 0.1), np.eye(3) * 0.01, target=1)
        assert not node.wheels(5.3, 0.1, 0.1, track=0.4)  # no time passed since the last interval
        assert not node.detection(4.0, (1.0, 0.0, 0.1), np.eye(3) * 0.01, target=1)  # before the start
        assert not node.odometry(5.3, 5.4, math.inf, 0.0)
        assert dict(node.feed.reasons) == {"bad_value": 2, "stale": 1}
        node.end()
        taken, _ = node.feed.take()
        assert [type(e).__name__ for e in taken] == ["Odometry", "Odometry", "Detection"]
        assert taken[1].t0 == 5.1 and taken[1].t1 == 5.3
        assert taken[1].v == pytest.approx(0.3) and taken[1].w == pytest.approx(0.25)
        assert node.latest is None and node.x is None and node.P is None
        with pytest.raises(KeyError):
            node.belief(5.0)
    finally:
        node.session.close()
    now = LiveNode(0, ((0.0, 0.0, 0.0), np.eye(3) * 0.01), team="unit", roster=[0], start=False)
    try:
        assert abs(now.feed.t0 - time.time()) < 5.0  # t0 None: the system clock's now
    finally:
        now.session.close()


def test_inputs_decode_and_malformed_ones_are_refused_with_their_reason():
    d = Detection(1, 2.0, "pose", np.array([1.0, 2.0, 0.3]), np.diag([0.01, 0.01, 0.001]), 2)
    what, raw = encode_event(d)
    got = decode_input(what, raw, 1)
    assert what == "det" and got.t == 2.0 and np.array_equal(got.z, d.z) and np.array_equal(got.cov, d.cov)
    bad = {
        b"{not json": "bad_schema",
        b'{"t": 1, "kind": "pose", "z": [1, 2], "cov": [1, 0, 0, 0, 1, 0, 0, 0, 1]}': "bad_size",
        b'{"t": 1, "kind": "sonar", "z": [1], "cov": [1]}': "bad_kind",
        b'{"t": 1, "kind": "range", "z": [1], "cov": [-1]}': "bad_covariance",
        b'{"t": 1, "kind": "range", "z": [1], "cov": [1], "extra": 0}': "bad_schema",
        b" " * 9000: "too_large",
    }
    for payload, reason in bad.items():
        with pytest.raises(ValueError) as exc:
            decode_input("det", payload, 1)
        assert exc.value.reason == reason


def test_input_publishers_block_instead_of_dropping():
    """Every input publisher waits for room in the link's queue: Zenoh's default (DROP) loses puts on a loaded
    machine, and an input stream ends with the count of what was sent."""
    s = open_session([f"tcp/127.0.0.1:{free_ports(1)[0]}"])
    try:
        ros_pub, json_pub = RosInputPublisher(s, 0, team="lab"), InputPublisher(s, "lab", 0)
        pubs = [*ros_pub._pubs.values(), *json_pub._pubs.values()]
        assert len(pubs) >= 4
        assert all(p.congestion_control == zenoh.CongestionControl.BLOCK for p in pubs)
        ros_pub.close()
        json_pub.close()
    finally:
        s.close()


def test_malformed_cdr_is_counted_and_the_node_keeps_reading():
    p = free_ports(2)
    a = open_session([f"tcp/127.0.0.1:{p[0]}"])
    b = open_session([f"tcp/127.0.0.1:{p[1]}"], [f"tcp/127.0.0.1:{p[0]}"])
    try:
        feed = LiveFeed(0, 0.0)
        ri = RosInput(a, feed, team="lab")
        ri.open()
        zi = ZenohInput(a, feed, "lab")
        zi.open()
        pub = RosInputPublisher(b, 0, team="lab")
        block = zenoh.CongestionControl.BLOCK  # each junk sample is counted: none may be dropped under load
        raw = b.declare_publisher(ri_key(ri, "odom"), congestion_control=block)
        jpub = b.declare_publisher(input_key("lab", 0, "det"), congestion_control=block)
        assert pub.wait_matched(10.0)
        wait_for(lambda: raw.matching_status.matching and jpub.matching_status.matching, 10.0, "the subscriptions")
        pub.odometry(0.1, 0.2, 0.0)
        for junk in (b"", b"\x00\x01\x00\x00" + b"\xff" * 3, os.urandom(200), b"\x00" * 5000):
            raw.put(junk)
        jpub.put(b"[1, 2")
        pub.odometry(0.2, 0.2, 0.0)
        pub.odometry(0.15, 0.2, 0.0)  # before the previous one
        det = Detection(0, 0.18, "pose", np.array([1.0, 0.0, 0.0]), np.eye(3) * 0.01, 1)
        pub.detection(det)
        # every sample decided, not only received: the input counts it received before it decodes and pushes it
        decided = lambda c: c["pushed"] + c["refused_by_feed"] + c["rejected"]  # noqa: E731
        wait_for(lambda: decided(ri.counts) >= 8 and decided(zi.counts) >= 1, 10.0, "every sample")
        assert dict(ri.reasons) == {"bad_cdr": 3, "too_large": 1, "stale": 1}
        assert dict(zi.reasons) == {"bad_schema": 1}
        assert ri.counts["no_attachment"] == 4 and ri.counts["pushed"] == 3
        assert feed.counts["accepted"] == 3
        ri.close()
        zi.close()
        pub.close()
    finally:
        b.close()
        a.close()


def ri_key(ri: RosInput, what: str) -> str:
    from swarmloc.live.ros_input import TOPICS, topic_key

    return topic_key(ri.topics[what], TOPICS[what], ri.domain)


# ------------------------------------------------------------------------------------------------ the Python API
@pytest.mark.parametrize("est", ["rdl", "dekf", "ci", "expfusion", "diekf", "irdl", "fls", "mcl"])
def test_python_api_three_live_nodes_equal_the_in_process_run(est):
    src = load_source("sim:random", **SIM)
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(3)]
    finals: dict = {}
    keep = lambda b: finals.__setitem__((b.robot, b.stamp), b) if b.final else None  # noqa: E731
    nodes = {
        r: LiveNode(
            r,
            src.initial[r],
            team=f"api{os.getpid()}",
            roster=src.robots,
            t0=src.t_start,
            config=src.config,
            estimator=est,
            listen=[eps[i]],
            connect=[e for e in eps if e != eps[i]],
            on_belief=keep,
            record_rate=src.config.record.rate,
        )  # fmt: skip
        for i, r in enumerate(src.robots)
    }
    try:
        # 4x real time, each input once it is known; robot 2's arrive 0.4 s of wall time (1.6 s of data) late
        late = {0: 0.0, 1: 0.0, 2: 0.4}
        known = sorted((e.t / 4 + late[owner(e)], i, e) for i, e in enumerate(src.events)
                       if isinstance(e, Odometry | Detection))  # fmt: skip
        w0 = time.monotonic()
        for due, _, e in known:
            time.sleep(max(0.0, w0 + due - time.monotonic()))
            assert nodes[owner(e)].push(e)
        assert nodes[0].x is not None and nodes[0].P.shape == (3, 3)  # beliefs while it runs
    finally:
        for n in nodes.values():
            n.end()
        reports = {r: n.close(timeout=60) for r, n in nodes.items()}
    assert all(rep is not None and rep.stats["pending"] == 0 for rep in reports.values())
    # lockstep held although robot 2 lagged: no answer was given before its state settled, none revised
    assert (
        sum(rep.net.get("answered_unsettled", 0) + rep.stats.get("revisions_sent", 0) for rep in reports.values()) == 0
    )
    finals = {k: b for k, b in finals.items() if k[1] in set(src.record_times())}
    d = max_diff(finals, reference(src, src.events, est))
    print(f"live API {est}: {len(finals)} final beliefs, max difference to the in-process run {d:.3g}")
    assert d <= 1e-9
    assert nodes[1].belief(src.record_times()[-1]).final


# ------------------------------------------------------------------------------------------------ acceptance
def test_three_node_processes_localize_live_from_a_ros2_publisher_process_as_the_replay_does():
    src = load_source("sim:random", **SIM)
    team = f"liveros{os.getpid()}"
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(4)]
    # each node's ROS input session (loopback, its own), on 127.0.0.2: the connections between 127.0.0.1 endpoints
    # that start meanwhile never take one of its ports (nor connect a socket to itself there)
    inputs = [f"tcp/127.0.0.2:{p}" for p in free_ports(3, host="127.0.0.2")]
    env = dict(os.environ)
    py = [sys.executable, "-m", "swarmloc.cli"]
    finals: dict = {}
    watch = open_session([eps[3]], eps[:3])
    watch_inputs = open_session([], inputs)  # the input nodes' tokens are on the input sessions

    def collect(sample) -> None:
        b = open_envelope(None, str(sample.key_expr), sample.payload.to_bytes(), team, src.robots, server_ok=False,
                          publication=True).body  # fmt: skip
        if isinstance(b, Belief) and b.final:
            finals[(b.robot, b.stamp)] = b
        elif isinstance(b, Report):
            reports[b.robot] = b

    reports: dict = {}
    graph: list = []
    sub = watch.declare_subscriber(robot_key(team, "*", "*"), handler=collect)
    tokens = [w.liveliness().declare_subscriber("@ros2_lv/0/**", history=True, handler=lambda x: graph.append(
        parse_entity_key(str(x.key_expr))) if x.kind == zenoh.SampleKind.PUT else None)
        for w in (watch, watch_inputs)]  # fmt: skip
    procs = []
    try:
        for i, r in enumerate(src.robots):
            cmd = py + ["node", "--robot", str(r), "--team", team, "--source", "ros2:sim:random", "--robots", "3",
                        "--duration", "4", "--seed", "1", "--estimator", "rdl", "--no-auth", "--max-wall", "90",
                        "--ros-domain", "0", "--input-listen", inputs[i],
                        "--listen", eps[i], "--connect", ",".join(e for e in eps if e != eps[i])]  # fmt: skip
            procs.append(subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        pub = subprocess.Popen([sys.executable, str(HERE / "live_publisher.py"), "--connect", ",".join(inputs),
                                "--team", team, "--speed", "1", "--duration", "4", "--seed", "1"],
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
        procs.append(pub)
        outs = [p.communicate(timeout=120) for p in procs]
        codes = [p.returncode for p in procs]
        assert codes == [0, 0, 0, 0], (codes, [o[1][-600:] for o in outs])
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        sub.undeclare()
        for t in tokens:
            t.undeclare()
        watch_inputs.close()
        watch.close()
    # each node was in the ROS graph: its node with its pose publisher, its input node with its 3 subscriptions
    ns = f"/swarmloc/{team}"
    for r in src.robots:
        mine = [e for e in graph if e.namespace == ns and e.node in (f"robot{r}", f"robot{r}_input")]
        assert sorted((e.kind, e.topic) for e in mine) == sorted(
            [("NN", None), ("MP", f"{ns}/robot{r}/pose"), ("NN", None)]
            + [("MS", f"{ns}/robot{r}/{w}") for w in ("detections", "input_progress", "odom")]
        )
    # the replay: the same messages, decoded as the nodes decode them
    events = []
    for r in src.robots:
        own = src.own_events(r)
        odom = [odometry_cdr(e.t1, e.v, e.w) for e in own if isinstance(e, Odometry)]
        dets = [detection_cdr(e) for e in own if isinstance(e, Detection)]
        events += decoded_events(r, src.t_start, odom, dets)
    ref = reference(src, events)
    assert sum(tr.times.size for tr in ref.tracks.values()) == len(finals) == 3 * src.record_times().size
    d = max_diff(finals, ref)
    print(f"live ros2 processes: {len(finals)} final beliefs, max difference to the replay {d:.3g}")
    assert d <= 1e-9
    assert sorted(reports) == src.robots and sum(r.stats["fused"] for r in reports.values()) > 30
    assert sum(r.net.get("answered_unsettled", 0) + r.stats["revisions_sent"] for r in reports.values()) == 0


def test_three_nodes_localize_from_swarmlocs_own_input_keys_as_the_in_process_run():
    """``inputs="zenoh"``: the JSON input keys, sent by an InputPublisher on another session, odometry as intervals."""
    src = load_source("sim:random", **SIM)
    team = f"zin{os.getpid()}"
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(4)]
    finals: dict = {}
    keep = lambda b: finals.__setitem__((b.robot, b.stamp), b) if b.final else None  # noqa: E731
    sender = open_session([eps[3]], eps[:3])
    nodes = {
        r: LiveNode(
            r,
            src.initial[r],
            team=team,
            roster=src.robots,
            t0=src.t_start,
            config=src.config,
            inputs="zenoh",
            listen=[eps[i]],
            connect=[e for e in eps if e != eps[i]],
            on_belief=keep,
        )  # fmt: skip
        for i, r in enumerate(src.robots)
    }
    try:
        pubs = {r: InputPublisher(sender, team, r) for r in src.robots}
        assert all(p.wait_matched(20.0) for p in pubs.values()), "the nodes' input subscriptions do not match"
        known = sorted((e.t, i, e) for i, e in enumerate(src.events) if isinstance(e, Odometry | Detection))
        w0 = time.monotonic()
        for t, _, e in known:
            time.sleep(max(0.0, w0 + t / 4 - time.monotonic()))
            pubs[owner(e)].push(e)
        for p in pubs.values():
            p.end()
        reports = {r: n.close(timeout=60) for r, n in nodes.items()}
    finally:
        for n in nodes.values():
            n.close(timeout=1)
        sender.close()
    assert all(rep is not None and rep.stats["pending"] == 0 for rep in reports.values())
    assert all(n.feed.counts["accepted"] == len(src.own_events(r)) and not n.feed.reasons for r, n in nodes.items())
    finals = {k: b for k, b in finals.items() if k[1] in set(src.record_times())}
    d = max_diff(finals, reference(src, src.events))
    print(f"live zenoh inputs: {len(finals)} final beliefs, max difference to the in-process run {d:.3g}")
    assert d <= 1e-9
