"""Message types: the project's one rosbags typestore (ROS 2 Jazzy + vision_msgs, :mod:`swarmloc.net.rosmsgs`) and
CDR encoding/decoding through it.

A message is a rosbags typestore object: ``typestore().types["nav_msgs/msg/Odometry"](...)``. Its CDR (XCDR1, the
4-byte encapsulation header ``00 01 00 00`` for little endian, then the fields with each primitive aligned to its
size counted from the end of the header) is what rmw_cyclonedds, Fast DDS and rmw_zenoh put on the wire.
"""

from __future__ import annotations

from typing import Any

from swarmloc.net.ros import type_hash
from swarmloc.net.rosmsgs import typestore

__all__ = ["typestore", "type_hash", "check_msgtype", "encode", "decode"]


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
