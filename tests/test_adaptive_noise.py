"""``diekf``'s adaptive process noise (:mod:`swarmloc.estimators.adaptive_noise`): the covariance-matching scale
as documented, replays rewrite rather than add, and a team whose process noise is given 3 times too small in std
is made consistent by the adaptation where the fixed filter is not."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from swarmloc.config import DEFAULTS
from swarmloc.engine.replay import run_engine
from swarmloc.estimators import make_team, node_options
from swarmloc.estimators.adaptive_noise import GUARD, LOW, Innovation, NoiseScale, innovation_terms
from swarmloc.evaluation.metrics import evaluate
from swarmloc.experiments.sources import load_source
from swarmloc.node import chi2_ppf
from swarmloc.runner import run

pytestmark = pytest.mark.unit


def test_innovation_terms_split_the_nis():
    R, HPH = np.diag([0.04, 0.01]), np.array([[0.02, 0.005], [0.005, 0.03]])
    S, r = HPH + R, np.array([0.3, -0.1])
    inn = innovation_terms(r, S, R)
    assert inn is not None and inn.m == 2
    assert inn.e == pytest.approx(r @ np.linalg.solve(S, r))
    assert inn.a == pytest.approx(np.trace(np.linalg.solve(S, R)))  # b = m - a = tr(S^-1 H P H^T)
    assert innovation_terms(r, np.zeros((2, 2)), R) is None


def test_scale_matches_the_window_and_reads_the_past_only():
    ns = NoiseScale(window=10.0, prior_dof=0.0)
    assert ns.scale(5.0) == 1.0  # nothing logged
    # the model's process noise 3 times too small: at the scale lam in force, e = a + (3 / lam) b with b = m - a
    for k in range(20):
        lam = ns.scale(float(k))
        ns.record(float(k), ("d", k), Innovation(e=0.5 + 3 / lam * 1.5, a=0.5, m=2))
    assert ns.scale(1.0) == pytest.approx(3.0)  # one window's step reaches the scale
    assert ns.scale(20.0) == pytest.approx(3.0)  # and stays there
    assert ns.scale(0.0) == 1.0  # an entry stamped at t is not read at t
    assert ns.scale(100.0) == 1.0  # the window has passed
    # small innovations never take the scale below the model's noise
    low = NoiseScale(window=10.0, prior_dof=0.0)
    low.record(0.0, "a", Innovation(e=0.01, a=1.5, m=2))
    assert low.scale(1.0) == LOW == 1.0


def test_outliers_are_capped_and_replays_rewrite():
    ns = NoiseScale(window=10.0, prior_dof=4.0)
    ns.record(1.0, "x", Innovation(e=1e6, a=1.0, m=2))
    cap = chi2_ppf(GUARD, 2)
    assert ns.scale(2.0) == pytest.approx((4.0 + cap - 1.0) / (4.0 + 1.0))
    ns.record(1.0, "x", Innovation(e=2.0, a=1.0, m=2))  # the same detection replayed: rewritten, not added
    assert ns.scale(2.0) == pytest.approx(1.0)
    P0, P1 = np.eye(3), 2 * np.eye(3)
    ns.record(1.5, "y", Innovation(e=cap, a=1.0, m=2))
    lam = ns.scale(2.0)
    assert lam > 1 and np.allclose(ns.inflate(P0, P1, 2.0), P0 + lam * (P1 - P0))


def test_config_option_reaches_diekf_only():
    cfg = dataclasses.replace(DEFAULTS, filter=dataclasses.replace(DEFAULTS.filter, diekf_adaptive=True))
    assert node_options("diekf", cfg, None)["adaptive"] is True
    assert "adaptive" not in node_options("diekf", DEFAULTS, None)  # the engine's diekf takes no such option
    assert "adaptive" not in node_options("rdl", cfg, None)


def test_the_engine_refuses_the_option_clearly():
    src = load_source("sim:landmarks", robots=2, duration=2.0, seed=0)
    with pytest.raises(ValueError, match="keeps its noise fixed"):
        run_engine(src, "diekf", adaptive=True)


def _anees(adaptive: bool, seed: int) -> float:
    src = load_source("sim:landmarks", robots=4, duration=60.0, seed=seed)
    opts = node_options("diekf", src.config, src.landmarks, src.t_start)
    noise = opts["noise"]  # every variance 9 times too small: the std 3 times
    small = {f.name: getattr(noise, f.name) / 9 for f in dataclasses.fields(noise)}
    opts["noise"] = dataclasses.replace(noise, **small)
    nodes = make_team("diekf", src.initial, adaptive=adaptive, **opts)
    res = run(nodes, src.events, src.record_times(), truth=src.truth, name="diekf")
    return float(evaluate(res)["team"]["anees"])


def test_adaptation_makes_a_misspecified_team_consistent():
    """Process noise given 3x too small in std (on seeds 0, 1; 60 s, 4 robots, landmarks): the fixed filter is
    over-confident beyond the band, the adaptive one inside it."""
    fixed = np.mean([_anees(False, s) for s in (0, 1)])
    adaptive = np.mean([_anees(True, s) for s in (0, 1)])
    assert fixed > 3.0
    assert 0.5 <= adaptive <= 2.0
