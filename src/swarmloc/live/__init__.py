"""Live inputs: a robot's odometry and detections streamed as they happen into the networked node.

* :mod:`swarmloc.live.api`: :class:`LiveNode`, the Python online API (push inputs, read beliefs);
* :mod:`swarmloc.live.zenoh_input`: swarmloc's own input schema on Zenoh keys (``--source zenoh:``) and a publisher;
* :mod:`swarmloc.live.ros_input`: ROS 2 topics in rmw_zenoh's layout, CDR (``--source ros2:``) and a publisher.

All of them feed a :class:`~swarmloc.net.feed.LiveFeed`, the incremental source of the network driver.
"""

from swarmloc.live.api import LiveNode, as_initial

__all__ = ["LiveNode", "as_initial"]
