#!/usr/bin/env python3
"""A stand-in for a ROS 2 node on rmw_zenoh, with nothing but ``eclipse-zenoh`` and ``rosbags`` (no swarmloc, no ROS).

rmw_zenoh's layout, written out here from its source (rmw_zenoh_cpp ``liveliness_utils.cpp`` ``TopicInfo``,
``attachment_helpers.cpp``): a message of type ``pkg/msg/Name`` on topic ``/a/b`` in domain ``D`` is put on the key
``D/a/b/pkg::msg::dds_::Name_/RIHS01_<hash>`` (REP 2011 type hash, computed by rosbags) with CDR payload and a
33-byte attachment: int64 LE sequence number, int64 LE source time [ns], the byte 16, a 16-byte gid.

Modes (each exits on its own after ``--duration`` seconds at most)::

    ros2_zenoh_peer.py publish --input msgs.jsonl --connect tcp/127.0.0.1:PORT
        Lines {"topic", "type", "msg"}: waits until each key has a matching subscriber, then puts each message.
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
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.base import Nodetype

STORE = get_typestore(Stores.ROS2_JAZZY)


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


def publish(args) -> int:
    lines = [json.loads(x) for x in open(args.input) if x.strip()]
    s = session(args)
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
    for rec in lines:
        k = key(args.domain, rec["topic"], rec["type"])
        gid = hashlib.sha256(f"{s.info.zid()}/{k}".encode()).digest()[:16]
        seqs[k] = seqs.get(k, 0) + 1
        payload = bytes(STORE.serialize_cdr(build(rec["type"], rec["msg"]), rec["type"]))
        pubs[k].put(payload, attachment=struct.pack("<qqB", seqs[k], time.time_ns(), 16) + gid)
    time.sleep(args.linger)
    s.close()
    return 0


def echo(args) -> int:
    s = session(args)
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
                if args.count and n[0] >= args.count:
                    done.set()

        return on

    subs = []
    for spec in args.topic:
        topic, typ = spec.split(":", 1)
        subs.append(s.declare_subscriber(key(args.domain, topic, typ), handler(topic, typ)))
    print("ready", file=sys.stderr, flush=True)
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
    ap.add_argument("--linger", type=float, default=0.5)
    ap.add_argument("--topic", action="append", default=[])
    ap.add_argument("--out", default=None)
    ap.add_argument("--count", type=int, default=0)
    args = ap.parse_args(argv)
    return publish(args) if args.mode == "publish" else echo(args)


if __name__ == "__main__":
    sys.exit(main())
