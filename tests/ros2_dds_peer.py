#!/usr/bin/env python3
"""A stand-in for a stock ROS 2 robot on DDS, with nothing but the ``cyclonedds`` Python package (no swarmloc, no ROS).

The message types are written out here by hand from the standard ROS 2 interface definitions (``.msg`` -> IDL as
rosidl maps them: ``byte`` -> octet, ``float64`` -> double, ``T[]`` -> sequence, ``T[N]`` -> array; every struct
``@final`` in ``pkg::msg::dds_::Name_``), and so is ROS 2's name mangling (topic ``/a/b`` -> DDS topic ``rt/a/b``).
Endpoints use ROS's default QoS (reliable, volatile, keep last 10) or ``--qos best_effort`` (keep last 5, the
sensor-data profile), and put ``typehash=RIHS01_...;`` in their USER_DATA only when ``--typehash`` gives it (a
ROS 2 Jazzy robot does; matching does not depend on it).

Modes (each exits on its own after ``--duration`` seconds at most)::

    ros2_dds_peer.py publish --input msgs.jsonl [--sent sent.jsonl]
        Lines {"topic": "/r1/odom", "type": "nav_msgs/msg/Odometry", "msg": {...}, "at": 0.5}: waits until every
        topic's writer has ``--readers`` matched readers (``--match-timeout``), then publishes each message at
        ``at`` seconds (default: one after the other), writing each line it sent, with its wall time ("sent_ns"),
        to ``--sent``; then stays ``--linger`` seconds so reliable data is acknowledged (with ``--expect TOPIC:N``:
        until ``N`` samples of each such echoed topic came, ``--linger`` s at most). Prints "matched" when it
        starts sending.
        With ``--restamp`` every ``header.stamp`` (nested ones too) is set to the wall time publishing began plus
        ``at``: ROS time, as a live robot stamps its messages. With ``--topic``/``--out`` it also echoes those topics
        (below) on the same participant while publishing and lingering: one process, a robot's both sides.
    ros2_dds_peer.py echo --topic /r1/odom:nav_msgs/msg/Odometry [...] [--out got.jsonl] [--count N]
        Subscribes and writes each sample as a line {"topic", "type", "msg", "source_ns"} (stdout if no --out),
        stops after ``--count`` samples in all. Prints "ready" on stderr once its readers exist.

``--scope localhost`` configures the domain as rmw_cyclonedds (jazzy) does for ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
(multicast off, the local host as static peer, participant index auto up to 32, on the default interface);
``loopback`` (default) the same bound to the loopback interface (what a robot's CYCLONEDDS_URI sets to meet a
loopback-only participant whichever starts first); ``subnet``: cyclonedds' defaults. The exit status is 0 when it
did what was asked (all published; ``--count`` samples echoed), else 1.
"""

# no "from __future__ import annotations": cyclonedds reads the field annotations as evaluated types

import argparse
import json
import sys
import threading
import time
import typing
from dataclasses import dataclass, field, fields, is_dataclass

from _echo_tally import Tally, parse_expect
from cyclonedds.core import Listener, Policy
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from cyclonedds.idl.annotations import final
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

# ---------------------------------------------------------------------------------------- ROS 2 types, by hand
# builtin_interfaces, std_msgs, geometry_msgs, nav_msgs, sensor_msgs, tf2_msgs, diagnostic_msgs, rosgraph_msgs,
# rmw_dds_common (ROS 2 Jazzy) and vision_msgs 4.1.1.


@final
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0


@final
@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@final
@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@final
@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@final
@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0
    w: t.float64 = 1.0


@final
@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@final
@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose = field(default_factory=Pose)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@final
@dataclass
class PoseWithCovarianceStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"):
    header: Header = field(default_factory=Header)
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)


@final
@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@final
@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist = field(default_factory=Twist)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@final
@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@final
@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@final
@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@final
@dataclass
class Imu(IdlStruct, typename="sensor_msgs::msg::dds_::Imu_"):
    header: Header = field(default_factory=Header)
    orientation: Quaternion = field(default_factory=Quaternion)
    orientation_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    angular_velocity: Vector3 = field(default_factory=Vector3)
    angular_velocity_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    linear_acceleration: Vector3 = field(default_factory=Vector3)
    linear_acceleration_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)


