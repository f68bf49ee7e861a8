"""ROS 2 messages to swarmloc's inputs and beliefs to ROS 2 messages: the one place both conversions are written
(the live node and the replay of a recording call these, so they see the same numbers).

Conventions (REP 103: x forward, y left, z up; REP 105: ``map``, ``odom``, ``base_link``):

* **Odometry in** (``nav_msgs/msg/Odometry``): the twist's ``linear.x`` [m/s] and ``angular.z`` [rad/s] of the
  message stamped ``t_k`` are the speed and yaw rate over ``(t_{k-1}, t_k]`` (wheel encoders report what happened
  since the last message): ``Odometry(robot, t_{k-1}, t_k, v, w)``. The first message only marks the start. The
  pose (in ``odom_frame``) is kept for the ``map -> odom`` transform, never fused.
* **Detections in** (``vision_msgs/msg/Detection3DArray``): ``header.frame_id`` the sensor's frame, mounted on
  ``base_link`` at ``(x, y, yaw)`` (a parameter). Per ``Detection3D``, the hypothesis with the highest score names
  the target: ``robot<N>`` (a teammate), ``landmark<N>``, or ``robot`` (a robot whose identity is not known:
  anonymous). Its ``pose`` is the target's pose in the sensor frame; the covariance's ``(x, y, yaw)`` block (rows
  and columns 0, 1, 5) is that pose's additive covariance in the sensor frame (ROS's convention). It becomes a
  ``"pose"`` detection ``z = mount * pose`` in ``base_link``, with the covariance of the exponential coordinates of
  ``z_true^-1 z`` to first order, ``T C T^T``, ``T = diag(R(yaw)^T, 1)`` (:func:`~swarmloc.kernels.group.
  absolute_to_pseudo`; a left composition by the mount leaves a right perturbation unchanged). A yaw variance of
  :data:`YAW_UNKNOWN` or more marks a position-only measurement (a landmark's barcode, a point): it becomes a
  ``"range_bearing"`` detection from ``base_link``, its covariance carried to first order.
* **Outputs**: the belief ``(mean, cov)`` of right-perturbation exponential coordinates, as ``(x, y, yaw)`` in
  ``world_frame`` with the first-order world covariance at rows/columns ``(0, 1, 5)``
  (:func:`swarmloc.net.ros.pose_message`); ``nav_msgs/msg/Odometry`` adds the twist in force; the transform
  ``world_frame -> odom_frame`` is ``T_map_base(t) T_odom_base(t)^-1``, ``T_odom_base(t)`` the odometry poses
  interpolated on SE(2) (the geodesic between the two messages around ``t``: constant twist).
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarmloc.events import Detection, Kind
from swarmloc.gaussian import symmetric
from swarmloc.kernels.group import absolute_to_pseudo
from swarmloc.lie import SE2
from swarmloc.net import ros as rosmsg
from swarmloc.rmw import typestore
from swarmloc.rmw.inbox import Refused
from swarmloc.rmw.types import header, pose_msg, stamp_of, twist_msg

ODOMETRY = "nav_msgs/msg/Odometry"
DETECTIONS = "vision_msgs/msg/Detection3DArray"
POSE = "geometry_msgs/msg/PoseWithCovarianceStamped"
TF = "tf2_msgs/msg/TFMessage"
DIAGNOSTICS = "diagnostic_msgs/msg/DiagnosticArray"
CLOCK = "rosgraph_msgs/msg/Clock"

YAW_UNKNOWN = 1e6
"""[rad^2] a detection whose yaw variance is at least this carries a position only."""
MAX_DETECTIONS = 256
"""Detections per array at most (the rest is refused, counted ``too_many``)."""
MAX_SPEED, MAX_RATE = 100.0, 100.0
"""[m/s], [rad/s]: odometry beyond these is refused (``bad_value``)."""
_TARGET = re.compile(r"^(robot|landmark)([0-9]{1,9})?$")


def _yaw(q: Any) -> float:
    return rosmsg.quaternion_to_yaw(q.x, q.y, q.z, q.w)


def _finite(*xs: float) -> bool:
    return all(math.isfinite(float(x)) for x in xs)


# ------------------------------------------------------------------------------------------------ inputs
@dataclass(frozen=True)
class OdomSample:
    """One odometry message: stamp [s], speed [m/s] and yaw rate [rad/s] over the interval ending at ``t``, its pose
    ``(x, y, yaw)`` in the odometry frame, and the twist's 6x6 covariance (row-major, passed on to the output)."""

    t: float
    v: float
    w: float
    pose: tuple[float, float, float]
    twist_cov: tuple[float, ...]


