"""``diekf``'s clusters with split covariance intersection (``split``, ``[filter] diekf_split``,
:mod:`swarmloc.estimators.diekf`): one outside detection is the Kalman update of the split-CI-bounded cluster and
the bound covers the true covariance when the independent part is independent of the outsider; the independent part
is the process noise since the robot's error last could leave the cluster; a team stays consistent and its traffic
per detection does not grow with the team; the option is opt-in and the engine refuses it.
(Figures against team size: ``benchmarks/diekf_swarm.py --split``.)"""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarmloc.engine import run_engine
from swarmloc.estimators import make_team, node_options
from swarmloc.estimators.diekf import DistributedInvariantEKF, TeamState
from swarmloc.estimators.world_form import Independent
from swarmloc.evaluation.metrics import evaluate
from swarmloc.events import Detection
from swarmloc.experiments.sources import load_source
from swarmloc.gaussian import GroupGaussian
from swarmloc.kernels import invariant as I
from swarmloc.lie import SE2
from swarmloc.messages import BeliefAnswer, BeliefQuery, TeamUpdate, flat
from swarmloc.motion import UnicycleNoise
from swarmloc.runner import run
from swarmloc.sensors.models import model
from swarmloc.sim import RelativeSensor, random_team
from swarmloc.sim.source import sim_source

pytestmark = pytest.mark.unit

NOISE = UnicycleNoise(q_v0=4e-3, q_w0=4e-3)


def _pair(split: bool) -> tuple[DistributedInvariantEKF, DistributedInvariantEKF]:
    init = GroupGaussian(SE2, np.eye(3), np.eye(3) * 0.01)
    return tuple(DistributedInvariantEKF(r, init, team=(0, 1, 2, 3), cluster=2, noise=NOISE, gate=None, split=split)
                 for r in (0, 1))  # type: ignore[return-value]  # fmt: skip


def test_an_outside_detection_is_the_kalman_update_of_the_split_ci_bounded_cluster() -> None:
    """Robots 0 and 1 a cluster, correlated with robot 2 outside it through the dependent part; robot 0's error has
    besides an independent part ``Pi`` (independent of both). Reference: the stacked ``(e_0, e_1)`` with covariance
    ``C_d / w + blockdiag(Pi, 0)``, noise ``R + H_2 P_22 H_2^T / (1 - w)``, the Kalman update. Both robots' results
    equal it (1e-9); it is tighter than covariance intersection's (``C / w``) and still covers the true covariance;
    robot 0's independent part is reset (its error is now in robot 1's), robot 1's kept."""
    rng = np.random.default_rng(3)
    n0, n1 = _pair(True)
    x0, x1, x2 = np.array([0.2, -0.1, 0.3]), np.array([1.5, 0.8, -0.4]), np.array([2.6, 1.9, 1.1])
    L = rng.normal(size=(9, 9)) * 0.08
    D = np.diag([1.0] * 6 + [0.15] * 3)
    Jd = D @ (L @ L.T + np.eye(9) * 0.01) @ D  # the dependent parts of (0, 1, 2), correlated
    Pi = np.diag([0.02, 0.015, 0.004])  # robot 0's process noise since its last exposure
    J = Jd.copy()
    J[:3, :3] += Pi
    P0, P1, S01, P2 = J[:3, :3], J[3:6, 3:6], J[:3, 3:6], J[6:, 6:]
    Sig = np.zeros((2, 2, 3, 3))
    Sig[0, 1], Sig[1, 0] = S01, S01.T
    kept = Independent(0.5, np.eye(3) * 1e-3)
    s0 = TeamState(1.0, 0.0, 0.0, x0, P0, Sig, Independent(0.5, Pi))
    s1 = TeamState(1.0, 0.0, 0.0, x1, P1, Sig.copy(), kept)
    R = np.diag([0.05**2, 0.03**2])
    mm = model("range_bearing")
    z = mm.predict(x0, x2)[0] + np.array([0.07, -0.02])
    d = Detection(0, 1.0, "range_bearing", z, R, target=2)
    g2 = SE2.from_xytheta(x2)
    answer = BeliefAnswer(sender=2, receiver=0, stamp=1.0, mean=flat(g2), cov=flat(I.world_to_body(g2, P2)))
    new0, (j, Hi, Hj, Sinv, nu, Pii, Pjj, w) = n0._one(s0, None, d, ("robot", answer))
    assert j == 0 and 0.001 < w < 0.999
    u = TeamUpdate(sender=0, receiver=1, stamp=1.0, target=j, m=2, Hi=flat(Hi), Hj=flat(Hj), Sinv=flat(Sinv),
                   nu=flat(nu), Pii=flat(Pii), Pjj=flat(Pjj), scale=w)  # fmt: skip
    new1, applied = n1._apply_update(s1, u)
    assert applied

    _, Hi_c, Hj_c = mm.predict(x0, x2)
    H0, H2 = Hi_c @ I.world_basis(x0), Hj_c @ I.world_basis(x2)
    H = np.hstack([H0, np.zeros((2, 3))])
    C = J[:6, :6] / w
    C[:3, :3] -= (1.0 / w - 1.0) * Pi  # C_d / w + blockdiag(Pi, 0)
    S = H @ C @ H.T + R + H2 @ P2 @ H2.T / (1 - w)
    K = C @ H.T @ np.linalg.inv(S)
    Cp = C - K @ S @ K.T
    r = mm.residual(z, mm.predict(x0, x2)[0])
    np.testing.assert_allclose(new0.x, I.left_correct(x0, (K @ r)[:3]), atol=1e-9)
    np.testing.assert_allclose(new1.x, I.left_correct(x1, (K @ r)[3:]), atol=1e-9)
    np.testing.assert_allclose(new0.P, Cp[:3, :3], atol=1e-9)
    np.testing.assert_allclose(new1.P, Cp[3:, 3:], atol=1e-9)
    np.testing.assert_allclose(new0.Sigma[0, 1], Cp[:3, 3:], atol=1e-9)
    A = np.eye(9)  # the true covariance of the estimator's errors after the update
    A[:6, :3] -= K @ H0
    A[:6, 6:] -= K @ H2
    true = (A @ J @ A.T)[:6, :6] + K @ R @ K.T
    assert np.linalg.eigvalsh(Cp - true).min() > -1e-12
    ci0, _ = _pair(False)  # covariance intersection alone: looser
    ci = ci0._one(s0._replace(indep=None), None, d, ("robot", answer))[0]
    assert np.trace(new0.P) < np.trace(ci.P)
    assert new0.indep is not None and new0.indep.since == 1.0 and not new0.indep.P.any()
    assert new1.indep is kept


