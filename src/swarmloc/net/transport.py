"""Zenoh sessions for a team: configuration, key expressions, and a helper that opens a session.

A team is a set of Zenoh peers. By default every peer listens on ``tcp/127.0.0.1:<port>`` and connects to the
others' endpoints given explicitly; multicast and gossip scouting are off, so nothing is sent beyond the
endpoints named (tests and ``swarmloc team`` use 127.0.0.1 only). For a team on several machines, give each node
the others' endpoints (``--listen``, ``--connect``) or a Zenoh configuration file (``--zenoh-config``): that file
is where TLS and access control are set (see ``docs/network.md``).

Key expressions (``<team>`` is the team's name; one run of a team launched by ``swarmloc team`` is
``<team>/run/<id>``, with a random id of its own, so that two teams of one name on one network never hear each other:
:func:`team_scope`)::

    swarmloc/<team>/robot/<id>/query      queryable: BeliefQuery / RdlStateQuery -> answer (get, reply)
    swarmloc/<team>/robot/<id>/inbox      subscriber: pushed answers (revisions) and pairwise updates
    swarmloc/<team>/robot/<id>/belief     publisher: the robot's beliefs at its record times
    swarmloc/<team>/robot/<id>/progress   publisher: how far the node has read its source (lockstep)
    swarmloc/<team>/robot/<id>/report     publisher: the node's counters when it stops
    swarmloc/<team>/alive/<id>            liveliness token of a running node
    swarmloc/<team>/robot/<id>/raw        publisher: raw measurements forwarded to a server-hosted estimator
    swarmloc/<team>/input/<id>/<what>     a robot's live inputs (odom, det, progress: :mod:`swarmloc.live.zenoh_input`)
    swarmloc/<team>/server/query          queryable of the belief server
    swarmloc/<team>/server/belief         publisher: the beliefs of a server-hosted centralized estimator
    swarmloc/<team>/server/report         publisher: the server's report (hosted estimator)
    swarmloc/<team>/server/ack            publisher: the server's requests for missing forwards (hosted estimator)
    swarmloc/<team>/hello/<member>        queryable: the per-pair handshake of each member (a robot id, ``server``,
                                          ``collector``; :mod:`swarmloc.net.pairing`)
"""

from __future__ import annotations

import functools
import json
import os
import re
import socket
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager, suppress
from typing import Any, ParamSpec

PREFIX = "swarmloc"
MAX_MESSAGE = 2 * 1024 * 1024
"""[bytes] the largest Zenoh message a session reassembles (Zenoh's default, 1 GiB, let one peer make a receiver
buffer that much before any check of ours; a signed frame is at most 1 MiB): set unless a configuration file
sets its own."""
_ZENOH_DEFAULT_MAX_MESSAGE = 1 << 30
MAX_ROUTERS = 16
"""The most routers :func:`router_mesh` starts (a mesh on one machine is for tests and demonstrations)."""
_TEAM = re.compile(r"^[A-Za-z0-9_\-]{1,64}$")
P = ParamSpec("P")


def check_team(team: str) -> str:
    """A team name is 1-64 letters, digits, '-' or '_' (it is part of every key expression)."""
    if not isinstance(team, str) or not _TEAM.match(team):
        raise ValueError(f"team name must be 1-64 letters, digits, '-' or '_', got {team!r}")
    return team


def team_scope(team: str, run_id: str | None = None) -> str:
    """The part of every key expression that names a team: ``<team>``, or ``<team>/run/<run_id>`` for one run of it
    (the run id is 1-64 letters, digits, '-' or '_'). Pass it as ``team`` to the key functions below."""
    check_team(team)
    if run_id is None:
        return team
    if not isinstance(run_id, str) or not _TEAM.match(run_id):
        raise ValueError(f"run id must be 1-64 letters, digits, '-' or '_', got {run_id!r}")
    return f"{team}/run/{run_id}"


def robot_key(team: str, robot: int | str, what: str) -> str:
    """``swarmloc/<team>/robot/<robot>/<what>`` (``robot`` may be ``*``)."""
    return f"{PREFIX}/{team}/robot/{robot}/{what}"


def alive_key(team: str, robot: int | str = "*") -> str:
    return f"{PREFIX}/{team}/alive/{robot}"


def hello_key(team: str, member: str) -> str:
    """``swarmloc/<team>/hello/<member>``: a member's handshake queryable (``member``: a robot id, ``server``,
    ``collector``, or ``*`` for every member's)."""
    return f"{PREFIX}/{team}/hello/{member}"


def server_key(team: str, what: str = "query") -> str:
    """``swarmloc/<team>/server/<what>``: ``query`` (its queryable); with a hosted estimator also ``belief`` and
    ``report`` (its publications, signed by the server)."""
    return f"{PREFIX}/{team}/server/{what}"


def robot_of(key: str) -> int | None:
    """The robot id in a ``.../robot/<id>/<what>``, ``.../input/<id>/<what>`` or ``.../alive/<id>`` key, or None.
    Read from the key's end, so that a team or run named ``robot`` or ``alive`` does not fool it."""
    parts = str(key).split("/")
    for n, word in ((3, "robot"), (3, "input"), (2, "alive")):
        if len(parts) >= n and parts[-n] == word and parts[1 - n].isascii() and parts[1 - n].isdigit():
            return int(parts[1 - n])
    return None


