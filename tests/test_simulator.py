"""Tests for swarmloc.sim: reproducibility, exact noise-free odometry, sensor geometry and noise statistics."""

from __future__ import annotations

import numpy as np
import pytest

from swarmloc.events import Detection, Odometry, Truth, sim_order
from swarmloc.lie import SE2
from swarmloc.motion import DiffDrive, increment_cov, increment_mean
from swarmloc.sim import (
    AbsoluteSensor,
    RelativeSensor,
    SimConfig,
    SimResult,
    WheelSchedule,
    random_team,
    simulate,
    thesis_ground_truth_neighbour,
    thesis_two_robot,
    wrap_angle,
)
from swarmloc.sim.simulator import in_view, seen_from

pytestmark = pytest.mark.unit


def _same(a: object, b: object) -> bool:
    if type(a) is not type(b):
        return False
    for name in a.__slots__:  # type: ignore[attr-defined]
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            if not np.array_equal(x, y):
                return False
        elif x != y:
            return False
    return True


def test_same_seed_identical_different_seed_different():
    a = random_team(
        4,
        20.0,
        seed=7,
        sensor=RelativeSensor(kinds=("pose", "range_bearing")),
        absolute=AbsoluteSensor(robots=(0,), rate=2.0),
    )
    b = random_team(
        4,
        20.0,
        seed=7,
        sensor=RelativeSensor(kinds=("pose", "range_bearing")),
        absolute=AbsoluteSensor(robots=(0,), rate=2.0),
    )
    assert len(a.events) == len(b.events) > 0
    assert all(_same(x, y) for x, y in zip(a.events, b.events, strict=True))
    c = random_team(4, 20.0, seed=8)
    assert len(c.events) != len(a.events) or not all(_same(x, y) for x, y in zip(a.events, c.events, strict=True))
    t1 = thesis_two_robot(0.05, seed=1, duration=10.0)
    t2 = thesis_two_robot(0.05, seed=2, duration=10.0)
    assert not np.array_equal(t1.truth, t2.truth)
    d1 = [e.z for e in t1.events if isinstance(e, Detection)]
    d2 = [e.z for e in t2.events if isinstance(e, Detection)]
    assert not all(np.array_equal(x, y) for x, y in zip(d1, d2, strict=False))


def test_sensor_stream_independent_of_motion_stream():
    base = thesis_two_robot(0.05, seed=3, duration=10.0)
    other = thesis_two_robot(0.1, seed=3, duration=10.0)  # only the sensor noise level differs
    np.testing.assert_array_equal(base.truth, other.truth)


def _check_sorted(events: list) -> None:
    cat = {Odometry: 0, Detection: 1, Truth: 2}
    keys = [(e.t, cat[type(e)]) for e in events]
    assert keys == sorted(keys)


def test_events_time_sorted_with_stable_category_order():
    for res in (random_team(5, 15.0, seed=1), thesis_ground_truth_neighbour(0.05, seed=0, duration=20.0)):
        _check_sorted(res.events)
        assert isinstance(res.events[0], Truth) and res.events[0].t == 0.0
        kinds = {getattr(e, "kind", None) for e in res.events}
        assert {"pose"} <= kinds
    res = thesis_ground_truth_neighbour(0.05, seed=0, duration=20.0)
    fixes = [e for e in res.events if isinstance(e, Detection) and e.kind == "absolute"]
    assert fixes and all(e.observer == 2 and e.target is None for e in fixes)
    assert len(fixes) == 200  # 10 Hz for 20 s


def test_sim_order_is_the_simulators_order():
    """The shared sort key puts odometry at its end ``t1`` and, at one time, odometry, detections, truth: a sort by
    it leaves the simulator's stream as it is, and orders a hand-made stream so."""
    res = random_team(3, 5.0, seed=2)
    assert sorted(res.events, key=sim_order) == res.events
    odo = Odometry(0, 0.0, 1.0, 0.1, 0.0)
    early = Detection(0, 0.5, "pose", np.zeros(3), np.eye(3), target=1)
    late = Detection(0, 1.0, "pose", np.zeros(3), np.eye(3), target=1)
    truth = Truth(0, 1.0, np.zeros(3))
    assert sorted([truth, late, odo, early], key=sim_order) == [early, odo, late, truth]


def _integrate_odometry(res: SimResult) -> dict[int, list[tuple[float, np.ndarray]]]:
    g = {k: SE2.from_xytheta(p) for k, p in res.initial_poses.items()}
    out: dict[int, list[tuple[float, np.ndarray]]] = {k: [(0.0, g[k])] for k in g}
    for e in res.events:
        if isinstance(e, Odometry):
            g[e.robot] = g[e.robot] @ SE2.exp(np.array([e.v * e.dt, 0.0, e.w * e.dt]))
            out[e.robot].append((e.t1, g[e.robot]))
    return out


