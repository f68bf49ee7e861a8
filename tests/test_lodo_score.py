"""The LODO filter score (issue 21, :mod:`swarmloc_studies.lodo`): the predictive landmark NIS against Monte
Carlo draws of the pose, the map entry and the reading, and the landmark folds."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from swarmloc.evaluation.heldout import (
    RECORD_LEAD,
    landmark_folds,
    landmark_innovations,
    landmark_nis,
    nis_summary,
    reading_times,
)
from swarmloc.events import Detection
from swarmloc.lie import SE2

pytestmark = pytest.mark.data


STD = (0.08, 0.01)  # [m], [rad]
MAP_STD = (0.03, 0.05)  # [m]


def _draw(n: int, scale: float, seed: int = 0):
    """``n`` beliefs (mean, cov) and a reading each, drawn from the model with the pose error drawn from
    ``scale`` times the belief's covariance (1: consistent)."""
    rng = np.random.default_rng(seed)
    mean = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-3, 3, n), rng.uniform(-np.pi, np.pi, n)])
    a = rng.normal(size=(n, 3, 3)) * np.array([0.06, 0.06, 0.03])[:, None]
    cov = a @ np.swapaxes(a, 1, 2) + np.diag([1e-4, 1e-4, 1e-5])
    xi = np.einsum("nij,nj->ni", np.linalg.cholesky(scale * cov), rng.normal(size=(n, 3)))
    true = SE2.to_xytheta(SE2.from_xytheta(mean) @ SE2.exp(xi))  # right perturbation
    lm_true = true[:, :2] + rng.uniform(1.0, 4.0, (n, 1)) * np.column_stack(
        [np.cos(a := rng.uniform(-1, 1, n) + true[:, 2]), np.sin(a)]
    )
    lm_map = lm_true + rng.normal(size=(n, 2)) * MAP_STD
    d = lm_true - true[:, :2]
    z = np.column_stack([np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0]) - true[:, 2]])
    z += rng.normal(size=(n, 2)) * STD
    times = np.arange(n, dtype=float)
    landmarks = {i: (*lm_map[i], *MAP_STD) for i in range(n)}
    dets = [Detection(0, times[i] + RECORD_LEAD, "range_bearing", z[i], np.diag(np.square(STD)), i, False)
            for i in range(n)]  # fmt: skip
    return times, mean, cov, dets, landmarks


def test_landmark_nis_is_chi_square_2_for_a_consistent_belief_and_grows_for_an_overconfident_one():
    nis = landmark_nis(*_draw(20_000, 1.0), STD)
    assert np.isfinite(nis).all()
    assert abs(nis.mean() - 2.0) < 0.08, nis.mean()  # std of the mean: 2 / sqrt(20000) = 0.014
    assert stats.kstest(nis, stats.chi2(2).cdf).pvalue > 1e-3
    over = landmark_nis(*_draw(20_000, 9.0), STD)  # errors three times the belief's std
    assert over.mean() > 5.0


def test_landmark_innovations_split_the_nis_with_the_jacobian_of_the_reading_model():
    """Each component's ``r^2 / S`` has mean 1 for a consistent belief (chi-square of 1 dof), the NIS is the
    innovations' Mahalanobis distance in ``belief + noise``, and ``H`` equals the finite-difference derivative of the
    predicted (range, bearing) under a right perturbation of the pose (an independent computation)."""
    times, mean, cov, dets, lms = _draw(20_000, 1.0, seed=4)
    li = landmark_innovations(times, mean, cov, dets, lms, STD)
    assert li.ok.all()
    S = li.belief + li.noise
    for c in (0, 1):
        assert abs(np.mean(li.r[:, c] ** 2 / S[:, c, c]) - 1.0) < 0.05
    nis = np.einsum("ni,ni->n", li.r, np.linalg.solve(S, li.r[..., None])[..., 0])
    np.testing.assert_allclose(nis, landmark_nis(times, mean, cov, dets, lms, STD), rtol=1e-12)
    np.testing.assert_allclose(li.belief, li.H @ cov @ np.swapaxes(li.H, 1, 2), rtol=1e-12)

    def predicted(pose, lm):
        d = lm - pose[:2]
        return np.array([np.hypot(*d), np.arctan2(d[1], d[0]) - pose[2]])

    for i in range(5):
        g, lm, h = SE2.from_xytheta(mean[i]), np.array(lms[i][:2]), 1e-6
        cols = []
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            up = predicted(SE2.to_xytheta(g @ SE2.exp(e)), lm)
            down = predicted(SE2.to_xytheta(g @ SE2.exp(-e)), lm)
            cols.append((up - down) / (2 * h))
        np.testing.assert_allclose(li.H[i], np.column_stack(cols), atol=1e-6)


