"""``swarmloc team`` writes its report whatever a node or the scoring meets.

Before: a source whose odometry ran far past the team's end (its ground truth ends at 10 s, one robot's odometry
at 60 s) made ``swarmloc team`` exit 2 with ``write_tum: 'times' and 'xytheta' must be finite`` and write no
report, where ``swarmloc evaluate`` scores the same file: the collector asked the truth for every record time at
once and, refused past its end, took the whole robot's truth as NaN. Now the team's run is scored on the record
times that have truth, as the in-process run is (the rest counted ``truth_missing``, with a note), and equals
``evaluate``'s score; a row that is still not finite is left out of its TUM file and marked in the report; a
scoring or drawing failure is a note; a node that crashes mid-run is named.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from swarmloc.cli import main
from swarmloc.experiments.evaluate import write_report
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import write_team_report
from swarmloc.net.team import TeamRun
from swarmloc.runner.result import RobotTrack, RunResult

pytestmark = pytest.mark.network


@pytest.fixture(scope="module")
def past_truth(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated event file (2 robots, 10 s, truth to 10 s) whose robot 1 then drives on to 60 s."""
    d = tmp_path_factory.mktemp("past")
    assert main(["simulate", "--robots", "2", "--duration", "10", "--seed", "3", "--out", str(d)]) == 0
    with (d / "events.csv").open("a") as f:
        f.write("odometry,60.0,1,10.0,0.2,0.0,,,,,,\n")
    return d / "events.csv"


def test_a_source_whose_odometry_runs_past_its_truth_is_scored_as_evaluate_scores_it(past_truth, tmp_path):
    ev, tm = tmp_path / "ev", tmp_path / "tm"
    assert main(["evaluate", "events", str(past_truth), "--estimators", "dekf", "--out", str(ev)]) == 0
    assert main(["team", "--source", f"events:{past_truth}", "--estimator", "dekf", "--out", str(tm)]) == 0
    a, b = (json.loads((d / n).read_text()) for d, n in ((tm, "team.json"), (ev, "events.json")))
    assert a["estimators"]["dekf"]["team"]["pos_rmse"] == pytest.approx(b["estimators"]["dekf"]["team"]["pos_rmse"],
                                                                          abs=1e-9)  # fmt: skip
    assert a["estimators"]["dekf"]["stats"]["truth_missing"] > 0
    assert any("have no ground truth" in n for n in a["notes"])
    for r in (0, 1):
        for what in ("dekf", "groundtruth"):
            got = np.loadtxt(tm / "tum" / f"{what}_robot{r}.tum")
            assert got.shape == np.loadtxt(ev / "tum" / f"{what}_robot{r}.tum").shape and np.isfinite(got).all()


def test_a_node_that_crashes_mid_run_is_named_and_the_report_still_written(past_truth, tmp_path):
    out = tmp_path / "o"
    rc = main(["team", "--source", f"events:{past_truth}", "--estimator", "dekf", "--out", str(out), "--speed", "4",
               "--faults", "killonly=1@3"])  # fmt: skip
    assert rc == 1  # a process ended badly: said by the exit status, after the report
    rep = json.loads((out / "team.json").read_text())
    assert any(e["process"] == "robot1" for e in rep["processes_ended"])
    assert any(n.startswith("robot1 (pid") and "killed" in n for n in rep["notes"]), rep["notes"]
    assert "robot1" in (out / "team.md").read_text()
    assert (out / "tum" / "dekf_robot0.tum").exists()


def _result(mean: np.ndarray, truth: np.ndarray) -> RunResult:
    t = np.arange(mean.shape[0], dtype=float)
    covs = np.tile(np.eye(3) * 0.01, (t.size, 1, 1))
    return RunResult("dekf", {0: RobotTrack(t, mean, covs, truth)}, 1.0, {"detections": 0, "fused": 0, "gated": 0,
                     "rejected": 0, "unknown": 0}, 0, {}, {})  # fmt: skip


def test_a_row_that_is_not_finite_is_left_out_of_its_tum_file_and_marked(tmp_path):
    mean = np.zeros((5, 3))
    mean[2] = [math.nan, 0.0, 0.0]
    truth = np.zeros((5, 3))
    truth[4] = math.inf
    report = {"truth": True, "duration_s": 4.0, "robots": [0], "estimators": {}}
    write_report(tmp_path, "x", report, {"dekf": _result(mean, truth)}, 0.0)
    assert np.loadtxt(tmp_path / "tum" / "dekf_robot0.tum").shape == (4, 8)
    assert np.loadtxt(tmp_path / "tum" / "groundtruth_robot0.tum").shape == (4, 8)
    got = json.loads((tmp_path / "x.json").read_text())
    assert got["tum_rows_left_out"] == {"tum/dekf_robot0.tum": 1, "tum/groundtruth_robot0.tum": 1}
    assert any("1 rows not finite" in n for n in got["notes"])


def test_a_scoring_failure_is_a_note_not_an_exit(tmp_path, monkeypatch):
    def broken(res):
        raise FloatingPointError("overflow in the NEES")

    monkeypatch.setattr("swarmloc.experiments.team.evaluate", broken)
    src = load_source("sim:random", robots=2, duration=3.0, seed=0)
    rep = write_team_report(TeamRun(run_id="x"), src, "dekf", tmp_path, {})
    assert "scoring failed: FloatingPointError: overflow in the NEES" in rep["notes"]
    assert (tmp_path / "team.json").exists() and "scoring failed" in (tmp_path / "team.md").read_text()
