"""ROS 2 topics over DDS/RTPS with cyclonedds (pip ``cyclonedds``), as rmw_cyclonedds_cpp puts them on the wire.

What follows rmw_cyclonedds (``rmw_cyclonedds_cpp/src/rmw_node.cpp``, jazzy branch):

* one participant per middleware, ``USER_DATA`` ``enclave=/;`` (``rmw_context_impl_s::init``);
* topic ``rt<topic>`` (``make_fqtopic`` with ``ROS_TOPIC_PREFIX``), type ``pkg::msg::dds_::Name_``;
* endpoint QoS (``create_readwrite_qos``): history keep last ``depth``; reliability reliable or best effort;
  durability volatile or transient local (with a durability service keeping the same history); writer autodispose
  off; liveliness automatic, infinite lease; ``USER_DATA`` ``typehash=RIHS01_<hex>;`` (rmw_dds_common ``qos.cpp``,
  ``encode_type_hash_for_user_data_qos``). swarmloc gives reliable writers a 100 ms ``max_blocking_time`` where
  rmw_cyclonedds waits forever: a live node must not hang on a stalled reader (a timed-out write is counted,
  ``write_timeout``); the blocking time is not part of QoS matching;
* data representation XCDR1 (what ROS 2 readers and writers offer);
* graph: the participant's ``ros_discovery_info`` writer (topic without prefix, type
  ``rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_``, reliable, transient local, keep last 1) publishing this
  node's name, namespace and its readers' and writers' gids, again after each change, so that ``ros2 node list``
  and ``ros2 topic info -v`` see the node (rmw_dds_common ``graph_cache.cpp``, ``context.cpp``).

Samples are written and read as CDR bytes encoded and decoded by rosbags (:mod:`swarmloc.rmw.types`); the
generated ``IdlStruct`` (:mod:`swarmloc.rmw.idl`) only registers the topic. A received sample's publisher gid is
the writer's 16-byte GUID, as rmw_cyclonedds reports it (``convert_guid_to_gid``).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

from swarmloc.net.settings import MAX_ROS_DOMAIN
from swarmloc.rmw.ddsconfig import dds_config
from swarmloc.rmw.inbox import MAX_BYTES, Callback, Inbox, Received
from swarmloc.rmw.names import check_namespace, check_node_name, check_topic, dds_topic
from swarmloc.rmw.qos import DEFAULT, DISCOVERY_INFO, Qos, check_qos
from swarmloc.rmw.types import check_msgtype, encode, type_hash, typestore

DISCOVERY_TOPIC = "ros_discovery_info"
DISCOVERY_TYPE = "rmw_dds_common/msg/ParticipantEntitiesInfo"
MAX_BLOCKING_NS = 100_000_000
TAKE_BATCH = 32
MAX_KNOWN_WRITERS = 4096
_ZERO_GID = bytes(16)
_domains: dict[int, list[Any]] = {}  # domain id -> [cyclonedds Domain, config, users]
_domains_lock = threading.Lock()


def _delete(entity: Any) -> None:
    """Delete a cyclonedds entity now (the binding deletes entities in ``__del__`` only)."""
    try:
        entity.__del__()
    except Exception:  # noqa: BLE001 - closing: the parent may be gone already
        pass


def _acquire_domain(domain: int, config: str) -> None:
    """Create the process's cyclonedds domain ``domain`` with ``config`` once; later users must ask the same."""
    from cyclonedds.domain import Domain

    with _domains_lock:
        have = _domains.get(domain)
        if have is None:
            _domains[domain] = [Domain(domain, config), config, 1]
        elif have[1] != config:
            raise ValueError(f"DDS domain {domain} is already open in this process with another scope/endpoints/size")
        else:
            have[2] += 1


def _release_domain(domain: int) -> None:
    with _domains_lock:
        have = _domains.get(domain)
        if have is not None:
            have[2] -= 1
            if have[2] == 0:
                del _domains[domain]
                _delete(have[0])


def endpoint_qos(qos: Qos, msgtype: str) -> Any:
    """The cyclonedds ``Qos`` of a reader or writer with ROS profile ``qos`` (module docstring)."""
    from cyclonedds.core import Policy
    from cyclonedds.qos import Qos as DdsQos

    history = Policy.History.KeepLast(qos.depth)
    reliable = qos.reliability == "reliable"
    policies = [
        history,
        Policy.Reliability.Reliable(MAX_BLOCKING_NS) if reliable else Policy.Reliability.BestEffort,
        Policy.WriterDataLifecycle(autodispose=False),
        Policy.DataRepresentation(use_cdrv0_representation=True),
        Policy.Userdata(f"typehash={type_hash(msgtype)};".encode()),
    ]
    if qos.durability == "transient_local":
        policies += [Policy.Durability.TransientLocal, Policy.DurabilityService(0, history, -1, -1, -1)]
    else:
        policies.append(Policy.Durability.Volatile)
    return DdsQos(*policies)


