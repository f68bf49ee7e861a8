"""ROS 2 compatible output of robot beliefs: ``geometry_msgs/msg/PoseWithCovarianceStamped`` messages, their CDR
bytes, the key expression and attachment rmw_zenoh uses for them, and rosbag2 files.

Conventions
-----------
A swarmloc belief is a Gaussian on SE(2) in exponential coordinates: a mean ``M`` (3x3 homogeneous matrix) and
the covariance ``S`` (3x3) of ``xi = (v1, v2, omega)`` in the *right* perturbation ``g = M exp(xi^)``, i.e. in
the robot's body frame. ROS wants the covariance of ``(x, y, z, rot_x, rot_y, rot_z)`` of the pose in the
message's frame (``frame_id``, default ``"map"``), 6x6 row-major (``geometry_msgs/msg/PoseWithCovariance``).
:func:`pose_covariance_world` maps ``S`` to first order: ``(x, y, theta)(M exp(xi)) = (t + R v, theta + omega)
+ O(|xi|^2)``, so the Jacobian is ``J = blockdiag(R, 1)`` and ``cov_xyt = J S J^T``. That 3x3 block goes to the
rows/columns ``(0, 1, 5)`` (x, y, yaw) of the 6x6 matrix.

* z, roll and pitch: position z is 0 and the orientation is the pure yaw quaternion ``(0, 0, sin(theta/2),
  cos(theta/2))``. Their variances and every cross term with them are ``unused_variance``, default **0.0**:
  the planar model holds them exactly, and this is what the planar localizer of ROS, nav2_amcl, publishes on
  ``/amcl_pose`` (it fills only the x/y block and ``[35]`` and leaves the rest 0), so RViz draws a flat
  ellipse. Pass e.g. ``unused_variance=1e6`` for consumers that treat 0 as "exactly measured" in 3D
  (robot_localization without ``two_d_mode``): a large variance marks the dimension as unknown.
* Times are float seconds. ``builtin_interfaces/msg/Time`` is ``(sec: int32, nanosec: uint32)``;
  :func:`stamp_to_ros` rounds to the nearest nanosecond and carries, so ``0 <= nanosec < 1e9`` always (a time
  of ``1.9999999999`` is ``(2, 0)``). Negative times and times past the int32 range are refused.
* Message definitions and type hash come from rosbags' typestore for **ROS 2 Jazzy** (``Stores.ROS2_JAZZY``,
  created once and cached, with vision_msgs added: :mod:`swarmloc.net.rosmsgs`). ``PoseWithCovarianceStamped``
  is the same in Humble and Jazzy (same RIHS01 hash).
* rosbags is imported only inside the functions here, so ``import swarmloc.net.ros`` works without it.

rmw_zenoh (source read: github.com/ros2/rmw_zenoh, rolling, ``rmw_zenoh_cpp/src/detail/``)
------------------------------------------------------------------------------------------
Data key expression (``liveliness_utils.cpp``, ``TopicInfo::TopicInfo``)::

    <domain_id>/<topic name without leading/trailing '/'>/<type name>/<type hash>

with the type name built as ``<namespace>::dds_::<Name>_`` (``type_support_common.cpp``,
``_create_type_name``), here ``geometry_msgs::msg::dds_::PoseWithCovarianceStamped_``, and the type hash as
``rosidl_stringify_type_hash`` writes it, ``RIHS01_<64 hex>`` (``rmw_publisher_data.cpp``). :func:`ros_key`
builds it; the hash is computed by rosbags (``Typestore.hash_rihs01``, REP 2011) and equals
``RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e``, the value that also appears in
generated ROS 2 type tables (the tests pin it). Humble has no type hashes; there the last component is
``TypeHashNotSupported`` (as third-party implementations of this wire format use; not read in rmw_zenoh's
humble branch). This module targets Jazzy and later.

Every sample rmw_zenoh publishes carries an **attachment** (``attachment_helpers.cpp``, ``AttachmentData::
serialize_to_zbytes``, zenoh-ext serialization), and an rmw_zenoh subscriber *drops* samples without one
("Unable to obtain attachment", ``rmw_subscription_data.cpp``). :func:`ros_attachment` builds it; 33 bytes::

    offset  size  field
    0       8     sequence_number   int64 little-endian (per publisher, starts at 1, +1 per sample)
    8       8     source_timestamp  int64 little-endian, ns since the Unix epoch (system clock at publish time)
    16      1     0x10              LEB128 length of the gid sequence (zenoh-ext serializes std::array as a
                                    length-prefixed sequence)
    17      16    source_gid        16 bytes (RMW_GID_STORAGE_SIZE since ROS 2 Iron)

rmw_zenoh derives the gid from an XXH3-128 hash of the publisher's liveliness token key; any 16 bytes that are
unique per publisher serve subscribers (they only report it in ``rmw_message_info_t``). Older rmw_zenoh_cpp
releases used other attachment encodings (zenoh-c 0.11 key/value pairs; an interim one with string keys).

The liveliness tokens (``@ros2_lv/<domain>/<zid>/<nid>/<id>/MP/<enclave>/<ns>/<node>/<topic>/<type>/<hash>/<qos>``)
that make the publisher appear in ``ros2 topic list``/``ros2 node list`` are :mod:`swarmloc.net.rosgraph`'s; a
node publishing with ``ros_domain`` declares them.
"""

