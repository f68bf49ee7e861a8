"""The node snippet a reader copies (``examples/node_snippet.py``, the one the documentation shows) runs and does
what its comments say: ``node.x`` at the present, the belief at 0.5 s after the odometry, the detection filed
once the teammate's answer is in."""

from __future__ import annotations

import runpy
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.unit

SNIPPET = Path(__file__).resolve().parents[1] / "examples" / "node_snippet.py"


def test_node_snippet_runs_and_says_what_its_comments_say(capsys):
    ns = runpy.run_path(str(SNIPPET), run_name="__main__")
    lines = capsys.readouterr().out.splitlines()
    # after the odometry over [0, 0.5] s alone: present 0, x the start pose (the odometry is filed at its t0)
    assert lines[0] == "ExpFusion(robot=0, estimator='expfusion', present=0, x=[0, 0, 0])"
    # the belief at 0.5 s: 0.4 m/s for 0.5 s at 0.1 rad/s
    np.testing.assert_allclose(ns["x_half"], [0.2, 0.005, 0.05], atol=2e-4)
    assert "belief at 0.5 s: GroupGaussian(SE2, mean (x, y, theta)=[0.1999, 0.004999, 0.05]" in lines[1]
    assert lines[2] == "BeliefQuery(sender=0, receiver=1, stamp=0.3, sub=())"
    node = ns["node"]
    # the answer stepped in: the detection is fused, the present is its stamp, x the pose there
    assert node.present == 0.3 and lines[3].startswith("ExpFusion(robot=0, estimator='expfusion', present=0.3, x=[")
    odometry_only = 0.4 * 0.3  # where the odometry alone puts robot 0 at 0.3 s (x)
    assert odometry_only < ns["x"][0] < 0.2  # pulled toward the detection: robot 1 (at 1.2 m) seen 1.0 m ahead
    assert {k: ns["stats"][k] for k in ("detections", "fused", "gated", "rejected", "unknown", "pending")} == {
        "detections": 1,
        "fused": 1,
        "gated": 0,
        "rejected": 0,
        "unknown": 0,
        "pending": 0,
    }
    assert not ns["x"].flags.writeable and ns["P"].shape == (3, 3)