class DdsPublisher:
    """A DDS writer of ``msgtype`` on ``topic``; :meth:`publish` encodes with rosbags and writes the CDR."""

    def __init__(self, mw: DdsMiddleware, topic: str, msgtype: str, qos: Qos) -> None:
        from cyclonedds.pub import DataWriter

        self.topic, self.msgtype, self.qos, self._mw = topic, msgtype, qos, mw
        self.writer = DataWriter(mw.publisher_entity, mw.topic_entity(topic, msgtype), qos=endpoint_qos(qos, msgtype))
        self.gid = self.writer.guid.bytes

    def publish(self, msg: Any) -> bool:
        """Write ``msg`` (a ``msgtype`` typestore object); False (counted) if DDS refused or timed out."""
        from cyclonedds._clayer import ddspy_write  # the binding's raw write: CDR bytes as they are

        data = encode(msg, self.msgtype)
        data = data.ljust((len(data) + 3) & ~3, b"\0")  # as the binding's own write pads
        if ddspy_write(self.writer._ref, data) < 0:
            self._mw.inbox.refuse("write_timeout", f"{self.topic}: DDS write failed or timed out")
            return False
        return True

    def matched(self) -> int:
        """Readers matched now."""
        return len(self.writer.get_matched_subscriptions())

    def close(self) -> None:
        self._mw.forget(self.gid, self, "writer")


class DdsSubscription:
    """A DDS reader of ``msgtype`` on ``topic``; each sample goes through the middleware's :class:`Inbox` to
    ``callback`` on cyclonedds' listener thread."""

    def __init__(self, mw: DdsMiddleware, topic: str, msgtype: str, callback: Callback, qos: Qos) -> None:
        from cyclonedds.core import Listener
        from cyclonedds.sub import DataReader

        self.topic, self.msgtype, self.qos, self.callback, self._mw = topic, msgtype, qos, callback, mw
        self._writers: dict[int, bytes] = {}
        self._lock = threading.Lock()
        self.listener = Listener(on_data_available=self._on_data)
        self.reader = DataReader(mw.subscriber_entity, mw.topic_entity(topic, msgtype),
                                 qos=endpoint_qos(qos, msgtype), listener=self.listener)  # fmt: skip
        self.gid = self.reader.guid.bytes

    def _writer_gid(self, handle: int) -> bytes:
        gid = self._writers.get(handle)
        if gid is None:
            try:
                ep = self.reader.get_matched_publication_data(handle)
                gid = ep.key.bytes if ep is not None else _ZERO_GID
            except Exception:  # noqa: BLE001 - the writer may be gone already
                gid = _ZERO_GID
            if len(self._writers) >= MAX_KNOWN_WRITERS:
                self._writers.clear()
            self._writers[handle] = gid
        return gid

    def _on_data(self, _reader: Any) -> None:
        from cyclonedds._clayer import ddspy_take  # the binding's raw take: CDR bytes, decoded here by rosbags
        from cyclonedds.core import InstanceState, SampleState, ViewState

        mask = SampleState.Any | ViewState.Any | InstanceState.Any
        with self._lock:  # one drain at a time per reader
            while True:
                got = ddspy_take(self.reader._ref, mask, TAKE_BATCH)
                if isinstance(got, int) or not got:
                    return
                for data, info in got:
                    if info.valid_data:
                        rec = Received(self._writer_gid(info.publication_handle), int(info.source_timestamp), len(data))
                        self._mw.inbox.deliver(self.topic, self.msgtype, data, rec, self.callback)

    def matched(self) -> int:
        """Writers matched now."""
        return len(self.reader.get_matched_publications())

    def close(self) -> None:
        self._mw.forget(self.gid, self, "reader")


