"""ROS 2 output of beliefs (swarmloc.net.ros): covariance conversion, messages, CDR, rmw_zenoh key and attachment,
rosbag2 round trip."""

from __future__ import annotations

import math
import re
import struct
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from swarmloc.lie.se2 import SE2, wrap_angle
from swarmloc.net import ros

pytestmark = pytest.mark.unit


# RIHS01 of geometry_msgs/msg/PoseWithCovarianceStamped (Jazzy; REP 2011). Pinned independently of rosbags: the
# same string appears in generated ROS 2 type tables (e.g. C type tables listing
# "geometry_msgs::msg::dds_::PoseWithCovarianceStamped" with this hash).
POSE_COV_STAMPED_HASH = "RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e"


@pytest.fixture
def rosbags():
    import rosbags

    return rosbags


def random_belief(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    xyt = np.array([rng.uniform(-100, 100), rng.uniform(-100, 100), rng.uniform(-np.pi, np.pi)])
    A = rng.normal(size=(3, 3)) * rng.uniform(0.01, 1.0)
    return SE2.from_xytheta(xyt), A @ A.T + 1e-6 * np.eye(3)


# ------------------------------------------------------------------------------------------------ covariance
def test_pose_covariance_world_matches_monte_carlo():
    """Sample xi ~ N(0, S), push M exp(xi) through (x, y, theta) and compare the sample covariance.

    Tolerance per entry (i, j): 6 standard errors of a sample covariance of N Gaussian draws,
    sqrt((C_ii C_jj + C_ij^2) / N), plus a bound on what the first-order map leaves out: the translation of
    M exp(xi) is t + R (v + (omega/2) [-v2, v1] + O(|xi|^3)), whose quadratic term adds about
    3 var(omega) tr(S_v) / 4 to the covariance (theta is exactly theta_M + omega).
    """
    rng = np.random.default_rng(20240611)
    M = SE2.from_xytheta(np.array([3.0, -1.0, 2.0]))
    sd = np.array([0.05, 0.02, 0.03])
    corr = np.array([[1.0, 0.3, -0.4], [0.3, 1.0, 0.2], [-0.4, 0.2, 1.0]])
    S = corr * np.outer(sd, sd)
    n = 200_000
    xi = rng.multivariate_normal(np.zeros(3), S, size=n)
    p = SE2.to_xytheta(M @ SE2.exp(xi))
    xyt0, C = ros.pose_covariance_world(M, S)
    d = p - xyt0
    d[:, 2] = wrap_angle(d[:, 2])
    C_hat = np.cov(d.T)

    se = np.sqrt((np.outer(np.diag(C), np.diag(C)) + C**2) / n)
    tol = 6 * se + 3 * S[2, 2] * np.trace(S[:2, :2]) / 4
    assert np.all(np.abs(C_hat - C) <= tol), (C_hat, C, tol)
    assert np.allclose(xyt0, [3.0, -1.0, 2.0])
    assert np.all(np.abs(d.mean(axis=0)) <= 6 * np.sqrt(np.diag(C) / n) + 0.5 * np.abs(S).max())

    # the test can tell the right map from the likely wrong ones: no rotation (S itself), and the
    # left-perturbation Jacobian [[I, (-y, x)], [0, 1]]
    assert np.any(np.abs(C_hat - S) > tol)
    x, y = xyt0[:2]
    J_left = np.array([[1.0, 0.0, -y], [0.0, 1.0, x], [0.0, 0.0, 1.0]])
    assert np.any(np.abs(C_hat - J_left @ S @ J_left.T) > tol)


def test_pose_covariance_world_is_rotation_and_batched():
    rng = np.random.default_rng(1)
    beliefs = [random_belief(rng) for _ in range(5)]
    Ms = np.stack([b[0] for b in beliefs])
    Ss = np.stack([b[1] for b in beliefs])
    xyt, C = ros.pose_covariance_world(Ms, Ss)
    assert xyt.shape == (5, 3) and C.shape == (5, 3, 3)
    for k, (M, S) in enumerate(beliefs):
        R = M[:2, :2]
        assert np.allclose(C[k][:2, :2], R @ S[:2, :2] @ R.T, atol=1e-14)
        assert np.allclose(C[k][:2, 2], R @ S[:2, 2], atol=1e-14)
        assert C[k][2, 2] == pytest.approx(S[2, 2], abs=1e-15)
        # a congruence by a rotation keeps the eigenvalues
        assert np.allclose(np.linalg.eigvalsh(C[k]), np.linalg.eigvalsh(S), atol=1e-12)
    with pytest.raises(ValueError):
        ros.pose_covariance_world(np.eye(3) * 2, np.eye(3))
    with pytest.raises(ValueError):
        ros.pose_covariance_world(np.eye(3), np.eye(2))


# ------------------------------------------------------------------------------------------------ quaternion
@pytest.mark.parametrize("theta", [0.0, 0.3, -0.3, 1.5, -2.9, np.pi, -np.pi + 1e-12, np.nextafter(np.pi, 0)])
def test_quaternion_yaw_round_trip(theta):
    q = ros.yaw_to_quaternion(theta)
    assert q[0] == 0.0 and q[1] == 0.0
    assert math.hypot(*q) == pytest.approx(1.0, abs=1e-15)
    back = ros.quaternion_to_yaw(*q)
    assert -np.pi < back <= np.pi
    assert abs(float(wrap_angle(back - theta))) < 1e-12
    # same rotation as the SE(2) matrix (z up, counter-clockwise positive)
    R = Rotation.from_quat(q).as_matrix()  # scipy: (x, y, z, w)
    assert np.allclose(R[:2, :2], SE2.from_xytheta(0.0, 0.0, theta)[:2, :2], atol=1e-15)


def test_quaternion_to_yaw_with_roll_and_pitch():
    rng = np.random.default_rng(2)
    for yaw, pitch, roll in rng.uniform([-np.pi, -1.2, -np.pi], [np.pi, 1.2, np.pi], size=(50, 3)):
        q = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat()
        assert abs(float(wrap_angle(ros.quaternion_to_yaw(*q) - yaw))) < 1e-9


# ------------------------------------------------------------------------------------------------ stamps
@pytest.mark.parametrize(
    "stamp, want",
    [
        (0.0, (0, 0)),
        (1.5, (1, 500_000_000)),
        (1e-9, (0, 1)),
        (4e-10, (0, 0)),
        (6e-10, (0, 1)),
        (1.9999999994, (1, 999_999_999)),
        (1.9999999999, (2, 0)),  # rounds up to 10**9 ns: carried into sec
        (41.0 - 1e-12, (41, 0)),
        (1_700_000_000.25, (1_700_000_000, 250_000_000)),
        (2**31 - 1 + 0.5, (2**31 - 1, 500_000_000)),
    ],
)
def test_stamp_to_ros_boundaries(stamp, want):
    sec, nsec = ros.stamp_to_ros(stamp)
    assert (sec, nsec) == want
    assert isinstance(sec, int) and isinstance(nsec, int)
    assert 0 <= nsec < 1_000_000_000


@pytest.mark.parametrize("stamp", [-1e-9, -1.0, float("nan"), float("inf"), 2.0**31, 2**31 - 1e-10])
def test_stamp_to_ros_refuses(stamp):
    with pytest.raises(ValueError):
        ros.stamp_to_ros(stamp)


@settings(max_examples=300, deadline=None)
@given(st.floats(min_value=0.0, max_value=2.0**31 - 1, allow_nan=False, allow_infinity=False))
def test_stamp_to_ros_nearest_nanosecond(stamp):
    sec, nsec = ros.stamp_to_ros(stamp)
    assert 0 <= nsec < 1_000_000_000
    err = Fraction(sec) + Fraction(nsec, 10**9) - Fraction(stamp)  # exact arithmetic
    assert abs(err) <= Fraction(1, 2 * 10**9) * (1 + Fraction(1, 10**6))


# ------------------------------------------------------------------------------------------------ messages / CDR
def test_pose_message_fields(rosbags):
    M = SE2.from_xytheta(np.array([1.25, -2.5, 2.0]))
    S = np.array([[0.04, 0.01, 0.002], [0.01, 0.09, -0.003], [0.002, -0.003, 0.01]])
    msg = ros.pose_message(12.000000001, M, S, frame_id="world")
    assert msg.__msgtype__ == "geometry_msgs/msg/PoseWithCovarianceStamped"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 1)
    assert msg.header.frame_id == "world"
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    assert (p.x, p.y, p.z) == (1.25, -2.5, 0.0)
    assert (q.x, q.y) == (0.0, 0.0) and q.z == pytest.approx(math.sin(1.0)) and q.w == pytest.approx(math.cos(1.0))
    cov6 = np.asarray(msg.pose.covariance).reshape(6, 6)
    _, C = ros.pose_covariance_world(M, S)
    idx = [0, 1, 5]
    assert np.array_equal(cov6[np.ix_(idx, idx)], C)
    others = np.ones((6, 6), bool)
    others[np.ix_(idx, idx)] = False
    assert np.all(cov6[others] == 0.0)
    assert np.array_equal(cov6, cov6.T)

    big = np.asarray(ros.pose_message(0.0, M, S, unused_variance=1e6).pose.covariance).reshape(6, 6)
    assert np.array_equal(np.diag(big)[[2, 3, 4]], [1e6] * 3)
    assert np.array_equal(big[np.ix_(idx, idx)], C)
    assert np.count_nonzero(big) == 9 + 3  # C's 3x3 block has no zero here, plus the 3 unused variances
    with pytest.raises(ValueError):
        ros.pose_message(0.0, M, S, unused_variance=-1.0)
    with pytest.raises(ValueError):
        ros.pose_message(0.0, np.stack([M, M]), np.stack([S, S]))