def odometry_in(msg: Any) -> OdomSample:
    """The :class:`OdomSample` of a ``nav_msgs/msg/Odometry``; :class:`Refused` for non-finite or absurd values."""
    t = stamp_of(msg.header)
    tw, p = msg.twist.twist, msg.pose.pose
    v, w = float(tw.linear.x), float(tw.angular.z)
    pose = (float(p.position.x), float(p.position.y), _yaw(p.orientation))
    if not _finite(t, v, w, *pose) or t <= 0:
        raise Refused("bad_value", f"odometry stamped {t} with twist ({v}, {w}) and pose {pose}")
    if abs(v) > MAX_SPEED or abs(w) > MAX_RATE:
        raise Refused("bad_value", f"odometry twist ({v} m/s, {w} rad/s) beyond ({MAX_SPEED}, {MAX_RATE})")
    cov = tuple(float(x) for x in np.asarray(msg.twist.covariance, dtype=float).reshape(36))
    return OdomSample(t, v, w, pose, cov if _finite(*cov) else (0.0,) * 36)


def _best(results: Any) -> Any:
    """The hypothesis with the highest finite score (the first of equal ones)."""
    if len(results) == 0:
        raise Refused("no_hypothesis", "a detection without any hypothesis")
    return max(results, key=lambda r: float(r.hypothesis.score) if math.isfinite(r.hypothesis.score) else -math.inf)


def _target(best: Any) -> tuple[int | None, bool]:
    """``(target id or None, is a robot)`` of a hypothesis's class id."""
    hit = _TARGET.match(str(best.hypothesis.class_id))
    if hit is None:
        raise Refused(
            "unknown_class", f"class id {str(best.hypothesis.class_id)[:40]!r} is not robot<N> or landmark<N>"
        )
    is_robot = hit.group(1) == "robot"
    if hit.group(2) is None and not is_robot:
        raise Refused("unknown_class", "a landmark needs its number (landmark<N>)")
    return (None if hit.group(2) is None else int(hit.group(2))), is_robot


def detection_in(
    det: Any, t: float, observer: int, mount: tuple[float, float, float], robots: frozenset[int] | None = None
) -> Detection:
    """The :class:`~swarmloc.events.Detection` of one ``vision_msgs/msg/Detection3D`` taken at ``t`` [s] by
    ``observer`` with a sensor mounted at ``mount`` on ``base_link`` (module docstring); ``robots``: the team (a
    robot outside it is refused ``unknown_robot``)."""
    best = _best(det.results)
    target, is_robot = _target(best)
    if is_robot and target is not None and robots is not None and target not in robots:
        raise Refused("unknown_robot", f"robot{target} is not in the team {sorted(robots)}")
    if is_robot and target == observer:
        raise Refused("self", f"robot{observer} detecting itself")
    p = best.pose.pose
    ps = np.array([p.position.x, p.position.y, _yaw(p.orientation)], dtype=float)
    C = np.asarray(best.pose.covariance, dtype=float).reshape(6, 6)[np.ix_((0, 1, 5), (0, 1, 5))]
    if not (np.all(np.isfinite(ps)) and np.all(np.isfinite(C))):
        raise Refused("bad_value", "non-finite detection pose or covariance")
    C = symmetric(C)
    M = SE2.from_xytheta(np.asarray(mount, dtype=float))
    if C[2, 2] >= YAW_UNKNOWN:
        return _range_bearing(ps, C[:2, :2], M, t, observer, target, is_robot)
    if not np.all(np.linalg.eigvalsh(C) > 0):
        raise Refused("bad_covariance", "the (x, y, yaw) covariance is not positive definite")
    z = SE2.to_xytheta(M @ SE2.from_xytheta(ps))
    _, cov = absolute_to_pseudo(ps, C)
    return Detection(observer, t, Kind.POSE, z, cov, target, is_robot)


