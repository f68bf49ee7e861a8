"""swarmloc.rmw: ROS 2 topics without ROS, checked against counterparts that do not import swarmloc: the DDS peer
(``ros2_dds_peer.py``, cyclonedds with hand-written ROS 2 types), the Zenoh peer (``ros2_zenoh_peer.py``, zenoh +
rosbags with rmw_zenoh's layout written out), and a hand-written XCDR1 reader."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _ros_json import to_json

from swarmloc.net.transport import free_ports
from swarmloc.rmw import (
    CLOCK,
    DEFAULT,
    SENSOR_DATA,
    TF,
    TF_STATIC,
    Qos,
    Received,
    check_node_name,
    check_topic,
    dds_topic,
    open_middleware,
    type_hash,
    typestore,
)
from swarmloc.rmw.ddsconfig import dds_config

HERE = Path(__file__).resolve().parent
DDS_PEER, ZENOH_PEER = HERE / "ros2_dds_peer.py", HERE / "ros2_zenoh_peer.py"
sys.path.insert(0, str(HERE))
import ros2_dds_peer as peer  # noqa: E402 - the counterpart's hand-written types (it imports no swarmloc)

pytestmark = pytest.mark.network

T = typestore().types
WAIT = 20.0  # [s] bound on every wait for discovery or delivery


# ------------------------------------------------------------------------------------------------ messages
def _time(sec: int, nsec: int) -> Any:
    return T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)


def _header(sec: int, frame: str) -> Any:
    return T["std_msgs/msg/Header"](stamp=_time(sec, 123_456_789), frame_id=frame)


def _vec(x: float, y: float, z: float) -> Any:
    return T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)


def _quat() -> Any:
    return T["geometry_msgs/msg/Quaternion"](x=0.1, y=-0.2, z=0.3, w=0.927)


def _pose(x: float) -> Any:
    return T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=-2.5, z=0.25), orientation=_quat())


def _pwc(x: float) -> Any:
    return T["geometry_msgs/msg/PoseWithCovariance"](pose=_pose(x), covariance=np.arange(36.0) / 7.0)


def odometry(i: int) -> Any:
    tw = T["geometry_msgs/msg/Twist"](linear=_vec(0.5 + i, 0.0, -0.1), angular=_vec(0.0, 0.01, 0.3))
    return T["nav_msgs/msg/Odometry"](header=_header(100 + i, "odom"), child_frame_id="base_link", pose=_pwc(1.0 + i),
                                      twist=T["geometry_msgs/msg/TwistWithCovariance"](
                                          twist=tw, covariance=np.linspace(0.0, 1.0, 36)))  # fmt: skip


def tf_message() -> Any:
    def ts(child: str, x: float) -> Any:
        tr = T["geometry_msgs/msg/Transform"](translation=_vec(x, 2.0, 0.0), rotation=_quat())
        return T["geometry_msgs/msg/TransformStamped"](header=_header(7, "map"), child_frame_id=child, transform=tr)

    return T["tf2_msgs/msg/TFMessage"](transforms=[ts("odom", 1.5), ts("robot1/base_link", -3.0)])


def diagnostic_array() -> Any:
    kv = T["diagnostic_msgs/msg/KeyValue"]
    st = T["diagnostic_msgs/msg/DiagnosticStatus"](level=1, name="swarmloc: filter", message="late inputs",
                                                   hardware_id="r1", values=[kv(key="late", value="3"),
                                                                             kv(key="rate", value="9.5")])  # fmt: skip
    ok = T["diagnostic_msgs/msg/DiagnosticStatus"](
        level=0, name="swarmloc: odom", message="", hardware_id="", values=[]
    )
    return T["diagnostic_msgs/msg/DiagnosticArray"](header=_header(9, ""), status=[st, ok])


def detections() -> Any:
    hyp = T["vision_msgs/msg/ObjectHypothesisWithPose"](
        hypothesis=T["vision_msgs/msg/ObjectHypothesis"](class_id="robot2", score=0.875), pose=_pwc(4.0)
    )
    box = T["vision_msgs/msg/BoundingBox3D"](center=_pose(4.0), size=_vec(0.4, 0.3, 0.2))
    det = T["vision_msgs/msg/Detection3D"](header=_header(11, "r1/camera"), results=[hyp, hyp], bbox=box, id="7")
    empty = T["vision_msgs/msg/Detection3D"](header=_header(11, "r1/camera"), results=[], bbox=box, id="")
    return T["vision_msgs/msg/Detection3DArray"](header=_header(11, "r1/camera"), detections=[det, empty])


def clock() -> Any:
    return T["rosgraph_msgs/msg/Clock"](clock=_time(5, 6))


def pose_stamped() -> Any:
    return T["geometry_msgs/msg/PoseWithCovarianceStamped"](header=_header(3, "map"), pose=_pwc(-1.0))


def imu() -> Any:
    c9 = np.arange(9.0) * 0.5
    return T["sensor_msgs/msg/Imu"](
        header=_header(2, "imu"),
        orientation=_quat(),
        orientation_covariance=c9,
        angular_velocity=_vec(0.0, 0.0, 0.2),
        angular_velocity_covariance=c9,
        linear_acceleration=_vec(0.0, 0.0, 9.81),
        linear_acceleration_covariance=c9,
    )


def discovery_info() -> Any:
    g = T["rmw_dds_common/msg/Gid"]
    gid = [g(data=np.arange(16, dtype=np.uint8) + k) for k in range(3)]
    node = T["rmw_dds_common/msg/NodeEntitiesInfo"](node_namespace="/r1", node_name="loc", reader_gid_seq=gid[:1],
                                                    writer_gid_seq=gid[1:])  # fmt: skip
    return T["rmw_dds_common/msg/ParticipantEntitiesInfo"](gid=gid[0], node_entities_info_seq=[node])


SAMPLES = {
    "nav_msgs/msg/Odometry": lambda: odometry(1),
    "tf2_msgs/msg/TFMessage": tf_message,
    "diagnostic_msgs/msg/DiagnosticArray": diagnostic_array,
    "vision_msgs/msg/Detection3DArray": detections,
    "rosgraph_msgs/msg/Clock": clock,
    "geometry_msgs/msg/PoseWithCovarianceStamped": pose_stamped,
    "sensor_msgs/msg/Imu": imu,
}


# ------------------------------------------------------------------------------------------------ names, QoS
def test_topic_names_follow_the_ros2_design_article():
    for ok in ("/foo", "/bar/baz", "/_private/thing", "/public_namespace/_private/thing", "/robot1/odom", "/foo_"):
        assert check_topic(ok) == ok
    for bad in ("foo", "/", "/foo/", "//bar", "/foo//bar", "/123abc", "/foo bar", "/~/foo", "/{sub}/foo", "/foo__bar",
                "/a/9b", "", "/" + "a" * 255):  # fmt: skip
        with pytest.raises(ValueError, match="topic"):
            check_topic(bad)
    assert dds_topic("/robot1/camera_left/image_raw") == "rt/robot1/camera_left/image_raw"
    assert check_node_name("localizer_2") == "localizer_2"
    for bad in ("2x", "a/b", "", "a-b"):
        with pytest.raises(ValueError, match="node_name"):
            check_node_name(bad)


def test_qos_presets_have_ros2_values_and_bad_profiles_are_refused():
    assert (DEFAULT.reliability, DEFAULT.durability, DEFAULT.depth) == ("reliable", "volatile", 10)
    assert (SENSOR_DATA.reliability, SENSOR_DATA.durability, SENSOR_DATA.depth) == ("best_effort", "volatile", 5)
    assert (TF.depth, TF_STATIC.durability, TF_STATIC.depth, CLOCK.reliability, CLOCK.depth) == (
        100, "transient_local", 1, "best_effort", 1)  # fmt: skip
    assert DEFAULT.zenoh_key() == ":2:,10:,:,:,,"  # rmw_zenoh's qos_to_keyexpr, defaults left empty
    assert TF_STATIC.zenoh_key() == "::,1:,:,:,,"
    for kw in ({"depth": 0}, {"depth": 10_001}, {"depth": True}, {"reliability": "sometimes"}, {"durability": "x"}):
        with pytest.raises(ValueError):
            Qos(**kw)


def test_type_hashes_are_rihs01_of_the_jazzy_definitions():
    # PoseWithCovarianceStamped's value is pinned by test_ros.py against ROS 2's generated tables; the
    # Detection3DArray value is the one an independent ROS 2 client's generated type table carries
    assert type_hash("vision_msgs/msg/Detection3DArray") == (
        "RIHS01_793f5eab9595ac1c0da07873cc859db42eae51f0ee76056db8562515d830e018")  # fmt: skip
    with pytest.raises(ValueError, match="unknown message type"):
        type_hash("nope_msgs/msg/Nothing")


# ------------------------------------------------------------------------------------------------ CDR
@pytest.mark.parametrize("msgtype", sorted(SAMPLES) + ["rmw_dds_common/msg/ParticipantEntitiesInfo"])
def test_generated_and_hand_written_idl_serialize_exactly_as_rosbags(msgtype):
    """The run-time IdlStruct, the peer's hand-written IdlStruct and rosbags give the same XCDR1 bytes."""
    from swarmloc.rmw.idl import idl_class

    msg = SAMPLES[msgtype]() if msgtype in SAMPLES else discovery_info()
    cdr = bytes(typestore().serialize_cdr(msg, msgtype))
    assert cdr[:4] == b"\x00\x01\x00\x00"
    generated = peer.from_json(idl_class(msgtype), to_json(msg)).serialize()
    hand = peer.from_json(peer.TYPES[msgtype], to_json(msg)).serialize()
    assert generated == cdr
    assert hand == cdr
    assert idl_class(msgtype).__idl_typename__ == peer.TYPES[msgtype].__idl_typename__