def test_cdr_bytes_layout(rosbags):
    """Decode the CDR by hand (independently of rosbags' deserializer)."""
    M = SE2.from_xytheta(np.array([1.25, -2.5, 0.7]))
    S = np.diag([0.04, 0.09, 0.01])
    data = ros.to_cdr(ros.pose_message(7.5, M, S))
    assert isinstance(data, bytes)
    assert data[:4] == b"\x00\x01\x00\x00"  # CDR little-endian encapsulation
    sec, nsec, slen = struct.unpack_from("<iII", data, 4)
    assert (sec, nsec, slen) == (7, 500_000_000, 4)
    assert data[16:20] == b"map\x00"
    # doubles are 8-aligned relative to the end of the encapsulation header: offset 16 + 4 = 20
    vals = struct.unpack_from("<7d36d", data, 20)
    assert vals[:3] == (1.25, -2.5, 0.0)
    assert vals[5] == pytest.approx(math.sin(0.35)) and vals[6] == pytest.approx(math.cos(0.35))
    cov6 = np.array(vals[7:]).reshape(6, 6)
    _, C = ros.pose_covariance_world(M, S)
    assert np.array_equal(cov6[np.ix_([0, 1, 5], [0, 1, 5])], C)
    assert len(data) == 20 + 8 * (7 + 36)


