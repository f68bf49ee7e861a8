"""``swarmloc ros``: one robot's localization as a ROS 2 node, modelled on robot_localization.

:class:`RosNode` wires four parts that own their state:

* the **ROS graph** (:mod:`swarmloc.rmw`: DDS through cyclonedds, or rmw_zenoh's layout), where the robot's
  ``nav_msgs/Odometry``, ``vision_msgs/Detection3DArray`` and ``/initialpose`` come in and the outputs go out;
* the **input timeline** (:class:`~swarmloc.ros.timeline.InputTimeline`): messages to events, ``t0`` at the first
  odometry (where the belief is ``initial_state``);
* the **clock** (:class:`RosClock`): ROS time, from the system clock or ``/clock`` (``use_sim_time``); every input
  stamped before ``now - window`` has come, so the node reads on as ROS time goes, with no progress topic;
* the **team node**: the robot's node of a distributed estimator (``diekf`` by default) driven over the team's
  own Zenoh network (signed) by :class:`~swarmloc.net.process.NetNode`, fed through a
  :class:`~swarmloc.net.feed.LiveFeed`.

At each output time ``t0 + k / frequency`` the node publishes, once the belief there is *settled* (no input the
team still reads can change it: :meth:`Publishing.settled`), ``nav_msgs/Odometry`` on ``odometry_topic``,
``PoseWithCovarianceStamped`` on ``pose_topic`` and, with ``publish_tf``, the ``world_frame -> odom_frame``
transform on ``/tf``; ``diagnostic_msgs/DiagnosticArray`` every ``diagnostics_period`` s. It runs until stopped.
Topic names are resolved and remapped as ``rcl`` does (:mod:`swarmloc.ros.args`).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter
from typing import Any

import numpy as np

from swarmloc.gaussian import GroupGaussian, symmetric
from swarmloc.lie import SE2
from swarmloc.net.feed import LiveFeed
from swarmloc.ros import convert as cv
from swarmloc.ros.args import RosArgs
from swarmloc.ros.params import RosParams
from swarmloc.ros.timeline import InputTimeline, refused_record

log = logging.getLogger(__name__)

TOPIC_PARAMS = ("odom_topic", "detections_topic", "initialpose_topic", "odometry_topic", "pose_topic",
                "diagnostics_topic")  # fmt: skip


def initial_belief(p: RosParams, given: tuple[np.ndarray, np.ndarray] | None = None) -> GroupGaussian:
    """The robot's belief at its start: ``given`` ``(x, y, yaw)`` and world-frame covariance (an ``/initialpose``
    before the start), else ``initial_state`` and ``initial_covariance``; the covariance carried to the
    right-perturbation exponential coordinates to first order."""
    from swarmloc.kernels.group import absolute_to_pseudo

    if given is None:
        c = np.asarray(p.initial_covariance, dtype=float)
        given = (np.asarray(p.initial_state, dtype=float), np.diag(c) if c.size == 3 else c.reshape(3, 3))
    xyt, C = given
    mean, cov = absolute_to_pseudo(xyt, symmetric(C))
    return GroupGaussian(SE2, mean, cov)


def timeline_of(p: RosParams, robot: int) -> InputTimeline:
    """Robot ``robot``'s :class:`~swarmloc.ros.timeline.InputTimeline` with the frames, sensor mounts and team of
    ``p``."""
    return InputTimeline(robot, base_frame=p.base_link_frame, world_frame=p.world_frame,
                         mounts={k: tuple(v) for k, v in p.sensor_mounts.items()},  # type: ignore[misc]
                         robots=frozenset(p.team_ids))  # fmt: skip


def outputs(p: RosParams, t: float, belief: GroupGaussian, odom_pose: np.ndarray | None,
            sample: cv.OdomSample | None) -> tuple[Any, Any | None]:  # fmt: skip
    """The ``nav_msgs/Odometry`` of ``belief`` at ``t`` and the ``tf2_msgs/TFMessage`` of the ``world_frame ->
    odom_frame`` transform (None without the odometry pose at ``t``); ``sample``: the odometry in force at ``t``."""
    odo = cv.odometry_out(t, belief.mean, belief.cov, sample, p.world_frame, p.base_link_frame, p.unused_variance)
    if odom_pose is None:
        return odo, None
    xyt = cv.map_to_odom(belief.mean, odom_pose)
    return odo, cv.tf_out([cv.transform_out(t, p.world_frame, p.odom_frame, xyt)])


class RosClock:
    """ROS time [s]: the system clock, or with ``sim`` the latest ``/clock`` (None before the first)."""

    def __init__(self, sim: bool) -> None:
        self.sim = bool(sim)
        self._t: float | None = None

    def on_clock(self, msg: Any, _info: Any = None) -> None:
        """A ``rosgraph_msgs/msg/Clock`` message."""
        t = cv.rosmsg.ros_to_stamp(msg.clock.sec, msg.clock.nanosec)
        if self._t is not None and t < self._t:  # back in time (a bag played in a loop): ignored
            return
        self._t = t

    def now(self) -> float | None:
        return self._t if self.sim else time.time()


class RosNode:
    """Robot ``params.robot_id``'s localization node (module docstring).

    ``name``/``namespace``: the node's ROS name (``args`` may remap them and its topics); ``middleware``: an open
    :class:`~swarmloc.rmw.Middleware` (None: opened from the parameters); ``team_session``: an open Zenoh session for
    the team's network (None: opened on ``team_listen``/``team_connect``); ``auth``: the team's
    :class:`~swarmloc.net.auth.Auth` (None: loaded from ``key_file``/``roster_file``; unsigned with ``no_auth``).
    """

    def __init__(
        self,
        params: RosParams,
        *,
        name: str = "swarmloc",
        namespace: str = "/",
        args: RosArgs | None = None,
        middleware: Any = None,
        team_session: Any = None,
        auth: Any = None,
        on_belief: Any = None,
    ) -> None:
        args = args or RosArgs()
        self.name = args.node or name
        self.namespace = args.namespace or namespace
        self.params = p = params
        self.robot = p.robot_id
        names = {**{k: getattr(p, k) for k in TOPIC_PARAMS}, "tf": "/tf", "clock": "/clock"}
        self.topics = {k: args.resolve(v, self.namespace, self.name) for k, v in names.items()}
        self.config = p.config()
        initial_belief(p)  # a bad initial state or covariance is refused now, not at the first odometry
        self.timeline = timeline_of(p, self.robot)
        self.clock = RosClock(p.use_sim_time)
        self.counts: Counter[str] = Counter()
        """Outputs published (``odometry``, ``tf``, ``diagnostics``), ``tf_no_odometry``, inputs refused by the feed."""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._started = threading.Event()
        self.feed: LiveFeed | None = None
        self.net: Any = None
        self.report: Any = None
        self._auth = auth if auth is not None else _load_auth(p)
        self._on_belief = on_belief
        self._team_session = team_session
        self._own_mw = middleware is None
        self.mw = middleware if middleware is not None else self._open_middleware()
        self._pubs = self._declare()

    # ------------------------------------------------------------------------------------------------ wiring
    def _open_middleware(self) -> Any:
        from swarmloc.rmw import open_middleware

        p = self.params
        return open_middleware(p.middleware, domain=p.domain_id, scope=p.discovery_range, node_name=self.name,
                               namespace=self.namespace, endpoints=tuple(p.ros_endpoints))  # fmt: skip

    def _declare(self) -> dict[str, Any]:
        from swarmloc.rmw import DEFAULT, TF

        mw, t = self.mw, self.topics
        pubs = {
            "odometry": mw.publisher(t["odometry_topic"], cv.ODOMETRY, DEFAULT),
            "pose": mw.publisher(t["pose_topic"], cv.POSE, DEFAULT),
            "diagnostics": mw.publisher(t["diagnostics_topic"], cv.DIAGNOSTICS, DEFAULT),
        }
        if self.params.publish_tf:
            pubs["tf"] = mw.publisher(t["tf"], cv.TF, TF)
        self._subs = [
            mw.subscription(t["odom_topic"], cv.ODOMETRY, self._on_odometry, DEFAULT),
            mw.subscription(t["detections_topic"], cv.DETECTIONS, self._on_detections, DEFAULT),
            mw.subscription(t["initialpose_topic"], cv.POSE, self._on_initialpose, DEFAULT),
        ]
        if self.params.use_sim_time:
            from swarmloc.rmw import CLOCK

            self._subs.append(mw.subscription(t["clock"], cv.CLOCK, self.clock.on_clock, CLOCK))
        return pubs

    # ------------------------------------------------------------------------------------------------ inputs
    def _push(self, events: list[Any]) -> None:
        """Events to the feed (called with the lock held); before the start they are dropped by the timeline."""
        if self.feed is None:
            return
        for e in events:
            if not self.feed.push(e):
                self.counts["refused_by_feed"] += 1

    def _on_odometry(self, msg: Any, _info: Any = None) -> None:
        with self._lock:
            first = self.timeline.t0 is None
            events = self.timeline.odometry(msg)
            if first and self.timeline.t0 is not None:
                self.feed = LiveFeed(self.robot, self.timeline.t0, window=self.params.window)
                self._started.set()
            self._push(events)

    def _on_detections(self, msg: Any, _info: Any = None) -> None:
        with self._lock:
            self._push(self.timeline.detections(msg))

    def _on_initialpose(self, msg: Any, _info: Any = None) -> None:
        with self._lock:
            self._push(self.timeline.initialpose(msg))

    # ------------------------------------------------------------------------------------------------ outputs
    def _on_settled(self, t: float, belief: GroupGaussian) -> None:
        """Publish the outputs at ``t`` (called on the team node's thread, in order of ``t``)."""
        p = self.params
        with self._lock:
            odom_pose, sample = self.timeline.odom_at(t)
        odometry, tf = outputs(p, t, belief, odom_pose, sample)
        self._pubs["odometry"].publish(odometry)
        self._pubs["pose"].publish(cv.pose_out(t, belief.mean, belief.cov, p.world_frame, p.unused_variance))
        self.counts["odometry"] += 1
        if "tf" not in self._pubs:
            return
        if tf is None:
            self.counts["tf_no_odometry"] += 1
            return
        self._pubs["tf"].publish(tf)
        self.counts["tf"] += 1

    def diagnostics(self) -> dict[str, Any]:
        """The counters published on ``/diagnostics`` (what came in, what was fused, refused and why)."""
        out: dict[str, Any] = {f"input_{k}": v for k, v in self.timeline.counts.items()}
        out.update({f"refused_{k}": v for k, v in self.timeline.reasons.items()})
        if self.feed is not None:
            out.update({f"late_{k}": v for k, v in self.feed.reasons.items()})
        if self.net is not None:
            out.update(self.net.node.stats())
            net = self.net.counts
            out["teammates_lost"] = net.get("peers_lost", 0)
            out["frames_refused"] = net.get("rejected", 0)
            out["queries_unanswered"] = net.get("no_reply", 0)
            out["updates_not_received"] = net.get("update_not_received", 0)
            out.update({f"frames_{k}": v for k, v in self.net.reasons.items()})
        out.update({f"output_{k}": v for k, v in self.counts.items()})
        for k, v in getattr(self.mw, "reasons", {}).items():
            out[f"middleware_{k}"] = v
        return out

    def refused_inputs(self) -> list[dict[str, Any]]:
        """The input events the feed refused (the first :data:`~swarmloc.net.feed.MAX_KEPT`), each a
        :func:`~swarmloc.ros.timeline.refused_record`: what :func:`~swarmloc.ros.replay.replay_messages` leaves out
        to replay what the node read."""
        if self.feed is None:
            return []
        with self._lock:
            return [refused_record(e, why) for why, e in self.feed.refused]

    def _publish_diagnostics(self) -> None:
        d = self.diagnostics()
        refused = sum(v for k, v in d.items() if k.startswith(("refused_", "late_", "frames_refused")))
        level = 1 if d.get("teammates_lost") or refused else 0
        msg = (
            "waiting for the first odometry"
            if self.net is None
            else f"{d.get('fused', 0)} detections fused, {d.get('gated', 0)} gated, {d.get('unknown', 0)} unknown"
        )
        now = self.clock.now() or time.time()
        self._pubs["diagnostics"].publish(cv.diagnostics_out(now, f"swarmloc: robot{self.robot} localization",
                                                             f"robot{self.robot}", level, msg, d))  # fmt: skip
        self.counts["diagnostics"] += 1

    # ------------------------------------------------------------------------------------------------ life
    def _start_team(self, feed: LiveFeed) -> None:
        """The robot's team node on ``feed``, made once its start ``t0`` is known (the first odometry)."""
        from swarmloc.net.entry import make_node
        from swarmloc.net.process import NetNode
        from swarmloc.net.settings import NetSettings
        from swarmloc.net.transport import open_session

        p = self.params
        initial = initial_belief(p, self.timeline.initial)
        node = make_node(p.estimator, self.robot, initial, self.config, p.landmark_table(), team=p.team_ids)
        node.start(feed.t0)
        if self._team_session is None:
            self._team_session = open_session(p.team_listen, p.team_connect)
            self._own_session = True
        settings = NetSettings(run_id=p.run_id or None, start_timeout=p.start_timeout, record_rate=p.frequency)
        self.net = NetNode(node, feed, session=self._team_session, team=p.team, roster=p.team_ids,
                           settings=settings, on_settled=self._on_settled, auth=self._auth,
                           on_belief=self._on_belief)  # fmt: skip
        self._thread = threading.Thread(target=self._run_team, name=f"swarmloc-ros-{self.robot}", daemon=True)
        self._thread.start()

    def _run_team(self) -> None:
        try:
            self.report = self.net.run()
        except Exception:  # noqa: BLE001 - reported: the thread has nobody else to tell
            log.exception("robot %s: the team node stopped on an error", self.robot)

    def run(self, max_wall: float | None = None) -> Any:
        """Run until :meth:`stop` (or ``max_wall`` s of wall time); returns the team node's report (None if no
        odometry ever came)."""
        deadline = math.inf if max_wall is None else time.monotonic() + max_wall
        self._own_session = False
        last_diag = -math.inf
        tick = min(0.05, 0.5 / self.params.frequency)
        try:
            while not self._stop.is_set() and time.monotonic() < deadline:
                if self.net is None and self._started.is_set() and self.feed is not None:  # started: a feed
                    self._start_team(self.feed)
                now = self.clock.now()
                if self.feed is not None and now is not None:
                    self.feed.advance(now - self.params.window)
                if time.monotonic() - last_diag >= self.params.diagnostics_period:
                    last_diag = time.monotonic()
                    self._publish_diagnostics()
                self._stop.wait(tick)
        finally:
            self._shutdown()
        return self.report

    def stop(self) -> None:
        """Ask :meth:`run` to end (from any thread or a signal handler)."""
        self._stop.set()

    def _shutdown(self) -> None:
        if self.feed is not None:
            self.feed.end()
        if self.net is not None:
            self._thread.join(30.0)
            if self._thread.is_alive():
                self.net.stop()
                self._thread.join(10.0)
        try:
            self._publish_diagnostics()
        except Exception as exc:  # noqa: BLE001 - closing: the graph may be gone
            log.debug("robot %s: last diagnostics not sent: %s", self.robot, exc)
        for s in self._subs:
            s.close()
        if self._own_mw:
            self.mw.close()
        if getattr(self, "_own_session", False):
            self._team_session.close()


def _load_auth(p: RosParams) -> Any:
    """The team's :class:`~swarmloc.net.auth.Auth` from ``key_file``/``roster_file`` (None with ``no_auth``)."""
    if p.no_auth:
        log.warning("no_auth: any process on the team's network can speak in any member's name")
        return None
    if not (p.key_file and p.roster_file):
        raise ValueError("give key_file and roster_file (make them with 'swarmloc keys'), or no_auth: true on a "
                         "trusted network")  # fmt: skip
    from swarmloc.net.auth import Auth

    return Auth.load(p.key_file, p.roster_file, p.robot_id)
