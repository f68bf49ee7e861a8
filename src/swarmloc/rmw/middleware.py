"""The middleware interface both implementations follow, and :func:`open_middleware`."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Any, Literal, Protocol

from swarmloc.rmw.inbox import MAX_BYTES, Callback
from swarmloc.rmw.qos import DEFAULT, Qos

INSTALL_HINT = "pip install 'swarmloc[ros]'"


class Publisher(Protocol):
    topic: str
    msgtype: str
    gid: bytes

    def publish(self, msg: Any) -> bool:
        """Send ``msg`` (a typestore object of the publisher's type); False if the middleware refused (counted)."""
        ...

    def matched(self) -> int:
        """Subscribers matched now (Zenoh: 1 if any, else 0)."""
        ...

    def close(self) -> None: ...


class Subscription(Protocol):
    topic: str
    msgtype: str

    def close(self) -> None: ...


class Middleware(Protocol):
    """ROS 2 publishers and subscriptions of one node. ``counts``: ``received``, ``delivered``, ``refused``;
    ``reasons``: why each refused sample was (``too_large``, ``bad_cdr``, ``callback_error``, ...)."""

    kind: str
    counts: Counter[str]
    reasons: Counter[str]

    def publisher(self, topic: str, msgtype: str, qos: Qos = DEFAULT) -> Publisher: ...

    def subscription(self, topic: str, msgtype: str, callback: Callback, qos: Qos = DEFAULT) -> Subscription: ...

    def close(self) -> None: ...


def open_middleware(kind: Literal["cyclonedds", "zenoh"], *, domain: int = 0,
                    scope: Literal["localhost", "subnet"] = "localhost", node_name: str = "swarmloc",
                    namespace: str = "/", session: Any = None, endpoints: Sequence[str] = (),
                    listen: Sequence[str] = (), max_bytes: int = MAX_BYTES) -> Middleware:  # fmt: skip
    """Open a ROS 2 middleware of ``kind`` for node ``namespace``/``node_name`` in ROS ``domain``.

    ``scope``: ``"localhost"`` (reachable from this host only) or ``"subnet"``. ``endpoints``: DDS static peers
    (addresses) or Zenoh endpoints to connect to (e.g. ``tcp/127.0.0.1:7447``, rmw_zenoh's router); ``listen``:
    Zenoh endpoints to listen on (DDS: unused). ``session``: an open Zenoh session to use instead (Zenoh only; the
    caller keeps owning it). ``max_bytes``: the largest CDR sample accepted.
    """
    if kind == "cyclonedds":
        try:
            import cyclonedds  # noqa: F401
        except ImportError:
            raise RuntimeError(f"the cyclonedds middleware needs the cyclonedds package: {INSTALL_HINT}") from None
        if session is not None or listen:
            raise ValueError("session and listen are Zenoh options; the cyclonedds middleware takes endpoints only")
        from swarmloc.rmw.dds import DdsMiddleware

        return DdsMiddleware(domain=domain, scope=scope, node_name=node_name, namespace=namespace,
                             endpoints=endpoints, max_bytes=max_bytes)  # fmt: skip
    if kind == "zenoh":
        from swarmloc.rmw.zenoh import ZenohMiddleware

        return ZenohMiddleware(domain=domain, scope=scope, node_name=node_name, namespace=namespace, session=session,
                               endpoints=endpoints, listen=listen, max_bytes=max_bytes)  # fmt: skip
    raise ValueError(f"kind must be 'cyclonedds' or 'zenoh', got {kind!r}")
