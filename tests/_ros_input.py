"""What :class:`swarmloc.live.ros_input.RosInput` should make of one robot's ROS 2 input samples, computed apart
from it: the offline replay the live tests (tests/test_live.py, tests/test_live_auth.py) compare a live run with."""

from __future__ import annotations

from swarmloc.events import Event, Odometry
from swarmloc.live.ros_input import decode_detection, decode_odometry


def decoded_events(robot: int, t0: float, odom: list[bytes], dets: list[bytes]) -> list[Event]:
    """The events of these samples of robot ``robot`` (odometry in order, each ending the interval since the last
    one or ``t0`` [s]; a sample not after it adds nothing), then its detections."""
    out: list[Event] = []
    prev = float(t0)
    for raw in odom:
        t, v, w = decode_odometry(raw)
        if t > prev:
            out.append(Odometry(robot, prev, t, v, w))
            prev = t
    out += [decode_detection(raw, robot) for raw in dets]
    return out
