"""``--source ros2:``: a robot's inputs as ROS 2 topics over Zenoh in rmw_zenoh's layout, CDR-encoded.

Topics of robot ``N`` (``<ns>`` the namespace, default ``/swarmloc/<team>``; each on the key
``<domain>/<topic without the leading '/'>/<DDS type name>/<RIHS01 type hash>`` as rmw_zenoh publishes it, see
:mod:`swarmloc.net.ros`; payloads CDR via rosbags' ROS 2 Jazzy typestore)::

    <ns>/robot<N>/odom            nav_msgs/msg/Odometry
    <ns>/robot<N>/detections      geometry_msgs/msg/PoseWithCovarianceStamped
    <ns>/robot<N>/input_progress  std_msgs/msg/Header

* **Motion from the twist**, not from differenced poses: the message stamped ``t_k`` carries in
  ``twist.twist.linear.x`` and ``twist.twist.angular.z`` the forward speed [m/s] and yaw rate [rad/s] *averaged
  over the interval ending at* ``t_k`` (as wheel encoders report it): it becomes ``Odometry(N, t_{k-1}, t_k, v, w)``
  with ``t_{k-1}`` the previous message's stamp (for the first, the node's start ``t0``; a message stamped at
  ``t0`` only marks the start). The pose fields are not read (a publisher may fill them with its dead reckoning).
* **A detection** is one ``PoseWithCovarianceStamped`` per detected robot: header stamp the time, ``frame_id``
  ``robot<id>`` (or ``landmark<id>``) naming *what was detected*, the pose its planar pose ``(x, y, yaw)`` in the
  observer's body frame (yaw from the quaternion), and rows/columns ``(0, 1, 5)`` of the covariance the 3x3
  covariance swarmloc's ``"pose"`` measurement uses (:class:`~swarmloc.events.Detection`). Detections at one stamp
  form one group.
* **Progress**: a ``Header`` stamped ``t`` says every input stamped before ``t`` was sent (the feed's explicit
  watermark); ``frame_id`` ``end`` ends the stream, ``end:<n>`` once ``n`` odometry and detection messages in all
  have come (the topics are separate keys, so the end may overtake the last of them; at most 5 s of wall time).

The attachment rmw_zenoh adds (sequence number, source time, gid; :func:`swarmloc.net.ros.parse_ros_attachment`)
is read when present: a repeated sequence number of one publisher is dropped (``duplicate``). Every sample is
checked (size at most :data:`MAX_BYTES`, CDR of the topic's type, finite numbers, a known ``frame_id``); a bad one
is counted with its reason (:attr:`RosInput.reasons`), logged once per reason, and never stops the node.
"""

from __future__ import annotations

import logging
import re
import threading
from collections import Counter, OrderedDict
from typing import Any

import numpy as np

from swarmloc.events import Detection, Kind, Odometry
from swarmloc.gaussian import symmetric
from swarmloc.net import ros
from swarmloc.net.feed import InputRefusals, LiveFeed
from swarmloc.net.rosgraph import RosGraph
from swarmloc.net.transport import block
from swarmloc.rmw.inbox import Refused
from swarmloc.rmw.types import header, odometry_msg, pose_msg, stamp_of

log = logging.getLogger(__name__)

ODOM, DET, PROGRESS = "nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseWithCovarianceStamped", "std_msgs/msg/Header"
TOPICS = {"odom": ODOM, "detections": DET, "input_progress": PROGRESS}
MAX_BYTES = 4096
"""Largest sample accepted [bytes] (an Odometry is about 700, a detection about 350)."""
MAX_PUBLISHERS = 1024
"""Publishers whose sequence numbers a :class:`RosInput` remembers at most."""
_TARGET = re.compile(r"^(robot|landmark)([0-9]{1,9})$")


def topic_key(topic: str, msgtype: str, domain: int = 0) -> str:
    """The Zenoh key rmw_zenoh publishes ``topic`` of ``msgtype`` on in ``domain`` (:func:`ros.ros_key`)."""
    return ros.ros_key(topic, domain, msgtype)


def robot_topics(namespace: str, robot: int) -> dict[str, str]:
    """``{what: topic}`` of robot ``robot``'s input topics under ``namespace``."""
    return {k: f"{namespace.rstrip('/')}/robot{int(robot)}/{k}" for k in TOPICS}


def default_namespace(team: str) -> str:
    return f"/swarmloc/{team.replace('-', '_')}"


# ------------------------------------------------------------------------------------------------ encoding
def odometry_cdr(t: float, v: float, w: float, pose: Any = (0.0, 0.0, 0.0), child: str = "base_link") -> bytes:
    """CDR of a ``nav_msgs/msg/Odometry`` stamped ``t`` [s] with twist ``(v, w)`` (averaged over the interval ending
    at ``t``) and the planar ``pose`` (x, y, yaw), which the reader ignores."""
    return ros.to_cdr(odometry_msg(t, v, w, pose, "odom", child, twist_var=0.0))