def test_cdr_round_trip(rosbags):
    rng = np.random.default_rng(3)
    for k in range(40):
        M, S = random_belief(rng)
        stamp = k * 0.1 + rng.integers(0, 10**6) + rng.integers(0, 10**9) * 1e-9
        data = ros.to_cdr(ros.pose_message(stamp, M, S, frame_id=f"map{k}"))
        t, xyt, C = ros.from_cdr(data)
        xyt0, C0 = ros.pose_covariance_world(M, S)
        sec, nsec = ros.stamp_to_ros(stamp)
        assert ros.stamp_to_ros(t) == (sec, nsec)
        assert abs(t - stamp) <= 1e-9
        assert np.allclose(xyt[:2], xyt0[:2], rtol=0, atol=1e-12)
        assert abs(float(wrap_angle(xyt[2] - xyt0[2]))) <= 1e-12
        assert -np.pi < xyt[2] <= np.pi
        assert np.allclose(C, C0, rtol=0, atol=1e-12)
        assert xyt.shape == (3,) and C.shape == (3, 3)


# ------------------------------------------------------------------------------------------------ rmw_zenoh
KEY_RE = re.compile(
    r"^(?P<domain>\d+)/(?P<topic>[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*)"
    r"/geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/RIHS01_(?P<hash>[0-9a-f]{64})$"
)


