"""``diekf``'s adaptive process noise (:mod:`swarmloc.estimators.adaptive_noise`): the covariance-matching scale
as documented, replays rewrite rather than add, and a team whose process noise is given 3 times too small in std
is made consistent by the adaptation where the fixed filter is not; the median variant's NIS modes against the
direct NIS, and its scale against a Monte Carlo of innovations drawn with a known prediction scale."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from swarmloc.config import DEFAULTS
from swarmloc.engine.replay import run_engine
from swarmloc.estimators import make_team, node_options
from swarmloc.estimators.adaptive_noise import (
    FLOOR,
    GUARD,
    LOW,
    MIN_COUNT,
    Innovation,
    MedianScale,
    NoiseScale,
    innovation_terms,
)
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


def test_config_option_reaches_diekf_and_flsd_only():
    cfg = dataclasses.replace(DEFAULTS, filter=dataclasses.replace(DEFAULTS.filter, diekf_adaptive=True))
    assert node_options("diekf", cfg, None)["adaptive"] is True
    median = dataclasses.replace(DEFAULTS, filter=dataclasses.replace(DEFAULTS.filter, diekf_adaptive="median"))
    assert node_options("diekf", median, None)["adaptive"] == "median" == DEFAULTS.filter.diekf_adaptive
    fixed = dataclasses.replace(DEFAULTS, filter=dataclasses.replace(DEFAULTS.filter, diekf_adaptive=False))
    assert node_options("diekf", fixed, None)["adaptive"] is False  # given, or the class default would apply
    assert node_options("flsd", fixed, None)["adaptive"] is False
    assert "adaptive" not in node_options("rdl", cfg, None)


def test_the_engine_refuses_the_option_clearly():
    """A scale the engine would not reproduce is refused (the default median scale where landmarks are fused);
    without landmarks to fuse the median scale is 1 and the engine replays the nodes' numbers."""
    src = load_source("sim:landmarks", robots=4, duration=8.0, seed=0)
    with pytest.raises(ValueError, match="keeps its noise fixed.*diekf_adaptive.*set it to false"):
        run_engine(src, "diekf", adaptive=True)
    with pytest.raises(ValueError, match="keeps its noise fixed"):
        run_engine(src, "diekf")  # the default, with a map and landmark detections
    assert run_engine(src, "diekf", backend="numba", adaptive=False).stats["fused"] > 0
    off = run_engine(src, "diekf", backend="numba", use_landmarks=False)  # median without landmarks: fixed noise
    opts = {**node_options("diekf", src.config, src.landmarks), "use_landmarks": False}
    assert opts["adaptive"] == "median"
    with_map = make_team("diekf", src.initial, **{**opts, "use_landmarks": True})
    assert all(isinstance(n.noise_scale, MedianScale) for n in with_map)  # the default where landmarks are fused
    nodes = make_team("diekf", src.initial, **opts)
    assert all(n.noise_scale is None for n in nodes)
    ref = run(nodes, src.events, record_times=src.record_times(), truth=src.truth)
    assert ref.stats["fused"] == off.stats["fused"] > 0
    for r, tr in ref.tracks.items():
        assert np.allclose(off.tracks[r].mean, tr.mean, rtol=0, atol=1e-10)


def _anees(adaptive: bool, seed: int) -> float:
    src = load_source("sim:landmarks", robots=4, duration=60.0, seed=seed)
    opts = node_options("diekf", src.config, src.landmarks, src.t_start)
    noise = opts["noise"]  # every variance 9 times too small: the std 3 times
    small = {f.name: getattr(noise, f.name) / 9 for f in dataclasses.fields(noise)}
    opts["noise"] = dataclasses.replace(noise, **small)
    nodes = make_team("diekf", src.initial, **{**opts, "adaptive": adaptive})
    res = run(nodes, src.events, src.record_times(), truth=src.truth, name="diekf")
    return float(evaluate(res)["team"]["anees"])


def test_adaptation_makes_a_misspecified_team_consistent():
    """Process noise given 3x too small in std (on seeds 0, 1; 60 s, 4 robots, landmarks): the fixed filter is
    over-confident beyond the band, the adaptive one inside it."""
    fixed = np.mean([_anees(False, s) for s in (0, 1)])
    adaptive = np.mean([_anees(True, s) for s in (0, 1)])
    assert fixed > 3.0
    assert 0.5 <= adaptive <= 2.0


def _pencil(rng: np.random.Generator, share: float) -> tuple[np.ndarray, np.ndarray]:
    """A random measurement noise ``R`` and prediction part ``B`` (2 x 2) with ``B`` about ``share`` times ``R``."""
    A, C = rng.normal(size=(2, 2)), rng.normal(size=(2, 2))
    R = A @ A.T + 0.1 * np.eye(2)
    return R, share * np.trace(R) / 2 * (C @ C.T / np.trace(C @ C.T) * 2 + 0.2 * np.eye(2))


