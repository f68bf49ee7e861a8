"""``swarmloc compare``: every estimator on identical events, the same numbers with one or two worker processes."""

from __future__ import annotations

import json
import os

import pytest

from swarmloc.cli import main
from swarmloc.experiments.compare import compare

pytestmark = pytest.mark.unit


def test_compare_identical_events_and_workers_do_not_change_results():
    est = ["dr", "cekf", "rdl"]
    one = compare("sim:random", est, runs=2, robots=3, duration=10.0, jobs=1)
    two = compare("sim:random", est, runs=2, robots=3, duration=10.0, jobs=2)
    for e in est:
        a, b = one["estimators"][e], two["estimators"][e]
        assert a["pos_rmse"] == b["pos_rmse"] and a["anees"] == b["anees"] and a["records"] == b["records"]
    dets = {e: one["estimators"][e]["detections"]["detections"] for e in est}
    assert len(set(dets.values())) == 1 and dets["dr"] > 0  # the same detections for every estimator
    assert one["estimators"]["dr"]["detections"]["rejected"] == dets["dr"]
    assert one["estimators"]["cekf"]["messages_per_robot_s"] == 0.0
    assert one["estimators"]["rdl"]["messages_per_robot_s"] > 0.0
    assert one["estimators"]["rdl"]["pos_rmse"] < one["estimators"]["dr"]["pos_rmse"]
    lo, hi = one["estimators"]["rdl"]["anees_band_95"]
    assert lo < 1.0 < hi


def test_compare_cli(tmp_path, capsys):
    rc = main(["compare", "--estimators", "dekf,ci", "--runs", "1", "--robots", "3", "--duration", "8",
               "--out", str(tmp_path), "--quiet", "--jobs", "1"])  # fmt: skip
    assert rc == 0
    out = capsys.readouterr().out
    assert "| dekf |" in out and "| ci |" in out
    s = json.loads((tmp_path / "compare.json").read_text())
    assert set(s["estimators"]) == {"dekf", "ci"} and s["estimators"]["ci"]["update_us"] > 0


@pytest.mark.parametrize(
    "bad",
    [["--estimators", "nope"], ["--runs", "0"], ["--runs", "100000000"], ["--scenario", "sim:unknown"]],
)
def test_compare_refuses_bad_input(bad, capsys):
    """(``--runs 100000000`` built its list of a hundred million jobs before refusing nothing.)"""
    assert main(["compare", "--quiet", *bad]) == 2
    assert "swarmloc compare:" in capsys.readouterr().err


def test_a_sweep_of_more_runs_than_the_bound_is_refused_before_it_starts(capsys):
    from swarmloc.runner.fanout import MAX_RUNS, check_runs

    assert check_runs(MAX_RUNS) == MAX_RUNS and check_runs(1) == 1
    for bad in (0, MAX_RUNS + 1, True, 2.0, "3"):
        with pytest.raises(ValueError, match=r"must be an integer in \[1, 10000\]"):
            check_runs(bad)
    assert main(["consistency", "--quiet", "--seeds", str(MAX_RUNS + 1)]) == 2
    assert "seeds must be an integer in [1, 10000]" in capsys.readouterr().err


def test_a_sweep_refuses_negative_or_more_worker_processes_than_four_per_core(capsys):
    """(``--jobs -1`` ran in this process; ``--jobs 100000`` would have started a process per run.)"""
    from swarmloc.runner.fanout import check_jobs, max_jobs

    assert check_jobs(0) == 0 and check_jobs(max_jobs()) == max_jobs() == 4 * (os.cpu_count() or 1)
    for jobs in ("-1", str(max_jobs() + 1)):
        assert main(["compare", "--quiet", "--runs", "2", "--duration", "2", "--jobs", jobs]) == 2
        assert "jobs (local worker processes) must be an integer in [0, " in capsys.readouterr().err


def test_compare_takes_a_3d_scenario_as_team_does(tmp_path, capsys):
    """``compare --scenario sim:3d`` runs (``swarmloc team --source sim:3d`` does): the SE(3) nodes on the 3-D
    team, scored per 6 dof, its table saying rotation RMSE. Before, it was refused (an SE(2) noise model)."""
    rc = main(["compare", "--scenario", "sim:3d", "--estimators", "dr,diekf", "--robots", "2", "--duration", "4",
               "--out", str(tmp_path), "--quiet", "--jobs", "1"])  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    s = json.loads((tmp_path / "compare.json").read_text())
    assert s["dof"] == 6
    dr, diekf = s["estimators"]["dr"], s["estimators"]["diekf"]
    assert diekf["records"] > 0 and diekf["detections"]["fused"] > 0 and diekf["pos_rmse"] < dr["pos_rmse"]
    assert "rotation RMSE [rad]" in capsys.readouterr().out


def test_compare_refuses_an_estimator_without_a_3d_form(capsys):
    assert main(["compare", "--scenario", "sim:3d", "--estimators", "rdl", "--quiet"]) == 2
    assert "has no SE(3) form" in capsys.readouterr().err
