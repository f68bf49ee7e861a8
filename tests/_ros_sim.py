"""A simulated team's inputs as ROS 2 messages (rosbags typestore objects), for the ROS node's tests: each robot's
``nav_msgs/Odometry`` (twist over the interval ending at the stamp, pose integrated from it in ``odom``) and one
``vision_msgs/Detection3DArray`` per detection instant (class id ``robot<N>``, the pose in ``base_link`` with the
ROS-convention covariance), every stamp shifted by ``offset`` s (ROS time)."""

from __future__ import annotations

from typing import Any

import numpy as np

from swarmloc.events import Detection, Odometry
from swarmloc.lie import SE2
from swarmloc.net import ros as rosmsg
from swarmloc.rmw import typestore


def header(t: float, frame: str) -> Any:
    T = typestore().types
    sec, nsec = rosmsg.stamp_to_ros(t)
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame)


def pose(xyt: Any) -> Any:
    T = typestore().types
    qx, qy, qz, qw = rosmsg.yaw_to_quaternion(float(xyt[2]))
    return T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=float(xyt[0]), y=float(xyt[1]), z=0.0),
        orientation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
    )


def odometry(t: float, v: float, w: float, xyt: Any) -> Any:
    T = typestore().types
    v3 = T["geometry_msgs/msg/Vector3"]
    tw = T["geometry_msgs/msg/Twist"](linear=v3(x=float(v), y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=float(w)))
    return T["nav_msgs/msg/Odometry"](
        header=header(t, "odom"),
        child_frame_id="base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(xyt), covariance=np.zeros(36)),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=np.diag([0.01] * 6).reshape(36)),
    )


def detections(t: float, dets: list[Detection], frame: str = "base_link") -> Any:
    """One array of ``"pose"`` detections; the exponential-coordinate covariance carried back to ROS's additive
    one (the inverse of what the node does: ``C = T^-1 S T^-T``, ``T = diag(R(yaw)^T, 1)``)."""
    T = typestore().types
    out = []
    for d in dets:
        z = np.asarray(d.z, dtype=float)
        c, s = np.cos(z[2]), np.sin(z[2])
        Tinv = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        C = Tinv @ np.asarray(d.cov, dtype=float) @ Tinv.T
        cov6 = np.zeros((6, 6))
        cov6[np.ix_((0, 1, 5), (0, 1, 5))] = C
        cov6[2, 2] = cov6[3, 3] = cov6[4, 4] = 1e6
        hyp = T["vision_msgs/msg/ObjectHypothesisWithPose"](
            hypothesis=T["vision_msgs/msg/ObjectHypothesis"](class_id=f"robot{d.target}", score=1.0),
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(z), covariance=cov6.reshape(36)),
        )
        bbox = T["vision_msgs/msg/BoundingBox3D"](
            center=pose(z), size=T["geometry_msgs/msg/Vector3"](x=0.3, y=0.3, z=0.2)
        )
        out.append(T["vision_msgs/msg/Detection3D"](header=header(t, frame), results=[hyp], bbox=bbox, id=""))
    return T["vision_msgs/msg/Detection3DArray"](header=header(t, frame), detections=out)


def team_messages(src: Any, offset: float, frame: str = "base_link") -> list[tuple[float, int, str, Any]]:
    """``(ROS time [s], robot, kind, message)`` of every robot's inputs, in time order; a first odometry message at
    the start (it only marks it)."""
    out: list[tuple[float, int, str, Any]] = []
    for r in src.robots:
        g = np.asarray(src.initial[r].mean)
        evs = [e for e in src.events if isinstance(e, Odometry) and e.robot == r]
        t_start = evs[0].t0 if evs else 0.0
        out.append((t_start + offset, r, "odometry", odometry(t_start + offset, 0.0, 0.0, SE2.to_xytheta(g))))
        for e in evs:
            step = np.array([e.v, 0.0, e.w]) * e.dt
            g = g @ SE2.exp(step)
            out.append((e.t1 + offset, r, "odometry", odometry(e.t1 + offset, e.v, e.w, SE2.to_xytheta(g))))
    groups: dict[tuple[int, float], list[Detection]] = {}
    for e in src.events:
        if isinstance(e, Detection) and e.kind == "pose" and e.target is not None:
            groups.setdefault((e.observer, e.t), []).append(e)
    for (r, t), dets in groups.items():
        out.append((t + offset, r, "detections", detections(t + offset, dets, frame.format(r=r))))
    out.sort(key=lambda x: (x[0], x[2] != "odometry"))
    return out


def to_json(msg: Any) -> Any:
    """A rosbags message as JSON: its fields (not its constants), arrays as lists."""
    import dataclasses

    if dataclasses.is_dataclass(msg):
        return {k: to_json(getattr(msg, k)) for k, _ in typestore().fielddefs[msg.__msgtype__][1]}
    if isinstance(msg, np.ndarray):
        return msg.tolist()
    if isinstance(msg, list | tuple):
        return [to_json(x) for x in msg]
    return msg


def from_json(msgtype: str, obj: dict) -> Any:
    """The rosbags message of type ``msgtype`` from :func:`to_json`'s form."""
    from rosbags.typesys.base import Nodetype

    ts = typestore()
    kw = {}
    for name, (node, desc) in ts.fielddefs[msgtype][1]:
        v = obj[name]
        if node == Nodetype.NAME:
            kw[name] = from_json(desc, v)
        elif node in (Nodetype.ARRAY, Nodetype.SEQUENCE) and desc[0][0] == Nodetype.NAME:
            kw[name] = [from_json(desc[0][1], x) for x in v]
        elif node in (Nodetype.ARRAY, Nodetype.SEQUENCE) and desc[0][1][0] != "string":
            kw[name] = np.asarray(v, dtype={"float64": np.float64, "float32": np.float32}.get(desc[0][1][0], np.uint8))
        else:
            kw[name] = v
    return ts.types[msgtype](**kw)