class Xcdr1:
    """A hand-written little-endian XCDR1 reader: each primitive aligned to its size from the end of the header."""

    def __init__(self, data: bytes) -> None:
        assert data[:4] == b"\x00\x01\x00\x00", data[:4].hex()
        self.b, self.p = data[4:], 0

    def prim(self, fmt: str) -> Any:
        n = struct.calcsize(fmt)
        self.p += -self.p % n
        (v,) = struct.unpack_from("<" + fmt, self.b, self.p)
        self.p += n
        return v

    def string(self) -> str:
        n = self.prim("I")
        raw = self.b[self.p : self.p + n]
        assert n >= 1 and raw[-1] == 0, "strings carry their NUL"
        self.p += n
        return raw[:-1].decode()

    def doubles(self, n: int) -> list[float]:
        return [self.prim("d") for _ in range(n)]


def test_odometry_cdr_decodes_with_a_hand_written_reader():
    from swarmloc.rmw.types import encode

    msg = odometry(3)
    r = Xcdr1(encode(msg, "nav_msgs/msg/Odometry"))
    assert (r.prim("i"), r.prim("I"), r.string(), r.string()) == (103, 123_456_789, "odom", "base_link")
    assert r.doubles(7) == [4.0, -2.5, 0.25, 0.1, -0.2, 0.3, 0.927]
    assert r.doubles(36) == list(np.arange(36.0) / 7.0)
    assert r.doubles(6) == [3.5, 0.0, -0.1, 0.0, 0.01, 0.3]
    assert r.doubles(36) == list(np.linspace(0.0, 1.0, 36))
    assert len(r.b) - r.p < 4  # nothing but padding left


