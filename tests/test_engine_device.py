"""The jax backends' device stamp (:mod:`swarmloc.engine.jax_stamp`): a whole stamp in one compiled call equals the
numpy engine's level path on every outcome (states, clocks, outcome and reason codes, counts, levels), with relative
poses, absolute fixes and range-bearing detections of map landmarks and of robots; a stamp with another kind takes
the level path; the compilations are bounded by the shape buckets, not one per stamp."""

from __future__ import annotations

import numpy as np
import pytest
from test_engine import _outcome_mix
from test_engine_landmarks import _landmark_mix, range_bearing

from swarmloc.engine import Detections, Engine
from swarmloc.lie import SE2
from swarmloc.motion import UnicycleNoise
from swarmloc.sensors.models import KIND_ORDER

# slow: the first test of the module compiles the engine's numba/JAX kernels
pytestmark = [pytest.mark.unit, pytest.mark.slow]


NOISE = UnicycleNoise(q_v0=1e-3, q_lat0=1e-4, q_w0=1e-3)


def _robot_ranges(x: np.ndarray, m: int, rng: np.random.Generator, kind: str = "range_bearing") -> Detections:
    """Range-bearing detections of other robots (targets among robots 1..n-1, none of robot 0), near the truth
    ``x``, a fifth 3 m off (for the gate)."""
    n = x.shape[0]
    obs = rng.integers(1, n, m)
    tgt = (obs + rng.integers(1, n - 1, m)) % n
    tgt = np.where(tgt == 0, 1 + (obs % (n - 1)), tgt)
    tgt = np.where(tgt == obs, 1 + (tgt % (n - 1)), tgt)
    z, R = range_bearing(x[obs], x[tgt, :2], rng)
    if kind != "range_bearing":
        z[:, 0] = z[:, 1] if kind == "bearing" else z[:, 0]
        R[:, 0, 0] = R[:, 1, 1] if kind == "bearing" else R[:, 0, 0]
        R[:, 0, 1] = R[:, 1, 0] = 0.0
    return Detections(obs, tgt, np.full(m, KIND_ORDER[kind]), z, R)


def _engines(rng: np.random.Generator, backends: tuple[str, ...], use_landmarks: bool = True, n: int = 9) -> tuple:
    xyt = np.column_stack([rng.normal(size=(n, 2)), rng.uniform(-3, 3, n)])
    A = rng.normal(size=(n, 3, 3))
    cov = 1e-2 * A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
    t0 = np.zeros(n)
    t0[7], t0[8] = 2.5, np.inf  # starts late; never starts
    lxy = np.r_[xyt[:1, :2], rng.uniform(-4, 4, (5, 2))]  # landmark 0 where robot 0 stays (it gets no command)
    lmap = {10 + i: (*lxy[i], 0.02, 0.03) for i in range(6)}
    engines = {b: Engine("dekf", SE2.from_xytheta(xyt), cov, noise=NOISE, t0=t0, gate=0.99, backend=b, landmarks=lmap,
                         use_landmarks=use_landmarks) for b in backends}  # fmt: skip
    return engines, lxy


def _step(engines: dict[str, Engine], t: float, det: Detections, cmd: tuple) -> None:
    """One stamp through every engine; each must equal ``"numpy"``'s (outcomes, levels, clocks, states to 1e-12)."""
    status = {}
    for b, eng in engines.items():
        eng.predict(cmd[0], t)
        status[b] = eng.fuse(t, det, presorted=True)
        eng.set_command(*cmd)
    ref = engines["numpy"]
    for b, eng in engines.items():
        np.testing.assert_array_equal(status[b], status["numpy"])
        assert eng.last_levels == ref.last_levels
        np.testing.assert_array_equal(eng.t, ref.t)
        np.testing.assert_allclose(eng.a, ref.a, rtol=0, atol=1e-12)
        np.testing.assert_allclose(eng.b, ref.b, rtol=0, atol=1e-12)


@pytest.mark.parametrize("use_landmarks", [True, False])
def test_device_stamp_equals_numpy_on_every_outcome(use_landmarks: bool) -> None:
    """Poses, absolute fixes, map landmarks (fused, gated, not in the map, degenerate, switched off) and robots'
    range-bearing detections, six stamps with new commands for some robots: every stamp in one device call (the
    per-kind kernels never compiled), equal to numpy."""
    rng = np.random.default_rng(5)
    engines, lxy = _engines(rng, ("numpy", "jax"), use_landmarks)
    calls = engines["jax"].ops.stamp.calls
    levels = []
    for k in range(1, 7):
        x = engines["numpy"].a
        poses = _outcome_mix(x, 20, rng)
        poses = poses.take(np.flatnonzero(poses.observer != 0))  # robot 0's estimate stays on landmark 0
        det = Detections.concat(poses, _landmark_mix(x, lxy, 12, rng), _robot_ranges(x, 8, rng)).canonical()
        some = np.sort(rng.choice(np.arange(1, 9), 4, replace=False))
        _step(engines, 0.5 * k, det, (some, rng.uniform(0, 1, 4), rng.uniform(-1, 1, 4)))
        levels.append(engines["jax"].last_levels)
    ref, jx = engines["numpy"], engines["jax"]
    assert ref.counts == jx.counts and ref.reasons == jx.reasons
    assert jx.ops.stamp.calls == calls + 6 and not {"pose", "landmark"} & set(jx.ops.compiles)  # not the kernels
    assert max(levels) >= 3 and jx.counts["fused"] >= 20 and jx.counts["gated"] >= 10
    if use_landmarks:
        assert jx.reasons["unknown: the landmark is not in the map"] > 0
        assert jx.reasons["rejected: degenerate geometry: the target is at the observer's position"] > 0
    else:
        assert jx.reasons["rejected: landmark measurements are switched off"] >= 40