def _range_bearing(
    ps: np.ndarray, Cxy: np.ndarray, M: np.ndarray, t: float, observer: int, target: int | None, is_robot: bool
) -> Detection:
    """A position-only detection as range and bearing from ``base_link`` (first-order covariance)."""
    if not np.all(np.linalg.eigvalsh(Cxy) > 0):
        raise Refused("bad_covariance", "the (x, y) covariance is not positive definite")
    q = M[:2, :2] @ ps[:2] + M[:2, 2]
    r = float(np.hypot(*q))
    if r < 1e-6:
        raise Refused("bad_value", "a position-only detection at the sensor's origin has no bearing")
    Cb = M[:2, :2] @ Cxy @ M[:2, :2].T
    J = np.array([[q[0] / r, q[1] / r], [-q[1] / r**2, q[0] / r**2]])
    cov = J @ Cb @ J.T
    return Detection(observer, t, Kind.RANGE_BEARING, np.array([r, math.atan2(q[1], q[0])]), symmetric(cov),
                     target, is_robot)  # fmt: skip


def detections_in(
    msg: Any,
    observer: int,
    mounts: Mapping[str, tuple[float, float, float]],
    base_frame: str,
    robots: frozenset[int] | None = None,
) -> tuple[float, list[Detection], Counter[str]]:
    """``(t, detections, refused by reason)`` of a ``Detection3DArray`` of ``observer`` (module docstring). A frame
    that is neither ``base_frame`` nor in ``mounts`` refuses the whole array (``unknown_frame``)."""
    t = stamp_of(msg.header)
    refused: Counter[str] = Counter()
    frame = str(msg.header.frame_id)
    if frame in ("", base_frame):
        mount = (0.0, 0.0, 0.0)
    elif frame in mounts:
        mount = tuple(mounts[frame])  # type: ignore[assignment]
    else:
        refused["unknown_frame"] += len(msg.detections)
        return t, [], refused
    if not _finite(t) or t <= 0:
        refused["bad_value"] += len(msg.detections)
        return t, [], refused
    out = []
    for k, det in enumerate(msg.detections):
        if k >= MAX_DETECTIONS:
            refused["too_many"] += len(msg.detections) - MAX_DETECTIONS
            break
        try:
            out.append(detection_in(det, t, observer, mount, robots))
        except Refused as exc:
            refused[exc.reason] += 1
    return t, out, refused


def initialpose_in(msg: Any, robot: int, world_frame: str, now: float) -> Detection:
    """An ``/initialpose`` (``PoseWithCovarianceStamped`` in ``world_frame``; stamp 0: ``now``) as an absolute fix
    ``(x, y, yaw)`` of ``robot`` with the message's world-frame covariance."""
    if str(msg.header.frame_id) not in ("", world_frame):
        raise Refused("wrong_frame", f"initial pose in {msg.header.frame_id!r}, not {world_frame!r}")
    t, z, C = rosmsg.pose_from_message(msg)
    t = t or now
    if not (np.all(np.isfinite(z)) and np.all(np.isfinite(C)) and math.isfinite(t)):
        raise Refused("bad_value", "non-finite initial pose")
    C = symmetric(C)
    if not np.all(np.linalg.eigvalsh(C) > 0):
        raise Refused("bad_covariance", "the initial pose's (x, y, yaw) covariance is not positive definite")
    return Detection(robot, float(t), Kind.ABSOLUTE, z, C, None, True)


# ------------------------------------------------------------------------------------------------ outputs
def detections_msg(t: float, dets: list[Detection], frame: str) -> Any:
    """The ``Detection3DArray`` of identified ``"pose"`` detections taken at ``t`` by a sensor at ``base_link``
    (``frame``): the inverse of :func:`detections_in`, each covariance carried back to ROS's additive one,
    ``C = T^-1 S T^-T``, and the unused z, roll, pitch variances large."""
    T = typestore().types
    out = []
    for d in dets:
        if d.kind != Kind.POSE or d.target is None:
            raise ValueError(f"detections_msg: identified 'pose' detections only, got {d.kind!r} of {d.target}")
        z = np.asarray(d.z, dtype=float)
        Ti = SE2.from_xytheta(np.array([0.0, 0.0, z[2]]))
        cov6 = np.diag([0.0, 0.0, 1e6, 1e6, 1e6, 0.0])
        cov6[np.ix_((0, 1, 5), (0, 1, 5))] = Ti @ np.asarray(d.cov, dtype=float) @ Ti.T
        name = f"{'robot' if d.target_is_robot else 'landmark'}{int(d.target)}"
        hyp = T["vision_msgs/msg/ObjectHypothesisWithPose"](
            hypothesis=T["vision_msgs/msg/ObjectHypothesis"](class_id=name, score=1.0),
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose_msg(z), covariance=cov6.reshape(36)),
        )
        size = T["geometry_msgs/msg/Vector3"](x=0.3, y=0.3, z=0.2)
        bbox = T["vision_msgs/msg/BoundingBox3D"](center=pose_msg(z), size=size)
        out.append(T["vision_msgs/msg/Detection3D"](header=header(t, frame), results=[hyp], bbox=bbox, id=name))
    return T[DETECTIONS](header=header(t, frame), detections=out)


