"""The batched engine on SE(3) teams (issue 22): equal to the per-robot SE(3) nodes on ``sim:3d`` (means and
covariances to 1e-9 at every record time, same outcome counts and reasons) for ``expfusion``, ``dekf`` and ``ci``;
its batched twist increments equal the node's; backends other than numpy refuse an SE(3) team."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from swarmloc.datasets.source import Source
from swarmloc.engine import Detections, Engine, run_engine
from swarmloc.engine.codes import POSE3
from swarmloc.engine.se3 import twist_increments
from swarmloc.estimators import make_team, node_options
from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.lie import SE3
from swarmloc.motion.twist3 import TwistNoise, twist_increment
from swarmloc.runner import RunResult, run
from swarmloc.sensors.models3 import pose3_vector

pytestmark = pytest.mark.unit


TOL = 1e-9
COUNTS = ("detections", "fused", "gated", "rejected", "unknown", "odometry", "odometry_used", "odometry_rejected",
          "odometry_stops", "recorded")  # fmt: skip


def _nodes(src: Source, estimator: str) -> RunResult:
    opts = {**node_options(estimator, src.config, src.landmarks, src.t_start), "noise": src.noise}
    return run(make_team(estimator, src.initial, **opts), src.events, record_times=src.record_times(), truth=src.truth)


def _assert_same(a: RunResult, b: RunResult) -> float:
    """Equal tracks (to :data:`TOL`) and counts; returns the largest difference."""
    assert sorted(a.tracks) == sorted(b.tracks)
    worst = 0.0
    for r, ta in a.tracks.items():
        tb = b.tracks[r]
        np.testing.assert_array_equal(ta.times, tb.times)
        assert ta.times.size > 0 and ta.mean.shape[1] == 7 and ta.cov.shape[1:] == (6, 6)
        np.testing.assert_allclose(ta.mean, tb.mean, rtol=0, atol=TOL)
        np.testing.assert_allclose(ta.cov, tb.cov, rtol=0, atol=TOL)
        np.testing.assert_array_equal(ta.truth, tb.truth)
        worst = max(worst, np.abs(ta.mean - tb.mean).max(), np.abs(ta.cov - tb.cov).max())
    assert {k: a.stats.get(k, 0) for k in COUNTS} == {k: b.stats.get(k, 0) for k in COUNTS}
    return worst


@pytest.mark.parametrize(
    ("estimator", "spec", "robots", "seed", "min_fused"),
    [("expfusion", "sim:3d", 4, 0, 150), ("dekf", "sim:3d", 4, 1, 150), ("ci", "sim:3d", 3, 2, 60),
     ("expfusion", "sim:3d_rot", 3, 3, 60), ("dekf", "sim:3d_rot", 3, 4, 5)],
)  # fmt: skip
def test_engine_equals_se3_nodes(estimator: str, spec: str, robots: int, seed: int, min_fused: int) -> None:
    """Equal tracks and counts; on ``sim:3d_rot`` (30 deg initial attitude) the first-order EKF gates most
    detections, and the engine gates the same ones."""
    src = load_source(spec, robots=robots, duration=8.0, seed=seed)
    ref, eng = _nodes(src, estimator), run_engine(src, estimator)
    _assert_same(ref, eng)
    assert ref.stats["fused"] >= min_fused


@pytest.mark.parametrize("estimator", ["expfusion", "dekf", "ci"])
def test_engine_se3_rejects_planar_kinds_and_keeps_the_odometry_contract(estimator: str) -> None:
    """Planar detections in a 3-D team (an absolute fix, a range/bearing of a robot, one of a robot outside the
    team) are rejected or unknown as the nodes decide, under their reasons; a gap in a robot's odometry stops it
    (the stop broadcast to all six axes) and an overlapping record is refused, as the nodes do."""
    src = load_source("sim:3d", robots=3, duration=6.0, seed=5)
    extra = [
        Detection(0, 2.0, "absolute", np.array([1.0, 2.0, 0.3]), np.diag([0.1, 0.1, 0.01])),
        Detection(1, 2.0, "range_bearing", np.array([2.0, 0.3]), np.diag([0.01, 0.001]), target=2),
        Detection(2, 3.05, "range_bearing", np.array([2.0, 0.3]), np.diag([0.01, 0.001]), target=9),
        Detection(2, 3.05, "pose3", np.zeros(6), np.eye(6) * 1e-2, target=9),
    ]
    events, overlap = [], None
    for e in src.events:
        if isinstance(e, Odometry) and e.robot == 1 and 2.5 <= e.t0 < 3.5:
            continue  # a gap: robot 1 stops at 2.5 s
        if isinstance(e, Odometry) and e.robot == 2 and overlap is None and e.t0 >= 4.0:
            overlap = dataclasses.replace(e, t0=e.t0 + 0.05, t1=e.t1 + 0.05)
            events += [e, overlap]
            continue
        events.append(e)
    events = sorted([*events, *extra], key=lambda e: e.stamp)
    src = dataclasses.replace(src, events=events)
    ref, eng = _nodes(src, estimator), run_engine(src, estimator)
    _assert_same(ref, eng)
    assert eng.stats["odometry_stops"] == 1 and eng.stats["odometry_rejected"] == 1
    for kind in ("absolute", "range_bearing"):
        key = f"rejected: kind {kind!r} is not supported on SE(3)"
        assert ref.reasons[key] == eng.reasons[key] == 1
    assert eng.stats["unknown"] == ref.stats["unknown"] == 2


def test_batched_twist_increments_equal_the_nodes() -> None:
    rng = np.random.default_rng(0)
    noise = TwistNoise(q_lin0=4e-4, q_lin1=1e-3, q_ang0=1e-4, q_ang1=2e-3)
    h = rng.normal(size=(40, 6))
    h[:3] = 0.0  # stopped
    h[3:6, 3:] *= 1e-9  # almost no rotation
    dt = rng.uniform(0.01, 2.0, 40)
    mean, cov = twist_increments(h[:, :3], h[:, 3:], dt, noise)
    for i in range(40):
        m1, c1 = twist_increment(h[i], float(dt[i]), noise)
        np.testing.assert_allclose(mean[i], m1, rtol=0, atol=1e-15)
        np.testing.assert_allclose(cov[i], c1, rtol=0, atol=1e-15)


def _team3() -> tuple[np.ndarray, np.ndarray]:
    mean = SE3.exp(np.array([[0.0, 0, 1, 0, 0, 0.1], [1.0, 0.2, 2, 0.1, 0, -0.3], [0.0, 1, 1.5, 0, 0.2, 2.0]]))
    cov = np.stack([np.diag([1e-2, 2e-2, 1e-2, 1e-3, 1e-3, 2e-3]) * (k + 1) for k in range(3)])
    return mean, cov


@pytest.mark.parametrize("backend", ["numba", "jax"])
def test_other_backends_refuse_se3_teams(backend: str) -> None:
    mean, cov = _team3()
    with pytest.raises(ValueError, match=r"SE\(2\) teams only.*backend='numpy'"):
        Engine("dekf", mean, cov, noise=TwistNoise(), backend=backend)
    with pytest.raises(ValueError, match=r"\(N, 4, 4\) and \(N, 6, 6\)"):
        Engine("expfusion", mean, cov[:, :3, :3], noise=TwistNoise())


def test_engine_se3_is_gauss_seidel_in_observer_order() -> None:
    """Mutual pose3 detections at one stamp, fused in one call (three levels), equal the groups fused one after
    the other in observer order."""
    mean, cov = _team3()
    R = np.diag([1e-3] * 3 + [1e-4] * 3)
    z = [pose3_vector(SE3.between(mean[i], mean[j])) + 0.01 for i, j in ((2, 1), (1, 0), (0, 1))]
    det = Detections(np.array([2, 1, 0]), np.array([1, 0, 1]), np.full(3, POSE3), np.stack(z),
                     np.broadcast_to(R, (3, 6, 6)))  # fmt: skip
    for estimator in ("expfusion", "dekf", "ci"):
        one = Engine(estimator, mean, cov, noise=TwistNoise(), gate=None)
        one.fuse(0.0, det)
        assert one.last_levels == 3
        seq = Engine(estimator, mean, cov, noise=TwistNoise(), gate=None)
        for k in (2, 1, 0):
            seq.fuse(0.0, det.take(np.array([k])))
        np.testing.assert_allclose(one.a, seq.a, rtol=0, atol=1e-14)
        np.testing.assert_allclose(one.b, seq.b, rtol=0, atol=1e-14)
        assert np.abs(one.b[1] - cov[1]).max() > 1e-5  # fused
