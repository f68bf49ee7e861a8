"""Thesis sec. 5.2.2 / Table 6.1 experiment (quick mode): output files, JSON keys and robust measured properties.

The asserted properties are findings of the experiment, not tuned targets. They hold, with wide margins, for the
means over seeds both in the quick configuration tested here (seeds 0-2, 30 s / 60 s) and in the full run (20 seeds,
90 s / 500 s): e.g. at noise 0.01 the cooperative estimators' RMSE is <= 0.27 x dead reckoning's, the distributed
estimators' ANEES >= 30 and the centralized EKF's <= 1.03 at every noise level.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from swarmloc import make_team
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.runner import run
from swarmloc.sim import thesis_two_robot
from swarmloc_studies.thesis_dynamic import ABLATIONS, NOISE_LEVELS, RUNS, run_dynamic, spread

# slow: its module fixture runs the thesis' dynamic experiments (half a minute)
pytestmark = [pytest.mark.unit, pytest.mark.slow]


COOPERATIVE = ("dekf", "expfusion", "expfusion1", "cekf")


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("dynamic")
    res = run_dynamic(out, seeds=3, progress=False, quick=True)
    js = json.loads((out / "dynamic.json").read_text())
    assert res["markdown"] == (out / "dynamic.md").read_text()
    assert res["two_robot"]["0.01"]["cekf"]["team"]["anees"] == js["two_robot"]["0.01"]["cekf"]["team"]["anees"]
    return out, js


def test_files_written(quick):
    out, js = quick
    for name in js["files"]:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    assert {"dynamic.json", "dynamic.md", "dynamic_error_vs_time.png", "dynamic_gt_neighbour.png"} <= set(js["files"])
    md = (out / "dynamic.md").read_text()
    assert "Table 6.1" in md and "## Analysis" in md and "Multi-robot MCL" in md


def test_json_holds_rmse_and_anees_over_seeds_per_experiment_and_estimator(quick):
    _, js = quick
    assert js["meta"]["seeds"] == 3 and js["meta"]["quick"] is True
    stats = {"mean", "std", "min", "max", "n"}
    for nk in (f"{n:g}" for n in NOISE_LEVELS):
        assert set(js["two_robot"][nk]) == set(RUNS)
        for key, s in js["two_robot"][nk].items():
            for q in ("pos_rmse", "heading_rmse", "anees"):
                assert set(s["team"][q]) >= stats and s["team"][q]["n"] == 3, (nk, key, q)
                assert np.isfinite(s["team"][q]["mean"])
            assert len(s["per_seed"]["pos_rmse"]) == 3
            assert s["timing"]["us_per_predict"] > 0 and s["timing"]["us_per_call_wall"] > 0
            c = s["robot1_error_vs_time"]
            assert len(c["times"]) == len(c["pos_mean"]) == len(c["pos_p10"]) == len(c["anees"]) > 10
    for key, s in js["ground_truth_neighbour"].items():
        assert key in RUNS
        for q in ("pos_rmse", "anees"):
            assert set(s["robots"]["1"][q]) >= stats and set(s["team"][q]) >= stats
    assert set(js["double_counting"]) == set(ABLATIONS)
    rows = {row["key"]: row for row in js["table_6_1"]}
    assert set(rows) == set(RUNS) and "mcl" in rows  # Table 6.1's MCL row is filled
    assert rows["mcl"]["implemented"] is True and rows["mcl"]["us_per_update"] > 0
    assert all(np.isfinite(v) for v in rows["mcl"]["pos_rmse"].values())
    assert (
        rows["expfusion"]["multiple_detections_at_once"] == "yes"
        and rows["dekf"]["multiple_detections_at_once"] == "no"
    )
    assert rows["cekf"]["distributed"] == "no" and rows["expfusion"]["distributed"] == "yes"
    assert rows["expfusion"]["us_per_update"] > 0 and rows["dr"]["us_per_update"] is None


def test_cooperation_beats_dead_reckoning(quick):
    _, js = quick
    per = js["two_robot"]["0.01"]
    dr = per["dr"]["team"]["pos_rmse"]["mean"]
    for key in COOPERATIVE:
        assert per[key]["team"]["pos_rmse"]["mean"] < 0.6 * dr, key
    gt = js["ground_truth_neighbour"]
    assert {"dr", "dekf", "expfusion", "cekf"} <= set(gt)
    for key in set(gt) - {"dr"}:
        assert gt[key]["robots"]["1"]["pos_rmse"]["mean"] < 0.3 * gt["dr"]["robots"]["1"]["pos_rmse"]["mean"], key


def test_consistency_findings(quick):
    _, js = quick
    for nk, per in js["two_robot"].items():
        # the centralized filter (cross-covariances kept) and dead reckoning are not over-confident ...
        assert per["cekf"]["team"]["anees"]["mean"] < 3, nk
        assert per["dr"]["team"]["anees"]["mean"] < 3, nk
        # ... the distributed ones, fusing a correlated neighbour belief as if independent, are
        for key in ("dekf", "expfusion", "expfusion1"):
            assert per[key]["team"]["anees"]["mean"] > 5, (nk, key)
        # and the centralized EKF is the most accurate
        assert per["cekf"]["team"]["pos_rmse"]["mean"] < per["expfusion"]["team"]["pos_rmse"]["mean"], nk
    # fusing less often reduces the over-confidence
    ab = js["double_counting"]
    a10 = ab["mutual_10hz"]["estimators"]["expfusion"]["robot1"]["anees"]["mean"]
    a01 = ab["mutual_0.1hz"]["estimators"]["expfusion"]["robot1"]["anees"]["mean"]
    assert a01 < a10


def test_first_and_second_order_nearly_agree(quick):
    _, js = quick
    for per in js["two_robot"].values():
        a, b = per["expfusion"]["team"]["pos_rmse"]["mean"], per["expfusion1"]["team"]["pos_rmse"]["mean"]
        assert abs(a - b) < 0.1 * b


def test_node_timing_books_time_and_leaves_results_unchanged():
    """``measure_time`` (Table 6.1) times predictions and updates without changing any number."""
    sim = thesis_two_robot(noise_std=0.05, seed=3, duration=5.0)
    init = {r: GroupGaussian(SE2, m, 1e-6 * np.eye(3)) for r, m in sim.initial_pose_matrices().items()}
    plain = run(make_team("expfusion", init, noise=sim.unicycle_noise()), sim.events)
    nodes = make_team("expfusion", init, noise=sim.unicycle_noise())
    for n in nodes:
        n.measure_time = True
    timed = run(nodes, sim.events)
    for r in plain.tracks:
        np.testing.assert_array_equal(plain.tracks[r].mean, timed.tracks[r].mean)
        np.testing.assert_array_equal(plain.tracks[r].cov, timed.tracks[r].cov)
    t = timed.timing
    assert plain.timing["predict_n"] == plain.timing["fuse_n"] == 0
    assert t["fuse_n"] >= timed.stats["fused"] // 2 > 0  # one group update per detection instant (1 or 2 each)
    assert t["predict_n"] >= timed.stats["odometry_used"] > 0
    assert t["predict_s"] > 0 and t["fuse_s"] > 0


def test_spread():
    s = spread([1.0, 2.0, 3.0])
    assert s == {"mean": 2.0, "std": 1.0, "min": 1.0, "max": 3.0, "n": 3}
    assert spread([4.0])["std"] == 0.0
