"""``diekf``'s clusters that re-form (:mod:`swarmloc.estimators.cluster_reform`, :class:`~swarmloc.estimators.diekf.
Reforming`): the covariance-intersection bound of stacked pieces bounds their true joint covariance, the schedule is
the cut its docstring says on a hand-made recording, and the nodes re-forming in process equal the centralized
prototype (``benchmarks/diekf_reform.py``) on a 10-robot team whose clusters change."""

from __future__ import annotations

import numpy as np
import pytest
from _benchmarks import load_benchmark

from swarmloc.engine.replay import run_engine
from swarmloc.estimators.cluster_reform import Schedule, id_cut, piece_weights, seen_cut, seen_schedule, stacked_bound
from swarmloc.events import Detection, Kind, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.lie import SE2
from swarmloc.messages import ClusterPiece, message_problem

pytestmark = pytest.mark.unit


def test_the_stacked_bound_bounds_any_joint_covariance_of_its_pieces() -> None:
    """Robots 0..8 in old clusters of 3; a new cluster takes 2 of the first, 1 of the second and 3 of the third.
    Whatever the true joint covariance (random, cross-cluster correlations included), ``P_new - J`` restricted to the
    new cluster is positive semi-definite, each piece's blocks are its true ones over its weight (sizes: 2/6, 1/6,
    3/6), and blocks across pieces are zero."""
    rng = np.random.default_rng(7)
    old = {r: r // 3 for r in range(9)}
    cluster = [0, 1, 5, 6, 7, 8]
    assert piece_weights([2, 1, 3]) == [2 / 6, 1 / 6, 3 / 6]
    for _ in range(50):
        L = rng.normal(size=(27, 27))
        J = L @ L.T + 0.05 * np.eye(27)
        B = stacked_bound(cluster, old, lambda a, b, J=J: J[3 * a : 3 * a + 3, 3 * b : 3 * b + 3], 3)
        P = B.transpose(0, 2, 1, 3).reshape(18, 18)
        rows = np.concatenate([np.arange(3 * r, 3 * r + 3) for r in cluster])
        assert np.linalg.eigvalsh(P - J[np.ix_(rows, rows)]).min() > -1e-9
        np.testing.assert_allclose(B[0, 1], J[0:3, 3:6] * 3)  # piece {0, 1}: w = 1/3
        np.testing.assert_allclose(B[2, 2], J[15:18, 15:18] * 6)  # piece {5}: w = 1/6
        np.testing.assert_allclose(B[3, 5], J[18:21, 24:27] * 2)  # piece {6, 7, 8}: w = 1/2
        assert not B[1, 3].any() and not B[2, 4].any()
    one = stacked_bound([3, 4], old, lambda a, b: np.full((3, 3), float(a + b)), 3)
    assert one[0, 1, 0, 0] == 7.0  # a cluster of one piece keeps its covariance (w = 1)


def _det(t: float, i: int, j: int) -> Detection:
    return Detection(t=t, observer=i, target=j, kind=Kind.RANGE_BEARING, z=np.array([1.0, 0.0]), cov=np.eye(2))


def test_seen_schedule_moves_a_robot_that_sees_another_cluster_more_than_twice_as_often() -> None:
    """Robots 0..5 in clusters of 3; in [0, 1) robot 2 detects robots 3 and 4 five times and its own cluster once
    (5 + 5 = 10 > 2 (1 + 1)): at 1 s it joins the second cluster, at its end; robot 0's detections of robot 1 keep it.
    In [1, 2) robot 5 detects robot 0 three times (3 > 2 (0 + 1)), the first at 1.0 (a detection at a boundary counts
    for the next one): at 2 s it joins the first cluster. The last boundary is the last stamp."""
    events = [Odometry(robot=r, t0=0.0, t1=2.5, v=0.0, w=0.0) for r in range(6)]
    events += [_det(0.1 * k, 2, 3 + k % 2) for k in range(10)] + [_det(0.5, 2, 1), _det(0.5, 0, 1)]
    events += [_det(1.0, 5, 0), _det(1.5, 5, 0), _det(1.9, 5, 0), _det(2.0, 1, 0)]
    s = seen_schedule(events, range(6), 3, 1.0)
    assert s.times == (1.0, 2.0)
    assert s.cuts == (((0, 1, 2), (3, 4, 5)), ((0, 1), (3, 4, 5, 2)), ((0, 1, 5), (3, 4, 2)))
    assert s.period(0.999) == 0 and s.period(1.0) == 1 and s.period(2.5) == 2
    assert s.cluster(2, 1) == (3, 4, 5, 2)
    two = seen_schedule(events[:-3], range(6), 3, 1.0)  # the last stamp 1.0: no boundary at 2 s
    assert two.times == (1.0,) and two.cuts[1] == s.cuts[1]
    # a full cluster (3K/2 = 4 robots) takes nobody, and a robot alone never leaves its cluster
    assert seen_cut(((0, 5), (1, 2, 3, 4)), {(0, 1): 9}, 3) == ((0, 5), (1, 2, 3, 4))
    assert seen_cut(((0,), (1, 2)), {(0, 1): 9}, 3) == ((0,), (1, 2))
    assert seen_cut(((0, 5), (1, 2)), {(0, 1): 9}, 3) == ((5,), (1, 2, 0))
    assert id_cut([4, 0, 2, 1, 3], 2) == ((0, 1), (2, 3), (4,))
    with pytest.raises(ValueError, match="increasing"):
        Schedule((1.0, 1.0), ((), (), ()))


def test_a_cluster_piece_is_checked_as_a_message() -> None:
    ok = ClusterPiece(sender=1, receiver=4, stamp=1.0, robots=(2, 3), sigma=tuple(np.arange(18.0)))
    assert message_problem(ok) is None
    np.testing.assert_array_equal(ok.blocks()[3], np.arange(9.0, 18.0).reshape(3, 3))
    for bad in (dict(sigma=ok.sigma[:9]), dict(robots=(2, 2)), dict(robots=(1, 3)), dict(n=6),
                dict(sigma=(np.nan,) + ok.sigma[1:])):  # fmt: skip
        assert message_problem(ClusterPiece(**{**dict(sender=1, receiver=4, stamp=1.0, robots=(2, 3),
                                                     sigma=ok.sigma), **bad})) is not None  # fmt: skip


def test_nodes_that_re_form_their_clusters_equal_the_prototype() -> None:
    """10 robots in the grouped arena, 30 s, clusters of 5 re-formed every second: the in-process nodes' beliefs
    equal the prototype's centralized replay (the same schedule and bound) to 1e-9 at every record time, robots did
    change clusters and pieces were sent; the prototype's fixed clusters equal the nodes' fixed ones as well."""
    scene, reform, swarm = load_benchmark("swarm_scene"), load_benchmark("diekf_reform"), load_benchmark("diekf_swarm")
    src = scene.scene(10, 30.0, 2, "grouped")
    for period in (1.0, 0.0):
        proto = reform.replay(src, 5, period)
        _, res = swarm.in_process(src, 10, 5, 30.0, period=period)
        worst = 0.0
        for r, tr in res.tracks.items():
            ts, xs, Ps = zip(*proto["beliefs"][r], strict=True)
            np.testing.assert_array_equal(tr.times, ts)
            Ad = SE2.Ad(SE2.from_xytheta(tr.mean))  # the body-frame covariances in the world frame: Ad S Ad^T
            Pw = Ad @ tr.cov @ np.swapaxes(Ad, -1, -2)
            worst = max(worst, float(np.abs(tr.mean - np.stack(xs)).max()), float(np.abs(Pw - np.stack(Ps)).max()))
        assert worst < 1e-9, (period, worst)
        assert (proto["moved"] > 0) == (period > 0), proto["moved"]
        assert res.stats["fused"] == proto["fused"] and res.stats["gated"] == proto["gated"]
        assert (res.stats.get("pieces_received", 0) > 0) == (period > 0)


def test_the_engine_refuses_re_forming_clusters_with_a_reason() -> None:
    src = load_source("sim:random", robots=4, duration=2.0, seed=0)
    with pytest.raises(ValueError, match="clusters stay fixed: run \\[filter\\] diekf_reform with the nodes"):
        run_engine(src, "diekf", cluster=2, reform=1.0)


def test_a_period_too_short_for_the_recording_is_refused_before_any_loop() -> None:
    events = [Odometry(0, 0.0, 1.0, 0.1, 0.0), Odometry(0, 2000.0, 2001.0, 0.1, 0.0)]
    with pytest.raises(ValueError, match="more than 100000 re-formings: take a longer period"):
        seen_schedule(events, [0, 1, 2], 2, 0.01)
    assert len(seen_schedule(events, [0, 1, 2], 2, 100.0).times) == 20
