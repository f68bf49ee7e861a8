"""A stranger writing robots' live inputs, run as its own process (tests/test_live_auth.py). It does not import
swarmloc: it speaks the documented formats (docs/network.md) with eclipse-zenoh, json and rosbags only::

    python tests/live_attacker.py zenoh --connect EP,... --scope TEAM --robots 0,1,2 --t0 S --t1 S [--forge]
        [--key robot2.key --member 2]
    python tests/live_attacker.py ros2 --connect EP,... --team TEAM --robots 0,1,2 --t0 S --t1 S [--probe H:P,...]

For each robot it sends three attacks on that robot's input keys: an **odometry race** (intervals of 0.1 s over
``[t0, t1]`` at +5 m/s, overlapping every genuine one), **injected detections** (robot 0 or 1 seen 1 m ahead,
every 0.5 s) and an **end of stream**, in that order (against an unprotected input each one bites: the race's
intervals are taken and the genuine ones refused as overlapping, the end closes the stream; it carries the count
of the attacker's own inputs to that robot, so that it waits for them, as a genuine end waits for the robot's).

* ``zenoh``: swarmloc's JSON input keys ``swarmloc/<scope>/input/<robot>/{odom,det,progress}``, once each unsigned;
  with ``--forge`` once more each as a signed frame claiming to be the robot, signed with a key of its own (its key
  id is not the robot's); with ``--key FILE --member M``: only as signed frames of member ``M`` (a valid roster key,
  not the robot's), in the inputs' signing context. It waits (30 s at most) until a subscriber matches each key.
* ``ros2``: CDR in rmw_zenoh's key layout (``0/swarmloc/<team>/robot<id>/{odom,detections,input_progress}/...``),
  the end a ``std_msgs/msg/Header`` with frame_id ``end``. It first waits (30 s at most) for the team's liveliness
  tokens (``swarmloc/<team>/alive/<id>``: proof that it reached the team's network), and tries a plain TCP
  connection to each ``--probe`` address.

It prints one JSON line: ``sent`` (per robot and key), ``matched`` (keys that had a subscriber), ``alive`` (robot
ids whose token it saw), ``probes`` (address -> "connected" or the error).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import socket
import struct
import sys
import threading
import time

import zenoh

INPUT_CONTEXT = b"swarmloc-input-v1\0"
HEADER = struct.Struct(">4siQq8s")  # magic, sender, seq, stamp [ns], key id


class FrameSigner:
    """The signed frame of docs/network.md: header, payload, Ed25519 signature of context + key + NUL + frame."""

    def __init__(self, member: int, private) -> None:  # noqa: ANN001 - a cryptography Ed25519PrivateKey
        from cryptography.hazmat.primitives import serialization

        self.member, self.private = member, private
        raw = private.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
        self.key_id = hashlib.sha256(raw).digest()[:8]
        self.seq = time.time_ns()

    def seal(self, key: str, payload: bytes) -> bytes:
        self.seq += 1
        frame = HEADER.pack(b"SLS1", self.member, self.seq, time.time_ns(), self.key_id) + payload
        return frame + self.private.sign(INPUT_CONTEXT + key.encode() + b"\0" + frame)


def json_attacks(robot: int, t0: float, t1: float) -> dict[str, list[bytes]]:
    """The three attacks on one robot as JSON payloads, by input key."""
    odom, det = [], []
    n = max(1, round((t1 - t0) / 0.1))
    for k in range(n):
        odom.append(json.dumps({"t0": t0 + k * 0.1, "t1": t0 + (k + 1) * 0.1, "v": 5.0, "w": 0.0}).encode())
    cov = [0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.01]
    for k in range(max(1, int((t1 - t0) / 0.5))):
        det.append(json.dumps({"t": t0 + 0.25 + 0.5 * k, "kind": "pose", "z": [1.0, 0.0, 0.0], "cov": cov,
                               "target": 1 if robot == 0 else 0, "target_is_robot": True}).encode())  # fmt: skip
    return {"det": det, "odom": odom, "progress": [json.dumps({"end": True, "count": len(det) + len(odom)}).encode()]}


def wait_matched(pubs: list, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while not all(p.matching_status.matching for p in pubs):
        if time.monotonic() > end:
            return False
        time.sleep(0.02)
    return True


def zenoh_attack(a: argparse.Namespace, session, robots: list[int]) -> dict:  # noqa: ANN001
    signers = []
    if a.key:
        from cryptography.hazmat.primitives import serialization

        with open(a.key, "rb") as f:
            signers.append(FrameSigner(a.member, serialization.load_pem_private_key(f.read(), password=None)))
    block = zenoh.CongestionControl.BLOCK
    pubs = {(r, w): session.declare_publisher(f"swarmloc/{a.scope}/input/{r}/{w}", congestion_control=block)
            for r in robots for w in ("odom", "det", "progress")}  # fmt: skip
    matched = wait_matched(list(pubs.values()), 30.0)
    sent: dict[str, dict[str, int]] = {}  # way (unsigned, forged, member) -> robot -> frames
    for r in robots:
        ways: dict[str, FrameSigner | None] = {"member": signers[0]} if signers else {"unsigned": None}
        if a.forge:  # a key of its own, claiming to be robot r
            from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

            ways["forged"] = FrameSigner(r, Ed25519PrivateKey.generate())
        for what, payloads in json_attacks(r, a.t0, a.t1).items():  # detections, the odometry race, the end
            key = f"swarmloc/{a.scope}/input/{r}/{what}"
            for way, signer in ways.items():
                for p in payloads:
                    pubs[(r, what)].put(p if signer is None else signer.seal(key, p))
                    n = sent.setdefault(way, {})
                    n[str(r)] = n.get(str(r), 0) + 1
    return {"sent": sent, "matched": matched}


def ros2_attack(a: argparse.Namespace, session, robots: list[int]) -> dict:  # noqa: ANN001
    import numpy as np
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    alive: set[int] = set()
    seen = threading.Event()

    def on_token(sample) -> None:  # noqa: ANN001
        alive.add(int(str(sample.key_expr).rsplit("/", 1)[-1]))
        if alive >= set(robots):
            seen.set()

    tokens = session.liveliness().declare_subscriber(f"swarmloc/{a.team}/alive/*", history=True, handler=on_token)
    seen.wait(30.0)

    def key(r: int, what: str, msgtype: str) -> str:
        pkg, sub, name = msgtype.split("/")
        return f"0/swarmloc/{a.team}/robot{r}/{what}/{pkg}::{sub}::dds_::{name}_/{ts.hash_rihs01(msgtype)}"

    def header(t: float, frame: str):  # noqa: ANN202
        sec = int(t // 1)
        stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def pose(x: float):  # noqa: ANN202
        q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
        return T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=0.0, z=0.0), orientation=q)

    V3 = T["geometry_msgs/msg/Vector3"]
    odom_t, det_t, hdr_t = "nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseWithCovarianceStamped", "std_msgs/msg/Header"
    block = zenoh.CongestionControl.BLOCK
    sent: dict[str, int] = {}  # robot -> messages
    matched = False
    for r in robots:
        pubs = {w: session.declare_publisher(key(r, w, m), congestion_control=block)
                for w, m in (("odom", odom_t), ("detections", det_t), ("input_progress", hdr_t))}  # fmt: skip
        msgs: dict[str, list[bytes]] = {"detections": [], "odom": [], "input_progress": []}  # sent in this order
        n = max(1, round((a.t1 - a.t0) / 0.1))
        for k in range(1, n + 1):
            tw = T["geometry_msgs/msg/Twist"](linear=V3(x=5.0, y=0.0, z=0.0), angular=V3(x=0.0, y=0.0, z=0.0))
            twc = T["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=np.zeros(36))
            m = T[odom_t](header=header(a.t0 + 0.1 * k, "odom"), child_frame_id="base_link",
                          pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(0.0), covariance=np.zeros(36)),
                          twist=twc)  # fmt: skip
            msgs["odom"].append(bytes(ts.serialize_cdr(m, odom_t)))
        cov = np.diag([0.01, 0.01, 0, 0, 0, 0.01]).reshape(36)
        for k in range(max(1, int((a.t1 - a.t0) / 0.5))):
            m = T[det_t](header=header(a.t0 + 0.25 + 0.5 * k, f"robot{1 if r == 0 else 0}"),
                         pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(1.0), covariance=cov))  # fmt: skip
            msgs["detections"].append(bytes(ts.serialize_cdr(m, det_t)))
        n_in = len(msgs["odom"]) + len(msgs["detections"])
        msgs["input_progress"].append(bytes(ts.serialize_cdr(header(a.t0, f"end:{n_in}"), hdr_t)))
        for what, payloads in msgs.items():
            matched = matched or pubs[what].matching_status.matching
            for p in payloads:
                pubs[what].put(p)
                sent[str(r)] = sent.get(str(r), 0) + 1
    tokens.undeclare()
    return {"sent": sent, "matched": matched, "alive": sorted(alive)}


def probe(address: str) -> str:
    host, _, port = address.rpartition(":")
    s = socket.socket()
    s.settimeout(3.0)
    try:
        s.connect((host, int(port)))
        return "connected"
    except OSError as exc:
        return f"{type(exc).__name__}: {exc}"
    finally:
        s.close()


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("mode", choices=["zenoh", "ros2"])
    p.add_argument("--connect", required=True)
    p.add_argument("--scope", default=None, help="zenoh: the team's scope in the keys")
    p.add_argument("--team", default=None, help="ros2: the team's name")
    p.add_argument("--robots", required=True)
    p.add_argument("--t0", type=float, required=True)
    p.add_argument("--t1", type=float, required=True)
    p.add_argument("--forge", action="store_true")
    p.add_argument("--key", default=None)
    p.add_argument("--member", type=int, default=None)
    p.add_argument("--probe", default="")
    a = p.parse_args()
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("listen/endpoints", "[]")
    cfg.insert_json5("connect/endpoints", json.dumps(a.connect.split(",")))
    session = zenoh.open(cfg)
    robots = [int(r) for r in a.robots.split(",")]
    out = zenoh_attack(a, session, robots) if a.mode == "zenoh" else ros2_attack(a, session, robots)
    out["probes"] = {x: probe(x) for x in a.probe.split(",") if x}
    out["pid"] = os.getpid()
    time.sleep(1.0)  # let Zenoh flush what was put before the session closes
    session.close()
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
