"""The report tables a reader sees (``team.md``, ``evaluate``'s table, ``compare``'s): what they print for an
association scored only in the counters, a 3-D team's rotation errors, speeds below 1x real time, and a table per
robot."""

from __future__ import annotations

import pytest

from swarmloc.experiments.compare import compare_table
from swarmloc.experiments.evaluate import markdown_table, speed_text

pytestmark = pytest.mark.unit


def _summary(pos: float, rot: float, n: int, se3: bool) -> dict:
    s = {"n": n, "pos_rmse": pos, "heading_rmse": rot, "anees": 1.234, "nees_median": 1.0, "frac_in_95": 0.95}
    return {**s, "rot_rmse": rot, "dof": 6} if se3 else s


def _team_report(se3: bool) -> dict:
    """A report shaped as ``swarmloc team`` writes it: no ``association_accuracy`` key, the counters in ``stats``."""
    stats = {"detections": 200, "fused": 190, "gated": 4, "rejected": 6, "unknown": 0, "association_right": 190,
             "association_wrong": 0}  # fmt: skip
    ev = {"stats": stats, "wall_time_s": 12.3456, "x_real_time": 2.4567, "team": _summary(0.1234, 0.0456, 300, se3),
          "robots": {"0": _summary(0.1, 0.04, 150, se3), "1": _summary(0.14, 0.05, 150, se3)}}  # fmt: skip
    return {"title": "live team", "duration_s": 30.0, "robots": [0, 1], "truth": True, "estimators": {"diekf": ev}}


def test_team_table_shows_the_association_accuracy_its_counters_hold():
    md = markdown_table(_team_report(se3=False))
    assert "| 1.000 (190/190) |" in md


def test_speed_has_the_decimals_it_needs():
    md = markdown_table(_team_report(se3=False))
    assert md.splitlines()[4].endswith("| 12.3 | 2.46 |")
    assert [speed_text(x) for x in (1234.5, 56.78, 2.4567, 0.01234, float("inf"))] == ["1234", "56.8", "2.46",
                                                                                       "0.0123", "-"]  # fmt: skip


def test_se3_rows_say_rotation_and_se2_rows_heading():
    se3, se2 = markdown_table(_team_report(se3=True)), markdown_table(_team_report(se3=False))
    assert "rotation RMSE [rad]" in se3 and "heading RMSE" not in se3
    assert "heading RMSE [rad]" in se2 and "rotation RMSE" not in se2


def test_table_per_robot():
    md = markdown_table(_team_report(se3=True))
    rows = md[md.index("Per robot:") :].splitlines()
    assert "| estimator | robot | pos RMSE [m] | rotation RMSE [rad] |" in rows[2]
    assert rows[4] == "| diekf | 0 | 0.100 | 0.040 | 1.23 | 0.95 | 150 |"
    assert rows[5] == "| diekf | 1 | 0.140 | 0.050 | 1.23 | 0.95 | 150 |"


def test_compare_table_says_rotation_for_a_3d_scenario_and_counts_the_association():
    row = {"pos_rmse": 0.2, "heading_rmse": 0.06, "anees": 1.5, "anees_band_95": (0.8, 1.2), "frac_in_95": 0.9,
           "update_us": 10.0, "predict_us": 5.0, "messages_per_robot_s": 1.0,
           "detections": {"fused": 9, "gated": 0, "rejected": 1, "unknown": 0},
           "association": {"right": 9, "wrong": 1}}  # fmt: skip
    s = {"scenario": "sim:3d", "runs": 1, "robots": 3, "duration_s": 4.0, "dof": 6, "estimators": {"diekf": row}}
    md = compare_table(s)
    assert "rotation RMSE [rad]" in md and "| 0.900 (9/10) |" in md
    assert "heading RMSE [rad]" in compare_table({**s, "dof": 3})
