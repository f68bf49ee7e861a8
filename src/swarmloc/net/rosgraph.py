"""Presence in the ROS 2 graph: the liveliness tokens rmw_zenoh declares for a node and its publishers/subscribers.

rmw_zenoh keeps the ROS graph (``ros2 node list``, ``ros2 topic list``, matched-publisher counts) from Zenoh
liveliness tokens, one per entity. Their key expression, from rmw_zenoh's source (github.com/ros2/rmw_zenoh,
rolling of 2024-10, ``rmw_zenoh_cpp/src/detail/liveliness_utils.hpp``: the comment above ``class Entity`` and
``Entity::Entity`` in ``liveliness_utils.cpp``; ``docs/design.md``, "Graph Cache", gives the older, shorter form
``<ADMIN_SPACE>/<domainid>/<id>/<entity>/<namespace>/<nodename>``)::

    @ros2_lv/<domainid>/<zid>/<nid>/<id>/<entity>/<enclave>/<namespace>/<nodename>
    @ros2_lv/<domainid>/<zid>/<nid>/<id>/<entity>/<enclave>/<namespace>/<nodename>/<topic>/<type>/<type hash>/<qos>

* ``<zid>``: the Zenoh session's id; ``<nid>``: the node's id within the session; ``<id>``: the entity's id within
  the session (a node's ``<id>`` equals its ``<nid>``);
* ``<entity>``: ``NN`` node, ``MP`` publisher, ``MS`` subscription, ``SS`` service server, ``SC`` service client;
* names are *mangled*: every ``/`` becomes ``%`` (``mangle_name``), so the root namespace ``/`` is ``%``, the
  enclave ``/`` is ``%`` and the topic ``/swarmloc/lab/robot1/pose`` is ``%swarmloc%lab%robot1%pose``;
* ``<type>``: the DDS type name, ``geometry_msgs::msg::dds_::PoseWithCovarianceStamped_``; ``<type hash>``:
  ``RIHS01_<hex>``;
* ``<qos>`` (``qos_to_keyexpr``): ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<deadline ns>:
  <lifespan s>,<lifespan ns>:<liveliness>,<lease s>,<lease ns>``, each field the rmw enum value, left *empty*
  where it equals rmw_zenoh's default (reliable, transient local, keep last, depth 42, infinite durations,
  automatic liveliness; ``qos.cpp``). The swarmloc publishers and subscriptions are reliable, volatile, keep last
  10: ``:2:,10:,:,:,,``.

:func:`entity_key` builds a key, :func:`parse_entity_key` reads one back; :class:`RosGraph` declares the tokens
of one ROS node on a Zenoh session (they vanish with the session, as rmw_zenoh's do).
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass
from typing import Any

from swarmloc.net.transport import undeclare_all

ADMIN_SPACE = "@ros2_lv"
KINDS = ("NN", "MP", "MS", "SS", "SC")
RELIABLE, BEST_EFFORT = 1, 2  # rmw_qos_reliability_policy_e
TRANSIENT_LOCAL, VOLATILE = 1, 2  # rmw_qos_durability_policy_e
KEEP_LAST, KEEP_ALL = 1, 2  # rmw_qos_history_policy_e
_DEFAULTS = (RELIABLE, TRANSIENT_LOCAL, KEEP_LAST, 42)  # rmw_zenoh's default QoS (qos.cpp)
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_ids = itertools.count(1)


def mangle(name: str) -> str:
    """rmw_zenoh's ``mangle_name``: every ``/`` becomes ``%``."""
    return name.replace("/", "%")


def demangle(name: str) -> str:
    return name.replace("%", "/")


def qos_key(reliability: int = RELIABLE, durability: int = VOLATILE, history: int = KEEP_LAST, depth: int = 10) -> str:
    """rmw_zenoh's ``qos_to_keyexpr`` for these policies (infinite deadline, lifespan and lease; automatic
    liveliness): fields equal to its defaults are left empty."""
    given = (reliability, durability, history, depth)
    r, d, h, n = ("" if v == dv else str(int(v)) for v, dv in zip(given, _DEFAULTS, strict=True))
    return f"{r}:{d}:{h},{n}:,:,:,,"


@dataclass(frozen=True)
class Entity:
    """One entity of the ROS graph as its liveliness token names it (names demangled: ``/`` not ``%``)."""

    domain: int
    zid: str
    nid: int
    id: int
    kind: str
    enclave: str
    namespace: str
    node: str
    topic: str | None = None
    type_name: str | None = None
    type_hash: str | None = None
    qos: str | None = None


