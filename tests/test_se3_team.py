"""3-D teams (issue 22): the SE(3) twist increment and expfusion's SE(3) prediction against Monte Carlo of the SDE,
a consistent single-fusion case on the 3-D team, the estimators chosen by the beliefs' group, SE(3) answers
validated on receipt, TUM output with full quaternions."""

from __future__ import annotations

import numpy as np
import pytest

from swarmloc.datasets.tum import pose7, pose_from7, read_tum, write_tum3
from swarmloc.estimators import DistributedEKF, ExpCI, ExpFusion, make_team
from swarmloc.evaluation.metrics import evaluate
from swarmloc.events import Detection, twist_odometry
from swarmloc.experiments.se3 import run_se3, write_tum_tracks
from swarmloc.experiments.sources import load_source
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, SE3
from swarmloc.messages import BeliefAnswer, BeliefQuery, message_problem
from swarmloc.motion import UnicycleNoise
from swarmloc.motion.propagation import increment_cov
from swarmloc.motion.twist3 import TwistNoise, twist_increment
from swarmloc.sim.sim3d import Sim3Config, simulate3d

pytestmark = pytest.mark.unit


H = np.array([0.6, 0.1, -0.2, 0.3, -0.4, 0.8])


def _mc_increment(h: np.ndarray, dt: float, noise: TwistNoise, n: int, steps: int, rng) -> np.ndarray:
    """Euler-Maruyama of ``(g^-1 dg)^v = h dt + H dw`` from the identity: ``n`` endpoints ``(n, 4, 4)``."""
    d = dt / steps
    L = np.linalg.cholesky(noise.Q(h))
    g = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for _ in range(steps):
        g = g @ SE3.exp(h * d + np.sqrt(d) * rng.standard_normal((n, 6)) @ L.T, validate=False)
    return g


def test_twist_increment_matches_planar_closed_form() -> None:
    nz = TwistNoise(1e-3, 0.0, 2e-3, 0.0)
    _, S = twist_increment(np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.8]), 2.0, nz)
    S2 = increment_cov(np.array([0.5, 0.0, 0.8]), np.diag([1e-3, 1e-3, 2e-3]), 2.0, "closed")
    idx = [0, 1, 5]
    assert np.abs(S[np.ix_(idx, idx)] - S2).max() < 1e-12


def test_twist_increment_covariance_vs_monte_carlo() -> None:
    rng = np.random.default_rng(0)
    nz = TwistNoise(q_lin0=2e-3, q_ang0=1e-3)
    dt = 2.0
    mean, S = twist_increment(H, dt, nz)
    g = _mc_increment(H, dt, nz, 20000, 100, rng)
    y = SE3.log(SE3.inverse(mean) @ g)
    C = np.cov(y.T)
    assert np.abs(y.mean(0)).max() < 0.01
    rel = np.linalg.norm(C - S) / np.linalg.norm(S)
    assert rel < 0.05, rel


def test_expfusion_se3_prediction_vs_monte_carlo() -> None:
    """A node's prediction (second-order convolution of an uncertain belief with 20 twist increments) against
    samples of the belief pushed through the SDE."""
    rng = np.random.default_rng(1)
    nz = TwistNoise(q_lin0=2e-3, q_ang0=1e-3)
    S0 = np.diag([0.02, 0.01, 0.01, 0.04, 0.04, 0.09])
    prior = GroupGaussian(SE3, SE3.exp(np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])), S0)
    node = ExpFusion(0, prior, noise=nz, t0=0.0)
    for k in range(20):
        node.step(twist_odometry(0, 0.1 * k, 0.1 * (k + 1), H))
    b = node.belief_at(2.0)
    g0 = prior.sample(20000, rng)
    g = g0 @ _mc_increment(H, 2.0, nz, 20000, 100, rng)
    y = SE3.log(SE3.inverse(b.mean) @ g)
    C = np.cov(y.T)
    assert np.abs(y.mean(0)).max() < 0.02
    rel2 = np.linalg.norm(C - b.cov) / np.linalg.norm(C)
    assert rel2 < 0.05, rel2


