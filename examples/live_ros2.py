"""Live inputs as ROS 2 messages over Zenoh (rmw_zenoh's key layout, CDR): a driver session publishes a simulated
team's ``nav_msgs/msg/Odometry`` and detections (``geometry_msgs/msg/PoseWithCovarianceStamped``, frame_id
``robot<id>``) as they happen (2x real time, 4 s of data); three nodes (LiveNode with ``inputs="ros2"``, Zenoh
peers on 127.0.0.1) localize from them and publish their poses as ROS 2 ``PoseWithCovarianceStamped``. Each node
reads its ROS inputs on a loopback endpoint of its own (``input_listen``: only this host can write a robot's
inputs), where the driver connects; the poses are on the team's network. The script prints the ROS graph as
rmw_zenoh's liveliness tokens show it (what ``ros2 node list`` / ``ros2 topic list`` read) and the final poses read
back from the ROS topics.

    PYTHONPATH=src python examples/live_ros2.py
"""

import time

from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.live import LiveNode
from swarmloc.live.ros_input import RosInputPublisher
from swarmloc.net import ros
from swarmloc.net.rosgraph import parse_entity_key
from swarmloc.net.transport import free_ports, open_session

SPEED, TEAM = 2.0, "rexample"
src = load_source("sim:random", robots=3, duration=4.0, seed=1)
eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(4)]
inputs = [f"tcp/127.0.0.1:{p}" for p in free_ports(3)]  # each node's ROS input endpoint (loopback)
driver = open_session([], inputs)  # the robots' drivers: their inputs
viewer = open_session([eps[3]], eps[:3])  # on the team's network: the poses
graph: dict[str, object] = {}
tokens = [
    s.liveliness().declare_subscriber(
        "@ros2_lv/0/**",
        history=True,
        handler=lambda s: graph.__setitem__(str(s.key_expr), parse_entity_key(str(s.key_expr))),
    )
    for s in (driver, viewer)
]
poses: dict[int, tuple] = {}
pose_subs = [
    viewer.declare_subscriber(
        ros.ros_key(f"/swarmloc/{TEAM}/robot{r}/pose"),
        handler=lambda s, r=r: poses.__setitem__(r, ros.from_cdr(s.payload.to_bytes())),
    )  # fmt: skip
    for r in src.robots
]
nodes = {
    r: LiveNode(
        r,
        src.initial[r],
        team=TEAM,
        roster=src.robots,
        t0=src.t_start,
        config=src.config,
        estimator="rdl",
        listen=[eps[i]],
        connect=[e for e in eps if e != eps[i]],
        inputs="ros2",
        input_listen=[inputs[i]],
        ros_domain=0,
    )  # fmt: skip
    for i, r in enumerate(src.robots)
}
pubs = {r: RosInputPublisher(driver, r, team=TEAM) for r in src.robots}
for p in pubs.values():  # the nodes' subscriptions match (what is sent before is lost)
    p.wait_matched(timeout=10)
known = sorted((e.t, i, e) for i, e in enumerate(src.events) if isinstance(e, Odometry | Detection))
w0 = time.monotonic()
for t, _, e in known:
    time.sleep(max(0.0, w0 + (t - src.t_start) / SPEED - time.monotonic()))
    if isinstance(e, Odometry):
        pubs[e.robot].odometry(e.t1, e.v, e.w)  # the twist averaged over the interval ending at t1
    else:
        pubs[e.observer].detection(e)
print("ROS 2 graph (rmw_zenoh liveliness tokens):")
for e in sorted(graph.values(), key=lambda e: (e.node, e.kind, e.topic or "")):
    print(f"  {e.kind}  {e.namespace}/{e.node}  {e.topic or ''}  {e.type_name or ''}")
for p in pubs.values():
    p.progress(src.t_end, end=True)
for n in nodes.values():
    n.close(timeout=30)
for r, (t, xyt, cov) in sorted(poses.items()):
    print(f"robot {r}: last ROS pose at {t:.2f} s: x={xyt[0]:.3f} y={xyt[1]:.3f} yaw={xyt[2]:.3f} "
          f"var_x={cov[0, 0]:.2e}")  # fmt: skip
for s in [*tokens, *pose_subs]:
    s.undeclare()
for p in pubs.values():
    p.close()
driver.close()
viewer.close()
