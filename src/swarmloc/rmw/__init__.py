"""TEMPORARY stub (the rmw branch replaces it): the typestore with vision_msgs."""

from functools import lru_cache
from typing import Any

_VISION = {
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": "vision_msgs/ObjectHypothesis hypothesis\n"
    "geometry_msgs/PoseWithCovariance pose\n",
    "vision_msgs/msg/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size\n",
    "vision_msgs/msg/Detection3D": "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
    "vision_msgs/BoundingBox3D bbox\nstring id\n",
    "vision_msgs/msg/Detection3DArray": "std_msgs/Header header\nvision_msgs/Detection3D[] detections\n",
}


@lru_cache(maxsize=1)
def typestore() -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for name, text in _VISION.items():
        types.update(get_types_from_msg(text, name))
    ts.register(types)
    return ts


DEFAULT, TF, CLOCK = "default", "tf", "clock"


def open_middleware(kind: str, **kw: Any) -> Any:
    raise NotImplementedError("stub")