class DdsMiddleware:
    """ROS 2 over cyclonedds: one participant for node ``namespace``/``node_name`` in DDS ``domain``."""

    kind = "cyclonedds"

    def __init__(self, *, domain: int = 0, scope: str = "localhost", node_name: str = "swarmloc", namespace: str = "/",
                 endpoints: Sequence[str] = (), max_bytes: int = MAX_BYTES, enclave: str = "/") -> None:  # fmt: skip
        from cyclonedds.core import Policy
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.pub import Publisher
        from cyclonedds.qos import Qos as DdsQos
        from cyclonedds.sub import Subscriber

        if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= MAX_ROS_DOMAIN:
            raise ValueError(f"domain must be a DDS domain id in 0..{MAX_ROS_DOMAIN}, got {domain!r}")
        self.node_name, self.namespace = check_node_name(node_name), check_namespace(namespace)
        self.domain, self.scope = domain, scope
        self.inbox = Inbox(max_bytes)
        self.counts, self.reasons = self.inbox.counts, self.inbox.reasons
        _acquire_domain(domain, dds_config(scope, endpoints, max_bytes))
        self._lock = threading.Lock()
        self._topics: dict[str, Any] = {}
        self._entities: dict[str, dict[bytes, Any]] = {"reader": {}, "writer": {}}
        try:
            ud = Policy.Userdata(f"enclave={check_namespace(enclave)};".encode())
            self.participant = DomainParticipant(domain, qos=DdsQos(ud))
            self.gid = self.participant.guid.bytes
            self.publisher_entity, self.subscriber_entity = Publisher(self.participant), Subscriber(self.participant)
            self._info = DdsPublisher(self, "/" + DISCOVERY_TOPIC, DISCOVERY_TYPE, DISCOVERY_INFO)
        except BaseException:
            _release_domain(domain)
            raise
        self._announce()

    def topic_entity(self, topic: str, msgtype: str) -> Any:
        """The participant's DDS topic for ROS ``topic`` (``ros_discovery_info`` unprefixed) of ``msgtype``."""
        from cyclonedds.topic import Topic

        from swarmloc.rmw.idl import idl_class

        name = DISCOVERY_TOPIC if topic == "/" + DISCOVERY_TOPIC else dds_topic(topic)
        with self._lock:
            have = self._topics.get(name)
            if have is None:
                have = self._topics[name] = (Topic(self.participant, name, idl_class(msgtype)), msgtype)
        if have[1] != msgtype:
            raise ValueError(f"topic {topic} is already used with type {have[1]} in this middleware, not {msgtype}")
        return have[0]

    def publisher(self, topic: str, msgtype: str, qos: Qos = DEFAULT) -> DdsPublisher:
        """A writer of ``msgtype`` on the fully qualified ROS topic ``topic``."""
        pub = DdsPublisher(self, check_topic(topic), check_msgtype(msgtype), check_qos(qos))
        self._add("writer", pub)
        return pub

    def subscription(self, topic: str, msgtype: str, callback: Callback, qos: Qos = DEFAULT) -> DdsSubscription:
        """A reader of ``msgtype`` on ``topic``; ``callback(msg, Received)`` runs on cyclonedds' thread."""
        if not callable(callback):
            raise ValueError(f"callback must be callable, got {callback!r}")
        sub = DdsSubscription(self, check_topic(topic), check_msgtype(msgtype), callback, check_qos(qos))
        self._add("reader", sub)
        return sub

    def _add(self, kind: str, endpoint: Any) -> None:
        with self._lock:
            self._entities[kind][endpoint.gid] = endpoint
        self._announce()

    def forget(self, gid: bytes, endpoint: Any, kind: str) -> None:
        """Delete ``endpoint``'s DDS entity and drop it from the graph announcement."""
        with self._lock:
            known = self._entities[kind].pop(gid, None) is not None
        _delete(endpoint.writer if kind == "writer" else endpoint.reader)
        if known:
            self._announce()

    def discovery_message(self) -> Any:
        """The ``ParticipantEntitiesInfo`` this participant publishes on ``ros_discovery_info``."""
        import numpy as np

        T = typestore().types
        gid = T["rmw_dds_common/msg/Gid"]

        def gids(kind: str) -> list[Any]:
            return [gid(data=np.frombuffer(g, dtype=np.uint8).copy()) for g in self._entities[kind]]

        with self._lock:
            readers, writers = gids("reader"), gids("writer")
        node = T["rmw_dds_common/msg/NodeEntitiesInfo"](
            node_namespace=self.namespace, node_name=self.node_name, reader_gid_seq=readers, writer_gid_seq=writers
        )
        own = gid(data=np.frombuffer(self.gid, dtype=np.uint8).copy())
        return T[DISCOVERY_TYPE](gid=own, node_entities_info_seq=[node])

    def _announce(self) -> None:
        if getattr(self, "_info", None) is not None:
            self._info.publish(self.discovery_message())

    def close(self) -> None:
        """Delete the participant (and with it every reader and writer)."""
        if getattr(self, "participant", None) is None:
            return
        participant = self.participant
        del self.participant  # closed: a second close finds none
        _delete(participant)
        _release_domain(self.domain)
