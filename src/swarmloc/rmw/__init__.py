"""ROS 2 topics without a ROS install, over the two middlewares a stock ROS 2 robot uses: DDS/RTPS via cyclonedds
(:class:`DdsMiddleware`, as rmw_cyclonedds_cpp) and Zenoh (:class:`ZenohMiddleware`, as rmw_zenoh_cpp).

Messages are rosbags typestore objects (:func:`typestore`, ROS 2 Jazzy + vision_msgs); names, QoS, CDR, discovery
information and the localhost scope follow ROS 2 (``docs/ros2-wire.md``)::

    mw = open_middleware("cyclonedds", node_name="localizer", namespace="/robot1")
    T = typestore().types
    sub = mw.subscription("/robot1/odom", "nav_msgs/msg/Odometry", lambda msg, rx: print(msg.header.stamp))
    pub = mw.publisher("/robot1/pose", "geometry_msgs/msg/PoseWithCovarianceStamped")
    ...
    mw.close()

Importing this package needs neither cyclonedds nor zenoh: each is imported when a middleware of its kind opens.
"""

from __future__ import annotations

from swarmloc.rmw.dds import DdsMiddleware
from swarmloc.rmw.inbox import MAX_BYTES, Received
from swarmloc.rmw.middleware import Middleware, Publisher, Subscription, open_middleware
from swarmloc.rmw.names import check_namespace, check_node_name, check_topic, dds_topic, dds_type_name
from swarmloc.rmw.qos import (
    CLOCK,
    DEFAULT,
    PARAMETER_EVENTS,
    SENSOR_DATA,
    TF,
    TF_STATIC,
    TF_STATIC_LISTENER,
    Qos,
)
from swarmloc.rmw.types import decode, encode, type_hash, typestore
from swarmloc.rmw.zenoh import ZenohMiddleware

__all__ = ["CLOCK", "DEFAULT", "MAX_BYTES", "PARAMETER_EVENTS", "SENSOR_DATA", "TF", "TF_STATIC",
           "TF_STATIC_LISTENER", "Middleware", "Publisher", "Qos", "Received", "Subscription", "check_namespace",
           "check_node_name", "check_topic", "dds_topic", "dds_type_name", "decode", "encode", "open_middleware",
           "type_hash", "typestore", "DdsMiddleware", "ZenohMiddleware"]  # fmt: skip
