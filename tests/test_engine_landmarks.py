"""The engine's ``dekf`` with a landmark map equals the per-robot nodes (to 1e-10, same counts and reasons) on
simulated teams with landmarks and on the first 60 s of MRCLAM dataset 6, on every backend; landmark detections
switched off, or of landmarks missing from the map, end as the nodes end them."""

from __future__ import annotations

import numpy as np
import pytest
from test_engine import _assert_same, _outcome_mix, step_both_and_compare

from swarmloc.engine import Detections, Engine, run_engine
from swarmloc.engine.codes import NO_LANDMARK, POSE, landmark_code
from swarmloc.estimators import make_team, node_options
from swarmloc.experiments.sources import load_source
from swarmloc.lie import wrap_angle
from swarmloc.motion import UnicycleNoise
from swarmloc.runner import RunResult, run
from swarmloc.sensors.models import KIND_ORDER

# slow: the first test of the module compiles the engine's numba/JAX kernels
pytestmark = [pytest.mark.data, pytest.mark.slow]


def _nodes(src, **options) -> RunResult:
    opts = {**node_options("dekf", src.config, src.landmarks), **options}
    return run(make_team("dekf", src.initial, **opts), src.events, record_times=src.record_times(), truth=src.truth)


def _landmark_detections(src) -> int:
    return sum(1 for e in src.events if getattr(e, "target_is_robot", True) is False)


@pytest.mark.parametrize("seed", [5, 6])
@pytest.mark.parametrize("backend", ["numpy", "numba", "jax"])
def test_engine_with_landmarks_equals_the_nodes_on_simulated_teams(seed, backend) -> None:
    src = load_source("sim:landmarks", robots=4, duration=15.0, seed=seed)
    assert _landmark_detections(src) > 300  # landmark detections are most of the input
    a, b = _nodes(src), run_engine(src, "dekf", backend=backend)
    _assert_same(a, b)
    detection_reasons = {k: v for k, v in a.reasons.items() if not k.startswith("message")}  # no messages in it
    assert detection_reasons == b.reasons
    assert b.stats["fused"] > 0.99 * b.stats["detections"]


def test_landmarks_switched_off_or_missing_from_the_map_end_as_in_the_nodes() -> None:
    """Off: every landmark detection rejected (the nodes' reason); a map without two landmarks: their detections
    ``unknown``, the rest fused; the beliefs equal the nodes' in both."""
    src = load_source("sim:landmarks", robots=3, duration=10.0, seed=7)
    n_lm = _landmark_detections(src)
    off_a, off_b = _nodes(src, use_landmarks=False), run_engine(src, "dekf", use_landmarks=False)
    _assert_same(off_a, off_b)
    assert off_b.reasons["rejected: landmark measurements are switched off"] == n_lm
    assert off_a.reasons["rejected: landmark measurements are switched off"] == n_lm

    ids = sorted(src.landmarks)
    part = {k: v for k, v in src.landmarks.items() if k not in ids[:2]}
    gone = sum(1 for e in src.events if getattr(e, "target_is_robot", True) is False and e.target in ids[:2])
    assert gone > 0
    pa, pb = _nodes(src, landmarks=part), run_engine(src, "dekf", landmarks=part)
    _assert_same(pa, pb)
    assert pb.stats["unknown"] == pa.stats["unknown"] == gone
    named = {k: v for k, v in pb.reasons.items() if k.startswith("unknown: landmark")}  # named as the nodes name them
    assert sum(named.values()) == gone and named == {k: v for k, v in pa.reasons.items() if k in named}


def test_engine_with_landmarks_equals_the_nodes_on_mrclam6_first_60s(mrclam6) -> None:
    src = load_source(f"mrclam:{mrclam6}", duration=60.0)
    assert len(src.landmarks) == 15
    a, b = _nodes(src), run_engine(src, "dekf")
    _assert_same(a, b)
    assert a.stats["fused"] == b.stats["fused"] > 1000 and a.stats["gated"] == b.stats["gated"]


