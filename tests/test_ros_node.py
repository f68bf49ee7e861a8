"""The ROS-shaped node (``swarmloc ros``): three robots' nodes localize from ROS 2 messages played in real time on an
in-process bus, talking to each other over Zenoh on 127.0.0.1; what they publish (Odometry, TF) equals the offline
replay of the same messages to 1e-9."""

from __future__ import annotations

import threading
import time

import numpy as np
from _fake_rmw import Bus
from _ros_sim import team_messages

from swarmloc.experiments.sources import load_source
from swarmloc.net.transport import free_ports, open_session
from swarmloc.ros import convert as cv
from swarmloc.ros.args import RosArgs
from swarmloc.ros.node import RosNode
from swarmloc.ros.params import load_params
from swarmloc.ros.replay import replay_messages


def _xyt_cov(msg):
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return np.array([p.x, p.y, cv._yaw(q)]), np.asarray(msg.pose.covariance).reshape(6, 6)


def test_three_ros_nodes_on_a_bus_equal_the_replay_of_their_messages():
    src = load_source("sim:random", robots=3, duration=4.0, seed=1)
    bus = Bus()
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(3)]
    sessions = [open_session([eps[k]], eps[:k]) for k in range(3)]
    params, nodes = {}, {}
    for k, r in enumerate(src.robots):
        x0 = src.initial[r]
        from swarmloc.lie import SE2

        xyt = SE2.to_xytheta(np.asarray(x0.mean))
        p = load_params(
            [],
            {
                "robot_id": r,
                "team_robots": list(src.robots),
                "no_auth": True,
                "frequency": 5.0,
                "initial_state": [float(v) for v in xyt],
                "window": 0.3,
                "team": "rostest",
                "initial_covariance": [1e-4, 1e-4, 1e-4],
                "odom_frame": f"robot{r}/odom",
                "base_link_frame": f"robot{r}/base_link",
            },
            "swarmloc",
            f"/robot{r}",
        )
        params[r] = p
        nodes[r] = RosNode(
            p,
            name="swarmloc",
            namespace=f"/robot{r}",
            args=RosArgs(),
            middleware=bus.middleware(),
            team_session=sessions[k],
        )
    threads = [threading.Thread(target=n.run, kwargs={"max_wall": 60}, daemon=True) for n in nodes.values()]
    for th in threads:
        th.start()
    offset = time.time() + 1.0
    msgs = team_messages(src, offset, "robot{r}/base_link")
    pub = bus.middleware()
    pubs = {
        (r, kind): pub.publisher(f"/robot{r}/{'odom' if kind == 'odometry' else 'detections'}", "")
        for r in src.robots
        for kind in ("odometry", "detections")
    }
    sent = {r: [] for r in src.robots}
    for t, r, kind, m in msgs:
        delay = t - time.time()
        if delay > 0:
            time.sleep(delay)
        pubs[(r, kind)].publish(m)
        sent[r].append((kind, m))
    time.sleep(1.0)
    for n in nodes.values():
        n.stop()
    for th in threads:
        th.join(60)
    for s in sessions:
        s.close()
    got = {r: [(m.header, m) for topic, m in bus.log if topic == f"/robot{r}/odometry/filtered"] for r in src.robots}
    tfs = {}
    for topic, m in bus.log:
        if topic == "/tf":
            for tr in m.transforms:
                tfs[(tr.child_frame_id, cv.stamp_of(tr.header))] = tr
    ref = replay_messages(sent, params)
    assert ref.stats["fused"] > 10 and ref.stats["unknown"] == 0, ref.stats
    live_fused = sum(n.diagnostics()["fused"] for n in nodes.values())
    assert live_fused == ref.stats["fused"]
    for r in src.robots:
        live = {cv.stamp_of(h): m for h, m in got[r]}
        want = {t: o for t, o, _ in ref.outputs(r, params[r])}
        common = sorted(set(live) & set(want))
        assert len(common) >= 0.9 * len(want) > 5, (r, len(live), len(want))
        d = 0.0
        for t in common:
            m = live[t]
            a, ca = _xyt_cov(m)
            b, cb = _xyt_cov(want[t])
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