from __future__ import annotations

import math
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.gaussian import world_covariance
from swarmloc.lie.checks import as_element, as_square
from swarmloc.lie.se2 import wrap_angle
from swarmloc.net.rosmsgs import typestore  # noqa: F401 - ros.typestore() is the project's one typestore

MSGTYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
DDS_TYPE_NAME = "geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"
GID_SIZE = 16
_INDEX = (0, 1, 5)  # x, y, yaw rows/columns of the 6x6 ROS covariance
_INT32_MAX = 2**31 - 1
_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1
_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def dds_type_name(msgtype: str = MSGTYPE) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_``: the type name ROS 2 gives a message type on DDS and in rmw_zenoh's
    keys (rmw_zenoh ``type_support_common.cpp``, ``_create_type_name``; rosidl's DDS IDL mapping)."""
    parts = msgtype.split("/") if isinstance(msgtype, str) else []
    if len(parts) != 3 or not all(_TOKEN.match(p) for p in parts):
        raise ValueError(f"msgtype must be 'package/msg/Name', got {msgtype!r}")
    pkg, sub, name = parts
    return f"{pkg}::{sub}::dds_::{name}_"


# ------------------------------------------------------------------------------------------------ geometry
pose_covariance_world = world_covariance
"""``(x, y, theta)`` of SE(2) poses and their first-order world-frame covariance
(:func:`swarmloc.gaussian.world_covariance`, under the name the ROS messages' code uses)."""


def yaw_to_quaternion(theta: float) -> tuple[float, float, float, float]:
    """``(x, y, z, w)`` of the rotation by ``theta`` about z."""
    h = 0.5 * float(theta)
    return 0.0, 0.0, math.sin(h), math.cos(h)


def quaternion(theta: float) -> Any:
    """A ``geometry_msgs/msg/Quaternion`` of the rotation by ``theta`` [rad] about z (:func:`yaw_to_quaternion`)."""
    qx, qy, qz, qw = yaw_to_quaternion(theta)
    return typestore().types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)


def pose(x: float, y: float, theta: float, z: float = 0.0) -> Any:
    """A ``geometry_msgs/msg/Pose`` at ``(x, y, z)`` [m], turned by ``theta`` [rad] about z."""
    T = typestore().types
    return T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z)),
                                       orientation=quaternion(theta))  # fmt: skip


