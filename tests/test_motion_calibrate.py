"""Truth-free yaw-diffusion calibration from pose snapshots (issue 21, :mod:`swarmloc.motion.calibrate`): the
held integrals against quadrature, the heading residuals against a simulated robot, the scale's fit and its
uncertainty against Monte Carlo, and the fitted scales of the MRCLAM recordings."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from swarmloc.motion import UnicycleNoise
from swarmloc.motion.calibrate import fit_yaw_scale, heading_increments, held_integral, scale_yaw

pytestmark = pytest.mark.data


NOISE = UnicycleNoise(q_v0=1e-4, q_w0=1e-3, q_w1=0.004, q_w2=0.05, q_wv=0.02)


def _step(t: np.ndarray, x: np.ndarray):  # noqa: ANN202
    return lambda s: float(x[np.searchsorted(t, s, side="right") - 1])


def test_held_integral_equals_quadrature_of_the_held_signal() -> None:
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.01, 0.5, 40))
    x = rng.normal(size=40)
    got = held_integral(t, x)
    f = _step(t, x)
    want = [quad(f, t[0], b, points=t[(t > t[0]) & (t < b)], limit=200)[0] for b in t]
    np.testing.assert_allclose(got, want, atol=1e-10)


def _robot(seed: int, s_true: float, fit_std: float, n_snap: int = 400):  # noqa: ANN202
    """Odometry of one robot and snapshots of its heading: the true heading drifts from the odometry's yaw
    integral as a random walk with variance ``s_true`` times the model's diffusion; snapshots add ``fit_std``."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.05, 0.2, 12_000))
    v = rng.choice([0.0, 0.1, 0.25], size=t.size)
    w = rng.choice([0.0, 0.3, -0.5], size=t.size)
    q = NOISE.diag(v, w)[2]
    walk = np.concatenate([[0.0], np.cumsum(rng.normal(size=t.size - 1) * np.sqrt(s_true * q[:-1] * np.diff(t)))])
    heading = held_integral(t, w) + walk
    ts = np.sort(rng.uniform(t[0] + 1, t[-1] - 1, n_snap))
    # a snapshot between stamps: the heading held from the last stamp (no drift inside one record: exact)
    k = np.searchsorted(t, ts, side="right") - 1
    th = heading[k] + w[k] * (ts - t[k]) + rng.normal(size=ts.size) * fit_std
    pose = np.column_stack([np.zeros_like(ts), np.zeros_like(ts), (th + np.pi) % (2 * np.pi) - np.pi])
    cov = np.zeros((ts.size, 3, 3))
    cov[:, 2, 2] = fit_std**2
    snaps = {"observer": np.full(ts.size, 3), "t": ts, "pose": pose, "cov": cov}
    return {3: np.column_stack([t, v, w])}, snaps, (t, v, w, heading, walk)


def test_heading_increments_are_the_drift_and_the_model_diffusion_by_quadrature() -> None:
    odo, snaps, (t, v, w, heading, walk) = _robot(1, 1.0, 0.0, n_snap=300)
    inc = heading_increments(odo, snaps, NOISE, min_gap=1.0, max_gap=8.0)
    assert inc["res"].size > 100 and set(inc["robot"].tolist()) == {3}
    ts = snaps["t"]
    q = NOISE.diag(v, w)[2]
    for j in range(0, inc["res"].size, 17):
        b = int(np.flatnonzero(ts == inc["t"][j])[0])
        a = b - 1
        ka, kb = (int(np.searchsorted(t, ts[i], side="right") - 1) for i in (a, b))
        assert inc["res"][j] == pytest.approx(walk[kb] - walk[ka], abs=1e-9)  # the drift between the two
        pts = t[(t > ts[a]) & (t < ts[b])]
        assert inc["model"][j] == pytest.approx(quad(_step(t, q), ts[a], ts[b], points=pts, limit=500)[0], rel=1e-9)
        turn = quad(_step(t, np.abs(w)), ts[a], ts[b], points=pts, limit=500)[0]
        assert inc["turn"][j] == pytest.approx(turn, rel=1e-9, abs=1e-12)
        assert 1.0 <= ts[b] - ts[a] <= 8.0
    # the excluded span leaves no pair with an end in it; a narrower gap only fewer pairs
    out = heading_increments(odo, snaps, NOISE, exclude=(t[0] + 300, t[0] + 600))
    assert out["res"].size < inc["res"].size
    assert out["res"].size and not np.any((out["t"] >= t[0] + 300) & (out["t"] <= t[0] + 600))
    assert heading_increments(odo, snaps, NOISE, max_gap=2.0)["res"].size < inc["res"].size