def test_make_team_picks_se3_estimators() -> None:
    sim = simulate3d(Sim3Config(robots=2, duration=2.0), seed=0)
    assert isinstance(make_team("dekf", sim.initial, noise=sim.noise)[0], DistributedEKF)
    assert isinstance(make_team("ci", sim.initial, noise=sim.noise)[0], ExpCI)
    with pytest.raises(ValueError, match="no SE\\(3\\) form"):
        make_team("rdl", sim.initial, noise=sim.noise)
    with pytest.raises(ValueError, match="TwistNoise"):
        make_team("expfusion", sim.initial, noise=UnicycleNoise())


def test_se3_team_runs_every_estimator_and_accounts() -> None:
    src = load_source("sim:3d", robots=3, duration=10.0, seed=2)
    for name in ("dr", "expfusion", "dekf", "ci"):
        res = run_se3(src, name)
        assert res.accounted()
        team = evaluate(res)["team"]
        assert team["dof"] == 6 and team["n"] > 0
        if name != "dr":
            assert res.stats["fused"] == res.stats["detections"] > 0
        assert team["pos_rmse"] < 0.5


def test_expfusion_consistent_single_fusion_large_rotation() -> None:
    """Two robots, 30 deg initial rotational std per axis, one relative-pose epoch at 5 s then 5 s of prediction:
    the independence the fusion assumes holds, so over 20 seeds the ANEES/dof must lie in [0.5, 2]; the
    first-order EKF, linearized at a 30 deg error, must not be better."""
    nees = {"expfusion": [], "dekf": []}
    for seed in range(20):
        cfg = Sim3Config(robots=2, duration=10.0, sensor_rate=0.2, init_rot=float(np.deg2rad(30.0)))
        sim = simulate3d(cfg, seed)
        # keep the 5 s epoch only (the sensor fires at 5 s and 10 s)
        events = [e for e in sim.events if not (isinstance(e, Detection) and e.t > 6.0)]
        for name in nees:
            nodes = make_team(name, sim.initial, noise=sim.noise, t0=0.0)
            from swarmloc.runner import run

            res = run(nodes, events, name=name)
            tr = res.tracks[0]
            nees[name].append(evaluate(res)["team"]["anees"])
            assert tr.mean.shape[-1] == 7
    a_exp = float(np.mean(nees["expfusion"]))
    a_ekf = float(np.mean(nees["dekf"]))
    assert 0.5 <= a_exp <= 2.0, a_exp
    assert abs(a_exp - 1) < abs(a_ekf - 1), (a_exp, a_ekf)


def test_se3_answers_validated_on_receipt() -> None:
    sim = simulate3d(Sim3Config(robots=2, duration=1.0), seed=0)
    node = ExpFusion(1, sim.initial[1], noise=sim.noise, t0=0.0)
    q = BeliefQuery(sender=0, receiver=1, stamp=0.5)
    (ans,) = node.step(q)
    assert ans.group == "SE3" and len(ans.mean) == 16 and len(ans.cov) == 36
    assert message_problem(ans) is None
    bad_mean = list(ans.mean)
    bad_mean[0] = 2.0
    cases = {
        "mean is not in SE\\(3\\)": BeliefAnswer(
            sender=1, receiver=0, stamp=0.5, group="SE3", mean=tuple(bad_mean), cov=ans.cov
        ),  # fmt: skip
        "16 and 36": BeliefAnswer(sender=1, receiver=0, stamp=0.5, group="SE3", mean=ans.mean, cov=ans.cov[:9]),
        "positive definite": BeliefAnswer(
            sender=1, receiver=0, stamp=0.5, group="SE3", mean=ans.mean, cov=tuple(-np.eye(6).ravel())
        ),  # fmt: skip
        "not supported": BeliefAnswer(sender=1, receiver=0, stamp=0.5, group="SO3", mean=ans.mean, cov=ans.cov),
    }
    other = ExpFusion(0, sim.initial[0], noise=sim.noise, t0=0.0)
    for why, m in cases.items():
        assert message_problem(m) is not None
        import re

        assert re.search(why, message_problem(m))
        before = other.stats()["messages_rejected"]
        assert other.step(m) == []  # refused, counted, no crash
        assert other.stats()["messages_rejected"] == before + 1