@pytest.mark.parametrize("which", ["team", "thesis"])
def test_zero_noise_odometry_integrates_to_truth(which: str):
    if which == "team":
        res = random_team(4, 30.0, seed=3, zero_noise=True, D=0.5)
    else:
        res = thesis_two_robot(0.1, seed=3, zero_noise=True, D=1.0)
    assert res.config.drive.D == 0.0
    dead = _integrate_odometry(res)
    truth = {(e.robot, e.t): e.pose for e in res.events if isinstance(e, Truth)}
    n = 0
    for rid, seq in dead.items():
        for t, g in seq:
            p = truth[(rid, t)]
            q = SE2.to_xytheta(g)
            assert np.abs(q[:2] - p[:2]).max() < 1e-9
            assert abs(wrap_angle(q[2] - p[2])) < 1e-9
            n += 1
    assert n == len(truth)
    # noise-free measurements are the true relative poses
    tr = {(e.robot, e.t): SE2.from_xytheta(e.pose) for e in res.events if isinstance(e, Truth)}
    for e in res.events:
        if isinstance(e, Detection) and e.kind == "pose":
            m = SE2.between(tr[(e.observer, e.t)], tr[(e.target, e.t)])
            np.testing.assert_allclose(SE2.to_xytheta(m), e.z, atol=1e-9)
            np.testing.assert_array_equal(e.cov, np.zeros((3, 3)))


def test_seen_from_and_in_view():
    """A target 1 m along world x from an observer facing +y is 1 m to its right; a full circle keeps bearing pi."""
    mx, my, r, b = seen_from(np.array(np.pi / 2), np.array(1.0), np.array(0.0))
    np.testing.assert_allclose([mx, my, r, b], [0.0, -1.0, 1.0, -np.pi / 2], atol=1e-15)
    ranges, bearings = np.array([1.0, 1.0, 2.5]), np.array([np.pi, -np.pi, 0.0])
    assert in_view(ranges, bearings, 2.0, 2 * np.pi).tolist() == [True, True, False]
    assert not in_view(np.array(1.0), np.array(np.pi / 2 + 1e-9), 2.0, np.pi)


def test_detections_respect_range_and_field_of_view():
    sensor = RelativeSensor(rate=5.0, max_range=1.0, fov=np.deg2rad(90.0), kinds=("pose", "range_bearing"))
    res = random_team(6, 40.0, seed=4, area=1.5, sensor=sensor)
    truth = {(e.robot, e.t): e.pose for e in res.events if isinstance(e, Truth)}
    dets = [e for e in res.events if isinstance(e, Detection)]
    assert len(dets) > 50
    seen = set()
    for e in dets:
        pi, pj = truth[(e.observer, e.t)], truth[(e.target, e.t)]
        c, s = np.cos(pi[2]), np.sin(pi[2])
        d = pj[:2] - pi[:2]
        x, y = c * d[0] + s * d[1], -s * d[0] + c * d[1]
        assert np.hypot(x, y) <= 1.0 + 1e-12
        assert abs(np.arctan2(y, x)) <= np.deg2rad(45.0) + 1e-12
        seen.add((e.observer, e.target, e.t, e.kind))
    # completeness: every pair in range and view at a sensor time was detected, with both kinds
    times = sorted({t for (_, t) in truth if abs(t * 5.0 - round(t * 5.0)) < 1e-9 and t > 0})
    ids = res.robot_ids
    expected = 0
    for t in times:
        for i in ids:
            for j in ids:
                if i == j:
                    continue
                pi, pj = truth[(i, t)], truth[(j, t)]
                c, s = np.cos(pi[2]), np.sin(pi[2])
                d = pj[:2] - pi[:2]
                x, y = c * d[0] + s * d[1], -s * d[0] + c * d[1]
                if np.hypot(x, y) <= 1.0 and abs(np.arctan2(y, x)) <= np.pi / 4:
                    expected += 1
                    assert (i, j, t, "pose") in seen and (i, j, t, "range_bearing") in seen
    assert expected * 2 == len(dets)


def test_measurement_noise_matches_stated_covariance():
    sensor = RelativeSensor(
        rate=10.0,
        max_range=2.0,
        sigma_xy=0.05,
        sigma_theta=0.1,
        kinds=("pose", "range_bearing"),
        sigma_range=0.03,
        sigma_bearing=0.02,
    )
    absolute = AbsoluteSensor(robots=(0, 1, 2), rate=10.0, sigma_xy=0.2, sigma_theta=0.05)
    still = WheelSchedule((0.0,), ((0.0, 0.0),))
    cfg = SimConfig(duration=150.0, drive=DiffDrive(D=0.0), sensor=sensor, absolute=absolute)
    start = {0: (0.0, 0.0, 0.3), 1: (1.0, 0.5, -2.0), 2: (-0.5, 1.0, 3.0)}
    res = simulate(start, {k: still for k in start}, cfg, seed=11)
    g = {k: SE2.from_xytheta(p) for k, p in start.items()}
    res_pose, res_rb, res_abs = [], [], []
    for e in res.events:
        if not isinstance(e, Detection):
            continue
        if e.kind == "pose":
            m_true = SE2.between(g[e.observer], g[e.target])
            res_pose.append(SE2.log(SE2.inverse(m_true) @ SE2.from_xytheta(e.z)))
            np.testing.assert_allclose(e.cov, sensor.pose_cov())
        elif e.kind == "range_bearing":
            p = SE2.to_xytheta(SE2.between(g[e.observer], g[e.target]))
            res_rb.append([e.z[0] - np.hypot(p[0], p[1]), wrap_angle(e.z[1] - np.arctan2(p[1], p[0]))])
            np.testing.assert_allclose(e.cov, sensor.range_bearing_cov())
        else:
            p = np.asarray(start[e.observer])
            res_abs.append([e.z[0] - p[0], e.z[1] - p[1], wrap_angle(e.z[2] - p[2])])
            np.testing.assert_allclose(e.cov, absolute.cov())
    for r, cov in ((res_pose, sensor.pose_cov()), (res_rb, sensor.range_bearing_cov()), (res_abs, absolute.cov())):
        r = np.asarray(r)
        assert len(r) >= 4500
        assert np.linalg.norm(np.cov(r.T) - cov) / np.linalg.norm(cov) < 0.05
        assert np.all(np.abs(r.mean(0)) < 4 * np.sqrt(np.diag(cov) / len(r)))


