"""Correlated camera errors (swarmloc.sensors.decorrelate): the information formula against linear algebra and a
Monte Carlo computation, recovery of the correlation from synthetic streams, clear errors, and MRCLAM."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from _data import MRCLAM_DATASETS

from swarmloc.config import DEFAULTS, Config, SensorConfig
from swarmloc.events import Detection, Odometry
from swarmloc.sensors.decorrelate import (
    CameraModel,
    DetectionSet,
    ErrorComponent,
    ar1_information,
    calibrate,
    decorrelate,
    fit_correlation,
    information_weights,
    lag_correlation,
)
from swarmloc.sensors.snapshots import fit_residuals

pytestmark = pytest.mark.data


def _cov(times: np.ndarray, phi: float, tau: float) -> np.ndarray:
    """Error covariance (unit variance) of readings at ``times``: OU part ``phi`` plus white part ``1 - phi``."""
    lag = np.abs(times[:, None] - times[None, :])
    return phi * np.exp(-lag / tau) + (1.0 - phi) * np.eye(times.size)


def _simulate(times: np.ndarray, phi: float, tau: float, rng: np.random.Generator, n: int = 1) -> np.ndarray:
    """``n`` independent error sequences (unit variance) at ``times``: exact OU recursion plus white noise."""
    s = np.empty((n, times.size))
    s[:, 0] = rng.normal(size=n) * math.sqrt(phi)
    for k in range(1, times.size):
        a = math.exp(-(times[k] - times[k - 1]) / tau)
        s[:, k] = a * s[:, k - 1] + rng.normal(size=n) * math.sqrt(phi * (1.0 - a * a))
    return s + rng.normal(size=s.shape) * math.sqrt(1.0 - phi)


# ----------------------------------------------------------------------------------------------------------------
# the information formula


def test_pure_ar1_weights_are_the_closed_form() -> None:
    """phi = 1, equal spacing: w = 1, then (1 - rho) / (1 + rho); the sum is (n (1 - rho) + 2 rho) / (1 + rho),
    which is 1' Sigma^-1 1."""
    n, dt, tau = 40, 0.25, 2.0
    rho = math.exp(-dt / tau)
    t = np.arange(n) * dt
    w = information_weights(t, 1.0, tau)
    assert w[0] == pytest.approx(1.0)
    np.testing.assert_allclose(w[1:], (1 - rho) / (1 + rho), rtol=1e-12)
    one = np.ones(n)
    gls = one @ np.linalg.solve(_cov(t, 1.0, tau), one)
    assert w.sum() == pytest.approx(ar1_information(n, rho), rel=1e-12)
    assert w.sum() == pytest.approx(gls, rel=1e-9)
    assert ar1_information(1, rho) == pytest.approx(1.0)
    # about n (1 - rho) / (1 + rho) for many readings, far below n
    assert ar1_information(10_000, rho) / (10_000 * (1 - rho) / (1 + rho)) == pytest.approx(1.0, rel=5e-3)


@pytest.mark.parametrize(("phi", "tau"), [(0.0, 1.0), (0.7, 3.0), (0.95, 10.0)])
def test_weights_add_up_to_the_gls_information_for_any_spacing(phi: float, tau: float) -> None:
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.0, 2.0, size=60))  # irregular, with some near-duplicates
    w = information_weights(t, phi, tau)
    assert np.all((w > 0) & (w <= 1 + 1e-12))
    for k in (1, 2, 7, 30, 60):
        one = np.ones(k)
        assert w[:k].sum() == pytest.approx(one @ np.linalg.solve(_cov(t[:k], phi, tau), one), rel=1e-9)
    if phi == 0.0:
        np.testing.assert_allclose(w, 1.0)  # white noise: every reading counts in full


