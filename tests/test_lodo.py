"""Fitting code of the leave-one-dataset-out camera check (issue 21): pooled calibration over recordings, the
truncated-normal correction of the inlier cut, the exact stream likelihood, held-out scores and snapshot poses."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_decorrelate import _cov, _simulate, _synthetic_landmark_detections

from swarmloc.sensors.decorrelate import (
    KAPPA_3SIGMA,
    CameraModel,
    DetectionSet,
    ErrorComponent,
    calibrate,
    calibrate_pooled,
    heldout_residuals,
    heldout_score,
    snapshot_poses,
    stream_nll,
    truncated_variance,
)
from swarmloc.sensors.snapshots import _fit_group

pytestmark = pytest.mark.unit


def _set(seed: int, sr: float, sb: float, phi: float, tau: float, shift: float = 0.0) -> DetectionSet:
    a, lm = _synthetic_landmark_detections(seed, sr, sb, phi, tau)
    lm = {k: (x + shift, y) for k, (x, y) in lm.items()}  # another map: the same field moved
    a[:, 1] += 1000.0 * seed
    # the robots moved with the map: range and bearing unchanged
    return DetectionSet(a[:, 0], a[:, 1], a[:, 2], a[:, 3:5], lm, f"set{seed}")


def test_truncated_variance_is_the_known_constant() -> None:
    assert truncated_variance(3.0) == pytest.approx(KAPPA_3SIGMA, abs=1e-4)
    assert truncated_variance(math.inf) == 1.0
    x = np.random.default_rng(0).normal(size=2_000_000)
    assert truncated_variance(2.0) == pytest.approx(np.var(x[np.abs(x) <= 2.0]), rel=5e-3)
    with pytest.raises(ValueError):
        truncated_variance(0.0)


def test_stream_nll_is_the_exact_gaussian_likelihood() -> None:
    """The prediction-error decomposition equals the dense multivariate normal NLL, streams independent, for any
    spacing and with missing values."""
    rng = np.random.default_rng(1)
    comp = ErrorComponent(0.2, 0.7, 3.0)
    stream, t, v, dense = [], [], [], 0.0
    for s in range(3):
        ts = np.sort(rng.uniform(0, 30, size=25))
        x = comp.std * _simulate(ts, comp.phi, comp.tau, rng)[0]
        x[[3, 10]] = np.nan  # missing: dropped from the likelihood, time still runs
        keep = np.isfinite(x)
        C = comp.std**2 * _cov(ts[keep], comp.phi, comp.tau)
        _, logdet = np.linalg.slogdet(2 * np.pi * C)
        dense += 0.5 * (logdet + x[keep] @ np.linalg.solve(C, x[keep]))
        stream += [s] * ts.size
        t += ts.tolist()
        v += x.tolist()
    perm = rng.permutation(len(t))  # input order does not matter
    total, n = stream_nll(np.array(stream)[perm], np.array(t)[perm], np.array(v)[perm], comp)
    assert n == 3 * 23
    assert total == pytest.approx(dense, rel=1e-10)


def test_stream_nll_prefers_the_true_model() -> None:
    """On simulated streams the true (std, phi, tau) scores better than a wrong std, white noise or a wrong tau."""
    rng = np.random.default_rng(2)
    ts = np.cumsum(rng.uniform(0.3, 0.7, size=400))
    x = 0.1 * _simulate(ts, 0.8, 5.0, rng, n=20)
    stream, t = np.repeat(np.arange(20), ts.size), np.tile(ts, 20)
    score = {
        key: stream_nll(stream, t, x.ravel(), c)[0]
        for key, c in {"true": ErrorComponent(0.1, 0.8, 5.0), "std": ErrorComponent(0.15, 0.8, 5.0),
                       "white": ErrorComponent(0.1), "tau": ErrorComponent(0.1, 0.8, 0.5)}.items()
    }  # fmt: skip
    assert score["true"] < min(score["std"], score["white"], score["tau"])


def test_pooled_calibration_recovers_known_parameters_across_recordings() -> None:
    """Two recordings with different maps and the same camera: the pooled fit recovers the std (5%) and the
    correlation time (25%); one set pooled equals the single-set calibration exactly."""
    sets = [_set(0, 0.1, 0.01, 0.8, 5.0), _set(1, 0.1, 0.01, 0.8, 5.0, shift=7.0)]
    m = calibrate_pooled(sets, range_std=0.3, bearing_std=0.05)
    assert "pooled over 2" in m.source and m.instants > 2000
    assert m.range.std == pytest.approx(0.1, rel=0.05) and m.bearing.std == pytest.approx(0.01, rel=0.05)
    assert m.range.tau == pytest.approx(5.0, rel=0.25) and m.bearing.tau == pytest.approx(5.0, rel=0.25)
    s = sets[0]
    one = calibrate(s.observer, s.t, s.target, s.z, s.landmarks, range_std=0.3, bearing_std=0.05)
    assert one == calibrate_pooled(sets[:1], range_std=0.3, bearing_std=0.05)
    # a wider inlier cut lets more of the (here Gaussian) distribution in and still estimates the same std
    wide = calibrate_pooled(sets, range_std=0.3, bearing_std=0.05, cut=4.0)
    assert wide.range.std == pytest.approx(0.1, rel=0.05)
    with pytest.raises(ValueError, match="no detection sets"):
        calibrate_pooled([])


def test_heldout_score_ranks_a_model_fitted_elsewhere() -> None:
    """A model pooled from two recordings scores on a third (same camera) as well as that recording's own fit and
    better than a wrong std or white noise; its robust variance ratio is near 1."""
    train = [_set(0, 0.1, 0.01, 0.8, 5.0), _set(1, 0.1, 0.01, 0.8, 5.0, shift=7.0)]
    test = _set(2, 0.1, 0.01, 0.8, 5.0, shift=-5.0)
    pooled = calibrate_pooled(train)
    held = heldout_residuals(test, 0.1, 0.01)
    s = heldout_score(pooled, held)
    assert 0.6 < s["ratio_range"] < 1.4 and 0.6 < s["ratio_bearing"] < 1.4
    wrong = CameraModel(ErrorComponent(0.3, pooled.range.phi, pooled.range.tau), pooled.bearing)
    white = CameraModel(ErrorComponent(pooled.range.std), ErrorComponent(pooled.bearing.std))
    assert s["nll"] < heldout_score(wrong, held)["nll"]
    assert s["nll"] < heldout_score(white, held)["nll"]
    assert heldout_score(wrong, held)["ratio_range"] < 0.3


def test_snapshot_poses_recover_the_observer() -> None:
    """Noise-free readings: every snapshot's fitted pose is the true one."""
    lm = {10: (4.0, 0.0), 11: (0.0, 4.0), 12: (-3.0, -1.0)}
    pose = np.array([0.5, -0.2, 0.3])
    rows = []
    for t in (1.0, 2.0):
        for k, (x, y) in lm.items():
            dx, dy = x - pose[0], y - pose[1]
            rows.append((1, t, k, math.hypot(dx, dy), math.remainder(math.atan2(dy, dx) - pose[2], 2 * math.pi)))
    a = np.array(rows)
    p = snapshot_poses(DetectionSet(a[:, 0], a[:, 1], a[:, 2], a[:, 3:5], lm), 0.1, 0.01)
    assert p["t"].tolist() == [1.0, 2.0] and p["observer"].tolist() == [1, 1]
    np.testing.assert_allclose(p["pose"], np.tile(pose, (2, 1)), atol=1e-9)
    assert np.all(np.linalg.eigvalsh(p["cov"]) > 0)
    assert int(p["unconverged"]) == 0


def test_snapshot_fits_that_have_not_converged_are_dropped_and_counted() -> None:
    """A fit whose last Gauss-Newton step exceeds STEP_TOL of its own std is neither used nor silently lost: noisy
    readings stopped after one step (from the Procrustes start) are counted as unconverged; the full fit converges."""
    rng = np.random.default_rng(3)
    pos = np.array([[4.0, 0.0], [0.0, 4.0], [-3.0, -1.0]])
    pose = np.array([0.5, -0.2, 0.3])
    d = pos - pose[:2]
    z = np.column_stack([np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0]) - pose[2]])
    z = z + rng.normal(0.0, [0.1, 0.01], (5, 3, 2))
    p = np.broadcast_to(pos, z.shape)
    *_, ok, _, _, dropped = _fit_group(z, p, 0.1, 0.01, iterations=1)
    assert not ok.any() and dropped == 5
    *_, ok, _, _, dropped = _fit_group(z, p, 0.1, 0.01)
    assert ok.all() and dropped == 0
