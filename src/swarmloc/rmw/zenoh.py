"""ROS 2 topics over Zenoh in rmw_zenoh_cpp's layout, without ROS: the key expression, the 33-byte attachment and
the type hash of :mod:`swarmloc.net.ros`, the liveliness tokens of :mod:`swarmloc.net.rosgraph` (which make the node
and its endpoints visible to ``ros2 node list`` / ``ros2 topic list`` through rmw_zenoh), CDR by rosbags.

* A publisher puts each message's CDR on ``<domain>/<topic>/<DDS type name>/<RIHS01 hash>`` with the attachment
  ``(sequence number from 1, source time [ns], gid)``; the gid is 16 bytes hashed from the publisher's liveliness
  token key (rmw_zenoh hashes the same key with XXH3-128; any bytes unique per publisher serve, subscribers only
  report them). Congestion control is BLOCK (:func:`swarmloc.net.transport.block`): a put waits rather than drops.
* A subscription declares a subscriber on the same key (type hash included, so a publisher of another definition
  of the type is not heard). rmw_zenoh drops samples without an attachment; here they are delivered with a zero gid
  and no source time, and counted (``no_attachment``); an attachment of another layout is refused
  (``bad_attachment``).
* QoS goes into the liveliness tokens (:meth:`Qos.zenoh_key`); Zenoh itself delivers reliably over TCP.
  ``transient_local`` is not served to late subscribers here (rmw_zenoh does it with zenoh-ext's advanced
  publisher cache).
* Scope ``localhost``: the session (when swarmloc opens it) has multicast scouting off and accepts only loopback
  endpoints (``tcp/127.0.0.1:<port>``, ``tcp/localhost:<port>``, ``tcp/[::1]:<port>``) to listen on and connect to,
  e.g. ``tcp/127.0.0.1:7447``, where rmw_zenoh's router (``ros2 run rmw_zenoh_cpp rmw_zenohd``) listens by
  default; ``subnet``: multicast scouting on. A caller's ``session`` is used as it is (the caller owns and closes
  it).
"""

from __future__ import annotations

import hashlib
import re
import threading
import time
from collections.abc import Sequence
from typing import Any

from swarmloc.net import ros
from swarmloc.net.rosgraph import RosGraph
from swarmloc.net.transport import block, open_session, undeclare_all
from swarmloc.rmw.inbox import MAX_BYTES, Callback, Inbox, Received
from swarmloc.rmw.names import check_namespace, check_node_name, check_topic
from swarmloc.rmw.qos import DEFAULT, Qos, check_qos
from swarmloc.rmw.types import check_msgtype, encode

_LOOPBACK = re.compile(r"^(tcp|udp|quic|tls)/(127\.0\.0\.1|localhost|\[::1\]):[0-9]{1,5}$")
_ZERO_GID = bytes(ros.GID_SIZE)


def check_endpoints(endpoints: Sequence[str], what: str, localhost: bool) -> list[str]:
    """``endpoints`` as a list; ValueError for a bare string, or a non-loopback endpoint when ``localhost``."""
    if isinstance(endpoints, str):
        raise ValueError(f"{what} must be a sequence of Zenoh endpoints, got the string {endpoints!r}")
    out = [str(e) for e in endpoints]
    bad = [e for e in out if localhost and not _LOOPBACK.match(e)]
    if bad:
        raise ValueError(f"scope 'localhost' takes loopback {what} only (e.g. tcp/127.0.0.1:7447), got {bad!r}")
    return out


class ZenohPublisher:
    """Puts ``msgtype`` messages on ``topic``'s rmw_zenoh key, with the attachment, and declares its ``MP`` token."""

    def __init__(self, mw: ZenohMiddleware, topic: str, msgtype: str, qos: Qos) -> None:
        self.topic, self.msgtype, self.qos, self._mw = topic, msgtype, qos, mw
        self.key = ros.ros_key(topic, mw.domain, msgtype)
        self.token = mw.graph.publisher(topic, ros.dds_type_name(msgtype), ros.type_hash(msgtype), qos.zenoh_key())
        self.gid = hashlib.blake2b(self.token.encode(), digest_size=ros.GID_SIZE).digest()
        self.pub = mw.session.declare_publisher(self.key, congestion_control=block())
        self._seq = 0
        self._lock = threading.Lock()

    def publish(self, msg: Any) -> bool:
        """Put ``msg`` (a ``msgtype`` typestore object)."""
        data = encode(msg, self.msgtype)
        with self._lock:
            self._seq += 1
            self.pub.put(data, attachment=ros.ros_attachment(self._seq, time.time_ns(), self.gid))
        return True

    def matched(self) -> int:
        """1 if a subscriber matches the key now, else 0."""
        return int(bool(self.pub.matching_status.matching))

    def close(self) -> None:
        undeclare_all([self.pub])
        self._mw.graph.undeclare(self.token)