def test_information_matches_monte_carlo() -> None:
    """20 000 simulated streams: the variance of the best (GLS) estimate of a constant is 1 / sum(w). The weighted
    mean a filter computes when it fuses the readings as independent with variance std^2 / w is not the GLS
    combination: its variance is w' Sigma w / sum(w)^2, here 7% above the claim (the module docstring states the
    range). Treating the readings as white would claim 1 / n, many times too small."""
    rng = np.random.default_rng(7)
    phi, tau = 0.8, 4.0
    t = np.cumsum(rng.uniform(0.2, 0.8, size=80))
    w = information_weights(t, phi, tau)
    e = _simulate(t, phi, tau, rng, n=20_000)
    cov = _cov(t, phi, tau)
    g = np.linalg.solve(cov, np.ones(t.size))
    gls = e @ (g / g.sum())
    filt = e @ (w / w.sum())
    claimed = 1.0 / w.sum()
    assert np.var(gls) == pytest.approx(claimed, rel=0.05)
    actual = w @ cov @ w / w.sum() ** 2
    assert np.var(filt) == pytest.approx(actual, rel=0.05)
    assert 1.0 < actual / claimed < 1.1
    assert np.var(e.mean(axis=1)) > 5.0 / t.size  # the white-noise claim 1 / n is over-confident


# ----------------------------------------------------------------------------------------------------------------
# recovering the correlation


def test_lag_correlation_and_fit_recover_an_ou_plus_white_stream() -> None:
    rng = np.random.default_rng(3)
    phi, tau = 0.8, 4.0
    stream, times, values = [], [], []
    for s in range(40):
        t = np.cumsum(rng.uniform(0.2, 1.0, size=500))
        stream.append(np.full(t.size, s))
        times.append(t)
        values.append(0.1 * _simulate(t, phi, tau, rng)[0])
    lc = lag_correlation(np.concatenate(stream), np.concatenate(times), np.concatenate(values))
    est_phi, est_tau = fit_correlation(lc["lag"], lc["rho"], lc["pairs"])
    assert est_phi == pytest.approx(phi, abs=0.05)
    assert est_tau == pytest.approx(tau, rel=0.2)
    ok = lc["pairs"] > 0
    np.testing.assert_allclose(lc["rho"][ok], phi * np.exp(-lc["lag"][ok] / tau), atol=0.08)


def test_fit_without_enough_bins_is_white() -> None:
    assert fit_correlation(np.array([1.0, 2.0]), np.array([0.5, 0.4]), np.array([100, 100])) == (0.0, 1.0)


def _synthetic_landmark_detections(seed: int = 0, sr: float = 0.1, sb: float = 0.01, phi: float = 0.8,
                                   tau: float = 5.0) -> tuple[np.ndarray, dict]:  # fmt: skip
    """Three robots circling among ten landmarks, each (observer, landmark) stream with OU + white errors."""
    rng = np.random.default_rng(seed)
    xy = [(4, 0), (4, 1), (0, 4), (-1, 4), (-4, 0), (-4, -1), (0, -4), (1, -4), (3, 3), (-3, -3)]
    lm = {10 + i: p for i, p in enumerate(xy)}
    rows = []
    for o in (1, 2, 3):
        t = np.cumsum(rng.uniform(0.3, 0.7, size=800))
        pos = 1.5 * np.c_[np.cos(0.05 * t + o), np.sin(0.05 * t + o)]
        heading = 0.2 * t + o
        err = {k: (sr * _simulate(t, phi, tau, rng)[0], sb * _simulate(t, phi, tau, rng)[0]) for k in lm}
        for i, ti in enumerate(t):
            for k in (k for k in lm if rng.uniform() < 0.5):
                d = np.subtract(lm[k], pos[i])
                b = math.remainder(math.atan2(d[1], d[0]) - heading[i], 2 * math.pi)
                rows.append((o, ti, k, math.hypot(*d) + err[k][0][i], b + err[k][1][i]))
    return np.array(rows), lm


def test_calibration_recovers_std_and_correlation_time_without_truth() -> None:
    """From the detections and the map only: the std within 5%, the correlation time within 25%; the correlated
    fraction comes out lower than the truth (a snapshot residual mixes the errors of one instant's landmarks)."""
    a, lm = _synthetic_landmark_detections()
    m = calibrate(a[:, 0], a[:, 1], a[:, 2], a[:, 3:5], lm, range_std=0.3, bearing_std=0.05)
    assert m.source.startswith("estimated") and m.instants > 1000
    assert m.range.std == pytest.approx(0.1, rel=0.05) and m.bearing.std == pytest.approx(0.01, rel=0.05)
    assert m.range.tau == pytest.approx(5.0, rel=0.25) and m.bearing.tau == pytest.approx(5.0, rel=0.25)
    assert 0.4 < m.range.phi <= 0.85 and 0.4 < m.bearing.phi <= 0.85
    kept = calibrate(a[:, 0], a[:, 1], a[:, 2], a[:, 3:5], lm, range_std=0.3, bearing_std=0.05, estimate_std=False)
    assert (kept.range.std, kept.bearing.std) == (0.3, 0.05) and kept.range.phi > 0.4