@final
@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: t.sequence[TransformStamped] = field(default_factory=list)


@final
@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str = ""
    value: str = ""


@final
@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: t.byte = 0
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: t.sequence[KeyValue] = field(default_factory=list)


@final
@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header = field(default_factory=Header)
    status: t.sequence[DiagnosticStatus] = field(default_factory=list)


@final
@dataclass
class Clock(IdlStruct, typename="rosgraph_msgs::msg::dds_::Clock_"):
    clock: Time = field(default_factory=Time)


@final
@dataclass
class ObjectHypothesis(IdlStruct, typename="vision_msgs::msg::dds_::ObjectHypothesis_"):
    class_id: str = ""
    score: t.float64 = 0.0


@final
@dataclass
class ObjectHypothesisWithPose(IdlStruct, typename="vision_msgs::msg::dds_::ObjectHypothesisWithPose_"):
    hypothesis: ObjectHypothesis = field(default_factory=ObjectHypothesis)
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)


@final
@dataclass
class BoundingBox3D(IdlStruct, typename="vision_msgs::msg::dds_::BoundingBox3D_"):
    center: Pose = field(default_factory=Pose)
    size: Vector3 = field(default_factory=Vector3)


@final
@dataclass
class Detection3D(IdlStruct, typename="vision_msgs::msg::dds_::Detection3D_"):
    header: Header = field(default_factory=Header)
    results: t.sequence[ObjectHypothesisWithPose] = field(default_factory=list)
    bbox: BoundingBox3D = field(default_factory=BoundingBox3D)
    id: str = ""


@final
@dataclass
class Detection3DArray(IdlStruct, typename="vision_msgs::msg::dds_::Detection3DArray_"):
    header: Header = field(default_factory=Header)
    detections: t.sequence[Detection3D] = field(default_factory=list)


@final
@dataclass
class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: t.array[t.uint8, 16] = field(default_factory=lambda: [0] * 16)  # char[16]: IDL uint8


@final
@dataclass
class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: t.bounded_str[256] = ""
    node_name: t.bounded_str[256] = ""
    reader_gid_seq: t.sequence[Gid] = field(default_factory=list)
    writer_gid_seq: t.sequence[Gid] = field(default_factory=list)


@final
@dataclass
class ParticipantEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
    gid: Gid = field(default_factory=Gid)
    node_entities_info_seq: t.sequence[NodeEntitiesInfo] = field(default_factory=list)


TYPES = {
    "nav_msgs/msg/Odometry": Odometry,
    "geometry_msgs/msg/PoseWithCovarianceStamped": PoseWithCovarianceStamped,
    "geometry_msgs/msg/TransformStamped": TransformStamped,
    "sensor_msgs/msg/Imu": Imu,
    "tf2_msgs/msg/TFMessage": TFMessage,
    "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray,
    "rosgraph_msgs/msg/Clock": Clock,
    "vision_msgs/msg/Detection3DArray": Detection3DArray,
    "rmw_dds_common/msg/ParticipantEntitiesInfo": ParticipantEntitiesInfo,
}


