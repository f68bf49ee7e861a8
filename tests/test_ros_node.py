"""The ROS-shaped node (``swarmloc ros``): three robots' nodes localize from ROS 2 messages played in real time on an
in-process bus (the middlewares themselves are tested against separate processes in test_rmw.py and
test_ros_team.py), talking to each other over Zenoh on 127.0.0.1; what they publish (Odometry, TF) equals the
offline replay of the same messages (less any input a node refused as late) to 1e-9, on the system clock and on
``/clock`` (``use_sim_time``)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from _fake_rmw import Bus

from swarmloc.experiments.sources import load_source
from swarmloc.lie import SE2
from swarmloc.net.transport import free_ports, open_session
from swarmloc.rmw import typestore
from swarmloc.ros import convert as cv
from swarmloc.ros.args import RosArgs
from swarmloc.ros.node import RosNode
from swarmloc.ros.params import load_params
from swarmloc.ros.replay import replay_messages
from swarmloc.ros.simulate import team_messages

pytestmark = [pytest.mark.network, pytest.mark.slow]


def _xyt_cov(msg):
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return np.array([p.x, p.y, cv._yaw(q)]), np.asarray(msg.pose.covariance).reshape(6, 6)


def team_params(src, **extra):
    out = {}
    for r in src.robots:
        xyt = SE2.to_xytheta(np.asarray(src.initial[r].mean))
        over = {"robot_id": r, "team_robots": list(src.robots), "no_auth": True, "frequency": 5.0, "window": 1.0,
                "initial_state": [float(v) for v in xyt], "team": "rostest", "initial_covariance": [1e-4] * 3,
                "odom_frame": f"robot{r}/odom", "base_link_frame": f"robot{r}/base_link", **extra}  # fmt: skip
        out[r] = load_params([], over, "swarmloc", f"/robot{r}")
    return out


def run_team_on_bus(src, params, offset, clock=None):
    """Start a node per robot on one bus, play the messages at their ROS times (``clock``: publish /clock too, and
    play as fast as it says), stop; returns (bus, nodes, messages sent per robot)."""
    bus = Bus()
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(len(src.robots))]
    sessions = [open_session([eps[k]], eps[:k]) for k in range(len(src.robots))]
    nodes = {r: RosNode(params[r], name="swarmloc", namespace=f"/robot{r}", args=RosArgs(), middleware=bus.middleware(),
                        team_session=sessions[k]) for k, r in enumerate(src.robots)}  # fmt: skip
    threads = [threading.Thread(target=n.run, kwargs={"max_wall": 60}, daemon=True) for n in nodes.values()]
    for th in threads:
        th.start()
    pub = bus.middleware()
    pubs = {(r, kind): pub.publisher(f"/robot{r}/{'odom' if kind == 'odometry' else 'detections'}", "")
            for r in src.robots for kind in ("odometry", "detections")}  # fmt: skip
    tick = pub.publisher("/clock", "")
    sent = {r: [] for r in src.robots}
    msgs = team_messages(src, offset)
    w0, t_first = time.time() + 0.5, msgs[0][0]
    for t, r, kind, m in msgs:
        delay = w0 + (t - t_first) - time.time()
        if delay > 0:
            time.sleep(delay)
        if clock is not None:
            tick.publish(typestore().types[cv.CLOCK](clock=cv.header(t, "").stamp))
        pubs[(r, kind)].publish(m)
        sent[r].append((kind, m))
    if clock is not None:  # time goes on past the last input, as a played bag's clock does
        for k in range(1, 11):
            time.sleep(0.1)
            tick.publish(typestore().types[cv.CLOCK](clock=cv.header(msgs[-1][0] + 0.1 * k, "").stamp))
    else:
        time.sleep(1.0)
    for n in nodes.values():
        n.stop()
    for th in threads:
        th.join(60)
    for s in sessions:
        s.close()
    return bus, nodes, sent


@pytest.mark.parametrize("sim_time", [False, True], ids=["system_clock", "use_sim_time"])
def test_three_ros_nodes_on_a_bus_equal_the_replay_of_their_messages(sim_time):
    src = load_source("sim:random", robots=3, duration=4.0, seed=1)
    params = team_params(src, use_sim_time=sim_time)
    offset = 1000.0 if sim_time else time.time() + 1.0  # on /clock, ROS time is the bag's, far from the wall clock
    bus, nodes, sent = run_team_on_bus(src, params, offset, clock=True if sim_time else None)
    got = {r: [m for topic, m in bus.log if topic == f"/robot{r}/odometry/filtered"] for r in src.robots}
    tfs = {(tr.child_frame_id, cv.stamp_of(tr.header)): tr for topic, m in bus.log if topic == "/tf"
           for tr in m.transforms}  # fmt: skip
    refused = [x for n in nodes.values() for x in n.refused_inputs()]  # late inputs (a loaded machine) are left out
    late = {r: n.diagnostics().get("late_stale", 0) for r, n in nodes.items()}
    assert len(refused) == sum(n.feed.counts["refused"] for n in nodes.values()) == sum(late.values()), refused
    ref = replay_messages(sent, params, refused=refused)
    assert ref.stats["fused"] > 10 and ref.stats["unknown"] == 0, ref.stats
    assert sum(n.diagnostics()["fused"] for n in nodes.values()) == ref.stats["fused"]
    for r in src.robots:
        live = {cv.stamp_of(m.header): m for m in got[r]}
        want = {t: o for t, o, _ in ref.outputs(r, params[r])}
        common = sorted(set(live) & set(want))
        assert len(common) >= 0.9 * len(want) > 5, (r, len(live), len(want))
        d = 0.0
        for t in common:
            (a, ca), (b, cb) = _xyt_cov(live[t]), _xyt_cov(want[t])
            d = max(d, float(np.abs(a - b).max()), float(np.abs(ca - cb).max()))
        assert d < 1e-9, (r, d)
        n_tf = 0
        for t, _, tf in ref.outputs(r, params[r]):
            if t in live and tf is not None:
                a, b = tfs[(f"robot{r}/odom", t)].transform, tf.transforms[0].transform
                va = [a.translation.x, a.translation.y, a.rotation.z, a.rotation.w]
                vb = [b.translation.x, b.translation.y, b.rotation.z, b.rotation.w]
                assert np.abs(np.subtract(va, vb)).max() < 1e-9, (r, t)
                n_tf += 1
        assert n_tf >= 0.9 * len(common), (r, n_tf, len(common))
        diag = [m for topic, m in bus.log if topic == "/diagnostics" and m.status[0].hardware_id == f"robot{r}"]
        assert diag and {kv.key for kv in diag[-1].status[0].values} >= {"fused", "gated", "unknown", "input_odometry"}
