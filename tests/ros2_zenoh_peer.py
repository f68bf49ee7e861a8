#!/usr/bin/env python3
"""A stand-in for a ROS 2 node on rmw_zenoh, with nothing but ``eclipse-zenoh`` and ``rosbags`` (no swarmloc, no ROS).

rmw_zenoh's layout, written out here from its source (rmw_zenoh_cpp ``liveliness_utils.cpp`` ``TopicInfo``,
``attachment_helpers.cpp``): a message of type ``pkg/msg/Name`` on topic ``/a/b`` in domain ``D`` is put on the key
``D/a/b/pkg::msg::dds_::Name_/RIHS01_<hash>`` (REP 2011 type hash, computed by rosbags) with CDR payload and a
33-byte attachment: int64 LE sequence number, int64 LE source time [ns], the byte 16, a 16-byte gid.

Modes (each exits on its own after ``--duration`` seconds at most)::

    ros2_zenoh_peer.py publish --input msgs.jsonl --connect tcp/127.0.0.1:PORT
        Lines {"topic", "type", "msg", "at"}: waits until each key has a matching subscriber, then puts each message
        at ``at`` s (default one after the other), writing what it sent to ``--sent``; ``--restamp`` sets every
        ``header.stamp`` to the wall time publishing began plus ``at``; ``--late K:S`` sends line ``K`` (from 0) ``S``
        seconds after its ``at`` (its stamp unchanged: a late input); with ``--topic``/``--out`` it also echoes
        (below) on the same session while publishing and lingering (``--linger`` s; with ``--expect TOPIC:N``, until
        ``N`` samples of each such topic came, ``--linger`` s at most).
    ros2_zenoh_peer.py echo --topic /r1/odom:nav_msgs/msg/Odometry --listen tcp/127.0.0.1:PORT --count N
        Writes each sample as {"topic", "type", "msg", "seq", "source_ns", "gid"} (stdout, or --out); "ready" on stderr.

Messages are JSON objects of the fields of the ROS message (arrays as lists). Exit status 0 when done as asked.
"""

import argparse
import dataclasses
import hashlib
import json
import struct
import sys
import threading
import time

import numpy as np
import zenoh
from _echo_tally import Tally, parse_expect
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype

STORE = get_typestore(Stores.ROS2_JAZZY)
VISION = {  # vision_msgs 4.1.1 (ROS 2 Jazzy), from its .msg files
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": "vision_msgs/ObjectHypothesis hypothesis\n"
    "geometry_msgs/PoseWithCovariance pose\n",
    "vision_msgs/msg/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size\n",
    "vision_msgs/msg/Detection3D": "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
    "vision_msgs/BoundingBox3D bbox\nstring id\n",
    "vision_msgs/msg/Detection3DArray": "std_msgs/Header header\nvision_msgs/Detection3D[] detections\n",
}
STORE.register({k: v for name, text in VISION.items() for k, v in get_types_from_msg(text, name).items()})


def key(domain: int, topic: str, msgtype: str) -> str:
    pkg, sub, name = msgtype.split("/")
    return f"{domain}/{topic.strip('/')}/{pkg}::{sub}::dds_::{name}_/{STORE.hash_rihs01(msgtype)}"


def build(msgtype: str, obj: dict):
    _consts, fields = STORE.fielddefs[msgtype]
    kw = {}
    for name, (node, desc) in fields:
        v = obj[name]
        if node == Nodetype.NAME:
            kw[name] = build(desc, v)
        elif node in (Nodetype.ARRAY, Nodetype.SEQUENCE) and desc[0][0] == Nodetype.NAME:
            kw[name] = [build(desc[0][1], x) for x in v]
        elif node in (Nodetype.ARRAY, Nodetype.SEQUENCE) and desc[0][1][0] != "string":
            kw[name] = np.asarray(v, dtype={"float64": np.float64, "float32": np.float32}.get(desc[0][1][0], np.uint8))
        else:
            kw[name] = v
    return STORE.types[msgtype](**kw)


def to_json(msg):
    if dataclasses.is_dataclass(msg):  # the message's fields, not its constants
        return {k: to_json(getattr(msg, k)) for k, _ in STORE.fielddefs[msg.__msgtype__][1]}
    if isinstance(msg, np.ndarray):
        return msg.tolist()
    if isinstance(msg, list):
        return [to_json(x) for x in msg]
    return msg


def session(args):
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("listen/endpoints", json.dumps(args.listen))
    cfg.insert_json5("connect/endpoints", json.dumps(args.connect))
    return zenoh.open(cfg)


def restamp(obj, sec, nanosec):
    """``obj`` (a message as JSON) with every ``header.stamp`` set to ``(sec, nanosec)``."""
    if isinstance(obj, dict):
        out = {k: restamp(v, sec, nanosec) for k, v in obj.items()}
        if isinstance(out.get("header"), dict) and "stamp" in out["header"]:
            out["header"] = {**out["header"], "stamp": {"sec": sec, "nanosec": nanosec}}
        return out
    if isinstance(obj, list):
        return [restamp(v, sec, nanosec) for v in obj]
    return obj


