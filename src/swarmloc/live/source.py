"""Live source specs for ``swarmloc node``: ``zenoh:<spec>`` and ``ros2:<spec>``.

The inner ``<spec>`` (``sim:random``, ``events:PATH``...) describes the team: its robot ids, initial beliefs,
landmarks, models' configuration and record times; its events are *not* read. The robot's odometry and detections
come live instead: ``zenoh:`` from swarmloc's own input keys (:mod:`swarmloc.live.zenoh_input`), ``ros2:`` from
ROS 2 topics in rmw_zenoh's layout (:mod:`swarmloc.live.ros_input`; domain ``--ros-domain``, default 0).

**Who may write a robot's inputs.** ``zenoh:`` inputs travel on the team's session and network: in a team with a
roster each is a frame signed by the robot itself (the input layer refuses anything else). Stock ROS 2 publishers
cannot sign: ``ros2:`` inputs are read through a Zenoh session of their own that listens and connects on loopback
endpoints only (:func:`loopback_session`: ``127.0.0.0/8``, ``::1`` or a Unix socket; scouting and gossip off), never
through the team's session, so that only a process on the robot's own host can write them (its end of stream
included); the team's session may listen on any interface. The robot's publishers connect to
:data:`INPUT_LISTEN` unless ``--input-listen`` / ``--input-connect`` say otherwise (``--input-connect`` to a local
rmw_zenoh router, which must then itself listen on loopback only).
"""

from __future__ import annotations

import ipaddress
import re
from collections.abc import Callable, Sequence
from typing import Any

from swarmloc.net.auth import Roster
from swarmloc.net.feed import LiveFeed
from swarmloc.net.transport import open_session, team_scope

LIVE_KINDS = ("zenoh", "ros2")
INPUT_LISTEN = "tcp/127.0.0.1:7448"
"""The endpoint a node's ``ros2:`` input session listens on by default (next to rmw_zenoh's router port, 7447): the
robot's ROS 2 publishers connect to it. One node per host with the default; several: give each its own."""
_IP_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")


def split_live(spec: str) -> tuple[str | None, str]:
    """``("zenoh" | "ros2", inner spec)`` of a live spec, ``(None, spec)`` of a recorded one."""
    kind, _, inner = spec.partition(":")
    if kind in LIVE_KINDS:
        if not inner:
            raise ValueError(f"{kind}: needs the team's spec after it (e.g. {kind}:sim:random or {kind}:events:PATH)")
        return kind, inner
    return None, spec


def check_loopback(endpoint: str, option: str) -> str:
    """``endpoint`` if it can only be reached from this host (``tcp/127.0.0.1:PORT``, ``tcp/[::1]:PORT``, another
    IP protocol on a loopback address, ``unixsock-stream/PATH``); ValueError naming ``option`` otherwise."""
    proto, _, rest = str(endpoint).partition("/")
    addr = re.split(r"[?#]", rest, maxsplit=1)[0]
    if proto == "unixsock-stream" and addr:
        return endpoint
    if proto in _IP_PROTOCOLS:
        host, _, port = addr.rpartition(":")
        try:
            if ipaddress.ip_address(host.strip("[]")).is_loopback and port.isdigit():
                return endpoint
        except ValueError:
            pass
    raise ValueError(f"{option}: {endpoint!r} is not a loopback endpoint (tcp/127.0.0.1:PORT, tcp/[::1]:PORT or "
                     "unixsock-stream/PATH): a robot's ROS 2 inputs are heard from its own host only")  # fmt: skip


def input_endpoints(listen: Sequence[str] = (), connect: Sequence[str] = ()) -> tuple[list[str], list[str]]:
    """The checked ``(listen, connect)`` endpoints of a ``ros2:`` input session (default: listen on
    :data:`INPUT_LISTEN`)."""
    listen = [check_loopback(e, "--input-listen") for e in listen]
    connect = [check_loopback(e, "--input-connect") for e in connect]
    return (listen or ([] if connect else [INPUT_LISTEN])), connect


def loopback_session(listen: Sequence[str] = (), connect: Sequence[str] = ()) -> Any:
    """A Zenoh peer session on loopback endpoints only (:func:`input_endpoints`), multicast scouting and gossip off:
    nothing off this host can reach it, and it tells nobody of the team's network about anything."""
    listen, connect = input_endpoints(listen, connect)
    try:
        return open_session(listen, connect)
    except Exception as exc:  # noqa: BLE001 - zenoh's own error type; say which option to change
        raise RuntimeError(f"the ROS 2 input session (listen {listen}, connect {connect}) did not open: {exc} "
                           "(another node on this host? give each its own --input-listen)") from None  # fmt: skip


def live_inputs(
    kind: str,
    *,
    team: str,
    run_id: str | None = None,
    domain: int = 0,
    window: float = 0.2,
    roster: Roster | None = None,
    input_listen: Sequence[str] = (),
    input_connect: Sequence[str] = (),
) -> Callable[[Any, int, float], tuple[LiveFeed, Callable[[], None]]]:
    """``open(session, robot, t0) -> (feed, close)``: subscribes robot ``robot``'s live inputs of ``kind``
    (:func:`attach`; the endpoints are checked now)."""
    _check_kind(kind, input_listen, input_connect)

    def open_inputs(session: Any, robot: int, t0: float) -> tuple[LiveFeed, Callable[[], None]]:
        feed = LiveFeed(robot, t0, window=window)
        return feed, attach(kind, session, feed, team=team, run_id=run_id, domain=domain, roster=roster,
                            input_listen=input_listen, input_connect=input_connect)  # fmt: skip

    return open_inputs


def _check_kind(kind: str, listen: Sequence[str], connect: Sequence[str]) -> None:
    if kind not in LIVE_KINDS:
        raise ValueError(f"unknown live input {kind!r}; choose from {list(LIVE_KINDS)}")
    if kind == "ros2":
        input_endpoints(listen, connect)
    elif listen or connect:
        raise ValueError("--input-listen / --input-connect are for ros2: inputs (zenoh: inputs are signed and come "
                         "over the team's session)")  # fmt: skip


def attach(
    kind: str,
    session: Any,
    feed: LiveFeed,
    *,
    team: str,
    run_id: str | None = None,
    domain: int = 0,
    roster: Roster | None = None,
    input_listen: Sequence[str] = (),
    input_connect: Sequence[str] = (),
) -> Callable[[], None]:
    """Subscribe ``feed.robot``'s live inputs of ``kind`` into ``feed``; returns the closer. ``zenoh``: on the team's
    ``session``, signed by the robot when ``roster`` is given (None: a trusted network, unsigned). ``ros2``: on a
    :func:`loopback_session` of its own (``input_listen``, ``input_connect``), closed with it."""
    _check_kind(kind, input_listen, input_connect)
    if kind == "zenoh":
        from swarmloc.live.zenoh_input import ZenohInput, input_key

        sub: Any = ZenohInput(session, feed, team_scope(team, run_id), roster)
        feed.listens_on = f"Zenoh keys {input_key(team_scope(team, run_id), feed.robot, '*')}"
        sub.open()
        return sub.close
    from swarmloc.live.ros_input import RosInput

    own = loopback_session(input_listen, input_connect)
    sub = RosInput(own, feed, team=team, domain=domain)
    try:
        where = ", ".join(sum(input_endpoints(input_listen, input_connect), []))
        feed.listens_on = f"ROS 2 topics {', '.join(sub.topics.values())} (domain {sub.domain}), on {where}"
        sub.open()
    except Exception:
        own.close()
        raise

    def close() -> None:
        sub.close()
        own.close()

    return close