PORT_RANGE_ENV = "SWARMLOC_PORT_RANGE"
"""``LO-HI``: where :func:`free_ports` picks (e.g. ``20000-20999``); unset: the OS picks in its ephemeral range."""


def port_range(env: dict[str, str] | os._Environ = os.environ) -> tuple[int, int] | None:
    """``(lo, hi)`` of :data:`PORT_RANGE_ENV` (ValueError naming it when malformed), or None when unset."""
    text = env.get(PORT_RANGE_ENV, "").strip()
    if not text:
        return None
    lo, sep, hi = text.partition("-")
    if not (sep and lo.strip().isdigit() and hi.strip().isdigit() and 1024 <= int(lo) <= int(hi) <= 65535):
        raise ValueError(f"{PORT_RANGE_ENV} must be LO-HI with 1024 <= LO <= HI <= 65535, got {text!r}")
    return int(lo), int(hi)


_HANDED: set[int] = set()
"""Ports :func:`free_ports` handed out before in this process: not handed out again while others are left."""


def free_ports(n: int, host: str = "127.0.0.1") -> list[int]:
    """``n`` distinct TCP ports free on ``host`` now: picked by the OS in its ephemeral range, or at random in
    :data:`PORT_RANGE_ENV`'s range when it is set. Either way a port is free when returned, not reserved: another
    program may take it before its user binds it. A range apart (below the ephemeral range, one per concurrent
    test worker) keeps it from ports the OS hands to outgoing connections and to the other workers. Two calls in one
    process never return the same port while the range holds others (a port handed out but not yet bound looks
    free); when every port of the range was handed out, the memory starts again."""
    rng = port_range()
    if rng is not None and n > rng[1] - rng[0] + 1:
        raise ValueError(f"free_ports: {n} ports asked, {PORT_RANGE_ENV} holds {rng[1] - rng[0] + 1}")
    try:
        ports = _bind_free(n, host, rng, _HANDED)
    except OSError:
        if rng is None or not _HANDED:
            raise
        _HANDED.clear()  # the range is used up by earlier calls: their ports may be handed out again
        ports = _bind_free(n, host, rng, _HANDED)
    _HANDED.update(ports)
    return ports


def _bind_free(n: int, host: str, rng: tuple[int, int] | None, skip: set[int]) -> list[int]:
    """Bind ``n`` ports not in ``skip`` (the OS's picks, or candidates of ``rng`` at random) and release them."""
    import random

    socks: list[socket.socket] = []
    ports: list[int] = []
    candidates = None
    if rng is not None:
        pool = [p for p in range(rng[0], rng[1] + 1) if p not in skip]
        candidates = iter(random.sample(pool, len(pool)))
    tries = 0
    try:
        while len(ports) < n:
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((host, 0 if candidates is None else next(candidates)))
            except StopIteration:
                s.close()
                raise OSError(f"free_ports: fewer than {n} free ports in {PORT_RANGE_ENV} {rng}") from None
            except OSError:
                s.close()
                if candidates is None:
                    raise
                continue  # taken: the next candidate
            socks.append(s)
            port = s.getsockname()[1]
            tries += 1
            if candidates is None and port in skip and tries < 64 * n:
                continue  # the OS gave back a port handed out before: keep it bound and ask again
            ports.append(port)
    finally:
        for s in socks:
            s.close()
    return ports


def block() -> Any:
    """Zenoh's ``CongestionControl.BLOCK``: a put waits for room in the link's queue instead of being dropped (the
    default, ``DROP``, loses puts when a loaded machine does not drain the queue in time: 4,879 of 20,000 small puts
    to a slow subscriber with six busy loops beside, 2 cores). For what is counted or announced: beliefs, progress,
    pushes, inputs."""
    import zenoh

    return zenoh.CongestionControl.BLOCK


MODES = ("peer", "client", "router")
"""Zenoh's session modes: a team's node is a ``peer`` (the default: it listens and connects to the others) or a
``client`` of a router (it listens nowhere; everything goes through the router); ``router`` relays for clients and
meshes with other routers (:func:`router_mesh`, ``swarmloc router``)."""