def test_ros_key_layout(rosbags):
    key = ros.ros_key("/robot1/pose")
    m = KEY_RE.match(key)
    assert m is not None, key
    assert m["domain"] == "0" and m["topic"] == "robot1/pose"
    assert len(m["hash"]) == 64
    assert key == f"0/robot1/pose/geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/{POSE_COV_STAMPED_HASH}"
    assert ros.type_hash() == POSE_COV_STAMPED_HASH
    assert ros.ros_key("robot1/pose") == key
    k7 = ros.ros_key("/team/robot_2/belief", domain_id=7)
    assert KEY_RE.match(k7)["domain"] == "7" and k7.startswith("7/team/robot_2/belief/")


@pytest.mark.parametrize("topic", ["", "/", "/a//b", "/a/", "/1abc", "/a b", "/a*", "/x/**", None])
def test_ros_key_refuses_bad_names(rosbags, topic):
    with pytest.raises(ValueError):
        ros.ros_key(topic)


@pytest.mark.parametrize("domain", [-1, 1.5, True, "0"])
def test_ros_key_refuses_bad_domain(rosbags, domain):
    with pytest.raises(ValueError):
        ros.ros_key("/a", domain_id=domain)


def test_ros_key_is_a_zenoh_key_expression(rosbags):
    import zenoh

    key = ros.ros_key("/robot1/pose", 3)
    ke = zenoh.KeyExpr(key)
    assert str(ke) == key
    assert zenoh.KeyExpr("3/robot1/pose/*/*").intersects(ke)
    assert not zenoh.KeyExpr("0/robot1/pose/**").intersects(ke)


def test_ros_attachment_layout():
    gid = bytes(range(16))
    att = ros.ros_attachment(1, 1_700_000_000_123_456_789, gid)
    assert len(att) == 33
    assert att[:8] == (1).to_bytes(8, "little")
    assert att[8:16] == (1_700_000_000_123_456_789).to_bytes(8, "little")
    assert att[16] == 0x10 and att[17:] == gid
    assert ros.parse_ros_attachment(att) == (1, 1_700_000_000_123_456_789, gid)
    neg = ros.ros_attachment(-2, 0, b"\xff" * 16)
    assert neg[:8] == b"\xfe" + b"\xff" * 7
    assert ros.parse_ros_attachment(neg) == (-2, 0, b"\xff" * 16)
    for bad in [(1, 0, b"\x00" * 15), (1, 0, b"\x00" * 24), (2**63, 0, gid), (1, -(2**63) - 1, gid), (1.0, 0, gid)]:
        with pytest.raises(ValueError):
            ros.ros_attachment(*bad)
    with pytest.raises(ValueError):
        ros.parse_ros_attachment(att[:-1])
    with pytest.raises(ValueError):
        ros.parse_ros_attachment(att[:16] + b"\x18" + gid)


