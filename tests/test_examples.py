"""The node snippet a reader copies (``examples/node_snippet.py``, the one the documentation shows) runs and does
what its comments say: ``node.x`` at the present, the belief at 0.5 s after the odometry, the detection filed
once the teammate's answer is in. The sources' other methods' examples (``docs/toolbox.md`` shows them; the
thesis' closed forms ``docs/thesis.md``, the beliefs' fusion ``docs/concepts-beliefs.md``) run and come out as their
docstrings say."""

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


EXAMPLES = SNIPPET.parent


def _run(name: str, *argv: str) -> dict:
    """Run ``examples/<name>`` as a script (with ``argv``) and return its globals."""
    import sys

    old = sys.argv
    sys.argv = [name, *argv]
    try:
        return runpy.run_path(str(EXAMPLES / name), run_name="__main__")
    finally:
        sys.argv = old


def test_book_fusion_example_fuses_and_the_team_beats_dead_reckoning(capsys):
    """Serial fusion carries the observer's uncertainty (robot 2 as seen is less certain than the observer), parallel
    fusion shrinks every input's variance, and in the chapter's experiment both robots end nearer the truth and more
    certain with cooperation than by dead reckoning."""
    ns = _run("book_fusion.py")
    assert len(capsys.readouterr().out.splitlines()) == 5

    # the Jacobian, by central differences of the book's model (x_j = x_r + R(theta_r) e, theta_j = theta_r + theta_e)
    def model(v):
        c, s = np.cos(v[2]), np.sin(v[2])
        return np.array([v[0] + c * v[3] - s * v[4], v[1] + s * v[3] + c * v[4], v[2] + v[5]])

    M, h = np.concatenate([ns["observer"], ns["z"]]), 1e-6
    fd = np.stack([(model(M + h * e) - model(M - h * e)) / (2 * h) for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(ns["J"], fd, atol=1e-8)
    np.testing.assert_array_equal(ns["J"][2], [0, 0, 1, 0, 0, 1])  # the printed third row is [0, 1, 0, 0, 0, 1]
    B = np.zeros((6, 6))
    B[:3, :3], B[3:, 3:] = ns["observer_cov"], ns["z_cov"]
    np.testing.assert_allclose(ns["seen_cov"], ns["J"] @ B @ ns["J"].T, atol=1e-15)
    assert np.all(np.diag(ns["seen_cov"]) > [0.01, 0.02, 0.003])
    for cov in (ns["own_cov"], ns["seen_cov"]):
        assert np.all(np.linalg.eigvalsh(cov - ns["fused_cov"]) > -1e-12)
    truth = ns["truth"]
    alone = np.linalg.norm(ns["alone"][-1] - truth, axis=-1)
    team = np.linalg.norm(ns["team"][-1] - truth, axis=-1)
    assert np.all(team < alone)
    assert np.all(np.trace(ns["team_cov"][-1], axis1=-2, axis2=-1) < np.trace(ns["alone_cov"][-1], axis1=-2, axis2=-1))


def test_robocentric_example_tracks_teammates_and_shows_the_separate_filters_overconfident(capsys):
    """Both filters end within 10 cm of the teammates' true relative poses; the joint filter's ANEES lies in the
    chi-square band, the separate filters' above it (the lecture's over-confidence)."""
    ns = _run("robocentric.py")
    assert len(capsys.readouterr().out.splitlines()) == 5
    for f in ns["filters"].values():
        assert np.all(np.linalg.norm(f.q[:, :2] - ns["truth"][:, :2], axis=1) < 0.1)
    lo, hi = ns["mc"]["band"]
    assert lo <= ns["mc"]["joint_mean_anees"] <= hi < ns["mc"]["separate_mean_anees"]
    assert np.all(np.linalg.eigvalsh(ns["frame_cov"]) > 0) and ns["frame"].shape == (3,)


def test_sensor_network_example_localizes_and_names_the_weak_node(capsys):
    """Every node within 3 std (and 15 cm) of where it is, nearer than its MDS-MAP start; without its ranges to
    anchors 1, 2 and node 14, node 13 is refused by name."""
    ns = _run("sensor_network.py")
    out = capsys.readouterr().out
    sol = ns["solution"]
    assert out.startswith("localizable: True") and sol.dof == 7
    for node, true in ns["nodes"].items():
        err = sol.positions[node] - true
        assert np.linalg.norm(err) < 0.15 and err @ np.linalg.solve(sol.marginal(node), err) < 9.0
    assert "refused: node(s) with fewer than 3 distinct measured neighbours: 13 (2)" in out
    # the MDS-MAP start is near (every node within 0.3 m) and the least squares improves on it
    np.testing.assert_array_equal(sol.position_array(), [sol.positions[n] for n in sol.node_ids])
    assert max(np.linalg.norm(ns["start"][n] - true) for n, true in ns["nodes"].items()) < 0.3
    assert ns["rms"] < 0.6 * ns["start_rms"] and f"least squares {ns['rms']:.3f} m" in out


def test_anonymous_localization_example_counts_the_symmetric_solutions_and_finds_the_unique_one(capsys):
    """The square has 3! = 6 solutions, each a different assignment of identities to robot 0's points; with one
    robot moved the one solution puts every teammate within 5 cm (and 0.05 rad) of where it is, computed here from
    the world poses."""
    ns = _run("anonymous_localization.py")
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "square: symmetry metric 0.000 m, 6 solution(s) (theory 6)"
    assert lines[1].startswith("one robot moved: symmetry metric 0.") and lines[1].endswith("1 solution(s) (theory 1)")
    assert len({tuple(s.features[j] for j in (1, 2, 3)) for s in ns["square_result"].solutions}) == 6
    poses = ns["poses"]
    c, s = np.cos(poses[0, 2]), np.sin(poses[0, 2])
    for j in (1, 2, 3):
        d = poses[j, :2] - poses[0, :2]
        true = [c * d[0] + s * d[1], -s * d[0] + c * d[1], poses[j, 2] - poses[0, 2]]
        found = ns["result"].solutions[0].poses[j]
        assert np.hypot(*(found[:2] - true[:2])) < 0.05
        assert abs((found[2] - true[2] + np.pi) % (2 * np.pi) - np.pi) < 0.05


def test_thesis_motion_example_closed_forms_agree_with_the_general_ones(capsys):
    """Every closed form within 1e-12 (relative) of the general form, the second-order mean 0.1-0.3 off; and the
    closed forms against the geometry written out here: the arc ends at ``a (sin theta, 1 - cos theta)`` heading
    ``theta``, the straight run's lateral variance is ``q_w v^2 t^3 / 3``."""
    ns = _run("thesis_motion.py")
    assert len(capsys.readouterr().out.splitlines()) == 6
    *exact, second_order = ns["difference"].values()
    assert max(exact) < 1e-12 and 0.1 < second_order < 0.3
    a, theta = ns["a"], ns["alpha_dot"] * ns["t"]
    arc_mean = ns["forms"]["arc mean (5.7)"][0]
    np.testing.assert_allclose(arc_mean[:2, 2], [a * np.sin(theta), a * (1 - np.cos(theta))], atol=1e-15)
    np.testing.assert_allclose(np.arctan2(arc_mean[1, 0], arc_mean[0, 0]), theta, atol=1e-15)
    v, q_w = ns["r"] * ns["w"], ns["Q"][2, 2]
    lateral = ns["forms"]["straight covariance (5.6)"][0][1, 1]
    np.testing.assert_allclose(lateral, q_w * v**2 * ns["t"] ** 3 / 3, rtol=1e-14)


def test_group_fusion_example_agrees_with_sampling_and_with_the_formulas_written_out(capsys):
    """Every comparison the example prints, as it says: the transforms exact, the second-order prediction and the
    two fusions near sampling, the fix and the landmark's innovation as computed here by hand."""
    ns = _run("group_fusion.py")
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 11 and lines[8].startswith("log against the matrix logarithm:")
    SE2 = ns["SE2"]
    np.testing.assert_allclose(ns["turned"].cov, np.diag([0.01, 0.02, 0.25]), atol=1e-15)  # x and y swapped
    np.testing.assert_allclose(SE2.to_xytheta(ns["shifted"].mean), [6.0, 0.5, 0.3], atol=1e-15)
    np.testing.assert_array_equal(ns["shifted"].cov, ns["belief"].cov)
    assert ns["first"] > 0.03 and ns["second"] < 0.01  # sampling's own error: about 0.3%
    for mean_apart, cov_off in (ns["relative"], ns["point"]):
        assert mean_apart < 0.005 and cov_off < 0.03
    # the fix (variance 0.01 in x, as the prior's) halves the x variance and lands halfway, to first order
    np.testing.assert_allclose(SE2.to_xytheta(ns["fixed"].mean)[0], 0.025, atol=5e-4)
    np.testing.assert_allclose(ns["fixed"].cov[0, 0], 0.005, atol=5e-4)
    # the innovation by hand: h = (range, bearing) of the landmark seen from the pose, differentiated numerically
    landmark, C, R, P = ns["landmark"], ns["landmark_cov"], ns["R"], ns["prior"].cov

    def h(y, p):  # the landmark p seen from exp(y) (the prior's mean is the identity)
        g = SE2.exp(y)
        q = g[:2, :2].T @ (p - g[:2, 2])
        return np.array([np.hypot(*q), np.arctan2(q[1], q[0])])

    e = 1e-6
    H = np.stack([(h(e * u, landmark) - h(-e * u, landmark)) / (2 * e) for u in np.eye(3)], axis=1)
    Hp = np.stack(
        [(h(np.zeros(3), landmark + e * u) - h(np.zeros(3), landmark - e * u)) / (2 * e) for u in np.eye(2)], 1
    )
    r = ns["z"] - h(np.zeros(3), landmark)
    np.testing.assert_allclose(ns["nis"], r @ np.linalg.solve(H @ P @ H.T + Hp @ C @ Hp.T + R, r), rtol=1e-6)
    assert float(lines[8].split()[-1]) < 1e-12  # log(exp(x)) = x by the matrix logarithm
    assert ns["bch"][0] > ns["bch"][1] > ns["bch"][2] and ns["bch"][1] < 0.01
    assert np.abs(ns["moved"] - SE2.right_jacobian(ns["x"]) @ ns["d"]).max() < 1e-8


def test_cooperative_positioning_example_beats_dead_reckoning(capsys):
    ns = _run("cooperative_positioning.py")
    rms = {line.split(":")[0]: float(line.split()[4]) for line in capsys.readouterr().out.splitlines()}
    assert set(rms) == {"dr", "cekf", "rdl"} and ns["estimator"] == "rdl"
    # known starts (the true poses, 1 mm / 1 mrad): measured cekf 0.092 m and rdl 0.089 m against dead reckoning's
    # 0.186 m
    assert rms["cekf"] < 0.6 * rms["dr"] and rms["rdl"] < 0.6 * rms["dr"]


def test_observability_example_bounds_the_absolute_error_only_with_fixes(capsys, tmp_path):
    """Without fixes the absolute error exceeds the relative one; one robot with fixes halves it; the figure is
    written. Along the team's rigid motions the centralized EKF gains information about the rotation only, the
    invariant EKF none."""
    ns = _run("observability.py", str(tmp_path / "obs.png"))
    lines = capsys.readouterr().out.splitlines()
    cekf, iekf = (ns["gained"][name] for name in ("cekf", "iekf"))
    assert cekf["updates"] == iekf["updates"] > 100
    assert np.abs(iekf["information"]).max() < 1e-9 < 1.0 < cekf["information"][2, 2]
    assert np.abs(cekf["information"][:2, :2]).max() < 1e-6 * cekf["information"][2, 2]
    assert lines[2] == "cekf: information along the team's x 0, y 0, rotation 36 [rad^-2]"
    (abs0, rel0), (abs1, _) = ([float(w) for w in line.split() if w[0].isdigit() and "." in w] for line in lines[:2])
    assert abs0 > 2 * rel0 and abs1 < 0.6 * abs0
    assert (tmp_path / "obs.png").stat().st_size > 10_000