def detection_cdr(d: Detection) -> bytes:
    """CDR of the ``PoseWithCovarianceStamped`` of a ``"pose"`` detection of an identified robot or landmark."""
    if d.kind != Kind.POSE or d.target is None:
        raise ValueError(f"ROS detections carry identified 'pose' measurements, got kind {d.kind!r}, target {d.target}")
    T = ros.typestore().types
    z = np.asarray(d.z, dtype=float).reshape(3)
    cov6 = np.zeros((6, 6))
    cov6[np.ix_((0, 1, 5), (0, 1, 5))] = np.asarray(d.cov, dtype=float).reshape(3, 3)
    frame = f"{'robot' if d.target_is_robot else 'landmark'}{int(d.target)}"
    pose = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose_msg(z), covariance=cov6.reshape(36))
    return ros.to_cdr(T[DET](header=header(d.t, frame), pose=pose))


def progress_cdr(t: float, end: bool = False, count: int | None = None) -> bytes:
    """CDR of the ``std_msgs/msg/Header`` announcing progress to ``t`` [s] (``end``: the stream is over, after
    ``count`` odometry and detection messages in all when given: frame_id ``end:<count>``)."""
    frame = "progress" if not end else "end" if count is None else f"end:{int(count)}"
    return ros.to_cdr(header(t, frame))


# ------------------------------------------------------------------------------------------------ decoding
def _decode(payload: bytes, msgtype: str) -> Any:
    if len(payload) > MAX_BYTES:
        raise Refused("too_large", f"{len(payload)} bytes > {MAX_BYTES}")
    try:
        return ros.typestore().deserialize_cdr(payload, msgtype)
    except Exception as exc:  # noqa: BLE001 - rosbags raises several kinds on bad bytes
        raise Refused("bad_cdr", f"not CDR of {msgtype}: {type(exc).__name__}: {exc}") from None


def decode_odometry(payload: bytes) -> tuple[float, float, float]:
    """``(t [s], v [m/s], w [rad/s])`` of a ``nav_msgs/msg/Odometry`` sample; :class:`Refused` if refused."""
    m = _decode(payload, ODOM)
    out = (stamp_of(m.header), float(m.twist.twist.linear.x), float(m.twist.twist.angular.z))
    if not np.all(np.isfinite(out)):
        raise Refused("bad_value", f"non-finite odometry {out}")
    return out


def decode_detection(payload: bytes, observer: int) -> Detection:
    """The :class:`~swarmloc.events.Detection` of a detection sample of ``observer``; :class:`Refused` if refused."""
    m = _decode(payload, DET)
    hit = _TARGET.match(m.header.frame_id)
    if hit is None:
        raise Refused("bad_frame_id", f"frame_id {m.header.frame_id[:40]!r} is not robot<id> or landmark<id>")
    t, z, cov = ros.pose_from_message(m)
    if not (np.all(np.isfinite(z)) and np.all(np.isfinite(cov))):
        raise Refused("bad_value", "non-finite detection")
    if not (np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(symmetric(cov)) > 0)):
        raise Refused("bad_covariance", "the (x, y, yaw) covariance is not symmetric positive definite")
    return Detection(observer, t, Kind.POSE, z, cov, int(hit.group(2)), hit.group(1) == "robot")


def decode_progress(payload: bytes) -> tuple[float, bool, int | None]:
    """``(t [s], end, count)`` of a progress ``Header`` sample."""
    m = _decode(payload, PROGRESS)
    t = stamp_of(m)
    hit = re.match(r"^end(?::([0-9]{1,12}))?$", m.frame_id)
    return t, hit is not None, None if hit is None or hit.group(1) is None else int(hit.group(1))