def test_ros_attachment_matches_zenoh_ext_serializer():
    """rmw_zenoh serializes (int64, int64, std::array<uint8_t, 16>) with zenoh-ext; the Python binding of the
    same serializer must give the same bytes."""
    import zenoh
    import zenoh.ext as ext

    gid = bytes([7, 0, 255, 3, 9, 9, 1, 2, 200, 100, 50, 25, 12, 6, 3, 1])
    for seq, ts in [(1, 0), (42, 1_700_000_000_000_000_001), (-5, -(2**63))]:
        want = ext.z_serialize((ext.Int64(seq), ext.Int64(ts), [ext.UInt8(b) for b in gid])).to_bytes()
        assert ros.ros_attachment(seq, ts, gid) == want
        ours = zenoh.ZBytes(ros.ros_attachment(seq, ts, gid))
        assert ext.z_deserialize(tuple[ext.Int64, ext.Int64, list[ext.UInt8]], ours) == (seq, ts, list(gid))


# ------------------------------------------------------------------------------------------------ rosbag2
def test_bag_write_then_read(rosbags, tmp_path):
    rng = np.random.default_rng(4)
    written: dict[str, list[tuple[float, np.ndarray, np.ndarray]]] = {"/robot1/pose": [], "/robot2/pose": []}
    path = tmp_path / "beliefs"
    with ros.BagWriter(path) as bag:
        for k in range(12):
            topic = "/robot1/pose" if k % 3 else "/robot2/pose"
            t = 100.0 + 0.25 * k + rng.integers(0, 10**9) * 1e-9 / 8
            M, S = random_belief(rng)
            bag.write(topic, t, M, S)
            written[topic].append((t, M, S))
    with pytest.raises(RuntimeError):
        bag.write("/robot1/pose", 200.0, *random_belief(rng))

    got = ros.read_bag(path)
    assert set(got) == set(written)
    for topic, rows in written.items():
        times, xyt, cov = got[topic]
        assert times.shape == (len(rows),) and xyt.shape == (len(rows), 3) and cov.shape == (len(rows), 3, 3)
        for (t, M, S), tt, p, C in zip(rows, times, xyt, cov, strict=True):
            xyt0, C0 = ros.pose_covariance_world(M, S)
            assert ros.stamp_to_ros(tt) == ros.stamp_to_ros(t)
            assert np.allclose(p[:2], xyt0[:2], rtol=0, atol=1e-12)
            assert abs(float(wrap_angle(p[2] - xyt0[2]))) <= 1e-12
            assert np.allclose(C, C0, rtol=0, atol=1e-12)

    # what other rosbag2 readers see: topic types, cdr, counts, log times = header stamps, the type hash
    from rosbags.rosbag2 import Reader

    with Reader(path) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert set(conns) == set(written)
        for topic, c in conns.items():
            assert c.msgtype == "geometry_msgs/msg/PoseWithCovarianceStamped"
            assert c.ext.serialization_format == "cdr"
            assert c.msgcount == len(written[topic])
        logtimes = {topic: [] for topic in conns}
        for c, t, _raw in reader.messages():
            logtimes[c.topic].append(t)
    for topic, rows in written.items():
        sec_ns = [ros.stamp_to_ros(t) for t, _, _ in rows]
        assert logtimes[topic] == [s * 10**9 + n for s, n in sec_ns]
    meta = (path / "metadata.yaml").read_text()
    assert POSE_COV_STAMPED_HASH in meta
    assert "sqlite3" in meta

    with pytest.raises(Exception):  # noqa: B017 - rosbags refuses to overwrite an existing bag
        with ros.BagWriter(path) as bag:
            pass


def test_bag_writer_refuses_bad_topic(rosbags, tmp_path):
    with ros.BagWriter(tmp_path / "b") as bag:
        with pytest.raises(ValueError):
            bag.write("/bad topic", 1.0, np.eye(3), np.eye(3))
    assert ros.read_bag(tmp_path / "b") == {}