def test_landmark_codes_sort_after_the_robots_in_id_order_and_only_dekf_takes_a_map() -> None:
    noise = UnicycleNoise()
    mean = np.broadcast_to(np.eye(3), (2, 3, 3))
    cov = np.broadcast_to(1e-3 * np.eye(3), (2, 3, 3))
    eng = Engine("dekf", mean, cov, noise=noise, landmarks={30: (1.0, 0.0, 0.1, 0.1), 12: (0.0, 2.0, 0.1, 0.1)})
    assert eng.landmark_code(12) == landmark_code(0) and eng.landmark_code(30) == landmark_code(1)
    assert eng.landmark_code(99) == NO_LANDMARK
    rb = KIND_ORDER["range_bearing"]
    tgt = np.array([landmark_code(1), 1, landmark_code(0), NO_LANDMARK])
    det = Detections(np.zeros(4, dtype=np.int64), tgt, np.full(4, rb), np.zeros((4, 3)), np.zeros((4, 3, 3)))
    assert det.canonical().target.tolist() == [1, NO_LANDMARK, landmark_code(0), landmark_code(1)]
    assert POSE < rb  # kinds first: a pose of robot 1 precedes every range-bearing detection
    for estimator in ("expfusion", "ci"):
        with pytest.raises(ValueError, match="landmarks run with 'dekf'"):
            Engine(estimator, mean, cov, noise=noise, landmarks={1: (0.0, 0.0, 0.1, 0.1)})
    with pytest.raises(ValueError, match="planar"):
        Engine("dekf", mean, cov, noise=noise, landmarks={1: (0.0, 0.0, 0.0, 0.1, 0.1, 0.1)})


def test_landmark_kernels_equal_the_stacked_kalman_update_on_every_backend() -> None:
    """``landmark_update`` of numpy, numba and jax (float64) against the node's linearization and
    :func:`swarmloc.kernels.cartesian.kalman_update` on random observers and landmarks: 1e-12 on means and
    covariances, 1e-10 relative on NIS; jax32 to float32 rounding."""
    from swarmloc.engine.backends import JaxOps, NumpyOps
    from swarmloc.engine.numba_ops import NumbaOps
    from swarmloc.estimators.dekf import linearize
    from swarmloc.events import Detection
    from swarmloc.kernels import cartesian as C

    rng = np.random.default_rng(11)
    b = 200
    x = np.column_stack([rng.uniform(-3, 3, (b, 2)), rng.uniform(-np.pi, np.pi, b)])
    A = rng.normal(size=(b, 3, 3))
    P = 1e-2 * A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
    lk = rng.uniform(-5, 5, (b, 2))
    L = np.broadcast_to(np.diag([0.02**2, 0.03**2]), (b, 2, 2)).copy()
    z = np.column_stack([rng.uniform(0.5, 6, b), rng.uniform(-0.6, 0.6, b)])
    Rz = np.broadcast_to(np.diag([0.05**2, 0.02**2]), (b, 2, 2)).copy()
    want = []
    for i in range(b):
        d = Detection(0, 0.0, "range_bearing", z[i], Rz[i], target=1, target_is_robot=False)
        r, Hi, R_eff, _ = linearize(d, x[i], ("landmark", (lk[i], L[i])))
        want.append(C.kalman_update(x[i], P[i], r, Hi, R_eff))
    wx, wP, wn = (np.array([w[k] for w in want]) for k in range(3))
    noise = UnicycleNoise()
    for ops in (NumpyOps(noise), NumbaOps(noise), JaxOps(noise)):
        xn, Pn, nis, ok, pd = ops.landmark_update(x, P, lk, L, z, Rz)
        assert ok.all() and pd.all(), ops.name
        np.testing.assert_allclose(xn, wx, rtol=0, atol=1e-12, err_msg=ops.name)
        np.testing.assert_allclose(Pn, wP, rtol=0, atol=1e-12, err_msg=ops.name)
        np.testing.assert_allclose(nis, wn, rtol=1e-10, err_msg=ops.name)
    xn, Pn, nis, ok, pd = JaxOps(noise, np.float32).landmark_update(x, P, lk, L, z, Rz)
    assert np.abs(xn - wx).max() < 1e-4 and np.abs(Pn - wP).max() < 1e-5 and np.abs(nis / wn - 1).max() < 1e-2


