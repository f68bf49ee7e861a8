"""Message types: the project's one rosbags typestore (ROS 2 Jazzy + vision_msgs, :mod:`swarmloc.net.rosmsgs`),
CDR encoding/decoding through it, and the planar messages several parts build (a header, a pose, a twist, a robot's
wheel odometry).

A message is a rosbags typestore object: ``typestore().types["nav_msgs/msg/Odometry"](...)``. Its CDR (XCDR1, the
4-byte encapsulation header ``00 01 00 00`` for little endian, then the fields with each primitive aligned to its
size counted from the end of the header) is what rmw_cyclonedds, Fast DDS and rmw_zenoh put on the wire.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from swarmloc.net.ros import ros_to_stamp, stamp_to_ros, type_hash, yaw_to_quaternion
from swarmloc.net.rosmsgs import typestore

__all__ = ["typestore", "type_hash", "check_msgtype", "encode", "decode", "header", "stamp_of", "pose_msg",
           "twist_msg", "odometry_msg"]  # fmt: skip


def check_msgtype(msgtype: str) -> str:
    """``msgtype`` (``pkg/msg/Name``) if the typestore knows it, else ValueError naming it."""
    if not isinstance(msgtype, str) or msgtype not in typestore().fielddefs:
        raise ValueError(f"msgtype {msgtype!r} is not a known ROS 2 Jazzy message type ('pkg/msg/Name')")
    return msgtype


def encode(msg: Any, msgtype: str) -> bytes:
    """CDR bytes (little endian, with the encapsulation header) of ``msg``; ValueError if it is not a ``msgtype``."""
    cls = typestore().types[msgtype]
    if not isinstance(msg, cls):
        raise ValueError(f"message must be a {msgtype} (typestore().types[{msgtype!r}]), got {type(msg).__name__}")
    return bytes(typestore().serialize_cdr(msg, msgtype))


def decode(raw: bytes | memoryview, msgtype: str) -> Any:
    """The ``msgtype`` message in ``raw`` CDR; rosbags' ``SerdeError`` (a ValueError) if it is not one."""
    return typestore().deserialize_cdr(raw, msgtype)


def header(t: float, frame: str) -> Any:
    """A ``std_msgs/msg/Header`` stamped ``t`` [s] in ``frame``."""
    T = typestore().types
    sec, nsec = stamp_to_ros(t)
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame)


def stamp_of(header: Any) -> float:
    """[s] a ``std_msgs/msg/Header``'s stamp."""
    return ros_to_stamp(header.stamp.sec, header.stamp.nanosec)


def pose_msg(xyt: Any) -> Any:
    """A ``geometry_msgs/msg/Pose`` of the planar pose ``(x, y, yaw)``."""
    T = typestore().types
    qx, qy, qz, qw = yaw_to_quaternion(float(xyt[2]))
    point = T["geometry_msgs/msg/Point"](x=float(xyt[0]), y=float(xyt[1]), z=0.0)
    turn = T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)
    return T["geometry_msgs/msg/Pose"](position=point, orientation=turn)


def twist_msg(v: float, w: float, cov: Any) -> Any:
    """A ``geometry_msgs/msg/TwistWithCovariance`` of forward speed ``v`` [m/s] and yaw rate ``w`` [rad/s], with
    the 6x6 covariance ``cov`` (36 numbers, row-major)."""
    T = typestore().types
    v3 = T["geometry_msgs/msg/Vector3"]
    tw = T["geometry_msgs/msg/Twist"](linear=v3(x=float(v), y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=float(w)))
    return T["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=np.asarray(cov, dtype=float))


def odometry_msg(t: float, v: float, w: float, xyt: Any, frame: str = "odom", child: str = "base_link",
                 twist_var: float = 0.01) -> Any:  # fmt: skip
    """What a robot publishes as its wheel odometry (a ``nav_msgs/msg/Odometry``, the input of
    :func:`swarmloc.ros.convert.odometry_in`): stamped ``t`` [s], the twist ``(v, w)`` over the interval ending at
    ``t`` (variance ``twist_var`` on the diagonal), the pose ``xyt`` integrated in ``frame``."""
    T = typestore().types
    return T["nav_msgs/msg/Odometry"](header=header(t, frame), child_frame_id=child,
                                      pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose_msg(xyt),
                                                                                     covariance=np.zeros(36)),
                                      twist=twist_msg(v, w, np.diag([twist_var] * 6).reshape(36)))  # fmt: skip
