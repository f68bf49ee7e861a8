"""ROS 2 QoS profiles (the subset swarmloc uses: reliability, durability, keep-last depth) and ROS 2's presets.

Preset values, each from its source:

* ``DEFAULT``: reliable, volatile, keep last 10 (rmw ``qos_profiles.h``, ``rmw_qos_profile_default``);
* ``SENSOR_DATA``: best effort, volatile, keep last 5 (``rmw_qos_profile_sensor_data``);
* ``PARAMETER_EVENTS``: reliable, volatile, keep last 1000 (``rmw_qos_profile_parameter_events``);
* ``TF``: reliable, volatile, keep last 100 (tf2_ros ``qos.hpp``, ``DynamicBroadcasterQoS``/``DynamicListenerQoS``);
* ``TF_STATIC``: reliable, transient local, keep last 1 (``StaticBroadcasterQoS``; its listener keeps 100:
  ``TF_STATIC_LISTENER``);
* ``CLOCK``: best effort, volatile, keep last 1 (rclcpp ``qos.cpp``, ``ClockQoS``: the sensor-data profile with
  depth 1).

Durations (deadline, lifespan, liveliness lease) are left at ROS's defaults: infinite, automatic liveliness.
Matching follows DDS's request/offered rule: a reliable reader does not match a best-effort writer, a
transient-local reader does not match a volatile writer; the other combinations match.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from swarmloc.net import rosgraph

MAX_DEPTH = 10_000


@dataclass(frozen=True)
class Qos:
    """A ROS 2 QoS profile: ``reliability``, ``durability``, keep-last ``depth`` (1..10000)."""

    reliability: Literal["reliable", "best_effort"] = "reliable"
    durability: Literal["volatile", "transient_local"] = "volatile"
    depth: int = 10

    def __post_init__(self) -> None:
        if self.reliability not in ("reliable", "best_effort"):
            raise ValueError(f"reliability must be 'reliable' or 'best_effort', got {self.reliability!r}")
        if self.durability not in ("volatile", "transient_local"):
            raise ValueError(f"durability must be 'volatile' or 'transient_local', got {self.durability!r}")
        if isinstance(self.depth, bool) or not isinstance(self.depth, int) or not 1 <= self.depth <= MAX_DEPTH:
            raise ValueError(f"depth must be an integer in 1..{MAX_DEPTH}, got {self.depth!r}")

    def zenoh_key(self) -> str:
        """This profile as rmw_zenoh writes it in a liveliness token (:func:`swarmloc.net.rosgraph.qos_key`)."""
        rel = rosgraph.RELIABLE if self.reliability == "reliable" else rosgraph.BEST_EFFORT
        dur = rosgraph.VOLATILE if self.durability == "volatile" else rosgraph.TRANSIENT_LOCAL
        return rosgraph.qos_key(rel, dur, rosgraph.KEEP_LAST, self.depth)


def check_qos(qos: Qos) -> Qos:
    """``qos`` if it is a :class:`Qos`, else ValueError naming the argument."""
    if not isinstance(qos, Qos):
        raise ValueError(f"qos must be a swarmloc.rmw.Qos, got {qos!r}")
    return qos


DEFAULT = Qos("reliable", "volatile", 10)
SENSOR_DATA = Qos("best_effort", "volatile", 5)
PARAMETER_EVENTS = Qos("reliable", "volatile", 1000)
TF = Qos("reliable", "volatile", 100)
TF_STATIC = Qos("reliable", "transient_local", 1)
TF_STATIC_LISTENER = Qos("reliable", "transient_local", 100)
CLOCK = Qos("best_effort", "volatile", 1)
DISCOVERY_INFO = Qos("reliable", "transient_local", 1)
"""``ros_discovery_info``'s writer (rmw_cyclonedds ``rmw_node.cpp``: reliable, transient local, keep last 1)."""
