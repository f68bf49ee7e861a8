"""The Python online API: a robot's code pushes its odometry and detections as they happen and reads its beliefs.

:class:`LiveNode` runs one robot's node of a distributed estimator on a Zenoh session, with the network driver of
``swarmloc node`` (:class:`~swarmloc.net.process.NetNode`: clock, history, lockstep with the teammates, protocol,
signed transport) reading a :class:`~swarmloc.net.feed.LiveFeed` instead of a recording. The driver runs on a
thread of its own; every method here is safe to call from any thread::

    with LiveNode(1, initial, team="lab", roster=[0, 1, 2], listen=[...], connect=[...]) as robot:
        robot.velocity(t, v, w)            # odometry: (v, w) held over [previous stamp, t]
        robot.detection(t, target=2, z=(dx, dy, dtheta), cov=R)
        x, P = robot.x, robot.P            # latest belief: (x, y, theta) and its 3x3 covariance
    report = robot.report

Beliefs are the driver's published ones, at record times every ``1 / record_rate`` s from ``t0``: provisional
once the node's history passed the time, final a horizon later (:meth:`LiveNode.belief`); ``on_belief`` is called
with each (on the driver's thread: keep it short).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from swarmloc.config import DEFAULTS, Config
from swarmloc.events import Detection, Event, Kind, MeasurementKind, Odometry
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.net.entry import make_node
from swarmloc.net.feed import LiveFeed
from swarmloc.net.schema import Belief, Report
from swarmloc.net.transport import open_session

log = logging.getLogger(__name__)


def as_initial(initial: GroupGaussian | tuple[Any, Any]) -> GroupGaussian:
    """A :class:`GroupGaussian` on SE(2) from itself or ``((x, y, theta), cov 3x3)``."""
    if isinstance(initial, GroupGaussian):
        return initial
    xyt, cov = initial
    return GroupGaussian(SE2, SE2.from_xytheta(np.asarray(xyt, dtype=float)), np.asarray(cov, dtype=float))


class LiveNode:
    """Robot ``robot`` of team ``team`` localizing from inputs pushed live (module docstring).

    Parameters
    ----------
    robot, initial: the robot's id and its belief at ``t0`` (a GroupGaussian or ``((x, y, theta), cov)``).
    team, roster: the team's name and every robot id in it.
    estimator: a distributed estimator (``rdl`` default; see ``swarmloc node``).
    t0: [s] the start, on the clock the inputs are stamped with: nothing stamped before it is accepted, nothing
        more than ``max_ahead`` past the latest input (or ``t0``). None: now, ``time.time()`` (inputs stamped with
        the system clock, as ROS stamps are).
    config, landmarks: the models' configuration (default :data:`~swarmloc.config.DEFAULTS`) and known landmarks.
    session: an open Zenoh session to use (the caller closes it); else one is opened on ``listen``/``connect``.
    record_rate: [Hz] belief record times from ``t0``.
    window, max_ahead, max_items: the feed's bounds (:class:`~swarmloc.net.feed.LiveFeed`).
    on_belief: called with each published :class:`~swarmloc.net.schema.Belief`.
    inputs: also subscribe the robot's inputs: ``"zenoh"`` (swarmloc's input keys on the session,
        :mod:`~swarmloc.live.zenoh_input`: with ``auth`` in ``net`` only frames signed by this robot are taken) or
        ``"ros2"`` (ROS 2 topics in domain ``input_domain``, :mod:`~swarmloc.live.ros_input`, on a session of their
        own on loopback endpoints ``input_listen`` / ``input_connect``: :mod:`~swarmloc.live.source`); None: only
        what is pushed here.
    net: further :class:`~swarmloc.net.process.NetNode` options (``auth``, ``run_id``, ``ros_domain``, timeouts).
    """

    def __init__(
        self,
        robot: int,
        initial: GroupGaussian | tuple[Any, Any],
        *,
        team: str,
        roster: Iterable[int],
        estimator: str = "rdl",
        t0: float | None = None,
        config: Config | None = None,
        landmarks: Any = None,
        session: Any = None,
        listen: Sequence[str] = (),
        connect: Sequence[str] = (),
        record_rate: float = 4.0,
        window: float = 0.2,
        max_ahead: float = 60.0,
        max_items: int = 100_000,
        on_belief: Callable[[Belief], None] | None = None,
        inputs: str | None = None,
        input_domain: int = 0,
        input_listen: Sequence[str] = (),
        input_connect: Sequence[str] = (),
        start: bool = True,
        **net: Any,
    ) -> None:
        from swarmloc.net.process import NetNode

        self.robot = int(robot)
        t0 = time.time() if t0 is None else float(t0)
        self.roster = sorted(int(r) for r in roster)
        self.feed = LiveFeed(self.robot, t0, window=window, max_ahead=max_ahead, max_items=max_items)
        config = DEFAULTS if config is None else config
        node = make_node(estimator, self.robot, as_initial(initial), config, landmarks, team=self.roster)
        node.start(float(t0))
        self._own_session = session is None
        self.session = open_session(listen, connect) if session is None else session
        self._lock = threading.Lock()
        self._beliefs: dict[float, Belief] = {}
        self._latest: Belief | None = None
        self._user_cb = on_belief
        self._last_odo = float(t0)
        self.report: Report | None = None
        """The driver's report once :meth:`close` returned."""
        self.net = NetNode(node, self.feed, session=self.session, team=team, roster=self.roster,
                           record_rate=record_rate, on_belief=self._keep, **net)  # fmt: skip
        self._close_inputs: Callable[[], None] | None = None
        if inputs is not None:
            from swarmloc.live.source import attach

            auth = net.get("auth")
            if auth is None and inputs == "zenoh":
                log.warning("robot %s: zenoh inputs without auth: anybody on the network can write them", robot)
            self._close_inputs = attach(inputs, self.session, self.feed, team=team, run_id=net.get("run_id"),
                                        domain=input_domain, roster=None if auth is None else auth.roster,
                                        input_listen=input_listen, input_connect=input_connect)  # fmt: skip
        self._thread = threading.Thread(target=self._run, name=f"swarmloc-live-{robot}", daemon=True)
        if start:
            self.start()

    # ------------------------------------------------------------------------------------------------ life
    def start(self) -> None:
        """Start the driver's thread (done by the constructor unless ``start=False``)."""
        if not self._thread.is_alive() and self.report is None:
            self._thread.start()

    def _run(self) -> None:
        try:
            self.report = self.net.run()
        except Exception:  # noqa: BLE001 - reported, never silent: the thread has nobody else to tell
            log.exception("robot %s: the live driver stopped on an error", self.robot)

    def end(self) -> None:
        """End the input stream (returns at once): the node reads what is left and, once its teammates have read
        theirs, settles. Several nodes in one process: end them all, then :meth:`close` them (a node's ``close``
        waits for its teammates, which wait for their own streams to end)."""
        self.feed.end()

    def close(self, timeout: float = 30.0) -> Report | None:
        """End the input stream and wait (up to ``timeout`` s) for the team to settle; returns the report. With
        ``inputs`` subscribed, the sender ends the stream: its end is waited for (within ``timeout``) first."""
        deadline = time.monotonic() + timeout
        while self._close_inputs is not None and not self.feed.ending and time.monotonic() < deadline:
            time.sleep(0.02)
        if not self.feed.ending:
            self.feed.end()
        self._thread.join(max(0.0, deadline - time.monotonic()))
        if self._thread.is_alive():
            log.warning("robot %s: not settled after %.0f s; stopping", self.robot, timeout)
            self.net.stop()
            self._thread.join(10.0)
        if self._close_inputs is not None:
            self._close_inputs()
        if self._own_session:
            self.session.close()
        return self.report

    def __enter__(self) -> LiveNode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------------ inputs
    def push(self, event: Event) -> bool:
        """Push an :class:`~swarmloc.events.Odometry` or :class:`~swarmloc.events.Detection` of this robot; True if
        accepted (a refusal is counted in ``feed.reasons``)."""
        ok = self.feed.push(event)
        if ok and isinstance(event, Odometry):
            self._last_odo = max(self._last_odo, float(event.t1))
        return ok

    def odometry(self, t0: float, t1: float, v: float, w: float) -> bool:
        """Forward speed ``v`` [m/s] and yaw rate ``w`` [rad/s] held over ``[t0, t1]`` [s]."""
        return self.push(Odometry(self.robot, float(t0), float(t1), float(v), float(w)))

    def velocity(self, t: float, v: float, w: float) -> bool:
        """``(v, w)`` held since the previous odometry's end (or ``t0``) up to ``t`` [s]: the average velocity over
        the interval ending at ``t``, as wheel encoders report it."""
        return self.odometry(self._last_odo, t, v, w)

    def wheels(self, t: float, d_left: float, d_right: float, track: float) -> bool:
        """Wheel travel ``d_left``, ``d_right`` [m] of a differential drive with wheel separation ``track`` [m]
        since the previous odometry's end, up to ``t`` [s]."""
        dt = float(t) - self._last_odo
        if not dt > 0 or not float(track) > 0:
            return self.velocity(t, math.nan, math.nan)  # refused as bad_value, counted
        return self.velocity(t, (d_left + d_right) / (2.0 * dt), (d_right - d_left) / (float(track) * dt))

    def detection(
        self,
        t: float,
        z: Any,
        cov: Any,
        target: int | None,
        kind: MeasurementKind = Kind.POSE,
        target_is_robot: bool = True,
    ) -> bool:
        """A measurement of ``target`` (a robot, or a landmark with ``target_is_robot=False``) at ``t`` [s]:
        ``z`` and its covariance ``cov`` as :class:`~swarmloc.events.Detection` defines them for ``kind``."""
        z_, cov_ = np.asarray(z, dtype=float).reshape(-1), np.asarray(cov, dtype=float)
        return self.push(Detection(self.robot, float(t), kind, z_, cov_, target, target_is_robot))

    def advance(self, t: float) -> None:
        """Say that every input stamped before ``t`` [s] has been pushed (lets the team go on without waiting for
        the reorder window)."""
        self.feed.advance(t)

    # ------------------------------------------------------------------------------------------------ beliefs
    def _keep(self, b: Belief) -> None:
        with self._lock:
            self._beliefs[b.stamp] = b
            if self._latest is None or b.stamp >= self._latest.stamp:
                self._latest = b
        if self._user_cb is not None:
            self._user_cb(b)

    def belief(self, t: float) -> Belief:
        """The latest belief published at record time ``t`` [s] (KeyError if none was)."""
        with self._lock:
            return self._beliefs[float(t)]

    def beliefs(self) -> dict[float, Belief]:
        """Every belief published so far, by record time (the latest revision of each)."""
        with self._lock:
            return dict(self._beliefs)

    @property
    def latest(self) -> Belief | None:
        """The belief at the latest record time published so far (None before the first)."""
        with self._lock:
            return self._latest

    @property
    def x(self) -> np.ndarray | None:
        """``(x [m], y [m], theta [rad])`` of :attr:`latest`."""
        b = self.latest
        return None if b is None else SE2.to_xytheta(np.reshape(b.mean, (3, 3)))

    @property
    def P(self) -> np.ndarray | None:  # noqa: N802 - the usual name of a covariance
        """The 3x3 covariance of :attr:`latest` (right-perturbation exponential coordinates, body frame)."""
        b = self.latest
        return None if b is None else np.reshape(b.cov, (3, 3))