# ------------------------------------------------------------------------------------------------ DDS peer
def _domain(k: int) -> int:
    return 100 + (os.getpid() * 7 + k) % 120


def _spawn(args: list[str], ready: str | None = "ready") -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if ready is not None:
        seen = threading.Event()

        def watch() -> None:
            for line in p.stderr:
                if line.strip() == ready:
                    seen.set()
                    return

        threading.Thread(target=watch, daemon=True).start()
        if not seen.wait(WAIT):
            p.kill()
            raise AssertionError(f"{args[0]} did not start: {p.communicate(timeout=5)}")
    return p


def _finish(p: subprocess.Popen) -> str:
    try:
        out, err = p.communicate(timeout=WAIT + 10)
    except subprocess.TimeoutExpired:
        p.kill()
        out, err = p.communicate()
    assert p.returncode == 0, f"peer failed ({p.returncode}): {err}"
    return out


def _until(cond: Any, what: str) -> None:
    deadline = time.monotonic() + WAIT
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def test_dds_peer_receives_what_swarmloc_publishes():
    dom = _domain(1)
    topics = {"/r1/odom": "nav_msgs/msg/Odometry", "/tf": "tf2_msgs/msg/TFMessage",
              "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}  # fmt: skip
    echo = _spawn([str(DDS_PEER), "echo", "--domain", str(dom), "--count", "4", "--duration", str(WAIT)]
                  + [a for t, ty in topics.items() for a in ("--topic", f"{t}:{ty}")])  # fmt: skip
    mw = open_middleware("cyclonedds", domain=dom, node_name="pub_test")
    try:
        pubs = {t: mw.publisher(t, ty, TF if t == "/tf" else DEFAULT) for t, ty in topics.items()}
        _until(lambda: all(p.matched() for p in pubs.values()), "the peer's readers")
        sent = {"/r1/odom": [odometry(1), odometry(2)], "/tf": [tf_message()], "/diagnostics": [diagnostic_array()]}
        for t, msgs in sent.items():
            for m in msgs:
                assert pubs[t].publish(m)
        got = [json.loads(line) for line in _finish(echo).splitlines()]
    finally:
        mw.close()
    by_topic = {t: [g["msg"] for g in got if g["topic"] == t] for t in topics}
    assert by_topic == {t: [to_json(m) for m in msgs] for t, msgs in sent.items()}


def test_swarmloc_receives_what_the_dds_peer_publishes(tmp_path):
    dom = _domain(2)
    msgs = [("/r1/odom", "nav_msgs/msg/Odometry", odometry(k)) for k in range(3)]
    msgs.append(("/r1/detections", "vision_msgs/msg/Detection3DArray", detections()))
    lines = [{"topic": t, "type": ty, "msg": to_json(m)} for t, ty, m in msgs]
    (tmp_path / "in.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    got: list[tuple[str, Any, Received]] = []
    done = threading.Event()

    def on(topic: str) -> Any:
        def cb(msg: Any, rx: Received) -> None:
            got.append((topic, msg, rx))
            if len(got) == len(msgs):
                done.set()

        return cb

    mw = open_middleware("cyclonedds", domain=dom, node_name="sub_test")
    try:
        for t, ty in {(t, ty) for t, ty, _ in msgs}:
            mw.subscription(t, ty, on(t))
        before = time.time_ns()
        pub = _spawn([str(DDS_PEER), "publish", "--domain", str(dom), "--input", str(tmp_path / "in.jsonl"),
                      "--sent", str(tmp_path / "sent.jsonl"), "--duration", str(WAIT)], ready=None)  # fmt: skip
        assert done.wait(WAIT + 10), f"got {len(got)} of {len(msgs)}: {mw.counts}"
        _finish(pub)
    finally:
        mw.close()
    for t in ("/r1/odom", "/r1/detections"):
        assert [to_json(m) for tt, m, _ in got if tt == t] == [to_json(m) for tt, _, m in msgs if tt == t]
    for _, _, rx in got:
        assert len(rx.publisher) == 16 and rx.publisher != bytes(16)
        assert before <= rx.source_time_ns <= time.time_ns()
        assert rx.size > 0
    assert mw.counts["delivered"] == len(msgs) and not mw.reasons


def test_dds_qos_matching_best_effort_reader_matches_reliable_writer_not_the_reverse(tmp_path):
    dom = _domain(3)
    # three samples 0.3 s apart: a best-effort reader may miss the first if it matched the writer a moment later
    lines = [{"topic": "/q/odom", "type": "nav_msgs/msg/Odometry", "msg": to_json(odometry(k)), "at": 0.3 * k}
             for k in range(3)]  # fmt: skip
    (tmp_path / "in.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    got: dict[str, list[Any]] = {"reliable": [], "best_effort": []}
    mw = open_middleware("cyclonedds", domain=dom, node_name="qos_test")
    try:
        subs = {k: mw.subscription("/q/odom", "nav_msgs/msg/Odometry", lambda m, rx, k=k: got[k].append(m),
                                   Qos(reliability=k)) for k in got}  # fmt: skip
        for writer_qos in ("reliable", "best_effort"):
            for v in got.values():
                v.clear()
            # the peer sends once as many readers matched as should (reliable writer: both; best effort: one)
            args = ["publish", "--domain", str(dom), "--qos", writer_qos, "--input", str(tmp_path / "in.jsonl"),
                    "--readers", "2" if writer_qos == "reliable" else "1"]  # fmt: skip
            pub = _spawn([str(DDS_PEER), *args, "--linger", "1.5", "--duration", str(WAIT)], ready=None)
            _finish(pub)
            if writer_qos == "reliable":
                assert len(got["reliable"]) == 3 and len(got["best_effort"]) >= 1
            else:  # a reliable reader never matches a best-effort writer (DDS request/offered rule)
                assert len(got["best_effort"]) >= 1 and got["reliable"] == []
                assert subs["reliable"].matched() == 0
    finally:
        mw.close()


def test_ros_discovery_info_names_the_node_and_its_endpoints():
    from cyclonedds.core import Policy
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.qos import Qos as DdsQos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    dom = _domain(4)
    mw = open_middleware("cyclonedds", domain=dom, node_name="graph_test", namespace="/r1")
    try:
        sub = mw.subscription("/r1/odom", "nav_msgs/msg/Odometry", lambda m, rx: None)
        pub = mw.publisher("/r1/pose", "geometry_msgs/msg/PoseWithCovarianceStamped")
        dp = DomainParticipant(dom)
        qos = DdsQos(Policy.Reliability.Reliable(10**8), Policy.Durability.TransientLocal, Policy.History.KeepLast(1))
        rd = DataReader(dp, Topic(dp, "ros_discovery_info", peer.ParticipantEntitiesInfo), qos=qos)
        latest: list[Any] = []

        def announced(writers: int) -> bool:
            latest.extend(s for s in rd.take(N=16) if s.sample_info.valid_data)
            return bool(latest) and len(latest[-1].node_entities_info_seq[0].writer_gid_seq) == writers

        _until(lambda: announced(1), "the discovery info")
        info = latest[-1]
        assert bytes(info.gid.data) == mw.gid
        (node,) = info.node_entities_info_seq
        assert (node.node_namespace, node.node_name) == ("/r1", "graph_test")
        assert [bytes(g.data) for g in node.reader_gid_seq] == [sub.gid]
        assert [bytes(g.data) for g in node.writer_gid_seq] == [pub.gid]
        assert dp.guid.bytes != mw.gid
        pub.close()  # a closed writer leaves the announcement
        latest.clear()
        _until(lambda: announced(0), "the writer's removal")
        assert [bytes(g.data) for g in latest[-1].node_entities_info_seq[0].reader_gid_seq] == [sub.gid]
    finally:
        mw.close()


# ------------------------------------------------------------------------------------------------ bad input
def _raw_writer(dom: int, topic: str, cls: type) -> Any:
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    dp = DomainParticipant(dom)
    return DataWriter(dp, Topic(dp, peer.ros_topic(topic), cls), qos=peer.endpoint_qos(False, None))


def test_dds_refuses_oversize_counts_callback_errors_and_keeps_going():
    """(cyclonedds checks a sample against the topic's type before it is sent: an undecodable one cannot be written
    to a DDS reader here; the shared receive path's bad-CDR handling is tested below and over Zenoh.)"""
    from cyclonedds._clayer import ddspy_write

    dom = _domain(5)
    mw = open_middleware("cyclonedds", domain=dom, node_name="bad_test", max_bytes=1024)
    calls: list[Any] = []

    def cb(msg: Any, rx: Received) -> None:
        calls.append(msg.header.stamp.sec)
        if len(calls) == 1:
            raise RuntimeError("the first one fails")

    try:
        sub = mw.subscription("/bad/odom", "nav_msgs/msg/Odometry", cb)
        wr = _raw_writer(dom, "/bad/odom", peer.Odometry)
        _until(lambda: sub.matched() and wr.get_matched_subscriptions(), "the raw writer")
        big = odometry(0)
        big.child_frame_id = "x" * 2000
        ddspy_write(wr._ref, peer.from_json(peer.Odometry, to_json(big)).serialize())  # valid, but 2.7 kB
        for k in (1, 2):
            wr.write(peer.from_json(peer.Odometry, to_json(odometry(k))))
        _until(lambda: mw.counts["received"] == 3, "three samples")
    finally:
        mw.close()
    assert dict(mw.reasons) == {"too_large": 1, "callback_error": 1}
    assert calls == [101, 102] and mw.counts["delivered"] == 1 and mw.counts["refused"] == 2


def test_receive_path_refuses_undecodable_cdr_without_raising():
    from swarmloc.rmw.inbox import Inbox

    box, calls = Inbox(max_bytes=4096), []
    good = bytes(typestore().serialize_cdr(odometry(1), "nav_msgs/msg/Odometry"))
    huge_seq = bytes(typestore().serialize_cdr(tf_message(), "tf2_msgs/msg/TFMessage"))[:4] + b"\xff\xff\xff\x7f"
    for raw in (
        b"",
        b"\x00\x01",
        b"\x02\x00\x00\x00" + good[4:],
        good[:100],
        good + b"\x00" * 8,
        b"\x00\x01\x00\x00" + b"\x07" * 40,
    ):
        assert not box.deliver("/t", "nav_msgs/msg/Odometry", raw, Received(bytes(16), None, len(raw)), calls.append)
    assert not box.deliver("/tf", "tf2_msgs/msg/TFMessage", huge_seq, Received(bytes(16), None, 8), calls.append)
    assert box.deliver(
        "/t", "nav_msgs/msg/Odometry", good, Received(bytes(16), None, len(good)), lambda m, rx: calls.append(m)
    )
    assert box.reasons == {"bad_cdr": 7} and len(calls) == 1 and box.counts["delivered"] == 1


def test_zenoh_refuses_bad_attachment_and_bad_cdr_and_keeps_going():
    import zenoh

    from swarmloc.net import ros
    from swarmloc.net.transport import open_session

    (port,) = free_ports(1)
    mw = open_middleware("zenoh", listen=[f"tcp/127.0.0.1:{port}"], node_name="bad_zenoh", max_bytes=1024)
    got: list[Received] = []
    s = open_session(connect=[f"tcp/127.0.0.1:{port}"])
    try:
        mw.subscription("/bad/odom", "nav_msgs/msg/Odometry", lambda m, rx: got.append(rx))
        p = s.declare_publisher(ros.ros_key("/bad/odom", 0, "nav_msgs/msg/Odometry"),
                                congestion_control=zenoh.CongestionControl.BLOCK)  # fmt: skip
        _until(lambda: p.matching_status.matching, "the subscription")
        good = bytes(typestore().serialize_cdr(odometry(1), "nav_msgs/msg/Odometry"))
        gid = bytes(range(16))
        p.put(good, attachment=b"\x01\x02")  # not rmw_zenoh's layout
        p.put(b"\x00\x01\x00\x00garbage", attachment=ros.ros_attachment(1, 5, gid))
        p.put(good + b"\x00" * 2000, attachment=ros.ros_attachment(2, 5, gid))
        p.put(good, attachment=ros.ros_attachment(3, 6, gid))
        p.put(good)  # no attachment: delivered, counted
        _until(lambda: mw.counts["received"] == 5, "five samples")
    finally:
        s.close()
        mw.close()
    assert dict(mw.reasons) == {"bad_attachment": 1, "bad_cdr": 1, "too_large": 1}
    assert got == [Received(gid, 6, len(good)), Received(bytes(16), None, len(good))]
    assert mw.counts["no_attachment"] == 1


# ------------------------------------------------------------------------------------------------ Zenoh peer
def test_zenoh_round_trip_with_an_rmw_zenoh_layout_peer(tmp_path):
    a, b = free_ports(2)
    echo = _spawn([str(ZENOH_PEER), "echo", "--listen", f"tcp/127.0.0.1:{a}", "--count", "2", "--duration", str(WAIT),
                   "--topic", "/r1/odom:nav_msgs/msg/Odometry"])  # fmt: skip
    mw = open_middleware("zenoh", endpoints=[f"tcp/127.0.0.1:{a}"], listen=[f"tcp/127.0.0.1:{b}"], node_name="zt",
                         namespace="/r1")  # fmt: skip
    got: list[tuple[Any, Received]] = []
    done = threading.Event()
    try:
        pub = mw.publisher("/r1/odom", "nav_msgs/msg/Odometry")
        _until(pub.matched, "the peer's subscriber")
        for k in (1, 2):
            pub.publish(odometry(k))
        echoed = [json.loads(x) for x in _finish(echo).splitlines()]
        assert pub.token in mw.graph.keys
        pub.close()  # its MP liveliness token goes with it
        assert pub.token not in mw.graph.keys and any("/NN/" in k for k in mw.graph.keys)
        assert [e["msg"] for e in echoed] == [to_json(odometry(1)), to_json(odometry(2))]
        assert [e["seq"] for e in echoed] == [1, 2] and {e["gid"] for e in echoed} == {pub.gid.hex()}

        mw.subscription("/r1/odom_in", "nav_msgs/msg/Odometry", lambda m, rx: (got.append((m, rx)), done.set()))
        line = {"topic": "/r1/odom_in", "type": "nav_msgs/msg/Odometry", "msg": to_json(odometry(5))}
        (tmp_path / "in.jsonl").write_text(json.dumps(line) + "\n")
        before = time.time_ns()
        p = _spawn([str(ZENOH_PEER), "publish", "--connect", f"tcp/127.0.0.1:{b}", "--input",
                    str(tmp_path / "in.jsonl"), "--duration", str(WAIT)], ready=None)  # fmt: skip
        assert done.wait(WAIT), mw.counts
        _finish(p)
    finally:
        mw.close()
    ((msg, rx),) = got
    assert to_json(msg) == to_json(odometry(5))
    assert rx.publisher != bytes(16) and before <= rx.source_time_ns <= time.time_ns()


# ------------------------------------------------------------------------------------------------ scope, install
def test_localhost_config_binds_loopback_without_multicast_and_refuses_other_peers():
    root = ET.fromstring(dds_config("localhost", ["127.0.0.1", "localhost:7410"]))
    dom = root.find("Domain")
    assert [n.get("address") for n in dom.findall("General/Interfaces/NetworkInterface")] == ["127.0.0.1"]
    assert dom.findtext("General/AllowMulticast") == "false"
    assert [p.get("address") for p in dom.findall("Discovery/Peers/Peer")] == ["127.0.0.1", "127.0.0.1",
                                                                              "localhost:7410"]  # fmt: skip
    subnet = ET.fromstring(dds_config("subnet", ["192.0.2.7"])).find("Domain")
    assert subnet.find("General/Interfaces") is None and subnet.findtext("General/AllowMulticast") is None
    assert [p.get("address") for p in subnet.findall("Discovery/Peers/Peer")] == ["192.0.2.7"]
    with pytest.raises(ValueError, match="loopback"):
        dds_config("localhost", ["192.0.2.7"])
    with pytest.raises(ValueError, match="loopback"):
        open_middleware("zenoh", endpoints=["tcp/192.0.2.7:7447"])
    with pytest.raises(ValueError, match="scope"):
        dds_config("everywhere")


def test_importing_rmw_needs_no_cyclonedds_and_opening_it_names_the_extra():
    code = (
        "import sys; sys.modules['cyclonedds'] = None\n"
        "import swarmloc.rmw as r\n"
        "try:\n    r.open_middleware('cyclonedds')\nexcept RuntimeError as e:\n    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "pip install 'swarmloc[ros]'" in out.stdout