def test_the_jax_engine_fuses_landmarks_on_its_kernels(monkeypatch) -> None:
    """On the jax backend the landmark detections are fused by the compiled device stamp (counted compilations; the
    per-kind update kernels never compiled), with the result equal to the nodes' (the simulated-team test above)."""
    from swarmloc.engine import replay

    src = load_source("sim:landmarks", robots=3, duration=5.0, seed=8)
    made = []

    def keep(*a, **k):
        made.append(Engine(*a, **k))
        return made[-1]

    monkeypatch.setattr(replay, "Engine", keep)
    _assert_same(_nodes(src), run_engine(src, "dekf", backend="jax"))
    assert made[0].ops.stamp.compiles.total() >= 1
    assert not {"pose", "absolute", "landmark"} & set(made[0].ops.compiles)  # the predictions of belief queries only


def _landmark_mix(x: np.ndarray, lxy: np.ndarray, m: int, rng: np.random.Generator) -> Detections:
    """Range-bearing detections of map landmarks by random observers at ``x (n, 3)``: near the truth, a fifth 3 m
    off (for the gate), a tenth of landmarks missing from the map; robot 0 sees landmark 0 only (at its own
    position: degenerate)."""
    obs = np.r_[0, rng.integers(1, x.shape[0], m - 1)]
    k = np.r_[0, rng.integers(0, lxy.shape[0], m - 1)]
    tgt = np.array([landmark_code(int(i)) for i in k])
    tgt = np.where(rng.random(m) < 0.1, NO_LANDMARK, tgt)
    tgt[0] = landmark_code(0)
    z, R = range_bearing(x[obs], lxy[k], rng)
    return Detections(obs, tgt, np.full(m, KIND_ORDER["range_bearing"]), z, R)


