"""3-D point detections (issue 22): range-bearing-elevation (``"rbe3"``) and bearing-only (``"bearing3"``) of a
teammate or a known 3-D landmark. Jacobians against finite differences, the models' prediction against the
simulator's noise-free measurement, wrapped angles, the vertical singular direction, the sources and the
estimators (``dekf``, ``cekf``, ``diekf`` fuse them; ``expfusion`` and ``ci`` refuse and count them)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _se3 import fd, perturb

from swarmloc.estimators import make_team
from swarmloc.evaluation.metrics import evaluate
from swarmloc.events import Detection
from swarmloc.experiments.se3 import run_se3
from swarmloc.experiments.sources import load_source
from swarmloc.kernels.cartesian3 import world_basis3
from swarmloc.lie import SE3
from swarmloc.lie.se3 import so3_log
from swarmloc.runner import RunResult
from swarmloc.sensors.models3 import DEGENERATE3, model3
from swarmloc.sim.sim3d import Sim3Config, measure3, simulate3d

pytestmark = pytest.mark.unit


@pytest.mark.parametrize("kind", ["rbe3", "bearing3"])
def test_point_jacobians_finite_differences(kind: str) -> None:
    """``H_i`` (observer pose), ``H_k`` (teammate pose, landmark point) equal central differences of the wrapped
    residual to 1e-6, at random poses including an azimuth near +-pi (the wrap)."""
    rng = np.random.default_rng(5)
    for trial in range(12):
        gi, gk = SE3.random(rng, (), scale=2.0), SE3.random(rng, (), scale=2.0)
        if trial < 3:  # the target just behind the observer, across the azimuth's +-pi cut
            gk[:3, 3] = gi[:3, :3] @ np.array([-2.0, 1e-9 * (-1) ** trial, 0.3]) + gi[:3, 3]
        _check_point_at(kind, gi, gk)


def _check_point_at(kind: str, gi: np.ndarray, gk: np.ndarray) -> None:
    m = model3(kind)
    z = measure3(kind, gi, gk)
    h, Hi, Hk = m.predict(gi, gk)
    assert np.abs(m.residual(z, h)).max() < 1e-12
    Ji = fd(lambda e: m.residual(z, m.predict(perturb(gi, e), gk)[0]), 6)
    Jk = fd(lambda e: m.residual(z, m.predict(gi, perturb(gk, e))[0]), 6)
    assert np.abs(Ji + Hi).max() < 1e-6 and np.abs(Jk + Hk).max() < 1e-6
    p = gk[:3, 3]
    _, _, Hl = m.predict(gi, p)
    Jl = fd(lambda e: m.residual(z, m.predict(gi, p + e)[0]), 3)
    assert Hl.shape == (m.size, 3) and np.abs(Jl + Hl).max() < 1e-6


def test_world_basis_finite_differences() -> None:
    """``world_basis3`` maps a world-frame error (``exp(xi^) g``) to the Cartesian one, to first order."""
    rng = np.random.default_rng(6)
    g = SE3.random(rng, (), scale=3.0)
    J = fd(lambda xi: np.concatenate([(SE3.exp(xi) @ g)[:3, 3] - g[:3, 3],
                                       so3_log(g[:3, :3].T @ (SE3.exp(xi) @ g)[:3, :3])]), 6)  # fmt: skip
    assert np.abs(J - world_basis3(g)).max() < 1e-6


@pytest.mark.parametrize("kind", ["rbe3", "bearing3"])
def test_prediction_matches_simulator(kind: str) -> None:
    """Every simulated detection (robots and landmarks) equals the model's prediction at the true poses, with the
    sensor noise at 1e-9: the simulator and the models agree on frames, order and angle conventions."""
    cfg = Sim3Config(robots=3, duration=5.0, detection=kind, sigma_range=1e-9, sigma_angle=1e-9, landmarks=6)
    sim = simulate3d(cfg, seed=2)
    k_of = {round(t, 9): k for k, t in enumerate(sim.times)}
    seen = {"robot": 0, "landmark": 0}
    for e in sim.events:
        if not isinstance(e, Detection):
            continue
        assert e.kind in (kind, "rbe3")
        gi = sim.poses[k_of[round(e.t, 9)], e.observer]
        target = (sim.poses[k_of[round(e.t, 9)], e.target] if e.target_is_robot
                  else np.array(sim.landmarks[e.target][:3]))  # fmt: skip
        h = model3(e.kind).predict(gi, target)[0]
        assert np.abs(model3(e.kind).residual(e.z, h)).max() < 1e-7
        seen["robot" if e.target_is_robot else "landmark"] += 1
    assert seen["robot"] > 50 and seen["landmark"] > 50


def test_residual_wraps_angles() -> None:
    """Azimuths either side of the +-pi cut differ by a small wrapped residual, not 2 pi."""
    m = model3("rbe3")
    r = m.residual(np.array([2.0, np.pi - 0.01, 0.2]), np.array([2.0, -np.pi + 0.01, 0.2]))
    assert np.allclose(r, [0.0, -0.02, 0.0])
    r = model3("bearing3").residual(np.array([-np.pi + 0.01, 0.0]), np.array([np.pi - 0.01, 0.0]))
    assert np.allclose(r, [0.02, 0.0])


def test_vertical_direction_no_nan() -> None:
    """A neighbour straight above (elevation +90 deg): predictions and Jacobians finite; ``"rbe3"`` keeps the range
    only, ``"bearing3"`` is degenerate (refused); each filter counts it, no NaN in any state."""
    gi = SE3.exp(np.array([1.0, 2.0, 3.0, 0.0, 0.0, 0.4]))
    gk = gi.copy()
    gk[:3, 3] = gi[:3, 3] + np.array([0.0, 0.0, 2.5])  # straight above, in the body frame too (level observer)
    z = measure3("rbe3", gi, gk)
    assert np.isclose(z[2], np.pi / 2) and np.isfinite(z).all()
    for kind in ("rbe3", "bearing3"):
        h, Hi, Hk = model3(kind).predict(gi, gk)
        assert np.isfinite(h).all() and np.isfinite(Hi).all() and np.isfinite(Hk).all()
    lin = model3("rbe3").linearize(z, np.diag([0.05**2, 1e-4, 1e-4]), gi, gk)
    assert lin is not None and lin[0].shape == (1,) and np.isclose(lin[0][0], 0.0)
    assert model3("bearing3").linearize(z[1:], np.eye(2) * 1e-4, gi, gk) is None
    assert model3("bearing3").degenerate(gi, gk) and not model3("rbe3").degenerate(gi, gk)


def _vertical_team(kind: str, estimator: str) -> RunResult:
    """Two robots, robot 1 hovering exactly 2.5 m above robot 0, one detection each way of ``kind``."""
    from swarmloc.events import twist_odometry
    from swarmloc.gaussian import GroupGaussian
    from swarmloc.motion.twist3 import TwistNoise
    from swarmloc.runner import run

    g0 = SE3.exp(np.array([1.0, 2.0, 3.0, 0.0, 0.0, 0.4]))
    g1 = g0.copy()
    g1[:3, 3] += [0.0, 0.0, 2.5]
    S0 = np.diag([0.01] * 3 + [1e-3] * 3)
    initial = {0: GroupGaussian(SE3, g0, S0), 1: GroupGaussian(SE3, g1, S0)}
    cov = np.diag([0.05**2, 1e-4, 1e-4]) if kind == "rbe3" else np.diag([1e-4, 1e-4])
    events = [twist_odometry(r, 0.0, 1.0, np.zeros(6)) for r in (0, 1)]
    for i, j in ((0, 1), (1, 0)):
        z = measure3(kind, (g0, g1)[i], (g0, g1)[j])
        events.append(Detection(i, 1.0, kind, z, cov, target=j))
    noise = TwistNoise(q_lin0=4e-4, q_ang0=1e-4)
    return run(make_team(estimator, initial, noise=noise, t0=0.0), events, name=estimator)


@pytest.mark.parametrize("estimator", ["dekf", "cekf", "diekf"])
@pytest.mark.parametrize("kind", ["rbe3", "bearing3"])
def test_vertical_team_counts_and_stays_finite(kind: str, estimator: str) -> None:
    """Straight above in a team: ``"rbe3"`` fused (range only), ``"bearing3"`` refused as degenerate and counted;
    every recorded mean and covariance finite."""
    res = _vertical_team(kind, estimator)
    assert res.accounted()
    want_fused = 2 if kind == "rbe3" else 0
    assert res.stats["fused"] == want_fused
    assert res.stats["rejected"] == 2 - want_fused
    for tr in res.tracks.values():
        assert np.isfinite(tr.mean).all() and np.isfinite(tr.cov).all()


@pytest.mark.parametrize("spec", ["sim:3d_rbe", "sim:3d_bearing", "sim:3d_landmarks"])
def test_sources_run_and_filters_consistent(spec: str) -> None:
    """Each source runs with no data; ``dekf``, ``cekf``, ``diekf`` fuse every detection of it; ``cekf`` and
    ``diekf`` stay consistent (ANEES/dof in [0.3, 2] on 3 robots, 15 s, 2 seeds); ``expfusion`` and ``ci``
    refuse (and count) every detection that is not a relative pose."""
    for seed in (0, 1):
        src = load_source(spec, robots=3, duration=15.0, seed=seed)
        kinds = {e.kind for e in src.events if isinstance(e, Detection)}
        assert kinds == {"3d_rbe": {"rbe3"}, "3d_bearing": {"bearing3"}, "3d_landmarks": {"pose3", "rbe3"}}[spec[4:]]
        n_det = sum(isinstance(e, Detection) for e in src.events)
        n_pose3 = sum(isinstance(e, Detection) and e.kind == "pose3" for e in src.events)
        for est in ("dekf", "cekf", "diekf"):
            res = run_se3(src, est)
            assert res.accounted() and res.stats["fused"] == n_det, (est, res.stats)
            if est != "dekf":
                assert 0.3 <= evaluate(res)["team"]["anees"] <= 2.0, (spec, est, seed)
        for est in ("expfusion", "ci"):
            res = run_se3(src, est)
            assert res.accounted() and res.stats["fused"] <= n_pose3
            assert res.stats["rejected"] >= n_det - n_pose3


def test_landmarks_leave_team_events_unchanged() -> None:
    """``sim:3d_landmarks`` is ``sim:3d`` plus landmark detections: the team's own events and beliefs are those of
    the same seed; ``sim:3d_rbe`` has the same odometry and initial beliefs."""
    base = load_source("sim:3d", robots=3, duration=5.0, seed=4)
    lm = load_source("sim:3d_landmarks", robots=3, duration=5.0, seed=4)
    rbe = load_source("sim:3d_rbe", robots=3, duration=5.0, seed=4)
    team = [e for e in lm.events if not (isinstance(e, Detection) and not e.target_is_robot)]
    assert len(team) == len(base.events) and lm.landmarks and len(lm.landmarks) == 8
    for a, b in zip(team, base.events, strict=True):
        assert type(a) is type(b) and a.stamp == b.stamp
    odo = [e for e in rbe.events if not isinstance(e, Detection)]
    assert [dataclasses.astuple(e) for e in odo] == [dataclasses.astuple(e) for e in base.events
                                                      if not isinstance(e, Detection)]  # fmt: skip
    for r in base.initial:
        assert np.allclose(base.initial[r].mean, rbe.initial[r].mean)


def test_bad_values_refused() -> None:
    """A non-positive range or an elevation outside [-pi/2, pi/2] is not a value of these kinds."""
    from swarmloc.node.inputs import validate_detection

    cov3 = np.diag([0.01, 1e-4, 1e-4])
    assert "range" in validate_detection(Detection(0, 1.0, "rbe3", np.array([-1.0, 0.0, 0.0]), cov3, target=1))
    assert "elevation" in validate_detection(Detection(0, 1.0, "bearing3", np.array([0.0, 2.0]), cov3[1:, 1:], 1))
    assert validate_detection(Detection(0, 1.0, "rbe3", np.array([1.0, 3.0, -1.5]), cov3, target=1)) is None
    assert DEGENERATE3.startswith("degenerate")


@pytest.mark.network  # starts a team of node processes
@pytest.mark.parametrize(("spec", "est"), [("sim:3d_rbe", "dekf"), ("sim:3d_landmarks", "diekf")])
def test_networked_equals_in_process_with_points(spec: str, est: str) -> None:
    """Three node processes on 127.0.0.1 record the in-process run's means and covariances to 1e-6 with point
    detections of teammates (``dekf``, ``"rbe3"``) and of 3-D landmarks (``diekf``: each landmark update is one
    team broadcast)."""
    import os

    from test_net import leftovers, max_diff
    from test_net_se3 import reference3

    from swarmloc.experiments.team import run_team, team_result

    src = load_source(spec, robots=3, duration=6.0, seed=1)
    team = f"pts{est}{os.getpid()}"
    tr = run_team(src=src, source=spec, robots=3, duration=6.0, seed=1, estimator=est, team=team, max_wall=120)
    assert not leftovers(team)
    assert all(c == 0 for c in tr.exit_codes.values()), tr.exit_codes
    res = team_result(tr, src, est)
    ref = reference3(src, est)
    assert max_diff(res, ref) <= 1e-9
    assert res.stats["fused"] == ref.stats["fused"] == res.stats["detections"] > 50


@pytest.mark.parametrize("estimator", ["dekf", "cekf", "diekf", "expfusion", "ci"])
def test_planar_kinds_in_a_3d_team_are_refused_not_raised(estimator: str) -> None:
    """A planar detection (range-bearing of a teammate, an absolute fix) reaching an SE(3) node is rejected with the
    reason the engine uses, counted, and the run goes on (it raised ValueError 'unknown 3-D measurement kind' in the
    EKF-family SE(3) nodes after the point kinds came in)."""
    from swarmloc.runner import run

    src = load_source("sim:3d", robots=3, duration=4.0, seed=0)
    bad = [
        Detection(1, 2.0, "range_bearing", np.array([2.0, 0.3]), np.diag([0.01, 0.001]), target=2),
        Detection(0, 2.0, "absolute", np.array([0.0, 0.0, 0.0]), np.eye(3) * 1e-2),
    ]
    events = sorted([*src.events, *bad], key=lambda e: e.stamp)
    res = run(make_team(estimator, src.initial, noise=src.noise, t0=src.t_start), events)
    assert res.accounted()
    for kind in ("range_bearing", "absolute"):
        assert res.reasons[f"rejected: kind {kind!r} is not supported on SE(3)"] == 1, dict(res.reasons)