def quaternion_to_yaw(x: float, y: float, z: float, w: float) -> float:
    """Yaw (rotation about z, ZYX convention) of a quaternion, in (-pi, pi]; exact inverse of
    :func:`yaw_to_quaternion` up to rounding, and the usual yaw for quaternions with roll/pitch."""
    return float(wrap_angle(math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))))


# ------------------------------------------------------------------------------------------------ time
def stamp_to_ros(stamp: float) -> tuple[int, int]:
    """Float seconds -> ``(sec, nanosec)``, rounded to the nearest ns, ``0 <= nanosec < 10**9``.

    The fractional part ``stamp - floor(stamp)`` is exact in floating point, so no precision is lost beyond
    that of ``stamp`` itself; a fraction that rounds to 10**9 ns carries into ``sec``.
    """
    t = float(stamp)
    if not math.isfinite(t) or t < 0.0:
        raise ValueError(f"stamp must be a finite time >= 0 s, got {stamp!r}")
    sec = math.floor(t)
    nsec = round((t - sec) * 1e9)
    if nsec >= 1_000_000_000:
        sec, nsec = sec + 1, nsec - 1_000_000_000
    if sec > _INT32_MAX:
        raise ValueError(f"stamp {stamp!r} s is past the int32 seconds of builtin_interfaces/msg/Time")
    return int(sec), int(nsec)


def ros_to_stamp(sec: int, nanosec: int) -> float:
    """``(sec, nanosec)`` -> float seconds."""
    return int(sec) + int(nanosec) * 1e-9


def stamp_ns(stamp: float) -> int:
    """``stamp`` [s] in whole nanoseconds (:func:`stamp_to_ros`'s rounding)."""
    sec, nsec = stamp_to_ros(stamp)
    return sec * 1_000_000_000 + nsec


# ------------------------------------------------------------------------------------------------ messages
def pose_message(
    stamp: float, mean: np.ndarray, cov: np.ndarray, frame_id: str = "map", unused_variance: float = 0.0
) -> Any:
    """A ``geometry_msgs/msg/PoseWithCovarianceStamped`` (rosbags typestore object) for one belief.

    Header stamp from :func:`stamp_to_ros`; position ``(x, y, 0)``; yaw quaternion; 6x6 row-major covariance
    with :func:`pose_covariance_world`'s block at indices (0, 1, 5) and ``unused_variance`` on the z, roll and
    pitch diagonal (0.0 by default, see the module docstring).
    """
    if not isinstance(frame_id, str):
        raise ValueError(f"frame_id must be a string, got {frame_id!r}")
    uv = float(unused_variance)
    if not math.isfinite(uv) or uv < 0.0:
        raise ValueError(f"unused_variance must be finite and >= 0, got {unused_variance!r}")
    M = as_element(mean, 2, "pose_message", "mean")
    S = as_square(cov, 3, "pose_message", "cov")
    if M.shape != (3, 3) or S.shape != (3, 3):
        raise ValueError(f"pose_message: one belief at a time (mean (3, 3), cov (3, 3)), got {M.shape}, {S.shape}")
    xyt, C = pose_covariance_world(M, S)
    cov6 = np.zeros((6, 6))
    cov6[np.ix_(_INDEX, _INDEX)] = C
    cov6[2, 2] = cov6[3, 3] = cov6[4, 4] = uv
    T = typestore().types
    return T[MSGTYPE](
        header=T["std_msgs/msg/Header"](stamp=ros_time(stamp), frame_id=frame_id),
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(*xyt), covariance=cov6.reshape(36)),
    )


def pose_from_message(msg: Any) -> tuple[float, np.ndarray, np.ndarray]:
    """``(stamp [s], xytheta (3,), cov_xyt (3, 3))`` of a ``PoseWithCovarianceStamped`` (the x, y, yaw block
    of its covariance; z, roll, pitch and their cross terms are dropped)."""
    st = msg.header.stamp
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    xyt = np.array([p.x, p.y, quaternion_to_yaw(q.x, q.y, q.z, q.w)], dtype=float)
    cov6 = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)
    return ros_to_stamp(st.sec, st.nanosec), xyt, cov6[np.ix_(_INDEX, _INDEX)].copy()