def test_the_median_score_and_the_mean_anis_part_on_heavy_tails_only():
    """``nis_ratio`` (median / 1.386) and ``anis`` (mean / 2) both read 1 on chi-square-2 draws; on a scale mixture
    with the same mean (90 % of the errors at 0.2 of the claimed variance, 10 % at 8.2: a covariance that covers a
    few large errors, as on MRCLAM dataset 9) the mean stays at 1 and the median reads about 0.2."""
    rng = np.random.default_rng(3)
    x = stats.chi2(2).rvs(size=200_000, random_state=rng)
    row = nis_summary(x)
    assert abs(row["anis"] - 1.0) < 0.02 and abs(row["nis_ratio"] - 1.0) < 0.02
    mix = x * np.where(rng.random(x.size) < 0.9, 0.2, 8.2)
    row = nis_summary(mix)
    assert abs(row["anis"] - 1.0) < 0.05 and row["nis_ratio"] < 0.3
    assert row["beyond_gate"] > 0.01 and row["readings"] == x.size


def test_landmark_nis_is_nan_where_no_belief_was_recorded_just_before_the_reading():
    times, mean, cov, dets, lms = _draw(10, 1.0)
    nis = landmark_nis(times + 0.5, mean, cov, dets, lms, STD)
    assert np.isnan(nis).all()


@pytest.mark.parametrize("k", [2, 3, 5])
def test_landmark_folds_partition_the_ids_and_spread_over_them(k):
    ids = list(range(6, 21))
    folds = landmark_folds(ids[::-1], k)
    assert len(folds) == k and set().union(*folds) == set(ids) and sum(map(len, folds)) == len(ids)
    assert max(map(len, folds)) - min(map(len, folds)) <= 1
    assert all(max(f) - min(f) >= len(ids) - 2 * k + 1 for f in folds)  # each reaches across the ids


def test_filter_scores_score_every_reading_once_against_a_run_without_its_landmark(mrclam6):
    """With landmarks on, the folds' runs score every landmark reading of the span exactly once (the all-in run
    scores the same readings); with the model's std as the reference both scores are the same number; a larger
    reference std can only lower the score."""
    from swarmloc.datasets.mrclam import load_mrclam
    from swarmloc.sensors.decorrelate import CameraModel, ErrorComponent
    from swarmloc_studies.lodo import filter_scores

    data = load_mrclam(mrclam6)
    model = CameraModel(ErrorComponent(0.15), ErrorComponent(0.005), source="test")
    same = filter_scores(data, model, ["rdl"], True, 40.0, holdout=3, reference_std=(0.15, 0.005))["rdl"]
    assert same["readings"] == same["readings_all"] > 200
    assert same["nis_ratio_ref"] == same["nis_ratio"] and np.isfinite(same["anees_folds"])
    assert same["anis_ref"] == same["anis"] > 0
    wide = filter_scores(data, model, ["rdl"], True, 40.0, holdout=3, reference_std=(0.3, 0.01))["rdl"]
    assert wide["nis_ratio"] == same["nis_ratio"] and wide["nis_ratio_ref"] < same["nis_ratio"]
    assert wide["anis_ref"] < same["anis"]
    off = filter_scores(data, model, ["rdl"], False, 40.0)["rdl"]
    assert off["readings"] == same["readings"] and "readings_all" not in off and "anees_folds" not in off


