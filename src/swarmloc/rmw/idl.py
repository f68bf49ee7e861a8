"""cyclonedds ``IdlStruct`` classes generated at run time from the typestore's field definitions, so that no message
is written down twice: ``idl_class("nav_msgs/msg/Odometry")`` is the ``@final`` struct
``nav_msgs::msg::dds_::Odometry_`` with the fields, in order, of the ``.msg`` (constants are not members).

Type mapping (ROS 2 design article "Interface definition and language mapping", the ``.msg`` -> IDL table, as
rosidl_adapter applies it): ``bool`` boolean, ``byte`` octet, ``char`` uint8, ``int8``..``uint64`` and
``float32``/``float64`` themselves, ``string`` string, ``string<=N`` bounded string; ``T[N]`` array, ``T[]`` and
``T[<=N]`` (bounded) sequence; a nested message its own generated struct. ``wstring`` is refused. A final struct
serializes in XCDR1 exactly like rosbags' CDR (a test checks every type swarmloc uses).

DDS needs these classes to register a topic (type name, and the XTypes type information cyclonedds sends); the
samples themselves are written and read as rosbags CDR bytes (:mod:`swarmloc.rmw.dds`).
"""

from __future__ import annotations

from functools import cache
from typing import Any

from swarmloc.net.ros import dds_type_name
from swarmloc.rmw.types import check_msgtype, typestore

_BASE = ("bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32",
         "float64", "string")  # fmt: skip


def _base(name: str, bound: int) -> Any:
    from cyclonedds.idl import types

    if name not in _BASE:
        raise ValueError(f"field type {name!r} has no DDS mapping here (wstring is not supported)")
    if name == "string":
        return types.bounded_str[bound] if bound else str  # type: ignore[misc]  # cyclonedds: see _field
    return {"bool": bool, "byte": types.byte, "char": types.uint8}.get(name) or getattr(types, name)


def _field(node: Any, desc: Any) -> Any:
    from cyclonedds.idl import types
    from rosbags.typesys.base import Nodetype

    if node == Nodetype.BASE:
        return _base(*desc)
    if node == Nodetype.NAME:
        return idl_class(desc)
    sub, n = desc
    inner = _field(*sub)
    # cyclonedds' IDL types are subscripted at run time, which its annotations do not declare: hence the ignores
    if node == Nodetype.ARRAY:
        return types.array[inner, n]  # type: ignore[misc]
    return types.sequence[inner, n] if n else types.sequence[inner]  # type: ignore[misc]


@cache
def idl_class(msgtype: str) -> type:
    """The ``@final`` ``IdlStruct`` of ``msgtype`` (cached: one class per type and process)."""
    from cyclonedds.idl import make_idl_struct
    from cyclonedds.idl.annotations import final

    check_msgtype(msgtype)
    _consts, fields = typestore().fielddefs[msgtype]
    members = {name: _field(node, desc) for name, (node, desc) in fields}
    cls = make_idl_struct(msgtype.rsplit("/", 1)[1] + "_", dds_type_name(msgtype), members)
    return final(cls)
