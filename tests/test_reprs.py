"""What ``print`` shows of the public types: the numbers a reader looks for (a belief's mean and spread, an event's
values, a node's robot, estimator, present and pose, a run's counts), on one short line whatever the data's size."""

from __future__ import annotations

import numpy as np
import pytest

from swarmloc import SE2, Detection, GroupGaussian, Odometry, UnicycleNoise, make_team, run
from swarmloc.events import twist_odometry
from swarmloc.lie import SE3
from swarmloc.runner.result import RobotTrack, RunResult

pytestmark = pytest.mark.unit

LIMIT = 200
"""Characters at most of any repr below (one line)."""


def _short(r: str) -> str:
    assert len(r) <= LIMIT and "\n" not in r, r
    return r


def test_group_gaussian_shows_mean_and_spread():
    g = GroupGaussian(SE2, SE2.from_xytheta([1.0, 0.2, 0.3]), np.diag([0.01, 0.04, 0.0025]))
    assert _short(repr(g)) == "GroupGaussian(SE2, mean (x, y, theta)=[1, 0.2, 0.3], std=[0.1, 0.2, 0.05])"
    assert str(g) == repr(g)
    g3 = GroupGaussian(SE3, SE3.exp(np.array([1.0, 2.0, 3.0, 0.0, 0.0, 0.5])), 0.01 * np.eye(6))
    assert (
        "mean xyz=[" in _short(repr(g3)) and "rotvec=[0, 0, 0.5]" in repr(g3) and "std=[0.1, 0.1, 0.1, 0.1" in repr(g3)
    )


def test_a_batch_of_beliefs_prints_its_shape_and_first_element_only():
    n = 10_000
    g = GroupGaussian(
        SE2, np.broadcast_to(SE2.from_xytheta([3.0, 4.0, 0.0]), (n, 3, 3)), np.broadcast_to(np.eye(3), (n, 3, 3))
    )
    assert _short(repr(g)) == "GroupGaussian(SE2, batch (10000,), first: mean (x, y, theta)=[3, 4, 0], std=[1, 1, 1])"


def test_events_show_their_values():
    odo = Odometry(2, 1248272272.841, 1248272272.856, np.float64(0.4), 0.1)
    assert _short(repr(odo)) == "Odometry(robot=2, t0=1248272272.841, t1=1248272272.856, v=0.4, w=0.1)"
    assert "v=[0.1, 0, 0], w=[0, 0, 0.2]" in _short(repr(twist_odometry(0, 0.0, 0.1, [0.1, 0, 0, 0, 0, 0.2])))
    d = Detection(0, 0.3, "pose", np.array([1.0, 0.2, 0.0]), np.diag([1e-4, 1e-4, 4e-4]), target=1)
    assert _short(repr(d)) == (
        "Detection(observer=0, t=0.3, kind='pose', target=robot 1, z=[1, 0.2, 0], std=[0.01, 0.01, 0.02])"
    )
    lm = Detection(0, 0.3, "range_bearing", np.array([2.0, 0.1]), 1e-2 * np.eye(2), target=7, target_is_robot=False)
    assert "target=landmark 7" in _short(repr(lm))
    anon = Detection(0, 0.3, "range_bearing", np.array([2.0, 0.1]), 1e-2 * np.eye(2), target=None)
    assert "target=anonymous robot" in repr(anon)
    assert "std=?" in _short(repr(Detection(0, 0.3, "range", "junk", None)))  # malformed: printed, never raised


def test_nodes_show_robot_estimator_present_and_x():
    init = {r: GroupGaussian(SE2, SE2.from_xytheta([float(r), 0.0, 0.0]), 1e-2 * np.eye(3)) for r in range(50)}
    (node, *_) = make_team("dekf", {0: init[0], 1: init[1]}, noise=UnicycleNoise())
    assert repr(node) == "DistributedEKF(robot=0, estimator='dekf', not started)"
    node.start(0.0)
    node.step(Odometry(0, 0.0, 0.5, 0.4, 0.0))
    node.step(Odometry(0, 0.5, 1.0, 0.4, 0.0))
    assert _short(repr(node)) == "DistributedEKF(robot=0, estimator='dekf', present=0.5, x=[0.2, 0, 0])"
    (central,) = make_team("cekf", init, noise=UnicycleNoise(), t0=0.0)
    r = _short(repr(central))
    assert r.startswith("CentralizedEKF(robots=[0, 1, 2, 3, 4, 5, 6, 7, 8, ... 41 more], estimator='cekf', present=0")
    assert r.endswith("x=[0, 0, 0, 1, 0, 0, 2, 0, 0, ... 141 more])")


def test_run_result_shows_counts_not_arrays():
    init = {r: GroupGaussian(SE2, SE2.from_xytheta([float(r), 0.0, 0.0]), 1e-2 * np.eye(3)) for r in range(2)}
    events = [Odometry(0, 0.0, 1.0, 0.5, 0.0), Odometry(1, 0.0, 1.0, 0.5, 0.0)]
    res = run(make_team("dr", init, noise=UnicycleNoise()), events, record_times=np.linspace(0.0, 1.0, 5000))
    r = _short(repr(res))
    assert r.startswith("RunResult(estimator='dr', robots=[0, 1], records=10000, wall_time=")
    assert r.endswith(" s, detections=0 (fused 0, gated 0, rejected 0, unknown 0))")
    empty = RunResult("x", {5: RobotTrack(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)))}, 0.5)
    assert repr(empty) == "RunResult(estimator='x', robots=[5], records=0, wall_time=0.5 s)"