def test_snapshot_redundancy_numbers_add_up_to_the_redundancy() -> None:
    """An instant with k landmarks leaves 2k - 3 degrees of freedom: the redundancy numbers of all residuals add up
    to sum(2k - 3); without noise the residuals vanish."""
    a, lm = _synthetic_landmark_detections(sr=1e-9, sb=1e-9)
    snaps = DetectionSet(a[:, 0], a[:, 1], a[:, 2], a[:, 3:5], lm).snapshots()[0]
    res = fit_residuals(snaps, range_std=0.1, bearing_std=0.01)
    key = a[res["row"], 0] * 1e6 + a[res["row"], 1]
    k = np.unique(key, return_counts=True)[1]
    assert int(res["instants"]) == k.size
    assert res["r_range"].sum() + res["r_bearing"].sum() == pytest.approx(float(np.sum(2 * k - 3)), rel=1e-9)
    assert np.abs(res["v_range"]).max() < 1e-6 and np.abs(res["v_bearing"]).max() < 1e-6


def test_too_few_snapshots_fall_back_to_a_priori_white_noise_and_say_so() -> None:
    a, lm = _synthetic_landmark_detections()
    a = a[:150]
    m = calibrate(a[:, 0], a[:, 1], a[:, 2], a[:, 3:5], lm, range_std=0.1, bearing_std=0.035)
    assert m.source.startswith("a priori, white") and "needed" in m.source
    assert (m.range, m.bearing) == (ErrorComponent(0.1), ErrorComponent(0.035))


# ----------------------------------------------------------------------------------------------------------------
# the pre-processor


def _det(t: float, obs: int = 1, target: int = 7, z: tuple[float, float] = (2.0, 0.1)) -> Detection:
    return Detection(observer=obs, t=t, kind="range_bearing", z=np.array(z), cov=np.eye(2), target=target,
                     target_is_robot=False)  # fmt: skip


def test_decorrelate_rescales_each_stream_and_keeps_everything_else() -> None:
    model = CameraModel(ErrorComponent(0.1, 0.9, 5.0), ErrorComponent(0.01, 0.5, 5.0), source="test")
    odo = Odometry(robot=1, t0=0.0, t1=0.1, v=0.1, w=0.0)
    pose = Detection(observer=1, t=0.2, kind="pose", z=np.zeros(3), cov=np.eye(3), target=2, target_is_robot=True)
    events = [_det(0.0), odo, _det(0.0, target=8), pose, _det(0.25), _det(0.5), _det(60.0)]
    out = decorrelate(events, model)
    assert len(out) == len(events) and out[1] is odo and out[3] is pose
    first, other, second, third, late = (out[i] for i in (0, 2, 4, 5, 6))
    np.testing.assert_allclose(first.cov, np.diag([0.01, 1e-4]))  # first reading of a stream: the marginal std
    np.testing.assert_allclose(other.cov, first.cov)  # another target is another stream
    assert second.cov[0, 0] > 5 * first.cov[0, 0] and second.cov[1, 1] > 1.5 * first.cov[1, 1]
    assert late.cov[0, 0] == pytest.approx(0.01, rel=1e-3)  # a minute later: independent again
    w = information_weights(np.array([0.0, 0.25, 0.5, 60.0]), 0.9, 5.0)
    np.testing.assert_allclose([e.cov[0, 0] for e in (first, second, third, late)], 0.01 / w)
    assert not second.cov.flags.writeable


# ----------------------------------------------------------------------------------------------------------------
# bad input


