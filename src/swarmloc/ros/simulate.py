"""Simulated robots on a ROS 2 graph: a swarmloc simulation's inputs played as the ROS 2 messages real robots
publish (``swarmloc ros sim``), for trying the ROS node without robots and for its tests.

Each robot ``r`` publishes ``nav_msgs/Odometry`` on ``/robot<r>/odom`` (frame ``robot<r>/odom``, child
``robot<r>/base_link``; a first message at the start marks it) and a ``vision_msgs/Detection3DArray`` per detection
instant on ``/robot<r>/detections`` (sensor frame ``robot<r>/base_link``), converted by
:mod:`swarmloc.ros.convert`, stamped with ROS time: the wall time the play started plus the simulation's time.
:func:`node_params` gives the ``ros__parameters`` of the nodes that localize them (their initial poses, frames).
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from swarmloc.events import Detection, Kind, Odometry
from swarmloc.lie import SE2
from swarmloc.rmw.types import odometry_msg
from swarmloc.ros.convert import DETECTIONS, ODOMETRY, detections_msg

TOPICS = {"odometry": "/robot{r}/odom", "detections": "/robot{r}/detections"}
TYPES = {"odometry": ODOMETRY, "detections": DETECTIONS}


def team_messages(src: Any, offset: float, frame: str = "robot{r}/base_link") -> list[tuple[float, int, str, Any]]:
    """``(ROS time [s], robot, kind, message)`` of every robot's inputs of the source ``src``, in time order
    (``kind``: ``odometry`` or ``detections``); stamps are the simulation's times plus ``offset``. Only identified
    relative-pose detections are sent (``sim:random``'s)."""
    out: list[tuple[float, int, str, Any]] = []
    for r in src.robots:
        g = np.asarray(src.initial[r].mean)
        evs = [e for e in src.events if isinstance(e, Odometry) and e.robot == r]
        t = (evs[0].t0 if evs else 0.0) + offset
        frames = (f"robot{r}/odom", f"robot{r}/base_link")
        out.append((t, r, "odometry", odometry_msg(t, 0.0, 0.0, SE2.to_xytheta(g), *frames)))
        for e in evs:
            g = g @ SE2.exp(np.array([e.v, 0.0, e.w]) * e.dt)
            t = e.t1 + offset
            out.append((t, r, "odometry", odometry_msg(t, e.v, e.w, SE2.to_xytheta(g), *frames)))
    groups: dict[tuple[int, float], list[Detection]] = {}
    for e in src.events:
        if isinstance(e, Detection) and e.kind == Kind.POSE and e.target is not None:
            groups.setdefault((e.observer, e.t), []).append(e)
    for (r, t), dets in groups.items():
        out.append((t + offset, r, "detections", detections_msg(t + offset, dets, frame.format(r=r))))
    out.sort(key=lambda x: (x[0], x[2] != "odometry"))
    return out


def node_params(src: Any) -> dict[str, Any]:
    """The ``ros__parameters`` sections (``/**`` and ``/robot<r>/swarmloc``) of nodes localizing ``src``'s robots:
    the team, each robot's initial pose (from the source's initial beliefs) and frames."""
    out: dict[str, Any] = {"/**": {"ros__parameters": {"team_robots": [int(r) for r in src.robots]}}}
    for r in src.robots:
        xyt = SE2.to_xytheta(np.asarray(src.initial[r].mean))
        out[f"/robot{r}/swarmloc"] = {"ros__parameters": {
            "robot_id": int(r), "initial_state": [float(v) for v in xyt], "odom_frame": f"robot{r}/odom",
            "base_link_frame": f"robot{r}/base_link"}}  # fmt: skip
    return out


def play(mw: Any, src: Any, stop: threading.Event | None = None, wait_matched: float = 30.0,
         lead: float = 0.5) -> tuple[int, float]:  # fmt: skip
    """Publish the inputs of ``src``'s robots through the middleware ``mw`` in real time: wait up to
    ``wait_matched`` s for a reader of each robot's odometry, then stamp the messages from now + ``lead`` s
    (:func:`team_messages`) and publish each at its time. Returns how many were published and the time offset."""
    pubs = {(r, k): mw.publisher(TOPICS[k].format(r=r), TYPES[k]) for r in src.robots for k in TOPICS}
    until = time.monotonic() + wait_matched
    while not all(pubs[(r, "odometry")].matched() for r in src.robots) and time.monotonic() < until:
        if stop is not None and stop.wait(0.05):
            return 0, 0.0
        time.sleep(0.0 if stop is not None else 0.05)
    offset = time.time() + lead
    n = 0
    for t, r, kind, m in team_messages(src, offset):
        delay = t - time.time()
        if delay > 0:
            if stop is not None and stop.wait(delay):
                break
            if stop is None:
                time.sleep(delay)
        pubs[(r, kind)].publish(m)
        n += 1
    return n, offset