def test_truth_spread_matches_process_noise_model():
    """Many robots with identical constant commands: the scatter of the truth about the odometry prediction
    has the covariance (5.4) with Q = H H^T (the generative model the estimators should assume)."""
    dd = DiffDrive(D=0.5)
    n = 3000
    w1, w2 = dd.from_unicycle(0.3, 0.4)
    sched = WheelSchedule((0.0,), ((float(w1), float(w2)),))
    cfg = SimConfig(duration=4.0, drive=dd, sensor=None)
    res = simulate([(0.0, 0.0, 0.0)] * n, [sched] * n, cfg, seed=5)
    h = dd.twist(w1, w2)
    mu = increment_mean(h, 4.0)
    y = SE2.log(SE2.inverse(mu) @ SE2.from_xytheta(res.truth[-1]))
    S = increment_cov(h, res.config.drive.diffusion(), 4.0)
    assert np.linalg.norm(np.cov(y.T) - S) / np.linalg.norm(S) < 0.08
    np.testing.assert_allclose(res.unicycle_noise().Q(0.3, 0.4), res.config.drive.diffusion(), atol=1e-18)


def test_callable_commands_and_validation():
    dd = DiffDrive(D=0.0)
    cfg = SimConfig(duration=2.0, drive=dd, sensor=None)
    res = simulate({5: (0, 0, 0)}, {5: lambda t: (10.0, 10.0) if t < 1.0 else (12.0, 8.0)}, cfg, seed=0)
    odo = [e for e in res.events if isinstance(e, Odometry)]
    assert len(odo) == 20 and odo[0].robot == 5
    assert odo[0].w == 0.0 and odo[-1].w == pytest.approx(dd.r / dd.l * 4.0)
    with pytest.raises(ValueError):
        simulate({0: (0, 0, 0)}, {1: lambda t: (0.0, 0.0)}, cfg)
    with pytest.raises(ValueError):
        simulate({0: (0, 0, 0)}, {0: lambda t: (0.0, 0.0)}, SimConfig(duration=1.0, sensor=RelativeSensor(rate=3.0)))


def test_initial_beliefs_are_samples_of_the_prior_about_the_truth():
    """sim_source's initial beliefs: the true start is a sample of each prior (not its mean, which would make
    every filter under-confident while the initial covariance dominates), reproducibly from the seed."""
    from scipy.stats import chi2

    from swarmloc.sim.source import sim_source

    sim = random_team(300, 1.0, seed=4)
    src, again = sim_source(sim, "sim:test"), sim_source(sim, "sim:test")
    truth = sim.initial_poses.items()
    y = np.array([SE2.log(SE2.inverse(src.initial[r].mean) @ SE2.from_xytheta(p)) for r, p in truth])
    nees = np.einsum("ni,ij,nj->", y, np.linalg.inv(src.initial[0].cov), y)
    dof = 3 * len(y)
    assert chi2.ppf(0.001, dof) < nees < chi2.ppf(0.999, dof)
    assert all(np.array_equal(src.initial[r].mean, again.initial[r].mean) for r in sim.initial_poses)
    other = sim_source(random_team(300, 1.0, seed=5), "sim:test")
    assert not np.array_equal(src.initial[0].mean, other.initial[0].mean)


def test_dead_reckoning_is_consistent_on_the_simulator():
    """Dead reckoning on sim:random, whose noises are exactly its model: ANEES/dof about 1 over 20 seeds of 5
    independent robots (the initial beliefs' errors drawn from their covariance), not below as when every robot
    started at its belief's mean (about 0.5)."""
    from swarmloc.estimators import make_team, node_options
    from swarmloc.evaluation.metrics import evaluate
    from swarmloc.experiments.sources import load_source
    from swarmloc.runner import run

    anees = []
    for seed in range(1, 21):
        src = load_source("sim:random", robots=5, duration=10.0, seed=seed)
        nodes = make_team("dr", src.initial, **node_options("dr", src.config, src.landmarks))
        anees.append(evaluate(run(nodes, src.events, src.record_times(), truth=src.truth))["team"]["anees"])
    assert 0.8 < np.mean(anees) < 1.25