@pytest.mark.parametrize(
    ("times", "phi", "tau", "match"),
    [
        ([0.0, np.nan, 1.0], 0.5, 1.0, r"times\[1\] is nan: times must be finite"),
        ([0.0, 2.0, 1.0], 0.5, 1.0, r"must be sorted .*times\[2\] = 1.0 < times\[1\] = 2.0"),
        ([[0.0, 1.0]], 0.5, 1.0, "one-dimensional"),
        ([0.0, 1.0], 1.5, 1.0, r"phi .* \[0, 1\]"),
        ([0.0, 1.0], float("nan"), 1.0, "phi"),
        ([0.0, 1.0], 0.5, 0.0, "tau"),
        ([0.0, 1.0], 0.5, float("inf"), "tau"),
    ],
)
def test_information_weights_reject_bad_input(times: list, phi: float, tau: float, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        information_weights(times, phi, tau)


def test_bad_streams_and_detections_are_named() -> None:
    model = CameraModel(ErrorComponent(0.1, 0.5, 2.0), ErrorComponent(0.01))
    with pytest.raises(ValueError, match=r"detections of 7 by robot 1 must be sorted.*time order"):
        decorrelate([_det(1.0), _det(0.5)], model)
    with pytest.raises(ValueError, match=r"event 1: detection by robot 1 of 7 at t=0.5 is not finite"):
        decorrelate([_det(0.0), _det(0.5, z=(np.nan, 0.0))], model)
    a, lm = _synthetic_landmark_detections()
    a[5, 3] = np.inf
    with pytest.raises(ValueError, match=r"detection 5: z is not finite"):
        calibrate(a[:, 0], a[:, 1], a[:, 2], a[:, 3:5], lm)
    with pytest.raises(ValueError, match=r"shape \(n,\) and z \(n, 2\)"):
        calibrate(a[:, 0], a[:, 1], a[:, 2], a[:, 3:4], lm)
    with pytest.raises(ValueError, match="a-priori std"):
        calibrate(a[:, 0], a[:, 1], a[:, 2], a[:, 3:5], lm, range_std=0.0)
    with pytest.raises(ValueError, match="equal length"):
        lag_correlation(np.zeros(3), np.zeros(2), np.zeros(3))
    with pytest.raises(ValueError, match="n must be a positive integer"):
        ar1_information(0, 0.5)
    with pytest.raises(ValueError, match="std must be finite"):
        ErrorComponent(float("nan"))


# ----------------------------------------------------------------------------------------------------------------
# MRCLAM


@pytest.mark.parametrize("number", MRCLAM_DATASETS)
def test_every_shared_mrclam_folder_gives_finite_plausible_constants(number: int, mrclam_dataset) -> None:
    """The same code on every dataset (with or without odometry and truth): finite constants in the range a
    camera of this kind can have; none of them reads ground truth."""
    from swarmloc.datasets.mrclam import load_mrclam
    from swarmloc.experiments.mrclam import camera_model

    data = load_mrclam(mrclam_dataset(number), require=("measurements",))
    m = camera_model(data)
    assert m.source == "estimated (std and correlation)" and m.instants > 1000, m.source
    for c in (m.range, m.bearing):
        assert all(math.isfinite(x) for x in (c.std, c.phi, c.tau))
        assert 0.0 <= c.phi < 1.0 and 0.5 <= c.tau <= 200.0
    assert 0.03 <= m.range.std <= 0.5 and 0.001 <= m.bearing.std <= 0.05


def test_mrclam_evaluation_runs_with_the_calibrated_camera(mrclam6: Path) -> None:
    from swarmloc.experiments.mrclam import evaluate_mrclam
    from swarmloc.experiments.sources import load_source

    rep = evaluate_mrclam(mrclam6, estimators=("cekf", "rdl"), duration=120.0)
    cam = rep["camera"]
    assert cam["source"] == "estimated (std and correlation)" and DEFAULTS.sensors.decorrelate == "calibrate"
    assert math.isfinite(cam["range"]["std"]) and math.isfinite(cam["bearing"]["tau"])
    for ev in rep["estimators"].values():
        t = ev["team"]
        assert math.isfinite(t["pos_rmse"]) and t["pos_rmse"] < 0.5 and 0.2 < t["anees"] < 5.0, t
        assert ev["accounted"]
    off = Config(sensors=SensorConfig(decorrelate="off", range_std=0.3))
    rep_off = evaluate_mrclam(mrclam6, estimators=("cekf",), duration=20.0, landmarks=False, config=off)
    assert rep_off["camera"]["source"] == "a priori, white" and rep_off["camera"]["range"]["std"] == 0.3
    src = load_source(f"mrclam:{mrclam6}", duration=30.0)
    covs = {float(e.cov[0, 0]) for e in src.events if isinstance(e, Detection)}
    assert len(covs) > 10  # one covariance per reading, not one for all
