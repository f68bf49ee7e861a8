"""Your own robots from the command line: simulate -> event file -> evaluate events -> scores, figures, TUM files;
bad files and bad configurations give a clear message and exit status 2; `swarmloc config` prints every default."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from swarmloc.cli import main
from swarmloc.config import DEFAULTS, Config

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("my-run")
    assert main(["simulate", "--out", str(out), "--robots", "4", "--duration", "40", "--seed", "2"]) == 0
    return out


def test_simulate_writes_events_truth_and_config(sim_dir: Path):
    names = sorted(p.name for p in sim_dir.iterdir())
    assert names == ["config.toml", "events.csv", *[f"truth_robot{r}.tum" for r in range(4)]]
    cfg = Config.from_dict(tomllib.loads((sim_dir / "config.toml").read_text()))
    assert cfg.motion.q_v0 > 0 and cfg.motion.q_v2 == 0  # the simulation's own process noise, not MRCLAM's
    header = next(line for line in (sim_dir / "events.csv").read_text().splitlines() if not line.startswith("#"))
    assert header.split(",")[:3] == ["type", "t", "robot"]


def test_simulated_files_start_from_the_sim_sources_initial_beliefs(sim_dir: Path):
    """The written initial beliefs are ``sim:random``'s of the same seed, drawn about the true starts (the truth a
    sample of each prior), not the true starts: the files evaluate as the in-process source does."""
    from swarmloc.experiments.own_robots import load_event_source
    from swarmloc.experiments.sources import load_source
    from swarmloc.lie import SE2

    cfg = Config.from_dict(tomllib.loads((sim_dir / "config.toml").read_text()))
    _, initial, _, _, _, _ = load_event_source(sim_dir / "events.csv", cfg)
    src = load_source("sim:random", robots=4, duration=40.0, seed=2)
    assert sorted(initial) == sorted(src.initial) == [0, 1, 2, 3]
    for r, belief in initial.items():
        np.testing.assert_allclose(belief.mean, src.initial[r].mean, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(belief.cov, src.initial[r].cov)
        start = SE2.from_xytheta(src.truth(r, np.array([0.0]))[0])
        assert np.linalg.norm(SE2.log(SE2.inverse(belief.mean) @ start)) > 1e-4


def test_evaluate_events_scores_every_estimator(sim_dir: Path, tmp_path: Path, capsys):
    out = tmp_path / "scores"
    rc = main(["evaluate", "events", str(sim_dir / "events.csv"), "--config", str(sim_dir / "config.toml"),
               "--out", str(out), "--json", "--quiet"])  # fmt: skip
    assert rc == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["truth"] is True and rep["robots"] == [0, 1, 2, 3]
    rmse = {k: v["team"]["pos_rmse"] for k, v in rep["estimators"].items()}
    assert set(rmse) == {"dr", "dekf", "cekf", "iekf", "expfusion", "ci", "rdl", "diekf"}  # the CLI's default list
    assert rmse["cekf"] < rmse["dr"] and rmse["rdl"] < rmse["dr"], rmse
    for name, ev in rep["estimators"].items():
        assert ev["accounted"] and ev["stats"]["detections"] > 50
        if name in ("dr", "cekf", "iekf", "ci", "rdl", "diekf"):  # the consistent ones (dekf, expfusion double count)
            assert 0.2 < ev["team"]["anees"] < 3.0, (name, ev["team"]["anees"])
    for f in ("events.json", "events.md", "trajectories.png", "error_nees_over_time.png", "tum/rdl_robot2.tum",
              "tum/groundtruth_robot0.tum"):  # fmt: skip
        assert (out / f).is_file() and (out / f).stat().st_size > 0, f


def test_evaluate_events_jsonl_and_without_truth(tmp_path: Path, capsys):
    assert main(["simulate", "--out", str(tmp_path / "j"), "--robots", "2", "--duration", "10", "--format",
                 "jsonl"]) == 0  # fmt: skip
    capsys.readouterr()
    for tum in (tmp_path / "j").glob("*.tum"):
        tum.unlink()
    rc = main(["evaluate", "events", str(tmp_path / "j" / "events.jsonl"), "--estimators", "dr,rdl", "--json",
               "--quiet"])  # fmt: skip
    assert rc == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["truth"] is False and rep["estimators"]["rdl"]["team"] is None
    assert rep["estimators"]["rdl"]["accounted"]


def test_bad_event_file_names_every_bad_line(tmp_path: Path, capsys):
    f = tmp_path / "events.csv"
    f.write_text(
        "type,t,robot,t0,v,w,target,target_type,kind,z,std\n"
        "initial,0.0,1,,,,,,,0 0 0,0.01 0.01 0.01\n"
        "odometry,0.1,1,0.0,0.5,0.0,,,,,\n"
        "odometry,0.2,1,0.3,0.5,0.0,,,,,\n"  # t0 after t
        "detection,0.2,1,,,,7,landmark,range_bearing,4.2,0.1 0.035\n"  # z too short
        "detection,0.2,1,,,,2,robot,pose,1 0 0,-0.1 0.1 0.1\n"  # negative std
        "odometry,0.3,1,0.2,0.5,0.0,,,,,\n"
    )
    rc = main(["evaluate", "events", str(f), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    for line in (4, 5, 6):
        assert f"line {line}" in err, err
    rc = main(["evaluate", "events", str(f), "--quiet", "--skip-bad-lines", "--estimators", "dr"])
    cap = capsys.readouterr()
    assert rc == 0 and cap.err.count("skipped:") == 3


def test_a_detection_of_a_robot_outside_the_team_is_refused_with_its_line(tmp_path: Path, capsys):
    """A detection of robot 7 in a file whose team is robots 0 and 1 (those with odometry) is refused with its line
    number. Before, the file passed its check and the detection silently ended ``unknown``."""
    f = tmp_path / "events.csv"
    f.write_text(
        "type,t,robot,t0,v,w,target,target_type,kind,z,std\n"
        "initial,0.0,0,,,,,,,0 0 0,0.01 0.01 0.01\n"
        "initial,0.0,1,,,,,,,1 0 0,0.01 0.01 0.01\n"
        "odometry,0.5,0,0.0,0.5,0.0,,,,,\n"
        "odometry,0.5,1,0.0,0.5,0.0,,,,,\n"
        "detection,0.2,0,,,,1,robot,range_bearing,1.0 0.0,0.1 0.035\n"
        "detection,0.3,0,,,,7,robot,range_bearing,2.0 0.1,0.1 0.035\n"  # line 7: robot 7 is not in the team
        "detection,0.4,5,,,,0,robot,range_bearing,2.0 0.1,0.1 0.035\n"  # line 8: nor is observer 5
    )
    rc = main(["evaluate", "events", str(f), "--quiet", "--estimators", "dr"])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert "line 7: a detection of robot 7, which is not in the team (robots [0, 1]" in err, err
    assert "line 8: a detection by robot 5, which is not in the team (robots [0, 1]" in err, err
    rc = main(["evaluate", "events", str(f), "--quiet", "--skip-bad-lines", "--estimators", "dr", "--json"])
    cap = capsys.readouterr()
    assert rc == 0 and cap.err.count("skipped:") == 2
    stats = json.loads(cap.out)["estimators"]["dr"]["stats"]
    assert stats["detections"] == 1 and stats["unknown"] == 0


def test_missing_initial_belief_is_one_clear_line(tmp_path: Path, capsys):
    f = tmp_path / "events.csv"
    f.write_text("type,t,robot,t0,v,w\nodometry,0.1,3,0.0,0.5,0.0\n")
    rc = main(["evaluate", "events", str(f), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "no initial belief for robot(s) [3]" in err and err.count("\n") == 1


def test_config_defaults_print_every_default_and_check_reports_errors(tmp_path: Path, capsys):
    assert main(["config", "--defaults"]) == 0
    text = capsys.readouterr().out
    assert Config.from_dict(tomllib.loads(text)) == DEFAULTS
    assert "horizon = 5.0" in text and "gate = 0.997" in text and "rate = 4.0" in text
    bad = tmp_path / "bad.toml"
    bad.write_text("[filter]\nhorizn = 3.0\n")
    assert main(["config", "--check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "[filter]" in err and "horizn" in err and "horizon" in err
    good = tmp_path / "good.toml"
    good.write_text("[filter]\ngate = false\nhorizon = 3.0\n")
    assert main(["config", "--check", str(good)]) == 0
    assert Config.from_dict(tomllib.loads(capsys.readouterr().out)).filter.horizon == 3.0
    rc = main(["evaluate", "events", str(tmp_path / "none.csv"), "--config", str(bad), "--quiet"])
    assert rc == 2 and "horizn" in capsys.readouterr().err


def test_config_changes_the_run(sim_dir: Path, tmp_path: Path, capsys):
    """A config file is used: a tiny gate probability rejects more innovations than the default."""
    cfg = tmp_path / "tight.toml"
    cfg.write_text((sim_dir / "config.toml").read_text().replace("gate = 0.997", "gate = 0.3"))
    args = ["evaluate", "events", str(sim_dir / "events.csv"), "--estimators", "rdl", "--json", "--quiet"]
    assert main([*args, "--config", str(sim_dir / "config.toml")]) == 0
    loose = json.loads(capsys.readouterr().out)["estimators"]["rdl"]["stats"]
    assert main([*args, "--config", str(cfg)]) == 0
    tight = json.loads(capsys.readouterr().out)["estimators"]["rdl"]["stats"]
    assert tight["gated"] > loose["gated"] + 10
    assert np.isclose(tight["detections"], loose["detections"])


def test_evaluate_and_compare_show_progress_on_stderr_not_stdout(sim_dir: Path, capsys, terminal_progress):
    """The tables on stdout, the progress bars on stderr (before, rich drew them on stdout)."""
    assert main(["evaluate", "events", str(sim_dir / "events.csv"), "--estimators", "dr"]) == 0
    out, err = capsys.readouterr()
    assert "| dr |" in out and "dr" in err and "\x1b[" not in out
    assert main(["compare", "--estimators", "dr", "--robots", "2", "--duration", "3", "--jobs", "1"]) == 0
    out, err = capsys.readouterr()
    assert "| dr |" in out and "compare sim:random" in err and "1/1" in err and "\x1b[" not in out
