"""A simulated team's robots streaming their inputs as ROS 2 messages (CDR, rmw_zenoh layout), run as its own
process (tests/test_live.py, tests/test_live_auth.py)::

    python tests/live_publisher.py --connect tcp/127.0.0.1:P1,... --team T --robots 3 --duration 4 --seed 1 --speed 2

``--connect``: the nodes' ROS 2 input endpoints (``swarmloc node --input-listen``, on this host's loopback).

It waits (at most 30 s) until every robot's node has declared its ROS subscriptions (their rmw_zenoh liveliness
tokens), then publishes each robot's odometry (at the end of each interval: the twist averaged over it) and
detections in real time times ``--speed``, ordered by when each is known, and ends every robot's stream.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.live.ros_input import RosInputPublisher
from swarmloc.net.rosgraph import parse_entity_key
from swarmloc.net.transport import open_session


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--connect", required=True)
    p.add_argument("--team", required=True)
    p.add_argument("--robots", type=int, default=3)
    p.add_argument("--duration", type=float, default=4.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--speed", type=float, default=2.0)
    a = p.parse_args()
    src = load_source("sim:random", robots=a.robots, duration=a.duration, seed=a.seed)
    session = open_session([], a.connect.split(","))
    ready: set[int] = set()
    seen = threading.Event()

    def on_token(sample) -> None:
        e = parse_entity_key(str(sample.key_expr))
        if e.kind == "MS" and e.topic.endswith("/detections") and e.node.endswith("_input"):
            ready.add(int(e.node[len("robot") : -len("_input")]))
            if len(ready) == len(src.robots):
                seen.set()

    sub = session.liveliness().declare_subscriber("@ros2_lv/0/**", history=True, handler=on_token)
    if not seen.wait(30.0):
        print(f"nodes not ready: only {sorted(ready)}", file=sys.stderr)
        return 2
    pubs = {r: RosInputPublisher(session, r, team=a.team) for r in src.robots}
    if not all(p.wait_matched(10.0) for p in pubs.values()):
        print("the nodes' subscriptions do not match", file=sys.stderr)
        return 2
    known = sorted((e.t, i, e) for i, e in enumerate(src.events) if isinstance(e, Odometry | Detection))
    w0 = time.monotonic()
    for t, _, e in known:
        due = w0 + (t - src.t_start) / a.speed - time.monotonic()
        if due > 0:
            time.sleep(due)
        if isinstance(e, Odometry):
            pubs[e.robot].odometry(e.t1, e.v, e.w)
        else:
            pubs[e.observer].detection(e)
    for pub in pubs.values():
        pub.progress(src.t_end, end=True)
    time.sleep(1.0)  # let Zenoh flush before the session closes
    sub.undeclare()
    session.close()
    print("published", len(known))
    return 0


if __name__ == "__main__":
    sys.exit(main())
