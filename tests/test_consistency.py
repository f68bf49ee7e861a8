"""``swarmloc consistency`` and simulated landmarks: the band as documented, workers do not change results,
landmark detections agree with the truth, and landmarks bound the centralized EKF's error."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import chi2

from swarmloc.cli import main
from swarmloc.estimators import ESTIMATORS
from swarmloc.events import Detection
from swarmloc.experiments.consistency import bands, consistency, default_estimators
from swarmloc.experiments.sources import load_source
from swarmloc.lie import wrap_angle
from swarmloc.sim import random_team
from swarmloc.sim.landmarks import LandmarkSensor, add_landmarks, landmark_detections, place_landmarks

pytestmark = pytest.mark.unit


SMALL = {"seeds": 3, "robots": 3, "duration": 10.0}


@pytest.fixture(scope="module")
def runs():
    est = ["cekf", "rdl"]
    return consistency(est, jobs=1, **SMALL), consistency(est, jobs=2, **SMALL)


def test_structure_band_and_workers(runs):
    one, two = runs
    assert set(one["settings"]) == {"off", "on"} and set(one["settings"]["on"]) == {"cekf", "rdl"}
    S, n = 3, 3
    q = np.array([0.025, 0.975])
    assert np.allclose(one["band"]["team"], chi2.ppf(q, 3 * S) / (3 * S))  # seeds are the independent units
    assert np.allclose(one["band"]["independent"], chi2.ppf(q, 3 * S * n) / (3 * S * n))
    assert bands(S, n)["team"] == tuple(one["band"]["team"])
    lo, hi = one["band"]["team"]
    K = len(one["times"])
    assert K == 40 and one["times"][1] - one["times"][0] == pytest.approx(0.25)
    for setting in ("off", "on"):
        for e in ("cekf", "rdl"):
            a, b = one["settings"][setting][e], two["settings"][setting][e]
            a.pop("run_wall_s"), b.pop("run_wall_s")
            assert a == b  # bit-identical with one or two worker processes
            a_t = np.array(a["anees_t"])
            assert a_t.shape == (K,) and np.all(a_t > 0)
            assert a["in_band"] == pytest.approx(np.mean((a_t >= lo) & (a_t <= hi)))
            assert a["anees"] == pytest.approx(a_t.mean())  # every robot recorded at every time
            assert a["anees"] == pytest.approx(np.mean(a["anees_per_seed"]))
            assert a["detections"]["fused"] > 0
    # the same robot-robot detections with and without landmarks; landmark detections on top
    d_off, d_on = (one["settings"][s]["cekf"]["detections"]["detections"] for s in ("off", "on"))
    assert d_on > d_off


def test_landmarks_bound_the_centralized_error(runs):
    """Without landmarks the team's frame drifts (error grows); with them the error shrinks and stays small."""
    one, _ = runs
    off = np.array(one["settings"]["off"]["cekf"]["pos_rmse_t"])
    on = np.array(one["settings"]["on"]["cekf"]["pos_rmse_t"])
    q = len(off) // 4
    assert off[-q:].mean() > 1.3 * off[:q].mean()
    assert on[-q:].mean() < 0.6 * on[:q].mean()
    assert on[-q:].mean() < 0.3 * off[-q:].mean()


def test_noise_free_landmark_detections_match_truth():
    sim = random_team(3, 10.0, seed=4, area=3.0)
    lm = place_landmarks(6, (-1.0, 4.0, -1.0, 4.0), seed=2)
    assert len(lm) == 6 and all(-1 <= x <= 4 and -1 <= y <= 4 and sx == sy == 0 for x, y, sx, sy in lm.values())
    sensor = LandmarkSensor(rate=5.0, max_range=3.0)
    exact = landmark_detections(sim, lm, sensor.noiseless(), seed=7)
    noisy = landmark_detections(sim, lm, sensor, seed=7)
    assert exact and [(d.observer, d.t, d.target) for d in exact] == [(d.observer, d.t, d.target) for d in noisy]
    col = {r: j for j, r in enumerate(sim.robot_ids)}
    seen = set()
    for d, dn in zip(exact, noisy, strict=True):
        assert d.kind == "range_bearing" and not d.target_is_robot and d.target in lm
        k = int(np.argmin(np.abs(sim.times - d.t)))
        assert sim.times[k] == d.t
        x, y, th = sim.truth[k, col[d.observer]]
        dx, dy = lm[d.target][0] - x, lm[d.target][1] - y
        r, b = np.hypot(dx, dy), wrap_angle(np.arctan2(dy, dx) - th)
        assert d.z[0] == pytest.approx(r, abs=1e-12) and wrap_angle(d.z[1] - b) == pytest.approx(0, abs=1e-12)
        assert 0.1 <= r <= 3.0
        assert abs(dn.z[0] - r) < 6 * sensor.sigma_range and abs(wrap_angle(dn.z[1] - b)) < 6 * sensor.sigma_bearing
        seen.add((d.observer, d.t, d.target))
    # every landmark in range at a sensor time was detected
    for k in range(2, sim.times.size, 2):
        for r in sim.robot_ids:
            x, y, _ = sim.truth[k, col[r]]
            for lid, (lx, ly, *_) in lm.items():
                if 0.1 <= np.hypot(lx - x, ly - y) <= 3.0:
                    assert (r, float(sim.times[k]), lid) in seen


def test_landmark_source_keeps_the_robot_events():
    plain = load_source("sim:random", robots=3, duration=8.0, seed=5)
    with_lm = load_source("sim:landmarks", robots=3, duration=8.0, seed=5)
    assert plain.landmarks is None and len(with_lm.landmarks) == 6
    lm_dets = [e for e in with_lm.events if isinstance(e, Detection) and not e.target_is_robot]
    rest = [e for e in with_lm.events if not (isinstance(e, Detection) and not e.target_is_robot)]
    assert lm_dets and len(rest) == len(plain.events)
    for a, b in zip(rest, plain.events, strict=True):
        assert type(a) is type(b) and a.stamp == b.stamp
        if isinstance(a, Detection):
            assert a.observer == b.observer and a.target == b.target and np.array_equal(a.z, b.z)
    again, lm2 = add_landmarks(random_team(3, 8.0, seed=5, area=3.0), seed=5)
    assert lm2 == with_lm.landmarks  # deterministic in the seed
    with pytest.raises(ValueError, match="divide"):
        landmark_detections(again, lm2, LandmarkSensor(rate=3.0))


def test_default_estimators_come_from_the_registry():
    d = default_estimators()
    assert "mcl" not in d and "dr" not in d
    assert set(d) == set(ESTIMATORS) - {"mcl", "dr"}


def test_cli(tmp_path, capsys):
    rc = main(["consistency", "--estimators", "cekf", "--seeds", "2", "--robots", "2", "--duration", "4",
               "--landmarks", "on", "--jobs", "1", "--out", str(tmp_path), "--quiet", "--json"])  # fmt: skip
    assert rc == 0
    s = json.loads(capsys.readouterr().out)
    assert set(s["settings"]) == {"on"} and "cekf" in s["settings"]["on"]
    assert {"consistency.json", "consistency.md", "consistency.png"} <= {p.name for p in tmp_path.iterdir()}


@pytest.mark.parametrize("bad", [["--estimators", "nope"], ["--landmarks", "maybe"], ["--seeds", "0"]])
def test_cli_refuses_bad_input(bad, capsys):
    assert main(["consistency", "--quiet", *bad]) == 2
    err = capsys.readouterr().err
    assert "swarmloc consistency:" in err
    if "nope" in bad:
        assert "cekf" in err  # lists the choices
