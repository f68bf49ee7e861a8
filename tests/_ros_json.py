"""ROS 2 messages (rosbags typestore objects) as JSON and back: the form the tests' stand-in peers read and write."""

from __future__ import annotations

from typing import Any

import numpy as np

from swarmloc.rmw import typestore


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