def to_cdr(msg: Any) -> bytes:
    """CDR bytes (little-endian, with the 4-byte encapsulation header) of a typestore message (e.g. a
    ``PoseWithCovarianceStamped``): what rmw_zenoh puts in the sample payload and rosbag2 stores with
    ``serialization_format: cdr``."""
    return bytes(typestore().serialize_cdr(msg, msg.__msgtype__))


def msgdef(msgtype: str) -> str:
    """The ``ros2msg`` definition of ``msgtype`` with every type it uses (the concatenated text rosbag2 writes as an
    MCAP schema and Foxglove's ROS 2 bridge advertises: the type's fields, then ``MSG: <type>`` sections)."""
    return typestore().generate_msgdef(msgtype, ros_version=2)[0]


def ros_time(stamp: float) -> Any:
    """A ``builtin_interfaces/msg/Time`` of ``stamp`` [s] (:func:`stamp_to_ros`)."""
    sec, nsec = stamp_to_ros(stamp)
    return typestore().types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)


def from_cdr(data: bytes) -> tuple[float, np.ndarray, np.ndarray]:
    """Inverse of ``to_cdr(pose_message(...))``: ``(stamp [s], xytheta (3,), cov_xyt (3, 3))``."""
    return pose_from_message(typestore().deserialize_cdr(bytes(data), MSGTYPE))


# ------------------------------------------------------------------------------------------------ rmw_zenoh
def type_hash(msgtype: str = MSGTYPE) -> str:
    """``RIHS01_<64 hex>`` of ``msgtype`` (default ``geometry_msgs/msg/PoseWithCovarianceStamped``; REP 2011,
    computed by rosbags from :func:`typestore`'s definitions)."""
    if msgtype not in typestore().fielddefs:
        raise ValueError(f"unknown message type {msgtype!r} (not in the ROS 2 Jazzy typestore)")
    return typestore().hash_rihs01(msgtype)


def ros_key(topic: str, domain_id: int = 0, msgtype: str = MSGTYPE) -> str:
    """The Zenoh key expression rmw_zenoh publishes ``topic`` of ``msgtype`` on (default ``PoseWithCovarianceStamped``).

    ``topic`` is a fully qualified ROS name (``/robot1/pose``; a missing leading slash is read as the root
    namespace): ``<domain_id>/robot1/pose/geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/RIHS01_<hex>``.
    """
    if not isinstance(topic, str) or not topic:
        raise ValueError(f"topic must be a non-empty string, got {topic!r}")
    name = topic[1:] if topic.startswith("/") else topic
    tokens = name.split("/")
    bad = [t for t in tokens if not _TOKEN.match(t)]
    if bad:
        raise ValueError(
            f"topic {topic!r} is not a valid ROS topic name: each '/'-separated token must be letters, digits "
            f"and '_', not start with a digit, and not be empty (bad: {bad!r})"
        )
    if isinstance(domain_id, bool) or not isinstance(domain_id, int | np.integer) or domain_id < 0:
        raise ValueError(f"domain_id must be an integer >= 0, got {domain_id!r}")
    return f"{int(domain_id)}/{name}/{dds_type_name(msgtype)}/{type_hash(msgtype)}"