def pose_out(t: float, mean: np.ndarray, cov: np.ndarray, frame: str, unused_variance: float = 0.0) -> Any:
    """The ``PoseWithCovarianceStamped`` of a belief (:func:`swarmloc.net.ros.pose_message`)."""
    return rosmsg.pose_message(t, mean, cov, frame, unused_variance)


def odometry_out(
    t: float,
    mean: np.ndarray,
    cov: np.ndarray,
    twist: OdomSample | None,
    frame: str,
    child: str,
    unused_variance: float = 0.0,
) -> Any:
    """The ``nav_msgs/msg/Odometry`` of a belief at ``t``: its pose and covariance as :func:`pose_out`, the twist
    (speed, yaw rate, their covariance) of the odometry in force at ``t`` (zero without one)."""
    pm = pose_out(t, mean, cov, frame, unused_variance)
    tw = twist_msg(twist.v, twist.w, twist.twist_cov) if twist is not None else twist_msg(0.0, 0.0, np.zeros(36))
    return typestore().types[ODOMETRY](header=pm.header, child_frame_id=child, pose=pm.pose, twist=tw)


def transform_out(t: float, parent: str, child: str, xyt: np.ndarray) -> Any:
    """A ``geometry_msgs/msg/TransformStamped`` of the planar pose ``xyt`` of ``child`` in ``parent``."""
    T = typestore().types
    qx, qy, qz, qw = rosmsg.yaw_to_quaternion(float(xyt[2]))
    tr = T["geometry_msgs/msg/Transform"](
        translation=T["geometry_msgs/msg/Vector3"](x=float(xyt[0]), y=float(xyt[1]), z=0.0),
        rotation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
    )
    return T["geometry_msgs/msg/TransformStamped"](header=header(t, parent), child_frame_id=child, transform=tr)


def map_to_odom(mean: np.ndarray, odom_pose: np.ndarray) -> np.ndarray:
    """``(x, y, yaw)`` of ``odom`` in the map: ``T_map_base T_odom_base^-1`` (``mean`` the belief's SE(2) mean,
    ``odom_pose`` the base's ``(x, y, yaw)`` in odom at the same time)."""
    return SE2.to_xytheta(np.asarray(mean, dtype=float) @ SE2.inverse(SE2.from_xytheta(np.asarray(odom_pose))))


def interpolate_pose(t: float, a: OdomSample, b: OdomSample) -> np.ndarray:
    """The odometry pose at ``t`` in ``[a.t, b.t]``: the SE(2) geodesic from ``a.pose`` to ``b.pose``."""
    Ga, Gb = SE2.from_xytheta(np.asarray(a.pose)), SE2.from_xytheta(np.asarray(b.pose))
    s = 0.0 if b.t <= a.t else min(1.0, max(0.0, (t - a.t) / (b.t - a.t)))
    return SE2.to_xytheta(Ga @ SE2.exp(s * SE2.log(SE2.inverse(Ga) @ Gb)))


def tf_out(transforms: list[Any]) -> Any:
    """A ``tf2_msgs/msg/TFMessage`` of ``transforms``."""
    return typestore().types[TF](transforms=transforms)


def diagnostics_out(t: float, name: str, hardware_id: str, level: int, message: str, values: Mapping[str, Any]) -> Any:
    """A ``diagnostic_msgs/msg/DiagnosticArray`` with one status (``level`` 0 OK, 1 WARN, 2 ERROR, 3 STALE)."""
    T = typestore().types
    kv = [T["diagnostic_msgs/msg/KeyValue"](key=str(k), value=str(v)) for k, v in values.items()]
    status = T["diagnostic_msgs/msg/DiagnosticStatus"](level=int(level), name=name, message=message,
                                                       hardware_id=hardware_id, values=kv)  # fmt: skip
    return T[DIAGNOSTICS](header=header(t, ""), status=[status])