@pytest.mark.parametrize("s_true", [0.05, 1.0])
def test_fit_recovers_the_scale_within_its_own_uncertainty(s_true: float) -> None:
    """Monte Carlo over 60 simulated robots: the fitted log-scale is unbiased to within its spread (the truncation
    at the cut is in the likelihood: without it the fit read 0.76 for 1), and the reported ``log_std`` (posterior
    curvature) is within 0.9 to 1.6 times the spread of the estimates (above 1: pairs sharing a snapshot are taken
    as independent)."""
    logs, stds = [], []
    for seed in range(60):
        odo, snaps, _ = _robot(100 + seed, s_true, 0.01, n_snap=300)
        fit = fit_yaw_scale(heading_increments(odo, snaps, NOISE), prior_std=math.inf)
        logs.append(math.log(fit.scale))
        stds.append(fit.log_std)
        assert fit.fit_scale > 0 and fit.pairs > 80 and fit.outliers < 0.05 * fit.pairs
    logs_a = np.array(logs)
    spread = float(np.std(logs_a, ddof=1))
    assert abs(float(np.mean(logs_a)) - math.log(s_true)) < 3 * spread / math.sqrt(len(logs)) + 0.05
    assert 0.9 * spread < float(np.median(stds)) < 1.6 * spread


def test_the_prior_keeps_the_scale_off_zero_where_the_fits_explain_everything() -> None:
    """Residuals whose spread the fits' variance explains alone (the same at every pair, whatever the model's
    diffusion there): maximum likelihood drives the scale towards 0, the default weak prior keeps it off 0."""
    rng = np.random.default_rng(5)
    fitv = np.full(150, 0.003)
    res = np.sqrt(0.8 * fitv) * np.where(np.arange(150) % 2, 1.0, -1.0)
    inc = {"res": res, "fit": fitv, "model": rng.uniform(0.001, 0.004, 150)}
    ml, map_ = fit_yaw_scale(inc, prior_std=math.inf), fit_yaw_scale(inc)
    assert ml.scale < 1e-3 < 0.05 < map_.scale < 2.0


def test_bad_input_is_refused_with_a_reason() -> None:
    inc = {"res": np.zeros(10), "fit": np.ones(10), "model": np.ones(10)}
    with pytest.raises(ValueError, match="10 snapshot pairs"):
        fit_yaw_scale(inc)
    with pytest.raises(ValueError, match="cut and prior_std"):
        fit_yaw_scale(inc, cut=0.0)
    with pytest.raises(ValueError, match="scale"):
        scale_yaw(NOISE, float("nan"))
    odo, snaps, _ = _robot(2, 1.0, 0.01, n_snap=20)
    odo[3][5, 2] = np.nan
    with pytest.raises(ValueError, match="robot 3"):
        heading_increments(odo, snaps, NOISE)


def test_scale_yaw_scales_the_yaw_terms_only() -> None:
    got = scale_yaw(NOISE, 0.25)
    v, w = np.array([0.0, 0.2, 0.3]), np.array([0.4, 0.0, -0.6])
    for a, b, k in zip(got.diag(v, w), NOISE.diag(v, w), (1.0, 1.0, 0.25), strict=True):
        np.testing.assert_allclose(a, k * np.asarray(b) * np.ones(3), rtol=1e-15)


def test_mrclam_recordings_calibrate_as_their_snapshots_say(mrclam_dataset) -> None:
    """Dataset 9 (turn commands saturated, clipped by the loader) calibrates to a small fraction of the model's
    yaw diffusion, dataset 6 to about the model, each well outside the other's uncertainty; a fold of landmarks
    held out changes the scale by less than 4 of its std in log."""
    from swarmloc.datasets.mrclam import load_mrclam
    from swarmloc.sensors.decorrelate import CameraModel, ErrorComponent
    from swarmloc_studies.lodo import detection_set, landmark_folds, yaw_calibration

    model = CameraModel(ErrorComponent(0.158), ErrorComponent(0.0046), source="test")
    noise = UnicycleNoise(q_v0=1e-4, q_v2=0.05, q_lat0=1e-4, q_lat1=0.01, q_w0=1e-3, q_w2=0.05, q_wv=0.02)
    fits = {}
    for k in (6, 9):
        data = load_mrclam(mrclam_dataset(k))
        ds = detection_set(data)
        fits[k] = yaw_calibration(data, ds, model, noise)
        fold = yaw_calibration(data, ds, model, noise, landmark_folds(data.landmarks, 3)[0])
        assert abs(math.log(fold.scale / fits[k].scale)) < 4 * math.hypot(fold.log_std, fits[k].log_std)
    assert fits[9].scale < 0.1 and 0.3 < fits[6].scale < 2.0
    gap = math.log(fits[6].scale / fits[9].scale)
    assert gap > 4 * math.hypot(fits[6].log_std, fits[9].log_std)