# ------------------------------------------------------------------------------------------------ subscriber
class RosInput:
    """Subscribe to robot ``robot``'s input topics (module docstring) on ``session`` and push them to ``feed``;
    declares the subscriptions' rmw_zenoh liveliness tokens (ROS node ``robot<N>_input`` in ``namespace``)."""

    def __init__(self, session: Any, feed: LiveFeed, *, team: str, domain: int = 0, namespace: str | None = None):
        self.session, self.feed, self.robot = session, feed, feed.robot
        self.domain = int(domain)
        self.namespace = namespace or default_namespace(team)
        self.topics = robot_topics(self.namespace, self.robot)
        self.counts: Counter[str] = Counter()
        self.reasons: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._refuse = InputRefusals(f"robot {self.robot}: ROS input", self.counts, self.reasons, log, total="rejected")
        self._prev = feed.t0  # the previous odometry stamp: the next interval starts there
        self._seqs: OrderedDict[bytes, int] = OrderedDict()  # per publisher gid: its latest sequence number
        self._subs: list[Any] = []
        self.graph: RosGraph | None = None

    def open(self) -> None:
        self.graph = RosGraph(self.session, self.domain, self.namespace, f"robot{self.robot}_input")
        for what, msgtype in TOPICS.items():
            key = topic_key(self.topics[what], msgtype, self.domain)
            handler = (lambda w: lambda sample: self._on(w, sample))(what)
            self._subs.append(self.session.declare_subscriber(key, handler=handler))
            self.graph.subscription(self.topics[what], ros.dds_type_name(msgtype), ros.type_hash(msgtype))

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # noqa: BLE001 - closing
                pass
        self._subs.clear()
        if self.graph is not None:
            self.graph.close()

    def _on(self, what: str, sample: Any) -> None:
        """One sample (on Zenoh's thread): decoded, checked, pushed; a bad one counted, never raised."""
        with self._lock:
            try:
                self.counts["received"] += 1
                self._check_attachment(sample)
                self._handle(what, sample.payload.to_bytes())
            except Refused as exc:
                self._bad(exc.reason, f"{what}: {exc}", what)
            except Exception as exc:  # noqa: BLE001 - a live node never dies of one message
                self._bad("internal_error", f"{what}: {type(exc).__name__}: {exc}", what)

    def _check_attachment(self, sample: Any) -> None:
        att = sample.attachment
        if att is None:
            self.counts["no_attachment"] += 1
            return
        try:
            seq, _, gid = ros.parse_ros_attachment(att.to_bytes())
        except ValueError as exc:
            raise Refused("bad_attachment", str(exc)) from None
        if seq <= self._seqs.get(gid, 0):
            raise Refused("duplicate", f"sequence number {seq} of publisher {gid.hex()} again")
        self._seqs[gid] = seq
        self._seqs.move_to_end(gid)
        if len(self._seqs) > MAX_PUBLISHERS:  # bounded: the publishers heard longest ago are forgotten
            self._seqs.popitem(last=False)

    def _handle(self, what: str, raw: bytes) -> None:
        if what == "odom":
            t, v, w = decode_odometry(raw)
            if t <= self._prev:
                if t < self._prev:
                    raise Refused("stale", f"odometry stamped {t} before the previous one {self._prev}")
                self.feed.dropped()
                return  # a message at the start only marks it
            ok = self.feed.push(Odometry(self.robot, self._prev, t, v, w))
            self._prev = t  # a refused interval is lost; the next one starts after it, not before
        elif what == "detections":
            ok = self.feed.push(decode_detection(raw, self.robot))
        else:
            t, end, count = decode_progress(raw)
            self.feed.end(count) if end else self.feed.advance(t)
            ok = True
        self.counts["pushed" if ok else "refused_by_feed"] += 1

    def _bad(self, reason: str, detail: str, what: str) -> None:
        self.feed.refused_input(reason, counted=what != "input_progress")  # inputs count towards the end's count
        self._refuse(reason, detail)


class RosInputPublisher:
    """Publish robot ``robot``'s inputs as rmw_zenoh would (keys, CDR, attachment) for a :class:`RosInput`: the
    helper a robot without a ROS 2 stack (or a test) uses. Declares its ``MP`` tokens (ROS node ``robot<N>_driver``)."""

    def __init__(self, session: Any, robot: int, *, team: str, domain: int = 0, namespace: str | None = None):
        import hashlib

        self.robot, self.domain = int(robot), int(domain)
        ns = namespace or default_namespace(team)
        self.topics = robot_topics(ns, self.robot)
        self.graph = RosGraph(session, self.domain, ns, f"robot{self.robot}_driver")
        self._pubs: dict[str, Any] = {}  # what ("odom", "detections"): its Zenoh publisher
        self._gids: dict[str, bytes] = {}
        self._seq: Counter[str] = Counter()
        for what, msgtype in TOPICS.items():
            key = topic_key(self.topics[what], msgtype, self.domain)
            self._pubs[what] = session.declare_publisher(key, congestion_control=block())  # wait, never drop
            # unique per publisher and session (as rmw_zenoh's, hashed from a token key holding the session id), so a
            # restarted publisher's sequence numbers, counted from 1 again, are not taken for duplicates
            zid = str(session.info.zid())
            self._gids[what] = hashlib.blake2b(f"{zid}/{key}".encode(), digest_size=16).digest()
            self.graph.publisher(self.topics[what], ros.dds_type_name(msgtype), ros.type_hash(msgtype))

    def wait_matched(self, timeout: float = 10.0) -> bool:
        """Wait (up to ``timeout`` s) until a subscriber matches each of its topics (what is put before is lost)."""
        from swarmloc.live.zenoh_input import wait_matched_all

        return wait_matched_all(self._pubs.values(), timeout)

    def _put(self, what: str, payload: bytes) -> None:
        import time

        self._seq[what] += 1
        att = ros.ros_attachment(self._seq[what], time.time_ns(), self._gids[what])
        self._pubs[what].put(payload, attachment=att)

    def odometry(self, t: float, v: float, w: float, pose: Any = (0.0, 0.0, 0.0)) -> None:
        """The twist ``(v, w)`` averaged over the interval ending at ``t`` [s]."""
        self._put("odom", odometry_cdr(t, v, w, pose))

    def detection(self, d: Detection) -> None:
        self._put("detections", detection_cdr(d))

    def progress(self, t: float, end: bool = False) -> None:
        """Every input stamped before ``t`` [s] was sent; ``end``: the stream is over (with the count sent)."""
        sent = self._seq["odom"] + self._seq["detections"]
        self._put("input_progress", progress_cdr(t, end, sent if end else None))

    def close(self) -> None:
        for p in self._pubs.values():
            p.undeclare()
        self.graph.close()