def publish(args) -> int:
    lines = [json.loads(x) for x in open(args.input) if x.strip()]
    s = session(args)
    tally = Tally()
    if args.topic:
        start_echo(s, args, tally)  # echoes while publishing and lingering, until the session closes
    pubs, seqs = {}, {}
    for rec in lines:
        k = key(args.domain, rec["topic"], rec["type"])
        if k not in pubs:
            pubs[k] = s.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
    deadline = time.monotonic() + args.match_timeout
    while not all(p.matching_status.matching for p in pubs.values()):
        if time.monotonic() > deadline:
            print("no subscriber matched", file=sys.stderr)
            return 1
        time.sleep(0.02)
    print("matched", flush=True)
    sent = open(args.sent, "w") if args.sent else None
    t0, base_ns = time.monotonic() + 0.2, (time.time_ns() // 1_000_000 + 200) * 1_000_000
    late = dict((int(k), float(v)) for k, v in (x.split(":") for x in args.late))
    when = [float(rec.get("at", 0.0)) + late.get(i, 0.0) for i, rec in enumerate(lines)]
    for i in sorted(range(len(lines)), key=lambda i: when[i]):  # in the order of sending (stable)
        rec, at = lines[i], float(lines[i].get("at", 0.0))
        delay = when[i] - (time.monotonic() - t0)
        if delay > 0:
            time.sleep(delay)
        if args.restamp:
            ns = base_ns + round(at * 1e9)
            rec = {**rec, "msg": restamp(rec["msg"], ns // 1_000_000_000, ns % 1_000_000_000)}
        k = key(args.domain, rec["topic"], rec["type"])
        gid = hashlib.sha256(f"{s.info.zid()}/{k}".encode()).digest()[:16]
        seqs[k] = seqs.get(k, 0) + 1
        payload = bytes(STORE.serialize_cdr(build(rec["type"], rec["msg"]), rec["type"]))
        pubs[k].put(payload, attachment=struct.pack("<qqB", seqs[k], time.time_ns(), 16) + gid)
        if sent:
            sent.write(json.dumps({**rec, "sent_ns": time.time_ns()}) + "\n")
            sent.flush()
    tally.wait(parse_expect(args.expect), args.linger)
    s.close()
    return 0


def start_echo(s, args, tally=None):
    """Subscribers of ``--topic`` writing each sample to ``--out`` (stdout), counted in ``tally``; the event is set
    once ``--count`` came."""
    out = open(args.out, "w") if args.out else sys.stdout
    lock, done, n = threading.Lock(), threading.Event(), [0]

    def handler(topic, typ):
        def on(sample):
            att = sample.attachment.to_bytes() if sample.attachment is not None else b""
            seq, ns = struct.unpack_from("<qq", att) if len(att) == 33 else (None, None)
            msg = STORE.deserialize_cdr(sample.payload.to_bytes(), typ)
            rec = {"topic": topic, "type": typ, "msg": to_json(msg), "seq": seq, "source_ns": ns,
                   "gid": att[17:].hex()}  # fmt: skip
            with lock:
                out.write(json.dumps(rec) + "\n")
                out.flush()
                n[0] += 1
                if tally is not None:
                    tally.add(topic)
                if args.count and n[0] >= args.count:
                    done.set()

        return on

    for spec in args.topic:
        topic, typ = spec.split(":", 1)
        _subs.append(s.declare_subscriber(key(args.domain, topic, typ), handler(topic, typ)))
    print("ready", file=sys.stderr, flush=True)
    return done


_subs = []  # subscribers live as long as the session


def echo(args) -> int:
    s = session(args)
    done = start_echo(s, args)
    done.wait(args.duration)
    s.close()
    return 0 if (not args.count or done.is_set()) else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("mode", choices=("publish", "echo"))
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--listen", action="append", default=[])
    ap.add_argument("--connect", action="append", default=[])
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--input", default=None)
    ap.add_argument("--match-timeout", type=float, default=15.0)
    ap.add_argument("--linger", type=float, default=0.5, help="publish: stay [s] (at most, with --expect)")
    ap.add_argument("--expect", action="append", default=[], help="publish: TOPIC:N, stay until N echoed")
    ap.add_argument("--topic", action="append", default=[])
    ap.add_argument("--out", default=None)
    ap.add_argument("--count", type=int, default=0)
    ap.add_argument("--sent", default=None)
    ap.add_argument("--restamp", action="store_true", help="publish: header stamps = start wall time + at")
    ap.add_argument("--late", action="append", default=[], help="publish: K:S sends line K S seconds late")
    args = ap.parse_args(argv)
    return publish(args) if args.mode == "publish" else echo(args)


if __name__ == "__main__":
    sys.exit(main())