def zenoh_config(
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    config_file: str | os.PathLike[str] | None = None,
    extra: dict[str, Any] | None = None,
    mode: str = "peer",
) -> Any:
    """A ``zenoh.Config`` for one session: ``listen``/``connect`` endpoints (e.g. ``tcp/127.0.0.1:7447``), scouting
    off and ``mode`` (:data:`MODES`) unless ``config_file`` (a Zenoh JSON5 configuration) says otherwise; ``extra``
    sets further paths (``{"transport/link/tls/root_ca_certificate": "..."}``). Endpoints given here override the
    file's."""
    import zenoh

    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if config_file is not None and not os.path.isfile(config_file):
        raise TransportError(f"no Zenoh configuration file {os.fspath(config_file)!r}")
    cfg = zenoh.Config.from_file(str(config_file)) if config_file is not None else zenoh.Config()
    if config_file is None:
        cfg.insert_json5("mode", json.dumps(mode))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("scouting/gossip/enabled", "false")
    if listen or config_file is None:  # no endpoint named: listen nowhere (Zenoh's default listens on every interface)
        cfg.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if connect:
        cfg.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if json.loads(cfg.get_json("transport/link/rx/max_message_size")) == _ZENOH_DEFAULT_MAX_MESSAGE:
        cfg.insert_json5("transport/link/rx/max_message_size", str(MAX_MESSAGE))
    for k, v in (extra or {}).items():
        cfg.insert_json5(k, json.dumps(v))
    return cfg


def client_config(routers: Sequence[str]) -> dict[str, Any]:
    """A Zenoh configuration (JSON, a valid JSON5 file for ``--zenoh-config``) that makes a node a client of the
    first of ``routers`` that answers: no listening endpoint, no scouting."""
    if not routers:
        raise ValueError("client_config: name at least one router endpoint")
    return {
        "mode": "client",
        "connect": {"endpoints": list(routers)},
        "listen": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
    }


@contextmanager
def router_mesh(n: int, connect: Sequence[str] = (), host: str = "127.0.0.1") -> Iterator[list[str]]:
    """``n`` Zenoh routers in this process on free ports of ``host``, meshed (each connects to the ones before it and
    to ``connect``, e.g. ROS 2's router); yields their endpoints and closes them on exit. A team's processes are
    clients of these routers (:func:`client_config`) instead of peers of one another (``swarmloc team
    --routers``)."""
    if not (isinstance(n, int) and 1 <= n <= MAX_ROUTERS):
        raise ValueError(f"routers: between 1 and {MAX_ROUTERS}, got {n!r}")
    eps = [f"tcp/{host}:{p}" for p in free_ports(n, host)]
    sessions: list[Any] = []
    try:
        for i, ep in enumerate(eps):
            sessions.append(open_session([ep], [*eps[:i], *connect], mode="router"))
        yield eps
    finally:
        for s in sessions:
            s.close()


def undeclare_all(entities: Iterable[Any]) -> None:
    """Undeclare each Zenoh entity (subscriber, queryable, liveliness token...) of ``entities``; one that fails (the
    session may be gone already) is passed over: closing, nothing is left to do about it."""
    for e in entities:
        with suppress(Exception):
            e.undeclare()


def get_all(
    session: Any, key: str, payload: bytes, timeout: float, on_reply: Callable[[Any], Any], on_end: Callable[[], Any]
) -> Exception | None:
    """A Zenoh get of ``key`` from every queryable on it, taking every reply: ``on_reply(reply)`` for each, then
    ``on_end()`` (another peer's "complete" queryable or a forged reply cannot hide the real one: each reply is
    authenticated on its own). None, or the exception that kept the get from going out (a closed session: then
    ``on_end()`` has been called, with no reply before it)."""
    import zenoh

    try:
        session.get(key, payload=payload, timeout=timeout, target=zenoh.QueryTarget.ALL,
                    consolidation=zenoh.ConsolidationMode.NONE,
                    handler=zenoh.handlers.Callback(on_reply, on_end))  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - the caller says what a get that never went out means
        on_end()
        return exc
    return None


def close_query(query: Any) -> None:
    """Close a Zenoh query (its asker's get ends); one already closed, or of a session gone, is passed over."""
    with suppress(Exception):
        query.drop()


class TransportError(ValueError):
    """A Zenoh session that cannot be opened: a malformed endpoint, a port out of range or taken, a bad configuration
    file. The message is Zenoh's reason without the location in Zenoh's own sources it carries."""


def zenoh_reason(exc: BaseException) -> str:
    """Zenoh's reason for ``exc`` in one line: the message inside a JSON5 error, without the ``at <file>.rs:<line>``
    locations of Zenoh's sources."""
    text = str(exc)
    inner = re.search(r'msg: "((?:[^"\\]|\\.)*)"', text)
    if inner:
        text = inner.group(1)
    return " ".join(re.sub(r"\s+at \S+\.rs:\d+\.?", "", text).split())


def _opener(config: Callable[P, Any]) -> Callable[P, Any]:
    """A function of ``config``'s parameters that opens a Zenoh session with the configuration ``config`` makes of
    them: one parameter list serves both (``inspect.signature`` of the result shows ``config``'s)."""

    @functools.wraps(config, assigned=("__module__",))
    def open_session(*args: P.args, **kwargs: P.kwargs) -> Any:
        """Open a Zenoh session: ``zenoh.open`` of :func:`zenoh_config` of the same arguments; a session that Zenoh
        cannot open or configure raises :class:`TransportError`."""
        import zenoh

        try:
            return zenoh.open(config(*args, **kwargs))
        except zenoh.ZError as exc:
            raise TransportError(f"cannot open a Zenoh session: {zenoh_reason(exc)}") from None

    return open_session


open_session = _opener(zenoh_config)
