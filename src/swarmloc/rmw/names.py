"""ROS 2 names: validation of fully qualified topic names, node names and namespaces, and their DDS mangling.

Rules (ROS 2 design article "Topic and Service name mapping to DDS", sections "ROS 2 Topic and Service Name
Constraints", "Fully Qualified Names", "Name Tokens", "ROS Specific Namespace Prefix" and "ROS Topic and Service Name
Length Limit"): a fully qualified topic name starts with ``/``, does not end with ``/``, has no empty token (``//``),
no ``~`` or ``{}`` (those are expanded before a name is fully qualified), only ``[A-Za-z0-9_/]``, no token starting
with a digit and no repeated ``_``. On DDS the topic ``/robot1/odom`` is ``rt/robot1/odom`` (``rt``: ROS topics) and
the DDS topic name is at most 256 characters. Node names are one token of ``[A-Za-z0-9_]`` not starting with a digit;
a namespace is ``/`` or an absolute name with the topic rules.
"""

from __future__ import annotations

import re

from swarmloc.net.ros import dds_type_name

__all__ = ["dds_topic", "dds_type_name", "check_topic", "check_node_name", "check_namespace"]

TOPIC_PREFIX = "rt"
MAX_DDS_TOPIC = 256
_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _tokens_ok(name: str, what: str) -> None:
    if not isinstance(name, str) or not name.startswith("/"):
        raise ValueError(f"{what} must be a fully qualified ROS name starting with '/', got {name!r}")
    if name != "/" and name.endswith("/"):
        raise ValueError(f"{what} {name!r} must not end with '/'")
    bad = [t for t in name[1:].split("/") if not _TOKEN.match(t)] if name != "/" else []
    if bad:
        raise ValueError(
            f"{what} {name!r} is not a valid ROS name: each '/'-separated token is letters, digits and '_', not "
            f"empty and not starting with a digit (no '~' or '{{}}' in a fully qualified name); bad: {bad!r}"
        )
    if "__" in name:
        raise ValueError(f"{what} {name!r} must not contain repeated underscores '__'")


def check_topic(topic: str) -> str:
    """``topic`` if it is a valid fully qualified ROS 2 topic name (module docstring), else ValueError naming why."""
    if topic == "/":
        raise ValueError("topic must name a topic, not the root namespace '/'")
    _tokens_ok(topic, "topic")
    if len(TOPIC_PREFIX) + len(topic) > MAX_DDS_TOPIC:
        raise ValueError(f"topic {topic[:40]!r}... is too long: its DDS name must be at most {MAX_DDS_TOPIC} chars")
    return topic


def check_namespace(namespace: str) -> str:
    """``namespace`` if it is ``/`` or a valid absolute namespace, else ValueError."""
    _tokens_ok(namespace, "namespace")
    return namespace


def check_node_name(name: str) -> str:
    """``name`` if it is a valid ROS 2 node name (one token, at most 255 characters), else ValueError."""
    if not isinstance(name, str) or not _TOKEN.match(name) or len(name) > 255:
        raise ValueError(f"node_name must be letters, digits and '_', not starting with a digit, got {name!r}")
    return name


def dds_topic(topic: str) -> str:
    """The DDS topic name of the ROS topic ``topic``: ``/robot1/odom`` -> ``rt/robot1/odom``."""
    return TOPIC_PREFIX + check_topic(topic)
