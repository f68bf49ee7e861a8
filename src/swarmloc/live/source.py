"""Live source specs for ``swarmloc node``: ``zenoh:<spec>`` and ``ros2:<spec>``.

The inner ``<spec>`` (``sim:random``, ``events:PATH``...) describes the team: its robot ids, initial beliefs,
landmarks, models' configuration and record times; its events are *not* read. The robot's odometry and detections
come live instead: ``zenoh:`` from swarmloc's own input keys (:mod:`swarmloc.live.zenoh_input`), ``ros2:`` from
ROS 2 topics in rmw_zenoh's layout (:mod:`swarmloc.live.ros_input`; domain ``--ros-domain``, default 0).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from swarmloc.net.feed import LiveFeed
from swarmloc.net.transport import team_scope

LIVE_KINDS = ("zenoh", "ros2")


def split_live(spec: str) -> tuple[str | None, str]:
    """``("zenoh" | "ros2", inner spec)`` of a live spec, ``(None, spec)`` of a recorded one."""
    kind, _, inner = spec.partition(":")
    if kind in LIVE_KINDS:
        if not inner:
            raise ValueError(f"{kind}: needs the team's spec after it (e.g. {kind}:sim:random or {kind}:events:PATH)")
        return kind, inner
    return None, spec


def live_inputs(
    kind: str, *, team: str, run_id: str | None = None, domain: int = 0, window: float = 0.2
) -> Callable[[Any, int, float], tuple[LiveFeed, Callable[[], None]]]:
    """``open(session, robot, t0) -> (feed, close)``: subscribes robot ``robot``'s live inputs of ``kind``."""

    def open_inputs(session: Any, robot: int, t0: float) -> tuple[LiveFeed, Callable[[], None]]:
        feed = LiveFeed(robot, t0, window=window)
        return feed, attach(kind, session, feed, team=team, run_id=run_id, domain=domain)

    return open_inputs


def attach(
    kind: str, session: Any, feed: LiveFeed, *, team: str, run_id: str | None = None, domain: int = 0
) -> Callable[[], None]:
    """Subscribe ``feed.robot``'s live inputs of ``kind`` on ``session`` into ``feed``; returns the closer."""
    if kind == "zenoh":
        from swarmloc.live.zenoh_input import ZenohInput, input_key

        sub: Any = ZenohInput(session, feed, team_scope(team, run_id))
        feed.listens_on = f"Zenoh keys {input_key(team_scope(team, run_id), feed.robot, '*')}"
    elif kind == "ros2":
        from swarmloc.live.ros_input import RosInput

        sub = RosInput(session, feed, team=team, domain=domain)
        feed.listens_on = f"ROS 2 topics {', '.join(sub.topics.values())} (domain {sub.domain})"
    else:
        raise ValueError(f"unknown live input {kind!r}; choose from {list(LIVE_KINDS)}")
    sub.open()
    return sub.close