def ros_attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte rmw_zenoh sample attachment (layout in the module docstring).

    ``seq`` publication sequence number (int64, rmw_zenoh counts from 1), ``stamp_ns`` source timestamp in ns
    since the epoch (int64; rmw_zenoh uses the system clock at publish time), ``gid`` the 16-byte publisher id.
    """
    for name, v in (("seq", seq), ("stamp_ns", stamp_ns)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or not _INT64_MIN <= int(v) <= _INT64_MAX:
            raise ValueError(f"{name} must be an int64, got {v!r}")
    gid = bytes(gid)
    if len(gid) != GID_SIZE:
        raise ValueError(f"gid must be {GID_SIZE} bytes (RMW_GID_STORAGE_SIZE), got {len(gid)}")
    return struct.pack("<qqB", int(seq), int(stamp_ns), GID_SIZE) + gid


def parse_ros_attachment(data: bytes) -> tuple[int, int, bytes]:
    """Inverse of :func:`ros_attachment`: ``(seq, stamp_ns, gid)``; ValueError if ``data`` is not that layout."""
    data = bytes(data)
    if len(data) != 17 + GID_SIZE or data[16] != GID_SIZE:
        raise ValueError(f"not an rmw_zenoh attachment (want 33 bytes with 0x10 at offset 16): {data.hex()}")
    seq, stamp_ns = struct.unpack_from("<qq", data)
    return seq, stamp_ns, data[17:]


# ------------------------------------------------------------------------------------------------ rosbag2
class BagWriter:
    """Write beliefs to a rosbag2 as ``PoseWithCovarianceStamped``: sqlite3 storage (``.db3``), format version
    ``rosbags.rosbag2.Writer.VERSION_LATEST`` (9 in rosbags 0.11; the rosbags writer has no default version).

    ``path`` is the bag directory and must not exist. Topics are created on first use (type
    ``geometry_msgs/msg/PoseWithCovarianceStamped``, ``serialization_format: cdr``, the type's RIHS01 hash).
    The log time of each message is its header stamp. Use as a context manager::

        with BagWriter("out_bag") as bag:
            bag.write("/robot1/pose", t, mean, cov)
    """

    def __init__(self, path: str | Path, frame_id: str = "map", unused_variance: float = 0.0) -> None:
        self.path = Path(path)
        self.frame_id = frame_id
        self.unused_variance = unused_variance
        self._writer: Any = None
        self._connections: dict[str, Any] = {}

    def __enter__(self) -> BagWriter:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        if self._writer is not None:
            raise RuntimeError(f"bag {self.path} is already open")
        writer = Writer(self.path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.SQLITE3)
        writer.open()
        self._writer = writer

    def write(self, topic: str, stamp: float, mean: np.ndarray, cov: np.ndarray) -> None:
        """Append one belief on ``topic`` (a ROS topic name, e.g. ``/robot1/pose``) at ``stamp`` [s]."""
        if self._writer is None:
            raise RuntimeError("BagWriter is not open (use it as a context manager or call open())")
        msg = pose_message(stamp, mean, cov, self.frame_id, self.unused_variance)
        conn = self._connections.get(topic)
        if conn is None:
            ros_key(topic)  # validates the topic name
            conn = self._writer.add_connection(topic, MSGTYPE, typestore=typestore(), serialization_format="cdr")
            self._connections[topic] = conn
        self._writer.write(conn, stamp_ns(stamp), to_cdr(msg))

    def close(self) -> None:
        if self._writer is not None:
            writer, self._writer = self._writer, None
            writer.close()


def read_bag(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Every ``PoseWithCovarianceStamped`` topic of a rosbag2: ``{topic: (times (T,), xytheta (T, 3),
    cov (T, 3, 3))}`` with times the header stamps [s], in the bag's log-time order. Other topics are skipped."""
    from rosbags.rosbag2 import Reader

    with Reader(Path(path)) as reader:
        conns = [c for c in reader.connections if c.msgtype == MSGTYPE]
        rows: dict[str, list[tuple[float, np.ndarray, np.ndarray]]] = {c.topic: [] for c in conns}
        for conn, _t, raw in reader.messages(connections=conns):
            rows[conn.topic].append(from_cdr(raw))
    out = {}
    for topic, r in rows.items():
        times = np.array([x[0] for x in r], dtype=float)
        xyt = np.array([x[1] for x in r], dtype=float).reshape(-1, 3)
        cov = np.array([x[2] for x in r], dtype=float).reshape(-1, 3, 3)
        out[topic] = (times, xyt, cov)
    return out