def range_bearing(pose: np.ndarray, xy: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``(z (m, 3), R (m, 3, 3))``: range-bearing of points ``xy (m, 2)`` from poses ``(m, 3)``, noise 0.03 m and 0.01
    rad, a fifth of the ranges 3 m off (for the gate)."""
    m = pose.shape[0]
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    dx, dy = xy[:, 0] - pose[:, 0], xy[:, 1] - pose[:, 1]
    z = np.zeros((m, 3))
    z[:, 0] = np.hypot(dx, dy) + rng.normal(scale=0.03, size=m) + np.where(rng.random(m) < 0.2, 3.0, 0.0)
    z[:, 1] = wrap_angle(np.arctan2(-s * dx + c * dy, c * dx + s * dy) + rng.normal(scale=0.01, size=m))
    R = np.zeros((m, 3, 3))
    R[:, 0, 0], R[:, 1, 1], R[:, 0, 1] = 0.03**2, 0.01**2, 1e-5
    R[:, 1, 0] = R[:, 0, 1]
    return z, R


@pytest.mark.parametrize("use_landmarks", [True, False])
@pytest.mark.parametrize("parallel", [False, True])
def test_numba_kernels_equal_numpy_with_landmarks_on_every_outcome(monkeypatch, parallel, use_landmarks) -> None:
    """The numba backend's in-place kernel (screening, prediction and fusion in one loop) and its level path with
    landmark detections mixed in (fused, gated, missing from the map, degenerate, switched off) equal numpy: states,
    clocks, outcome and reason codes, counts, levels."""
    from swarmloc.engine import numba_ops
    from swarmloc.lie import SE2

    if parallel:
        monkeypatch.setattr(numba_ops, "PARALLEL_MIN", 0)
    rng = np.random.default_rng(5)
    n = 9
    xyt = np.column_stack([rng.normal(size=(n, 2)), rng.uniform(-3, 3, n)])
    A = rng.normal(size=(n, 3, 3))
    cov = 1e-2 * A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
    t0 = np.zeros(n)
    t0[7], t0[8] = 2.5, np.inf
    lxy = np.r_[xyt[:1, :2], rng.uniform(-4, 4, (5, 2))]  # landmark 0 where robot 0 stays (it gets no command)
    lmap = {10 + i: (*lxy[i], 0.02, 0.03) for i in range(6)}
    noise = UnicycleNoise(q_v0=1e-3, q_lat0=1e-4, q_w0=1e-3)
    engines = {b: Engine("dekf", SE2.from_xytheta(xyt), cov, noise=noise, t0=t0, gate=0.99, backend=b, landmarks=lmap,
                         use_landmarks=use_landmarks) for b in ("numpy", "numba")}  # fmt: skip
    for k in range(1, 7):
        t = 0.5 * k
        x = engines["numpy"].a
        poses, marks = _outcome_mix(x, 20, rng), _landmark_mix(x, lxy, 12, rng)
        poses = poses.take(np.flatnonzero(poses.observer != 0))  # robot 0's estimate stays on landmark 0
        det = Detections.concat(poses, marks).canonical()
        some = np.sort(rng.choice(np.arange(1, n), 4, replace=False))
        step_both_and_compare(engines, t, det, (some, rng.uniform(0, 1, 4), rng.uniform(-1, 1, 4)))
    assert engines["numpy"].counts == engines["numba"].counts
    reasons = engines["numba"].reasons
    assert engines["numpy"].reasons == reasons
    if use_landmarks:
        assert reasons["unknown: the landmark is not in the map"] > 0
        assert reasons["rejected: degenerate geometry: the target is at the observer's position"] > 0
        assert engines["numba"].counts["gated"] > 5
    else:
        assert reasons["rejected: landmark measurements are switched off"] >= 50  # the observer started


def test_the_swarm_landmark_scene_is_consistent_with_its_map() -> None:
    """fusion_step's landmark detections (:func:`swarmloc.engine.swarm._landmark_scene`) are of the right landmarks:
    through a 0.999 gate at the true poses nearly all pass (a wrong landmark would be metres off)."""
    from swarmloc.engine.swarm import Swarm, _landmark_scene
    from swarmloc.lie import SE2

    sw = Swarm(2000, seed=3)
    lmap, det = _landmark_scene(sw, 2, 3)
    assert len(lmap) == 80 and len(det) == 4000
    eng = Engine("dekf", SE2.from_xytheta(sw.pose), np.broadcast_to(1e-8 * np.eye(3), (2000, 3, 3)).copy(),
                 noise=UnicycleNoise(), gate=0.999, landmarks=lmap)  # fmt: skip
    status = eng.fuse(0.0, det.canonical(), presorted=True)
    assert (status == 1).mean() > 0.99 and eng.counts["gated"] < 20


def test_numba_level_kernel_equals_the_one_thread_kernel_to_the_bit_on_a_swarm(monkeypatch) -> None:
    """``NumbaOps.fuse_levels`` (screening on one thread, then the groups of each Gauss-Seidel level in parallel,
    a neighbour with a larger id read in the snapshot) gives the states, clocks, outcomes and levels of the
    one-thread kernel ``fuse_serial`` to the bit: 3,000 robots, 3 neighbours and 1 map landmark each, gated, five
    stamps with new commands."""
    from swarmloc.engine import numba_ops
    from swarmloc.engine.swarm import SWARM_NOISE, _landmark_scene, _step_scene
    from swarmloc.lie import SE2

    n = 3000
    sw, det, v, w = _step_scene(n, 3, 4)
    lmap, seen = _landmark_scene(sw, 1, 4)
    every = Detections.concat(det, seen).canonical()
    cov = np.broadcast_to(np.diag([1e-3, 1e-3, 1e-3]), (n, 3, 3)).copy()
    engines, status, calls = {}, {}, []
    levels = numba_ops.NumbaOps.fuse_levels
    monkeypatch.setattr(numba_ops.NumbaOps, "fuse_levels", lambda self, *a: calls.append(1) or levels(self, *a))
    for name, threshold in (("serial", 10**9), ("levels", 0)):
        monkeypatch.setattr(numba_ops, "PARALLEL_MIN", threshold)
        eng = engines[name] = Engine("dekf", SE2.from_xytheta(sw.pose), cov, noise=SWARM_NOISE, gate=0.99,
                                     backend="numba", landmarks=lmap)  # fmt: skip
        rng = np.random.default_rng(1)
        status[name] = []
        for k in range(5):
            some = np.sort(rng.choice(n, n // 2, replace=False))
            eng.predict(some, 0.1 * k)
            status[name].append(eng.fuse(0.1 * k, every, presorted=True))
            eng.set_command(some, v[some] * rng.uniform(0.5, 1.5), w[some])
    assert len(calls) == 5  # the second engine's stamps, each on the level kernel (this needs two numba threads)
    one, two = engines["serial"], engines["levels"]
    for a, b in zip(status["serial"], status["levels"], strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(one.a, two.a)
    np.testing.assert_array_equal(one.b, two.b)
    np.testing.assert_array_equal(one.t, two.t)
    assert one.counts == two.counts and one.reasons == two.reasons
    assert one.last_levels == two.last_levels >= 4
    assert one.counts["fused"] > 10 * n and one.counts["gated"] > 0