class ZenohSubscription:
    """Subscribes to ``topic``'s rmw_zenoh key; samples go through the middleware's :class:`Inbox` to ``callback``
    on Zenoh's thread. Declares its ``MS`` token."""

    def __init__(self, mw: ZenohMiddleware, topic: str, msgtype: str, callback: Callback, qos: Qos) -> None:
        self.topic, self.msgtype, self.qos, self.callback, self._mw = topic, msgtype, qos, callback, mw
        self.key = ros.ros_key(topic, mw.domain, msgtype)
        self.token = mw.graph.subscription(topic, ros.dds_type_name(msgtype), ros.type_hash(msgtype), qos.zenoh_key())
        self.sub = mw.session.declare_subscriber(self.key, self._on)

    def _on(self, sample: Any) -> None:
        inbox = self._mw.inbox
        try:
            size = len(sample.payload)
            gid, stamp = _ZERO_GID, None
            if sample.attachment is None:
                inbox.count("no_attachment")
            else:
                try:
                    _seq, stamp, gid = ros.parse_ros_attachment(sample.attachment.to_bytes())
                except ValueError as exc:
                    inbox.count("received")
                    inbox.refuse("bad_attachment", f"{self.topic}: {exc}")
                    return
            raw = sample.payload.to_bytes() if size <= inbox.max_bytes else b""
            inbox.deliver(self.topic, self.msgtype, raw, Received(gid, stamp, size), self.callback)
        except Exception as exc:  # noqa: BLE001 - never let a sample kill Zenoh's callback thread
            inbox.refuse("internal_error", f"{self.topic}: {type(exc).__name__}: {exc}")

    def close(self) -> None:
        undeclare_all([self.sub])
        self._mw.graph.undeclare(self.token)


class ZenohMiddleware:
    """ROS 2 over Zenoh in rmw_zenoh's layout: node ``namespace``/``node_name`` in ROS ``domain``."""

    kind = "zenoh"

    def __init__(self, *, domain: int = 0, scope: str = "localhost", node_name: str = "swarmloc", namespace: str = "/",
                 session: Any = None, endpoints: Sequence[str] = (), listen: Sequence[str] = (),
                 max_bytes: int = MAX_BYTES) -> None:  # fmt: skip
        if isinstance(domain, bool) or not isinstance(domain, int) or domain < 0:
            raise ValueError(f"domain must be an integer >= 0, got {domain!r}")
        if scope not in ("localhost", "subnet"):
            raise ValueError(f"scope must be 'localhost' or 'subnet', got {scope!r}")
        self.node_name, self.namespace = check_node_name(node_name), check_namespace(namespace)
        self.domain, self.scope = domain, scope
        self.inbox = Inbox(max_bytes)
        self.counts, self.reasons = self.inbox.counts, self.inbox.reasons
        local = scope == "localhost"
        connect = check_endpoints(endpoints, "endpoints", local)
        listen = check_endpoints(listen, "listen", local)
        self._own = session is None
        if session is None:
            extra = {} if local else {"scouting/multicast/enabled": True}
            session = open_session(listen=listen, connect=connect, extra=extra)
        elif connect or listen:
            raise ValueError("endpoints and listen configure a session swarmloc opens; not with session=")
        self.session = session
        self.graph = RosGraph(session, domain, namespace, node_name)

    def publisher(self, topic: str, msgtype: str, qos: Qos = DEFAULT) -> ZenohPublisher:
        """A publisher of ``msgtype`` on the fully qualified ROS topic ``topic``."""
        return ZenohPublisher(self, check_topic(topic), check_msgtype(msgtype), check_qos(qos))

    def subscription(self, topic: str, msgtype: str, callback: Callback, qos: Qos = DEFAULT) -> ZenohSubscription:
        """A subscription to ``msgtype`` on ``topic``; ``callback(msg, Received)`` runs on Zenoh's thread."""
        if not callable(callback):
            raise ValueError(f"callback must be callable, got {callback!r}")
        return ZenohSubscription(self, check_topic(topic), check_msgtype(msgtype), callback, check_qos(qos))

    def close(self) -> None:
        """Undeclare the node's tokens; close the session if swarmloc opened it."""
        self.graph.close()
        if self._own and self.session is not None:
            session, self.session = self.session, None
            session.close()