def test_a_stamp_with_a_range_only_detection_takes_the_level_path_and_still_equals_numpy() -> None:
    """The device stamp covers poses, fixes and range-bearing; a stamp that also holds a range-only detection runs
    on the per-kind kernels and the stacked-matrix update, with the same results as numpy."""
    rng = np.random.default_rng(7)
    engines, lxy = _engines(rng, ("numpy", "jax"))
    jx = engines["jax"]
    calls = jx.ops.stamp.calls
    x = engines["numpy"].a
    det = Detections.concat(_outcome_mix(x, 20, rng), _robot_ranges(x, 6, rng)).canonical()
    _step(engines, 0.5, det, (np.arange(1, 5), np.full(4, 0.3), np.full(4, 0.1)))
    assert jx.ops.stamp.calls == calls + 1 and "pose" not in jx.ops.compiles
    x = engines["numpy"].a
    det = Detections.concat(_outcome_mix(x, 20, rng), _robot_ranges(x, 6, rng, "range")).canonical()
    _step(engines, 1.0, det, (np.arange(1, 5), np.full(4, 0.3), np.full(4, 0.1)))
    assert jx.ops.stamp.calls == calls + 1 and jx.ops.compiles["pose"] >= 1
    assert jx.counts == engines["numpy"].counts and jx.counts["fused"] > 10


def test_device_stamp_compiles_per_shape_bucket_not_per_stamp() -> None:
    """Forty stamps of 1 to 60 detections among 40 robots (a team size no other test uses): the stamps compile once
    per bucket of their rows (8 to 64: 4 of them), not once per stamp, and the results equal numpy's throughout."""
    rng = np.random.default_rng(11)
    engines, lxy = _engines(rng, ("numpy", "jax"), n=40)
    before = engines["jax"].ops.stamp.compiles.total()
    for k in range(1, 41):
        x = engines["numpy"].a
        det = _outcome_mix(x, int(rng.integers(1, 61)), rng)
        _step(engines, 0.1 * k, det, (np.arange(1, 6), rng.uniform(0, 1, 5), rng.uniform(-1, 1, 5)))
    stamp = engines["jax"].ops.stamp
    assert 1 <= stamp.compiles.total() - before <= 4, stamp.compiles
    assert engines["jax"].counts == engines["numpy"].counts


def test_a_stamp_where_no_observer_runs_leaves_the_level_count_as_every_backend() -> None:
    """Detections only by a robot that never starts: all rejected (the observer had not started) on numpy, numba
    and jax alike, states and clocks untouched but for the robots given a command, ``last_levels`` that of the
    stamp before."""
    rng = np.random.default_rng(13)
    engines, _ = _engines(rng, ("numpy", "numba", "jax"))
    x = engines["numpy"].a
    _step(engines, 0.5, _outcome_mix(x, 20, rng), (np.arange(1, 5), np.full(4, 0.3), np.full(4, 0.1)))
    before = engines["numpy"].last_levels
    key = "rejected: the observer had not started"
    late = engines["numpy"].reasons[key]
    det = _outcome_mix(x, 10, rng)
    det = Detections(np.full(len(det), 8), det.target, det.kind, det.z, det.R).canonical()  # robot 8: t0 = inf
    _step(engines, 1.0, det, (np.arange(1, 3), np.full(2, 0.2), np.full(2, 0.0)))
    assert before >= 1 and all(e.last_levels == before for e in engines.values())
    assert all(e.reasons[key] == late + 10 for e in engines.values())


@pytest.mark.parametrize("backend", ["numpy", "numba", "jax"])
def test_rows_outside_the_team_are_refused_before_anything_changes(backend: str) -> None:
    """An observer or robot target that is no row of the team raises a ValueError naming it, on every backend (the
    compiled paths do not index-check: numba would read out of bounds, JAX clamp), and the engine is untouched."""
    rng = np.random.default_rng(17)
    engines, _ = _engines(rng, (backend,))
    eng = engines[backend]
    det = _outcome_mix(eng.a, 10, rng)
    before = (eng.a.copy(), eng.b.copy(), eng.t.copy(), dict(eng.counts))
    for obs, tgt in ((9, 1), (-1, 1), (2, 9)):
        bad = Detections(np.r_[det.observer[:-1], obs], np.r_[det.target[:-1], tgt], det.kind, det.z, det.R)
        with pytest.raises(ValueError, match=r"robot rows must be in \[0, 9\)"):
            eng.fuse(1.0, bad)
    np.testing.assert_array_equal(eng.a, before[0])
    np.testing.assert_array_equal(eng.b, before[1])
    np.testing.assert_array_equal(eng.t, before[2])
    assert dict(eng.counts) == before[3]
