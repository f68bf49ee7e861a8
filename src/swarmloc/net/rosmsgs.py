"""The one rosbags typestore of the project: ROS 2 **Jazzy** (``Stores.ROS2_JAZZY``) plus the vision_msgs types a
stock robot's 3D detector publishes, registered from their ``.msg`` definitions.

vision_msgs is not in rosbags' Jazzy store. Its definitions below are the field lines (comments left out) of
ros-perception/vision_msgs **4.1.1** (the ``ros2`` branch, the release Jazzy ships), ``vision_msgs/msg/*.msg``:
``Detection3DArray``, ``Detection3D``, ``ObjectHypothesisWithPose``, ``ObjectHypothesis``, ``BoundingBox3D``. rosbags
parses them as rosidl does (``rosbags.typesys.get_types_from_msg``) and computes their RIHS01 hashes (REP 2011) from
the parsed fields, as for every other type; the hash does not depend on comments.

rosbags is imported only inside :func:`typestore`, so importing this module needs no rosbags.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

VISION_MSGS: dict[str, str] = {
    "vision_msgs/msg/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size\n",
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": "ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n",
    "vision_msgs/msg/Detection3D": (
        "std_msgs/Header header\nObjectHypothesisWithPose[] results\nBoundingBox3D bbox\nstring id\n"
    ),
    "vision_msgs/msg/Detection3DArray": "std_msgs/Header header\nDetection3D[] detections\n",
}
"""``{type: .msg text}`` added to the Jazzy store (vision_msgs 4.1.1, field lines only)."""


@lru_cache(maxsize=1)
def typestore() -> Any:
    """The rosbags typestore used for every ROS message of the project (ROS 2 Jazzy + :data:`VISION_MSGS`, created
    once)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for name, text in VISION_MSGS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store
