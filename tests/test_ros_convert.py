"""ROS messages to swarmloc inputs and beliefs to ROS messages (swarmloc.ros.convert, swarmloc.ros.timeline), each
formula checked against an independent computation: Monte Carlo with scipy's expm/logm for the covariances, a
closed-form arc for the odometry interpolation, matrix products for the transform."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import logm

from swarmloc.events import Detection
from swarmloc.rmw import typestore
from swarmloc.rmw.types import odometry_msg
from swarmloc.ros import convert as cv
from swarmloc.ros.timeline import InputTimeline, record_times

pytestmark = pytest.mark.unit

T = typestore().types


def se2(x, y, th):
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, -s, x], [s, c, y], [0, 0, 1.0]])


def vee(X):
    return np.array([X[0, 2], X[1, 2], X[1, 0]])


def _array(z, C6, cls="robot2", frame="cam", t=10.0):
    hyp = T["vision_msgs/msg/ObjectHypothesisWithPose"](
        hypothesis=T["vision_msgs/msg/ObjectHypothesis"](class_id=cls, score=0.9),
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=cv.pose_msg(z), covariance=np.asarray(C6).reshape(36)),
    )
    size = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    bbox = T["vision_msgs/msg/BoundingBox3D"](center=cv.pose_msg(z), size=size)
    det = T["vision_msgs/msg/Detection3D"](header=cv.header(t, frame), results=[hyp], bbox=bbox, id="")
    return T["vision_msgs/msg/Detection3DArray"](header=cv.header(t, frame), detections=[det])


def test_a_pose_detection_in_a_mounted_sensor_frame_matches_monte_carlo():
    """z = mount * p; covariance of log(z_true^-1 z) (expm/logm, 200k samples) equals T C T^T to first order."""
    rng = np.random.default_rng(0)
    mount, p = (0.2, -0.1, 0.3), np.array([1.5, 0.4, 0.7])
    C = np.array([[4e-4, 1e-4, 2e-5], [1e-4, 9e-4, -3e-5], [2e-5, -3e-5, 2.5e-4]])
    C6 = np.zeros((6, 6))
    C6[np.ix_((0, 1, 5), (0, 1, 5))] = C
    t, dets, refused = cv.detections_in(_array(p, C6), 1, {"cam": mount}, "base_link", frozenset({1, 2}))
    (d,) = dets
    assert not refused and d.kind == "pose" and d.target == 2 and d.target_is_robot and t == 10.0
    M, Gp = se2(*mount), se2(*p)
    np.testing.assert_allclose(vee(np.real(logm(np.linalg.inv(se2(*d.z)) @ M @ Gp))), 0.0, atol=1e-12)
    n = 6000
    zt_inv = np.linalg.inv(M @ Gp)
    xi = np.array([vee(np.real(logm(zt_inv @ M @ se2(*s)))) for s in rng.multivariate_normal(p, C, n)])
    emp = np.cov(xi.T)
    se = np.sqrt((np.outer(np.diag(emp), np.diag(emp)) + emp**2) / n)  # standard error of each entry
    assert np.all(np.abs(d.cov - emp) < 4 * se), (d.cov - emp) / se
    assert np.abs(d.cov - C).max() > 10 * se.max()  # and the rotation matters: the sensor-frame C is not the answer


def test_a_position_only_detection_is_range_and_bearing_with_its_covariance():
    rng = np.random.default_rng(1)
    mount, p = (0.1, 0.05, -0.4), np.array([2.0, -0.5, 0.0])
    Cxy = np.array([[2e-3, 4e-4], [4e-4, 1e-3]])
    C6 = np.zeros((6, 6))
    C6[:2, :2], C6[5, 5] = Cxy, 1e9
    _, (d,), _ = cv.detections_in(_array(p, C6, "landmark7"), 1, {"cam": mount}, "base_link")
    assert d.kind == "range_bearing" and d.target == 7 and not d.target_is_robot
    M = se2(*mount)
    q = (M @ np.array([p[0], p[1], 1.0]))[:2]
    np.testing.assert_allclose(d.z, [np.hypot(*q), math.atan2(q[1], q[0])], atol=1e-12)
    s = rng.multivariate_normal(p[:2], Cxy, 200_000)
    qs = (M[:2, :2] @ s.T).T + M[:2, 2]
    rb = np.stack([np.hypot(qs[:, 0], qs[:, 1]), np.arctan2(qs[:, 1], qs[:, 0])], 1)
    np.testing.assert_allclose(d.cov, np.cov(rb.T), rtol=0.03, atol=1e-7)


@pytest.mark.parametrize(("cls", "frame", "cov_scale", "reason"), [
    ("robot9", "cam", 1.0, "unknown_robot"), ("robot1", "cam", 1.0, "self"), ("dog", "cam", 1.0, "unknown_class"),
    ("landmark", "cam", 1.0, "unknown_class"), ("robot2", "nowhere", 1.0, "unknown_frame"),
    ("robot2", "cam", -1.0, "bad_covariance"), ("robot2", "cam", float("nan"), "bad_value"),
])  # fmt: skip
def test_refused_detections_are_counted_by_reason(cls, frame, cov_scale, reason):
    C6 = np.eye(6) * 1e-3 * cov_scale
    _, dets, refused = cv.detections_in(_array([1.0, 0.0, 0.0], C6, cls, frame), 1, {"cam": (0, 0, 0)}, "base_link",
                                        frozenset({1, 2}))  # fmt: skip
    assert dets == [] and refused == {reason: 1}


def test_odometry_intervals_interpolation_and_the_map_to_odom_transform():
    tl = InputTimeline(3)
    v, w = 0.5, 0.4
    arc = lambda t: np.array([v / w * math.sin(w * t), v / w * (1 - math.cos(w * t)), w * t])  # noqa: E731
    assert tl.odometry(odometry_msg(100.0, 0.0, 0.0, arc(0.0))) == [] and tl.t0 == 100.0
    (o,) = tl.odometry(odometry_msg(101.0, v, w, arc(1.0)))
    assert (o.robot, o.t0, o.t1, o.v, o.w) == (3, 100.0, 101.0, v, w)
    assert tl.odometry(odometry_msg(100.5, v, w, arc(0.5))) == [] and tl.reasons["odometry_not_after_previous"] == 1
    pose, sample = tl.odom_at(100.3)
    np.testing.assert_allclose(pose, arc(0.3), atol=1e-12)  # constant twist: the geodesic is the arc
    assert sample.t == 101.0 and sample.v == v
    assert tl.odom_at(99.0) == (None, None) and tl.odom_at(102.0) == (None, None)
    mean = se2(4.0, -2.0, 1.1)
    xyt = cv.map_to_odom(mean, pose)
    np.testing.assert_allclose(se2(*xyt) @ se2(*pose), mean, atol=1e-12)  # T_map_odom T_odom_base = T_map_base
    np.testing.assert_allclose(record_times(100.0, 4.0, 101.0), [100.0, 100.25, 100.5, 100.75, 101.0])


def test_the_output_odometry_carries_the_belief_and_the_twist_in_force():
    mean, cov = se2(1.0, 2.0, 0.5), np.diag([1e-2, 4e-2, 1e-3])
    s = cv.OdomSample(5.0, 0.3, -0.1, (0, 0, 0), tuple(np.eye(6).ravel() * 0.02))
    m = cv.odometry_out(4.9, mean, cov, s, "map", "robot1/base_link", unused_variance=7.0)
    assert (m.header.frame_id, m.child_frame_id) == ("map", "robot1/base_link")
    assert cv.stamp_of(m.header) == pytest.approx(4.9, abs=1e-9)
    assert (m.twist.twist.linear.x, m.twist.twist.angular.z) == (0.3, -0.1)
    C = np.asarray(m.pose.covariance).reshape(6, 6)
    R = mean[:2, :2]
    np.testing.assert_allclose(C[:2, :2], R @ cov[:2, :2] @ R.T, atol=1e-15)
    assert C[5, 5] == 1e-3 and C[2, 2] == C[3, 3] == C[4, 4] == 7.0


def test_initialpose_before_the_start_sets_the_initial_belief_after_it_is_a_fix():
    from swarmloc.net.ros import pose_message

    tl = InputTimeline(0)
    msg = pose_message(0.0, se2(3.0, 1.0, 0.2), np.diag([0.01, 0.01, 0.001]))
    assert tl.initialpose(msg) == [] and tl.initial is not None
    np.testing.assert_allclose(tl.initial[0], [3.0, 1.0, 0.2], atol=1e-12)
    tl.odometry(odometry_msg(50.0, 0.0, 0.0, (0, 0, 0)))
    (d,) = tl.initialpose(msg)  # stamp 0: taken at the latest odometry's stamp
    assert isinstance(d, Detection) and d.kind == "absolute" and d.t == 50.0
    wrong = pose_message(60.0, se2(0, 0, 0), np.eye(3))
    wrong.header.frame_id = "odom"
    assert tl.initialpose(wrong) == [] and tl.reasons["initialpose_wrong_frame"] == 1


def test_detections_wait_for_the_first_odometry_and_those_before_it_are_refused():
    from swarmloc.events import Detection as D

    tl = InputTimeline(1, robots=frozenset({1, 2}))
    early = cv.detections_msg(9.0, [D(1, 9.0, "pose", np.array([1.0, 0, 0]), np.eye(3) * 1e-3, 2)], "base_link")
    late = cv.detections_msg(10.5, [D(1, 10.5, "pose", np.array([1.0, 0, 0]), np.eye(3) * 1e-3, 2)], "base_link")
    assert tl.detections(early) == [] and tl.detections(late) == []
    got = tl.odometry(odometry_msg(10.0, 0.0, 0.0, (0, 0, 0)))
    assert [d.t for d in got] == [10.5] and tl.reasons["before_start"] == 1