def test_the_independent_part_is_the_process_noise_since_the_belief_last_left_the_cluster() -> None:
    """A prediction adds its process noise to the independent part; a belief given to an outsider (a
    ``BeliefQuery`` answered) zeroes it from then on, also for a state predicted before the answer was known."""
    n0, _ = _pair(True)
    p = n0.protocol
    s = n0._initial_state(0.0)
    assert s.indep is not None and np.array_equal(s.indep.P, s.P)  # the robots' initial errors are independent
    s = n0._set_command(s, 0, 0.2, 0.1)
    s1 = n0._advance(s, 0, 1.0)
    np.testing.assert_allclose(s1.indep.P, s1.P, atol=1e-15)
    assert np.trace(s1.P) > np.trace(s.P)
    np.testing.assert_array_equal(p.independent(s1), s1.indep.P)
    assert n0._answer(s1, BeliefQuery(sender=2, receiver=0, stamp=0.5)) is not None
    assert p.exposed == [0.5] and not p.independent(s1).any()  # predicted before the answer: zero
    s2 = n0._advance(s1, 0, 2.0)
    assert not p.independent(s2).any()  # the exposure lies within (since, t]
    s3 = n0._advance(s, 0, 0.7)  # a prediction across the exposure restarts the part at its end
    assert s3.indep.since == 0.7 and not s3.indep.P.any()
    s4 = n0._advance(s3, 0, 1.5)
    np.testing.assert_allclose(p.independent(s4), s4.P - s3.P, atol=1e-15)
    assert p.independent(s4).any()


def _spread(n: int, duration: float) -> object:
    """``sim:random`` in an arena of side ``3 m sqrt(n / 5)`` (benchmarks/diekf_swarm.py's scene)."""
    sim = random_team(n, duration, seed=1, area=3.0 * math.sqrt(n / 5), sensor=RelativeSensor(rate=5.0))
    return sim_source(sim, "sim:random (spread)")


def test_a_split_team_stays_consistent_and_its_traffic_per_detection_does_not_grow() -> None:
    """Clusters of 2 with split CI on 8 and 16 robots (4 s): every detection accounted, ANEES per dof within the
    conservative side of [0.1, 2] (measured 0.20 on 8 robots: covariance intersection stays conservative), no
    message more than covariance intersection sends, and the messages per fused detection flat within 20% from 8
    to 16 robots (the exact filter's grow with the team: it broadcasts to all)."""
    per_detection = {}
    for n in (8, 16):
        src = _spread(n, 4.0)
        opts = node_options("diekf", src.config, src.landmarks)
        res = {}
        for name, extra in (("split", {"cluster": 2, "split": True}), ("ci", {"cluster": 2}), ("exact", {})):
            res[name] = run(make_team("diekf", src.initial, **{**opts, **extra}), src.events, src.record_times(),
                            truth=src.truth)  # fmt: skip
            per_detection[(n, name)] = res[name].stats["messages"] / res[name].stats["fused"]
        got = evaluate(res["split"])["team"]
        assert res["split"].accounted() and res["split"].stats["fused"] > 20 * n
        assert 0.1 <= got["anees"] <= 2.0, got
        assert res["split"].stats["messages"] == res["ci"].stats["messages"]
    assert 0.8 <= per_detection[(16, "split")] / per_detection[(8, "split")] <= 1.2, per_detection
    assert per_detection[(16, "exact")] / per_detection[(8, "exact")] > 1.5, per_detection


def test_split_is_opt_in_needs_clusters_and_the_engine_refuses_it(tmp_path) -> None:
    from swarmloc.config import load_config

    cfg = tmp_path / "split.toml"
    cfg.write_text("[filter]\ndiekf_cluster = 2\ndiekf_split = true\n")
    src = load_source("sim:random", robots=4, duration=2.0, seed=1, config=load_config(cfg))
    opts = node_options("diekf", src.config, src.landmarks)
    assert opts["split"] is True and all(n.protocol.split for n in make_team("diekf", src.initial, **opts))
    plain = load_source("sim:random", robots=4, duration=2.0, seed=1)
    assert "split" not in node_options("diekf", plain.config, plain.landmarks)
    with pytest.raises(ValueError, match="'split'.*needs 'cluster' > 0"):
        _ = DistributedInvariantEKF(0, src.initial[0], team=(0, 1), split=True)
    with pytest.raises(ValueError, match=r"run \[filter\] diekf_split with the nodes"):
        run_engine(src, "diekf", backend="numba")