def entity_key(e: Entity) -> str:
    """The liveliness key expression of ``e`` (module docstring); ValueError for a kind or name rmw_zenoh refuses."""
    if e.kind not in KINDS:
        raise ValueError(f"entity kind must be one of {KINDS}, got {e.kind!r}")
    if not _NAME.match(e.node):
        raise ValueError(f"a ROS node name is letters, digits and '_', not starting with a digit: {e.node!r}")
    for what, v in (("namespace", e.namespace), ("enclave", e.enclave)):
        if not v.startswith("/"):
            raise ValueError(f"the {what} must be absolute (start with '/'), got {v!r}")
    parts = [ADMIN_SPACE, str(int(e.domain)), e.zid, str(int(e.nid)), str(int(e.id)), e.kind, mangle(e.enclave),
             mangle(e.namespace), e.node]  # fmt: skip
    topical = e.kind != "NN"
    if topical != (e.topic is not None and e.type_name is not None and e.type_hash is not None and e.qos is not None):
        raise ValueError(f"a {e.kind} entity {'needs' if topical else 'has no'} topic, type, type hash and QoS")
    if e.topic is not None and e.type_name is not None and e.type_hash is not None and e.qos is not None:  # topical
        parts += [mangle(e.topic), e.type_name, e.type_hash, e.qos]
    return "/".join(parts)


def parse_entity_key(key: str) -> Entity:
    """Inverse of :func:`entity_key`; ValueError naming what does not fit the layout."""
    parts = str(key).split("/")
    if len(parts) not in (9, 13) or parts[0] != ADMIN_SPACE:
        raise ValueError(f"not an rmw_zenoh liveliness token (9 or 13 '/'-parts under {ADMIN_SPACE}): {key!r}")
    kind = parts[5]
    if kind not in KINDS or (kind == "NN") != (len(parts) == 9):
        raise ValueError(f"entity kind {kind!r} does not fit a token of {len(parts)} parts: {key!r}")
    if not (parts[1].isdigit() and parts[3].isdigit() and parts[4].isdigit()):
        raise ValueError(f"domain, node id and entity id must be numbers: {key!r}")
    topic = (demangle(parts[9]), *parts[10:13]) if len(parts) == 13 else (None, None, None, None)
    return Entity(int(parts[1]), parts[2], int(parts[3]), int(parts[4]), kind, demangle(parts[6]),
                  demangle(parts[7]), parts[8], *topic)  # fmt: skip


class RosGraph:
    """The liveliness tokens of one ROS node ``namespace``/``node`` (in ``domain``) on a Zenoh ``session``: its
    ``NN`` token at once, an ``MP``/``MS`` token per :meth:`publisher`/:meth:`subscription`; :meth:`close`
    undeclares them (closing the session does too)."""

    def __init__(self, session: Any, domain: int, namespace: str, node: str, enclave: str = "/") -> None:
        self.session = session
        self.domain = int(domain)
        self.zid = str(session.info.zid())
        self.nid = next(_ids)
        self.namespace, self.node, self.enclave = namespace, node, enclave
        self.keys: list[str] = []
        self._tokens: list[Any] = []
        self._declare(Entity(self.domain, self.zid, self.nid, self.nid, "NN", enclave, namespace, node))

    def _declare(self, e: Entity) -> str:
        key = entity_key(e)
        self._tokens.append(self.session.liveliness().declare_token(key))
        self.keys.append(key)
        return key

    def _topic(self, kind: str, topic: str, type_name: str, type_hash: str, qos: str) -> str:
        e = Entity(self.domain, self.zid, self.nid, next(_ids), kind, self.enclave, self.namespace, self.node, topic,
                   type_name, type_hash, qos)  # fmt: skip
        return self._declare(e)

    def publisher(self, topic: str, type_name: str, type_hash: str, qos: str | None = None) -> str:
        """Declare an ``MP`` token for ``topic`` (``type_name``: the DDS name); returns its key."""
        return self._topic("MP", topic, type_name, type_hash, qos or qos_key())

    def subscription(self, topic: str, type_name: str, type_hash: str, qos: str | None = None) -> str:
        """Declare an ``MS`` token for ``topic``; returns its key."""
        return self._topic("MS", topic, type_name, type_hash, qos or qos_key())

    def undeclare(self, key: str) -> None:
        """Undeclare the token of ``key`` (one entity gone: a closed publisher or subscription)."""
        if key in self.keys:
            i = self.keys.index(key)
            self.keys.pop(i)
            self._tokens.pop(i).undeclare()

    def close(self) -> None:
        undeclare_all(self._tokens)  # closing: the session may be gone already
        self._tokens.clear()
        self.keys.clear()
