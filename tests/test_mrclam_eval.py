"""`swarmloc evaluate mrclam` on the real data (all 756 s of dataset 6): metrics, accounting of every detection,
consistency of the consistent estimators, JSON, TUM files, and clear errors on every folder."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _data import MRCLAM_DATASETS

from swarmloc.cli import main
from swarmloc.datasets.mrclam import load_mrclam
from swarmloc.experiments.mrclam import evaluate_mrclam
from swarmloc.experiments.sources import load_source

# slow: its module fixture evaluates every estimator on all of dataset 6 (about a minute)
pytestmark = [pytest.mark.data, pytest.mark.slow]


@pytest.fixture(scope="module")
def report(tmp_path_factory, mrclam6: Path) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp("mrclam")
    return evaluate_mrclam(mrclam6, out_dir=out), out


def test_every_estimator_reported_with_metrics(report):
    rep, out = report
    assert set(rep["estimators"]) == {"dr", "dekf", "cekf", "expfusion", "ci", "rdl"}
    for ev in rep["estimators"].values():
        t = ev["team"]
        assert t["n"] > 10_000 and np.isfinite(t["pos_rmse"]) and np.isfinite(t["anees"])
        assert set(ev["robots"]) == {"1", "2", "3", "4", "5"}
    saved = json.loads((out / "mrclam.json").read_text())
    assert saved["estimators"]["cekf"]["team"]["pos_rmse"] == pytest.approx(
        rep["estimators"]["cekf"]["team"]["pos_rmse"]
    )
    assert (out / "trajectories.png").stat().st_size > 10_000


def test_cooperation_beats_dead_reckoning_on_real_data(report):
    rep, _ = report
    rmse = {k: v["team"]["pos_rmse"] for k, v in rep["estimators"].items()}
    for name in ("dekf", "cekf", "expfusion", "ci", "rdl"):
        assert rmse[name] < 0.8 * rmse["dr"], rmse
    # the correlation-tracking estimators are the best two and close to each other
    assert max(rmse["cekf"], rmse["rdl"]) < min(rmse["dekf"], rmse["expfusion"], rmse["ci"]), rmse
    assert rmse["rdl"] < 1.2 * rmse["cekf"], rmse


def test_every_detection_is_accounted_for(report):
    """fused + gated + rejected + unknown = detections in, for every estimator, none pending (16832 detections)."""
    rep, _ = report
    for name, ev in rep["estimators"].items():
        s = ev["stats"]
        assert s["detections"] == 16832, name
        assert s["fused"] + s["gated"] + s["rejected"] + s["unknown"] == s["detections"] and s["pending"] == 0, name
        assert ev["accounted"], name
        assert s["odometry"] == s["odometry_used"] > 250_000, name
    assert rep["estimators"]["dr"]["stats"]["rejected"] == 16832  # dead reckoning uses none, and says so


def test_consistent_estimators_are_consistent_with_landmarks(report):
    """Covariance intersection and recursive decentralized fusion: ANEES per dof in [0.5, 2] (measured 1.67 and
    1.44 with the calibrated camera model); the thesis estimator and the distributed EKF are over-confident
    (measured 3.0 and 2.8)."""
    rep, _ = report
    anees = {k: v["team"]["anees"] for k, v in rep["estimators"].items()}
    assert 0.5 <= anees["ci"] <= 2.0 and 0.5 <= anees["rdl"] <= 2.0, anees
    assert anees["expfusion"] > 2.5 and anees["dekf"] > 2.5, anees


def test_tum_files_are_evo_readable(report):
    _, out = report
    f = out / "tum" / "rdl_robot3.tum"
    rows = np.loadtxt(f, comments="#")
    assert rows.shape[1] == 8
    assert np.all(np.diff(rows[:, 0]) > 0)  # strictly increasing stamps
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:], axis=1), 1.0, atol=1e-6)  # unit quaternions
    gt = np.loadtxt(out / "tum" / "groundtruth_robot3.tum", comments="#")
    assert gt.shape == rows.shape


def test_cli_json_on_stdout(capsys, mrclam6: Path):
    rc = main(["evaluate", "mrclam", str(mrclam6), "--estimators", "dr,rdl", "--duration", "20", "--json", "--quiet"])
    assert rc == 0
    rep = json.loads(capsys.readouterr().out)
    assert set(rep["estimators"]) == {"dr", "rdl"}


def test_cli_calibrate_yaw_scales_the_yaw_terms_as_the_recording_says(capsys, mrclam6: Path):
    """``--calibrate-yaw``: the scale is the one :func:`yaw_calibrated` fits on the whole recording at the camera
    model's std, the four yaw terms are the defaults times it (the other terms unchanged), the estimators run
    with them (the result moves), and the text output names them; an event file is refused with a reason."""
    from swarmloc.config import DEFAULTS
    from swarmloc.datasets.mrclam import load_mrclam
    from swarmloc.experiments.mrclam import camera_model, detection_set, yaw_calibration

    args = ["evaluate", "mrclam", str(mrclam6), "--estimators", "dekf", "--duration", "20", "--json", "--quiet"]
    assert main([*args, "--calibrate-yaw"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert main(args) == 0
    plain = json.loads(capsys.readouterr().out)
    data = load_mrclam(mrclam6)
    fit = yaw_calibration(data, detection_set(data), camera_model(data), DEFAULTS.motion.noise())
    y = rep["yaw_calibration"]
    assert y["scale"] == fit.scale and y["pairs"] == fit.pairs > 100 and 0.1 < fit.scale < 2.0
    m = DEFAULTS.motion
    assert y["motion"] == pytest.approx({k: getattr(m, k) * fit.scale for k in ("q_w0", "q_w1", "q_w2", "q_wv")})
    assert "yaw_calibration" not in plain
    assert rep["estimators"]["dekf"]["team"]["anees"] != plain["estimators"]["dekf"]["team"]["anees"]
    assert main([*args[:-2], "--quiet", "--calibrate-yaw"]) == 0
    assert f"x{fit.scale:.3g}" in capsys.readouterr().out
    assert main(["evaluate", "events", str(mrclam6 / "x.csv"), "--calibrate-yaw", "--quiet"]) == 2
    assert "--calibrate-yaw needs an MRCLAM recording" in capsys.readouterr().err


def test_cli_engine_flag_runs_the_compiled_replays_with_the_nodes_results(capsys, mrclam6: Path, tmp_path: Path):
    """``--engine``: dekf, cekf, rdl and diekf (its noise fixed) through the engine's compiled replays score as the
    nodes do (same counts, RMSE and ANEES to 1e-9), their rows say so; diekf's default adaptive noise with
    landmarks, another estimator, an association policy or an event file is refused with the reason (exit 2)."""
    fixed = tmp_path / "fixed.toml"
    fixed.write_text("[filter]\ndiekf_adaptive = false\n")
    base = ["evaluate", "mrclam", str(mrclam6), "--estimators", "dekf,cekf,rdl,diekf", "--duration", "20", "--json",
            "--quiet"]  # fmt: skip
    assert main([*base[:4], "diekf", *base[5:], "--engine"]) == 2
    assert "diekf keeps its noise fixed: run [filter] diekf_adaptive" in capsys.readouterr().err
    args = [*base, "--config", str(fixed)]
    assert main([*args, "--engine"]) == 0
    eng = json.loads(capsys.readouterr().out)["estimators"]
    assert main(args) == 0
    nodes = json.loads(capsys.readouterr().out)["estimators"]
    for name in ("dekf", "cekf", "rdl", "diekf"):
        e, n = eng[name], nodes[name]
        assert e["driver"].startswith("engine") and "driver" not in n and e["compile_s"] >= 0
        assert e["team"]["pos_rmse"] == pytest.approx(n["team"]["pos_rmse"], rel=1e-9)
        assert e["team"]["anees"] == pytest.approx(n["team"]["anees"], rel=1e-9)
        assert {k: e["stats"][k] for k in ("fused", "gated", "rejected", "unknown")} == {
            k: n["stats"][k] for k in ("fused", "gated", "rejected", "unknown")}  # fmt: skip
        assert e["stats"]["fused"] > 100
    assert main([*args[:4], "dekf,ci", *args[5:], "--engine"]) == 2
    assert "compiled replays run ['dekf', 'cekf', 'iekf', 'rdl', 'diekf'], not ['ci']" in capsys.readouterr().err
    assert main([*args, "--engine", "--association", "nearest"]) == 2
    assert "tagged detections only" in capsys.readouterr().err
    assert main(["evaluate", "events", str(mrclam6 / "x.csv"), "--engine", "--quiet"]) == 2
    assert "--engine needs an MRCLAM recording" in capsys.readouterr().err


def test_cli_rejects_unknown_estimator(capsys, mrclam6: Path):
    rc = main(["evaluate", "mrclam", str(mrclam6), "--estimators", "dr,nope", "--duration", "5", "--quiet"])
    assert rc == 2
    assert "nope" in capsys.readouterr().err


def test_cli_missing_folder_is_one_clear_line(tmp_path, capsys):
    rc = main(["evaluate", "mrclam", str(tmp_path / "MRCLAM_Dataset42"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2
    assert "MRCLAM_Dataset42" in err and "Traceback" not in err


@pytest.mark.parametrize("number", MRCLAM_DATASETS)
def test_every_shared_folder_evaluates_or_says_why(number: int, mrclam_dataset, capsys):
    """Folders without odometry give a one-line reason (exit 2); with odometry but no ground truth they are
    replayed without metrics; dataset 6 is scored."""
    folder = mrclam_dataset(number)
    rc = main(["evaluate", "mrclam", str(folder), "--estimators", "dr,cekf,rdl", "--duration", "3", "--json"])
    cap = capsys.readouterr()
    has_odometry = any(folder.glob("Robot*_Odometry.dat"))
    if not has_odometry:
        assert rc == 2 and cap.err.count("\n") == 1 and "odometry" in cap.err.lower(), cap.err
        return
    assert rc == 0, cap.err
    rep = json.loads(cap.out)
    has_truth = any(folder.glob("Robot*_Groundtruth.dat"))
    assert rep["truth"] is has_truth
    for ev in rep["estimators"].values():
        assert (ev["team"] is not None) is has_truth
        assert ev["stats"]["odometry"] > 0


def test_a_recording_without_truth_starts_from_its_landmark_snapshots(mrclam_dataset, capsys):
    """Dataset 4 has no ground truth: the team starts from each robot's first fit to two or more landmarks read at
    once (9.4 s in), not from the placeholder at (id, 0, 0) with std 10 m, from which the filters gated most
    detections (measured on the first 40 s: dekf fused 146 of 938 and gated 792; from the snapshots 681 of 691,
    10 gated). What came before the start is left out and counted; the source of compare/node/team starts there
    too."""
    folder = mrclam_dataset(4)
    rc = main(["evaluate", "mrclam", str(folder), "--estimators", "dekf", "--duration", "40", "--json"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    rep = json.loads(cap.out)
    start = rep["start"]
    assert not start["truth"] and 5.0 < start["t0_s"] < 20.0 and start["events_before"] > 0
    assert "landmark snapshot" in start["how"]
    stats = rep["estimators"]["dekf"]["stats"]
    assert stats["gated"] < 0.05 * (stats["fused"] + stats["gated"])
    src = load_source(f"mrclam:{folder}", duration=40.0)
    assert src.t_start == pytest.approx(load_mrclam(folder).t_start + start["t0_s"], abs=1e-9)
    assert min(e.stamp for e in src.events) >= src.t_start


def test_a_span_that_ends_before_the_snapshots_keeps_the_placeholder_and_says_so(mrclam_dataset, capsys):
    folder = mrclam_dataset(4)
    rc = main(["evaluate", "mrclam", str(folder), "--estimators", "dr", "--duration", "3"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "start: no ground truth and the first landmark snapshots end 9.4 s in, after the span" in out
    assert "the trajectories are not poses" in out