def test_bad_twist_odometry_refused() -> None:
    sim = simulate3d(Sim3Config(robots=1, duration=1.0), seed=0)
    node = ExpFusion(0, sim.initial[0], noise=sim.noise, t0=0.0)
    node.step(twist_odometry(0, 0.0, 0.1, [np.nan, 0, 0, 0, 0, 0]))
    assert node.stats()["odometry_rejected"] == 1
    with pytest.raises(ValueError, match="6 components"):
        twist_odometry(0, 0.0, 0.1, [1.0, 2.0])


def test_tum3_round_trip_full_quaternions(tmp_path) -> None:
    g = SE3.random(np.random.default_rng(3), 5)
    p = pose7(g)
    assert np.allclose(np.linalg.norm(p[:, 3:], axis=1), 1.0) and (p[:, 6] >= 0).all()
    assert np.allclose(pose_from7(p), g, atol=1e-12)
    path = write_tum3(tmp_path / "t.tum", np.arange(5.0), g)
    rows = np.loadtxt(path)
    assert rows.shape == (5, 8) and np.allclose(rows[:, 1:], p, atol=1e-9)
    src = load_source("sim:3d", robots=2, duration=4.0, seed=0)
    paths = write_tum_tracks(run_se3(src, "expfusion"), tmp_path / "tum")
    assert len(paths) == 4 and all(np.loadtxt(q).shape[1] == 8 for q in paths)
    with pytest.raises(ValueError):  # the planar reader refuses a tilted pose: these are real 3-D poses
        read_tum(paths[0])
    assert SE2.dim == 3


def test_run_se3_records_every_truth_instant() -> None:
    """Truth instants merged in stamp order: every one is recorded (appended after the other events, a 20-s run
    recorded 76 of 164 and dropped the rest as ``record_too_old``)."""
    src = load_source("sim:3d", robots=4, duration=20.0, seed=0)
    res = run_se3(src, "dekf")
    assert res.stats["recorded"] == len(src.truth_events) == 164
    assert res.stats.get("record_too_old", 0) == 0
    assert sorted(np.concatenate([tr.times for tr in res.tracks.values()]))[0] == src.t_start


def test_se3_figures_draw_top_side_views_and_nees_over_time(tmp_path):
    """The 3-D figures: two PNGs from a short run of two estimators; a run that recorded nothing is refused."""
    from swarmloc.runner import RunResult
    from swarmloc_studies.se3 import se3_figures

    src = load_source("sim:3d", robots=3, duration=4.0, seed=0)
    results = {e: run_se3(src, e) for e in ("expfusion", "dr")}
    paths = se3_figures(tmp_path, results, src.t_start or 0.0)
    assert [p.name for p in paths] == ["trajectories3d.png", "error_nees3d.png"]
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000
    with pytest.raises(ValueError, match="nothing was recorded"):
        se3_figures(tmp_path, {"dr": RunResult("dr", {}, 0.0)})


def test_se3_table_rows_per_estimator_and_seed_and_summary_means():
    """One row per (scenario, estimator, seed) although a seed's estimators share one job; the summary is their
    mean."""
    from swarmloc_studies.se3 import se3_table

    t = se3_table(specs=("sim:3d",), estimators=("dr", "ci"), seeds=2, robots=3, duration=3.0, workers=1)
    assert sorted((r["estimator"], r["seed"]) for r in t["rows"]) == [("ci", 0), ("ci", 1), ("dr", 0), ("dr", 1)]
    for e in ("dr", "ci"):
        rs = [r for r in t["rows"] if r["estimator"] == e]
        assert t["summary"][f"sim:3d {e}"]["anees"] == pytest.approx(np.mean([r["anees"] for r in rs]), rel=1e-12)
        assert all(r["accounted"] for r in rs)