# ---------------------------------------------------------------------------------------- JSON <-> samples
def to_json(value: typing.Any) -> typing.Any:
    if is_dataclass(value):
        return {f.name: to_json(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, list | tuple):
        return [to_json(v) for v in value]
    return value


def _build(hint: typing.Any, value: typing.Any) -> typing.Any:
    meta = getattr(hint, "__metadata__", ())
    for m in meta:
        if isinstance(m, t.array | t.sequence):
            return [_build(m.subtype, v) for v in value]
    if isinstance(hint, type) and issubclass(hint, IdlStruct):
        return from_json(hint, value)
    return value


def from_json(cls: type, obj: dict) -> typing.Any:
    hints = typing.get_type_hints(cls, include_extras=True)
    unknown = set(obj) - set(hints)
    if unknown:
        raise ValueError(f"{cls.__name__} has no fields {sorted(unknown)}")
    return cls(**{k: _build(hints[k], v) for k, v in obj.items()})


# ---------------------------------------------------------------------------------------- DDS, as ROS 2 does it
CONFIGS = {
    # rmw_cyclonedds (jazzy) for ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST: no multicast, this host as static peer
    "localhost": "<CycloneDDS><Domain><General><AllowMulticast>false</AllowMulticast></General><Discovery>"
    "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
    '<Peers><Peer address="localhost"/></Peers></Discovery></Domain></CycloneDDS>',
    # a robot's CYCLONEDDS_URI binding it to the loopback interface, with the jazzy LOCALHOST discovery settings
    "loopback": '<CycloneDDS><Domain><General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
    '<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers></Discovery>'
    "</Domain></CycloneDDS>",
}


def ros_topic(name: str) -> str:
    if not name.startswith("/") or name.endswith("/") or "//" in name:
        raise ValueError(f"not a fully qualified ROS topic name: {name!r}")
    return "rt" + name


def endpoint_qos(best_effort: bool, typehash: str | None) -> Qos:
    policies = [
        Policy.History.KeepLast(5 if best_effort else 10),
        Policy.Reliability.BestEffort if best_effort else Policy.Reliability.Reliable(max_blocking_time=10**8),
        Policy.Durability.Volatile,
        Policy.DataRepresentation(use_cdrv0_representation=True),
    ]
    if typehash:
        policies.append(Policy.Userdata(f"typehash={typehash};".encode()))
    return Qos(*policies)


_domains: list[Domain] = []  # the configured domain lives as long as the process


def participant(args: argparse.Namespace) -> DomainParticipant:
    if args.peer:  # unicast discovery of the given hosts only (a participant on another host aiming at this one)
        peers = "".join(f'<Peer address="{a}"/>' for a in args.peer)
        _domains.append(
            Domain(
                args.domain,
                "<CycloneDDS><Domain><General><AllowMulticast>false</AllowMulticast>"
                "</General><Discovery><ParticipantIndex>auto</ParticipantIndex><Peers>"
                f"{peers}</Peers></Discovery></Domain></CycloneDDS>",
            )
        )
    elif args.scope in CONFIGS:
        _domains.append(Domain(args.domain, CONFIGS[args.scope]))
    return DomainParticipant(args.domain, qos=Qos(Policy.Userdata(b"enclave=/;")))


def restamp(obj: typing.Any, sec: int, nanosec: int) -> typing.Any:
    """``obj`` (a message as JSON) with every ``header.stamp`` set to ``(sec, nanosec)``."""
    if isinstance(obj, dict):
        out = {k: restamp(v, sec, nanosec) for k, v in obj.items()}
        if isinstance(out.get("header"), dict) and "stamp" in out["header"]:
            out["header"] = {**out["header"], "stamp": {"sec": sec, "nanosec": nanosec}}
        return out
    if isinstance(obj, list):
        return [restamp(v, sec, nanosec) for v in obj]
    return obj


def publish(args: argparse.Namespace) -> int:
    src = sys.stdin if args.input == "-" else open(args.input)  # noqa: SIM115
    lines = [json.loads(line) for line in src if line.strip()]
    dp = participant(args)
    tally = Tally()
    echoing = start_readers(dp, args, tally) if args.topic else None
    writers: dict[tuple[str, str], DataWriter] = {}
    for rec in lines:
        k = (rec["topic"], rec["type"])
        if k not in writers:
            topic = Topic(dp, ros_topic(k[0]), TYPES[k[1]])
            writers[k] = DataWriter(dp, topic, qos=endpoint_qos(args.qos == "best_effort", args.typehash))
    deadline = time.monotonic() + args.match_timeout
    while any(len(w.get_matched_subscriptions()) < args.readers for w in writers.values()):
        if time.monotonic() > deadline:
            print("no reader matched", file=sys.stderr)
            return 1
        time.sleep(0.02)
    print("matched", flush=True)
    out = open(args.sent, "w") if args.sent else None  # noqa: SIM115
    t0, base_ns = time.monotonic(), (time.time_ns() // 1_000_000 + 200) * 1_000_000  # a whole ms, 0.2 s ahead
    t0 += 0.2
    for rec in lines:
        at = float(rec.get("at", 0.0))
        delay = at - (time.monotonic() - t0)
        if delay > 0:
            time.sleep(delay)
        if time.monotonic() - t0 > args.duration:
            return 1
        if args.restamp:
            ns = base_ns + round(at * 1e9)
            rec = {**rec, "msg": restamp(rec["msg"], ns // 1_000_000_000, ns % 1_000_000_000)}
        writers[(rec["topic"], rec["type"])].write(from_json(TYPES[rec["type"]], rec["msg"]))
        if out:
            out.write(json.dumps({**rec, "sent_ns": time.time_ns()}) + "\n")
            out.flush()
    tally.wait(parse_expect(args.expect), args.linger)
    if echoing is not None:
        echoing.set()
    return 0


def start_readers(dp: DomainParticipant, args: argparse.Namespace, tally: Tally | None = None) -> threading.Event:
    """Readers of ``--topic`` writing each sample to ``--out`` (stdout), counted in ``tally``; the event is set once
    ``--count`` came."""
    out = open(args.out, "w") if args.out else sys.stdout  # noqa: SIM115
    lock, done, n = threading.Lock(), threading.Event(), [0]

    def handler(name: str, typ: str):
        def on_data(reader: DataReader) -> None:
            for s in reader.take(N=64):
                if not s.sample_info.valid_data:
                    continue
                with lock:
                    rec = {"topic": name, "type": typ, "msg": to_json(s), "source_ns": s.sample_info.source_timestamp}
                    out.write(json.dumps(rec) + "\n")
                    out.flush()
                    n[0] += 1
                    if tally is not None:
                        tally.add(name)
                    if args.count and n[0] >= args.count:
                        done.set()

        return on_data

    for spec in args.topic:
        name, typ = spec.split(":", 1)
        topic = Topic(dp, ros_topic(name), TYPES[typ])
        qos = endpoint_qos(args.qos == "best_effort", args.typehash)
        _readers.append(DataReader(dp, topic, qos=qos, listener=Listener(on_data_available=handler(name, typ))))
    print("ready", file=sys.stderr, flush=True)
    return done


_readers: list[DataReader] = []  # readers live as long as the process


def echo(args: argparse.Namespace) -> int:
    done = start_readers(participant(args), args)
    done.wait(args.duration)
    return 0 if (not args.count or done.is_set()) else 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("mode", choices=("publish", "echo"))
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--scope", choices=("loopback", "localhost", "subnet"), default="loopback")
    ap.add_argument("--qos", choices=("reliable", "best_effort"), default="reliable")
    ap.add_argument("--peer", action="append", default=[], help="discover only these hosts, by unicast (repeatable)")
    ap.add_argument("--typehash", default=None, help="RIHS01_... to announce in the endpoints' USER_DATA")
    ap.add_argument("--duration", type=float, default=30.0, help="longest run [s]")
    ap.add_argument("--input", default="-")
    ap.add_argument("--sent", default=None)
    ap.add_argument("--match-timeout", type=float, default=15.0)
    ap.add_argument("--readers", type=int, default=1, help="publish once each writer has this many matched readers")
    ap.add_argument("--linger", type=float, default=1.0, help="publish: stay [s] (at most, with --expect)")
    ap.add_argument("--expect", action="append", default=[], help="publish: TOPIC:N, stay until N echoed")
    ap.add_argument("--topic", action="append", default=[], help="TOPIC:TYPE to echo (repeatable)")
    ap.add_argument("--out", default=None)
    ap.add_argument("--count", type=int, default=0)
    ap.add_argument("--restamp", action="store_true", help="publish: header stamps = start wall time + at")
    args = ap.parse_args(argv)
    return publish(args) if args.mode == "publish" else echo(args)


if __name__ == "__main__":
    sys.exit(main())