def test_a_smoother_s_delayed_output_is_scored_on_the_held_out_readings_at_their_stamps(mrclam6):
    """``flsd`` gets a row ``flsd_delayed``: each fold's held-out readings scored against that fold's run's delayed
    output carried to their stamps (the pose filed last before each, predicted through the odometry: every reading
    after the first filing and before the run's last lag: 583 of 630 in these 30 s), and the truth at those
    instants.
    Filing the delayed output changes no causal belief: the causal row's truth metrics equal a run of the default
    configuration (no delayed output) to the bit, and the delayed row's those of the delayed output of a team run by
    hand, carried to those instants."""
    from swarmloc.config import DEFAULTS
    from swarmloc.datasets.mrclam import load_mrclam, mrclam_events
    from swarmloc.estimators import make_team, node_options
    from swarmloc.evaluation.delayed import carried_output
    from swarmloc.evaluation.metrics import evaluate
    from swarmloc.experiments.mrclam import detection_set
    from swarmloc.experiments.truthfree import fused_from_snapshots, landmark_readings
    from swarmloc.runner import run
    from swarmloc.sensors.decorrelate import CameraModel, ErrorComponent, decorrelate
    from swarmloc_studies.lodo import filter_scores

    data = load_mrclam(mrclam6)
    model = CameraModel(ErrorComponent(0.15), ErrorComponent(0.005), source="test")
    rows = filter_scores(data, model, ["flsd"], True, 30.0, holdout=3)
    causal, late = rows["flsd"], rows["flsd_delayed"]
    assert 0.8 * causal["readings"] < late["readings"] < causal["readings"] and np.isfinite(late["nis_ratio"])
    assert np.isfinite(late["anees_folds"]) and late["pos_rmse"] < causal["pos_rmse"]  # smoothed: more accurate
    # the causal belief scored on the very readings the delayed output scores (it has a belief before every reading)
    assert late["readings_causal"] == late["readings_causal_ref"] == late["readings"]
    assert np.isfinite(late["nis_ratio_causal"]) and "readings_causal" not in causal
    t0, initial = fused_from_snapshots(data, detection_set(data), DEFAULTS)[:2]
    readings = landmark_readings(data, t0, t0 + 30.0)
    rec = reading_times(readings)
    events = [e for e in decorrelate(mrclam_events(data, range_std=0.15, bearing_std=0.005), model)
              if t0 <= e.stamp <= t0 + 30.0]  # fmt: skip
    for config in (DEFAULTS, DEFAULTS.with_filter(delayed_output=True)):
        nodes = make_team("flsd", initial, **node_options("flsd", config, data.landmarks, t0))
        team = evaluate(run(nodes, events, record_times=rec, truth=data.truth_at, name="flsd"))["team"]
        assert (team["pos_rmse"], team["anees"]) == (causal["pos_rmse"], causal["anees"])
    at = np.unique([d.t for d in readings])
    team = evaluate(carried_output(nodes, events, at, data.truth_at, "flsd"))["team"]
    assert (team["pos_rmse"], team["anees"]) == (late["pos_rmse"], late["anees"])
    off = filter_scores(data, model, ["flsd"], False, 30.0)["flsd_delayed"]  # one run, no folds: none to average
    assert "anees_folds" not in off and 0 < off["readings"] == off["readings_causal"] and np.isfinite(off["anees"])


def test_filter_scores_calibrate_the_yaw_diffusion_without_the_scored_span_or_the_held_out_fold(mrclam6, monkeypatch):
    """``calibrate_yaw``: the run with every landmark uses the scale fitted outside the scored span, each fold's run
    the scale fitted without that fold's readings; the scales reach the filters (the score moves) and landmarks
    off is left as it is (nothing to calibrate from that the score does not use)."""
    import swarmloc.experiments.truthfree as truthfree_module
    import swarmloc_studies.lodo as lodo_module
    from swarmloc.config import DEFAULTS
    from swarmloc.datasets.mrclam import load_mrclam
    from swarmloc.sensors.decorrelate import CameraModel, ErrorComponent
    from swarmloc_studies.lodo import detection_set, filter_scores, yaw_calibration

    data = load_mrclam(mrclam6)
    model = CameraModel(ErrorComponent(0.15), ErrorComponent(0.005), source="test")
    seen: list[float] = []  # the yaw term each run's nodes get, in run order (every landmark, then the folds)
    options = lodo_module.node_options

    def record(name, config, *a):  # noqa: ANN001, ANN202
        if name == "rdl":  # (the truth-free start dead-reckons with "dr")
            seen.append(config.motion.q_w2)
        return options(name, config, *a)

    monkeypatch.setattr(lodo_module, "node_options", record)  # the run with every landmark
    monkeypatch.setattr(truthfree_module, "node_options", record)  # the folds' runs
    res = filter_scores(data, model, ["rdl"], True, 40.0, holdout=3, calibrate_yaw=True)
    row = res["rdl"]
    t0 = data.t_start + res["_span"]["t0"]
    span = (t0, t0 + res["_span"]["duration_s"])
    ds, noise = detection_set(data), DEFAULTS.motion.noise()
    assert row["yaw_scale"] == yaw_calibration(data, ds, model, noise, frozenset(), span).scale
    want = [yaw_calibration(data, ds, model, noise, f, span).scale for f in landmark_folds(data.landmarks, 3)]
    assert row["yaw_scale_folds"] == want and len(set(want)) == 3
    q_w2 = DEFAULTS.motion.q_w2
    assert seen == pytest.approx([q_w2 * s for s in [row["yaw_scale"], *want]], rel=1e-12)
    assert row["yaw_scale"] != yaw_calibration(data, ds, model, noise).scale  # the span is left out
    plain = filter_scores(data, model, ["rdl"], True, 40.0, holdout=3)["rdl"]
    assert "yaw_scale" not in plain and plain["readings"] == row["readings"]
    assert plain["nis_ratio"] != row["nis_ratio"] and plain["pos_rmse"] != row["pos_rmse"]
    off = filter_scores(data, model, ["rdl"], False, 40.0, calibrate_yaw=True)["rdl"]
    assert "yaw_scale" not in off