def test_modes_give_the_nis_at_any_scale():
    rng = np.random.default_rng(3)
    for _ in range(20):
        R, B = _pencil(rng, rng.uniform(0.1, 10.0))
        r = rng.normal(size=2)
        inn = innovation_terms(r, R + B, R, landmark=True)
        assert inn is not None and inn.landmark and len(inn.modes) == 2
        c, mu = np.array(inn.modes).T
        for lam in (0.01, 0.3, 1.0, 7.0):  # the NIS had the prediction part been lam B, solved directly
            assert np.sum(c / (1 + lam * mu)) == pytest.approx(r @ np.linalg.solve(R + lam * B, r), rel=1e-9)
        assert np.sum(1 / (1 + mu)) == pytest.approx(inn.a, rel=1e-9)
    assert innovation_terms(r, R + B, np.zeros((2, 2))).modes == ()  # type: ignore[union-attr]


def _draw(ms: MedianScale, rng: np.random.Generator, true: float, n: int, *, share: float = 300.0,
          landmark: bool = True, t0: float = 0.0) -> None:  # fmt: skip
    """``n`` innovations, one per 0.01 s from ``t0``, drawn from ``N(0, R + true B)`` and filed as the filter
    formed them: with the prediction part ``lam B`` at the scale ``lam`` in force."""
    for k in range(n):
        t = t0 + 0.01 * k
        R, B = _pencil(rng, share)
        r = rng.multivariate_normal(np.zeros(2), R + true * B)
        inn = innovation_terms(r, R + ms.scale(t) * B, R, landmark=landmark)
        assert inn is not None
        ms.record(t, ("d", t), inn)


@pytest.mark.parametrize("true", [0.05, 0.3, 1.0])
def test_median_scale_finds_the_true_prediction_scale(true: float):
    """Monte Carlo: prediction covariances drawn ``true`` times the model's; the scale read after a window of them
    is ``true`` (within the sampling error of a median of 400)."""
    rng = np.random.default_rng(7)
    ms = MedianScale(window=60.0)
    _draw(ms, rng, true, 400)
    lam = ms.scale(4.0)
    assert lam == pytest.approx(true, rel=0.15)


def test_median_scale_needs_a_landmark_enough_innovations_and_a_prediction_share():
    rng = np.random.default_rng(11)
    robots = MedianScale(window=60.0)
    _draw(robots, rng, 0.05, 200, landmark=False)  # robot-robot innovations alone: never below 1
    assert robots.scale(3.0) == 1.0
    _draw(robots, rng, 0.05, 1, landmark=True, t0=2.5)  # one landmark innovation in the window lets it move
    assert robots.scale(3.0) < 0.5
    few = MedianScale(window=60.0)
    _draw(few, rng, 0.05, MIN_COUNT - 1)
    assert few.scale(1.0) == 1.0
    measured = MedianScale(window=60.0)
    _draw(measured, rng, 0.05, 200, share=0.2)  # measurement-dominated: not filed
    assert measured.scale(3.0) == 1.0
    tiny = MedianScale(window=60.0)
    _draw(tiny, rng, 1e-4, 200)
    assert tiny.scale(3.0) == FLOOR  # never below the floor
    assert tiny.scale(3.0 + 61.0) == 1.0  # the window has passed
    assert np.allclose(tiny.inflate(np.eye(3), 3 * np.eye(3), 3.0), np.eye(3) + FLOOR * 2 * np.eye(3))


def test_median_scale_replays_rewrite():
    ms = MedianScale(window=60.0)
    rng = np.random.default_rng(5)
    _draw(ms, rng, 0.05, 50)
    before = ms.scale(1.0)
    R, B = _pencil(rng, 300.0)
    for k in range(50):  # the same detections replayed as huge innovations: rewritten, not added
        inn = innovation_terms(100 * np.ones(2), R + B, R, landmark=True)
        assert inn is not None
        ms.record(0.01 * k, ("d", 0.01 * k), inn)
    assert before < 0.5 and ms.scale(1.0) == 1.0


def test_median_scale_whose_only_entry_a_replay_drops_reads_1():
    """A replay that drops the one innovation filed (it is no longer prediction-dominated) leaves an empty log: the
    scale reads 1 (the empty window once failed to rebuild, first met by a lying teammate's replayed updates)."""
    ms = MedianScale(window=60.0)
    rng = np.random.default_rng(3)
    R, B = _pencil(rng, 300.0)
    ms.record(1.0, "d", innovation_terms(np.ones(2), R + B, R, landmark=True))  # type: ignore[arg-type]
    assert ms._log
    ms.record(1.0, "d", innovation_terms(np.ones(2), R + 1e-6 * B, R, landmark=True))  # type: ignore[arg-type]
    assert not ms._log and ms.scale(2.0) == 1.0
