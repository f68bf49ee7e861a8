"""The batched engine equals the per-robot nodes (means and covariances to 1e-10 at every record time, same outcome
counts), its structure-of-arrays kernels equal the kernels, its backends agree, and the swarm helpers run."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from swarmloc.datasets.source import Source
from swarmloc.engine import Detections, Engine, fuse_ekf, fusion_step, run_engine, soa, swarm_run
from swarmloc.engine.core import levels
from swarmloc.engine.swarm import neighbour_pairs
from swarmloc.estimators import make_team, node_options
from swarmloc.kernels import cartesian as C
from swarmloc.lie import SE2, wrap_angle
from swarmloc.motion import UnicycleNoise
from swarmloc.runner import RunResult, run
from swarmloc.sensors import models
from swarmloc.sim import AbsoluteSensor, RelativeSensor, random_team
from swarmloc.sim.source import sim_source

pytestmark = pytest.mark.unit


TOL = 1e-10
COUNTS = ("detections", "fused", "gated", "rejected", "unknown", "odometry", "odometry_used", "recorded")


def fixed_noise(src: Source) -> Source:
    """``src`` with ``diekf``'s process noise fixed (``[filter] diekf_adaptive = false``): the engine's replay does
    not scale it (it refuses the default median scale where landmarks are fused), so the nodes it is held equal to
    run it fixed too."""
    return dataclasses.replace(src, config=src.config.with_filter(diekf_adaptive=False))


def _source(n: int, duration: float, seed: int, kinds: tuple[str, ...] = ("pose",), fixes: bool = False) -> Source:
    absolute = AbsoluteSensor(robots=(0, n - 1), rate=2.0) if fixes else None
    sim = random_team(n, duration, seed=seed, area=3.0, sensor=RelativeSensor(rate=5.0, kinds=kinds), absolute=absolute)
    return sim_source(sim, "sim:test")


def _nodes(src: Source, estimator: str) -> RunResult:
    nodes = make_team(estimator, src.initial, **node_options(estimator, src.config, src.landmarks))
    return run(nodes, src.events, record_times=src.record_times(), truth=src.truth)


def _assert_same(a: RunResult, b: RunResult) -> None:
    assert sorted(a.tracks) == sorted(b.tracks)
    for r, ta in a.tracks.items():
        tb = b.tracks[r]
        np.testing.assert_array_equal(ta.times, tb.times)
        assert ta.times.size > 0
        np.testing.assert_allclose(ta.mean[:, :2], tb.mean[:, :2], rtol=0, atol=TOL)
        assert np.abs(wrap_angle(ta.mean[:, 2] - tb.mean[:, 2])).max() <= TOL
        np.testing.assert_allclose(ta.cov, tb.cov, rtol=0, atol=TOL)
        np.testing.assert_array_equal(ta.truth, tb.truth)
    assert {k: a.stats[k] for k in COUNTS} == {k: b.stats[k] for k in COUNTS}


CASES = [  # (estimator, robots, duration [s], seed)
    ("dekf", 4, 20.0, 0),
    ("dekf", 5, 15.0, 1),
    ("dekf", 6, 10.0, 2),
    ("expfusion", 4, 20.0, 3),
    ("expfusion", 5, 15.0, 4),
    ("expfusion", 6, 10.0, 5),
    ("ci", 4, 10.0, 6),
    ("ci", 5, 10.0, 7),
]


@pytest.mark.parametrize(("estimator", "n", "duration", "seed"), CASES)
def test_engine_equals_nodes_relative_pose(estimator: str, n: int, duration: float, seed: int) -> None:
    src = _source(n, duration, seed)
    ref = _nodes(src, estimator)
    eng = run_engine(src, estimator)
    _assert_same(ref, eng)
    assert ref.stats["fused"] > 50


@pytest.mark.parametrize("estimator", ["dekf", "expfusion", "ci"])
def test_engine_equals_nodes_range_bearing_and_fixes(estimator: str) -> None:
    kinds = ("range_bearing",) if estimator == "ci" else ("pose", "range_bearing")
    src = _source(4, 10.0, 11, kinds=kinds, fixes=True)
    ref = _nodes(src, estimator)
    _assert_same(ref, run_engine(src, estimator))
    assert ref.stats["fused"] > 50


@pytest.mark.parametrize("kinds", [("pose",), ("range_bearing",)])
def test_ci_weight_rule_is_the_class_attribute_and_both_drivers_follow_it(
    monkeypatch: pytest.MonkeyPatch, kinds: tuple[str, ...]
) -> None:
    """``ExpCI.ci_weight`` decides the weight rule for the node and the engine alike: with ``"search"`` both give
    the same result, and it differs from the closed form (so the attribute is not decoration)."""
    from swarmloc.estimators.ci import ExpCI

    src = _source(4, 6.0, 21, kinds=kinds)
    closed = _nodes(src, "ci")
    monkeypatch.setattr(ExpCI, "ci_weight", "search")
    searched = _nodes(src, "ci")
    _assert_same(searched, run_engine(src, "ci"))
    diff = max(np.abs(searched.tracks[r].cov - closed.tracks[r].cov).max() for r in closed.tracks)
    assert diff > 1e-8
    monkeypatch.setattr(ExpCI, "ci_weight", "golden")
    with pytest.raises(ValueError, match="golden"):
        run_engine(src, "ci")


@pytest.mark.parametrize("estimator", ["dekf", "expfusion"])
def test_engine_keeps_the_nodes_odometry_contract(estimator: str) -> None:
    """Gaps, an early end and an overlap in the odometry: the engine stops the robot at ``t1`` and refuses the
    overlap as the nodes do, so both drivers still agree (and count the same stops and refusals)."""
    import dataclasses

    from swarmloc.events import Odometry

    src = _source(4, 10.0, 31)
    events, extra = [], None
    for e in src.events:
        if isinstance(e, Odometry) and ((e.robot == 1 and 3.0 <= e.t0 < 5.0) or (e.robot == 2 and e.t0 >= 6.0)):
            continue  # a gap in robot 1's odometry; robot 2's odometry ends at 6 s
        if isinstance(e, Odometry) and e.robot == 3 and extra is None and e.t0 >= 4.0:
            extra = dataclasses.replace(e, t0=e.t0 + 0.5 * (e.t1 - e.t0), t1=e.t1 + 0.5 * (e.t1 - e.t0), v=2.0)
            events += [e, extra]  # overlaps the record before it and the one after
            continue
        events.append(e)
    src = dataclasses.replace(src, events=events)
    ref, eng = _nodes(src, estimator), run_engine(src, estimator)
    _assert_same(ref, eng)
    assert ref.stats["odometry_stops"] == eng.stats["odometry_stops"] == 2
    assert ref.stats["odometry_rejected"] == eng.stats["odometry_rejected"] == 1
    assert any("overlaps" in k for k in eng.reasons)


def test_engine_kernel_path_equals_nodes() -> None:
    """``fast=False``: the EKF through the stacked-matrix kernels of swarmloc.kernels.cartesian."""
    src = _source(5, 10.0, 12, kinds=("pose", "range_bearing"), fixes=True)
    _assert_same(_nodes(src, "dekf"), run_engine(src, "dekf", fast=False))


def test_engine_structure_of_arrays_path_equals_nodes(monkeypatch: pytest.MonkeyPatch) -> None:
    """The numpy structure-of-arrays EKF path (taken by large batches only) on a small team."""
    monkeypatch.setattr(fuse_ekf, "SOA_MIN_ROWS", 0)
    src = _source(5, 10.0, 15, fixes=True)
    _assert_same(_nodes(src, "dekf"), run_engine(src, "dekf"))


def test_engine_is_gauss_seidel_in_observer_order() -> None:
    """Mutual detections at one stamp, fused in one call, equal robot 0's group first and then robot 1's (which
    sees robot 0's updated belief), not both from the beliefs before the stamp."""
    mean = SE2.from_xytheta(np.array([[0.0, 0.0, 0.1], [1.0, 0.2, -0.3], [0.0, 1.0, 2.0]]))
    cov = np.stack([np.diag([1e-2, 2e-2, 1e-2]), np.diag([3e-2, 1e-2, 2e-2]), np.diag([1e-3, 1e-3, 1e-3])])
    R = np.diag([1e-3, 1e-3, 1e-4])
    rel = lambda i, j: SE2.to_xytheta(SE2.inverse(mean[i]) @ mean[j]) + 0.01  # noqa: E731
    det = Detections.poses(np.array([2, 1, 0]), np.array([1, 0, 1]), np.stack([rel(2, 1), rel(1, 0), rel(0, 1)]), R)
    for estimator in ("expfusion", "dekf", "ci"):
        one = Engine(estimator, mean, cov, noise=UnicycleNoise(), gate=None)
        one.fuse(0.0, det)
        assert one.last_levels == 3  # 0, then 1 (detects 0), then 2 (detects 1)
        seq = Engine(estimator, mean, cov, noise=UnicycleNoise(), gate=None)
        for k in (2, 1):  # robot 0's group, then robot 1's, then robot 2's
            seq.fuse(0.0, det.take(np.array([k])))
        seq.fuse(0.0, det.take(np.array([0])))
        np.testing.assert_allclose(one.a, seq.a, rtol=0, atol=1e-14)
        np.testing.assert_allclose(one.b, seq.b, rtol=0, atol=1e-14)
        jacobi = Engine(estimator, mean, cov, noise=UnicycleNoise(), gate=None)
        jacobi.fuse(0.0, det.take(np.array([1])))  # robot 1's group against robot 0's belief before the stamp
        assert np.abs(jacobi.b[1] - one.b[1]).max() > 1e-6


def test_levels_longest_path() -> None:
    # 0 -> 1 -> 2 -> 4, 0 -> 3; 5 alone
    src, dst = np.array([0, 1, 2, 0]), np.array([1, 2, 4, 3])
    np.testing.assert_array_equal(levels(6, src, dst), [0, 1, 2, 1, 3, 0])
    np.testing.assert_array_equal(levels(3, np.zeros(0, int), np.zeros(0, int)), [0, 0, 0])


def _up(P: np.ndarray) -> tuple[np.ndarray, ...]:
    return tuple(P[:, i, j] for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))


def test_soa_kernels_equal_kernels() -> None:
    rng = np.random.default_rng(0)
    noise = UnicycleNoise(q_v0=1e-3, q_v1=2e-3, q_v2=1e-3, q_lat0=1e-4, q_lat1=1e-4, q_w0=1e-3, q_w1=1e-3,
                          q_w2=1e-3, q_wv=1e-3)  # fmt: skip
    B = 300
    x = np.column_stack([rng.normal(size=(B, 2)), rng.uniform(-np.pi, np.pi, B)])
    A = rng.normal(size=(B, 3, 3))
    P = 0.01 * A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
    v, w, dt = rng.uniform(-1, 1, B), rng.uniform(-3, 3, B), rng.uniform(0, 2, B)
    w[:10], w[10:20], dt[:5] = 0.0, w[10:20] * 1e-7, 0.0
    xs, ps = soa.predict(np, tuple(x.T), _up(P), v, w, dt, noise)
    for i in range(B):
        if dt[i] > 0:
            xr, Pr, _, _ = C.predict_one(x[i], P[i], float(v[i]), float(w[i]), float(dt[i]), noise)
        else:
            xr, Pr = x[i], P[i]
        np.testing.assert_allclose([a[i] for a in xs], xr, rtol=0, atol=1e-12)
        np.testing.assert_allclose([a[i] for a in ps], Pr[np.triu_indices(3)], rtol=0, atol=1e-14)

    xk, Pk = x + 0.5 * rng.normal(size=(B, 3)), P[::-1].copy()
    z = 0.5 * rng.normal(size=(B, 3))
    Rz = np.broadcast_to(np.diag([0.01, 0.02, 0.003]), (B, 3, 3))
    xn, pn, nis, ok = soa.pose_update(np, tuple(x.T), _up(P), tuple(xk.T), _up(Pk), tuple(z.T), _up(Rz))
    h, Hi, Hk = models.predict("pose", x, xk)
    Reff = models.pose_noise_to_cartesian(z, Rz) + Hk @ Pk @ np.swapaxes(Hk, 1, 2)
    xr, Pr, nr, okr = C.kalman_update(x, P, models.residual("pose", z, h), Hi, Reff)
    np.testing.assert_allclose(np.stack(xn, -1), xr, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.stack(pn, -1), Pr[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]], rtol=0, atol=1e-14)
    np.testing.assert_allclose(nis, nr, rtol=1e-12)
    assert ok.all() and okr.all()

    xn, pn, nis, ok = soa.absolute_update(np, tuple(x.T), _up(P), tuple(xk.T), _up(Rz))
    xr, Pr, nr, _ = C.kalman_update(x, P, models.residual("pose", xk, x), np.broadcast_to(np.eye(3), P.shape), Rz)
    np.testing.assert_allclose(np.stack(xn, -1), xr, rtol=0, atol=1e-12)
    np.testing.assert_allclose(nis, nr, rtol=1e-12)


def test_one_compiled_prediction_serves_every_noise_model() -> None:
    """The compiled prediction takes the noise model's coefficients at run time: two models (every coefficient set,
    and the defaults) through one compiled function, each equal to the numpy formulas of its own model, and numba
    compiled it once (a replay's loops call it, so a second model in a process compiles nothing)."""
    from swarmloc.engine.joint import predict_kernel
    from swarmloc.engine.replay_io import noise_tuple

    rng = np.random.default_rng(4)
    B = 50
    x = np.column_stack([rng.normal(size=(B, 2)), rng.uniform(-np.pi, np.pi, B)])
    A = rng.normal(size=(B, 3, 3))
    P = 0.01 * A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
    v, w, dt = rng.uniform(-1, 1, B), rng.uniform(-3, 3, B), rng.uniform(0, 2, B)
    w[:5] = 0.0
    every = UnicycleNoise(q_v0=1e-3, q_v1=2e-3, q_v2=3e-3, q_lat0=1e-4, q_lat1=2e-4, q_w0=1e-3, q_w1=4e-3,
                          q_w2=5e-3, q_wv=6e-3)  # fmt: skip
    kernel = predict_kernel()
    outs = []
    for noise in (every, UnicycleNoise()):
        xs, ps = soa.predict(np, tuple(x.T), _up(P), v, w, dt, noise)
        ref = np.column_stack([*xs, *ps])
        got = np.array([kernel(*x[i], *P[i][np.triu_indices(3)], v[i], w[i], dt[i], noise_tuple(noise))
                        for i in range(B)])  # fmt: skip
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-14)
        outs.append(got)
    assert np.abs(outs[0][:, 3:] - outs[1][:, 3:]).min() > 0  # the models' covariances differ everywhere
    assert len(kernel.signatures) == 1


def test_jax_backend_equals_numpy() -> None:
    """jax is in the dev extra: this runs in CI, not skipped."""
    src = _source(5, 10.0, 13, fixes=True)
    a = run_engine(src, "dekf")
    b = run_engine(src, "dekf", backend="jax")
    _assert_same(a, b)


def test_numba_backend_equals_numpy() -> None:
    """numba is in the dev extra: this runs in CI, not skipped."""
    src = _source(5, 10.0, 14, fixes=True)
    _assert_same(_nodes(src, "dekf"), run_engine(src, "dekf", backend="numba"))


def test_engine_refuses_what_it_cannot_do() -> None:
    mean = np.broadcast_to(np.eye(3), (2, 3, 3))
    cov = np.broadcast_to(1e-3 * np.eye(3), (2, 3, 3))
    noise = UnicycleNoise()
    with pytest.raises(ValueError, match="rdl"):
        Engine("rdl", mean, cov, noise=noise)
    with pytest.raises(ValueError, match="landmarks"):
        Engine("expfusion", mean, cov, noise=noise, landmarks={1: (0.0, 0.0, 0.1, 0.1)})
    with pytest.raises(ValueError, match="fast EKF"):
        Engine("expfusion", mean, cov, noise=noise, backend="jax")


@pytest.mark.parametrize("estimator", ["cekf", "iekf", "diekf", "rdl"])
def test_replayed_estimators_name_the_one_backend_that_replays_them(estimator: str) -> None:
    """``cekf``, ``iekf``, ``diekf`` (in clusters too) and ``rdl`` run on the engine as numba's compiled replay only:
    any other backend is refused before a replay starts, by a ValueError naming numba and the backend given."""
    src = _source(3, 1.0, 3)
    for backend in ("numpy", "jax", "jax32"):
        for opts in ({}, {"cluster": 2}) if estimator == "diekf" else ({},):
            with pytest.raises(ValueError, match=rf"'{estimator}' .*backend='numba'.* not backend='{backend}'"):
                run_engine(src, estimator, backend=backend, **opts)


def test_neighbour_pairs_are_the_k_nearest_within_range() -> None:
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 6, (80, 2))
    obs, tgt = neighbour_pairs(xy, 3, 1.5)
    d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    for i in range(80):
        near = np.argsort(d[i])[:3]
        want = sorted(j for j in near if d[i, j] <= 1.5)
        assert tgt[obs == i].tolist() == want
    assert np.all(np.diff(obs) >= 0)


def test_swarm_run_and_fusion_step() -> None:
    out = swarm_run(60, 30, seed=1)
    for key in ("wall_sim_s", "wall_est_s", "robot_updates", "peak_mem_bytes", "n", "steps"):
        assert key in out
    assert out["robot_updates"] == 60 * 30 and out["n"] == 60 and out["steps"] == 30
    assert out["fused"] > 0.9 * out["detections"] > 0
    assert out["pos_rmse_m"] < 0.2
    fs = fusion_step(200, repeats=1)
    assert fs["n"] == 200 and fs["robot_updates_per_s"] > 0 and fs["levels"] >= 1


def mixed_targets(n: int, m: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``m`` observers and targets among ``n`` robots, a tenth of the targets unusable, a tenth unknown, a twentieth
    the observer itself; and the uniform draw ``special`` that chose them (for further kinds of detection)."""
    from swarmloc.engine.codes import UNKNOWN_ROBOT, UNUSABLE

    obs = rng.integers(0, n, m)
    tgt = rng.integers(0, n, m)
    special = rng.random(m)
    tgt = np.where(special < 0.1, UNUSABLE, np.where(special < 0.2, UNKNOWN_ROBOT, tgt))
    return obs, np.where((special > 0.2) & (special < 0.25), obs, tgt), special


def _outcome_mix(x: np.ndarray, m: int, rng: np.random.Generator) -> Detections:
    """Detections of every screening outcome for robots at ``x (n, 3)``: absolute fixes and relative poses near
    the truth ``x`` (a fifth of them 5 m off, for the gate), poses of the observer itself, of an unusable target and
    of an unknown robot; canonically sorted."""
    from swarmloc.engine.codes import ABSOLUTE, NO_TARGET, POSE

    obs, tgt, special = mixed_targets(x.shape[0], m, rng)
    absolute = special > 0.85
    tgt = np.where(absolute, NO_TARGET, tgt)
    kind = np.where(absolute, ABSOLUTE, POSE).astype(np.int64)
    j = np.where(tgt >= 0, tgt, obs)
    c, s = np.cos(x[obs, 2]), np.sin(x[obs, 2])
    dx, dy = x[j, 0] - x[obs, 0], x[j, 1] - x[obs, 1]
    rel = np.column_stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(x[j, 2] - x[obs, 2])])
    z = np.where(absolute[:, None], x[obs], rel) + rng.normal(scale=0.03, size=(m, 3))
    z += np.where(rng.random((m, 1)) < 0.2, 5.0, 0.0)
    A = rng.normal(size=(m, 3, 3))
    R = 1e-3 * A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
    return Detections(obs, tgt, kind, z, R).canonical()


def step_both_and_compare(engines: dict[str, Engine], t: float, det: Detections, cmd: tuple) -> None:
    """One stamp ``t`` through the ``"numpy"`` and ``"numba"`` engines (the robots of ``cmd`` predicted, ``det``
    fused, then ``cmd`` set); their outcomes, levels, clocks, states (1e-12) and commands must agree."""
    status = {}
    for b, eng in engines.items():
        eng.predict(cmd[0], t)
        status[b] = eng.fuse(t, det, presorted=True)
        eng.set_command(*cmd)
    np.testing.assert_array_equal(status["numpy"], status["numba"])
    one, two = engines["numpy"], engines["numba"]
    assert one.last_levels == two.last_levels
    np.testing.assert_array_equal(one.t, two.t)
    np.testing.assert_allclose(one.a, two.a, rtol=0, atol=1e-12)
    np.testing.assert_allclose(one.b, two.b, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(one.v, two.v)


@pytest.mark.parametrize("parallel", [False, True])
def test_numba_in_place_kernels_equal_numpy_on_every_outcome(monkeypatch: pytest.MonkeyPatch, parallel: bool) -> None:
    """The numba backend's in-place path (screening, prediction and fusion in one kernel, Gauss-Seidel without
    levels) and its level-parallel path equal numpy: states, clocks, outcome and reason codes, counts, levels."""
    from swarmloc.engine import numba_ops

    if parallel:
        monkeypatch.setattr(numba_ops, "PARALLEL_MIN", 0)
    rng = np.random.default_rng(3)
    n = 9
    mean = SE2.from_xytheta(np.column_stack([rng.normal(size=(n, 2)), rng.uniform(-3, 3, n)]))
    A = rng.normal(size=(n, 3, 3))
    cov = 1e-2 * A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
    t0 = np.zeros(n)
    t0[7], t0[8] = 2.5, np.inf  # starts late; never starts
    noise = UnicycleNoise(q_v0=1e-3, q_lat0=1e-4, q_w0=1e-3)
    engines = {b: Engine("dekf", mean, cov, noise=noise, t0=t0, gate=0.99, backend=b) for b in ("numpy", "numba")}
    for k in range(1, 7):
        t = 0.5 * k
        det = _outcome_mix(engines["numpy"].a, 25, rng)
        some = np.sort(rng.choice(n, 4, replace=False))  # commands for some robots; the others keep theirs
        cmd = (some, rng.uniform(0, 1, 4), rng.uniform(-1, 1, 4))
        step_both_and_compare(engines, t, det, cmd)
    assert engines["numpy"].counts == engines["numba"].counts
    assert engines["numpy"].reasons == engines["numba"].reasons
    assert all(engines["numba"].counts[k] >= 5 for k in ("fused", "gated", "rejected", "unknown"))
    assert len(engines["numba"].reasons) >= 4


def test_jax_compiles_once_per_power_of_two_bucket() -> None:
    """Batches of 1 to 300 rows (every size, in random order) compile each kernel once per padded size: the
    powers of two from 8 to 512 (7 buckets), not once per batch size; the padded rows do not reach the results."""
    from swarmloc.engine.backends import JaxOps, NumpyOps

    rng = np.random.default_rng(4)
    noise = UnicycleNoise(q_v0=1e-3, q_lat0=1e-4, q_w0=1e-3)
    jx, ref = JaxOps(noise), NumpyOps(noise)
    sizes = rng.permutation(np.arange(1, 301))
    for b in sizes[:60].tolist() + [1, 8, 9, 300]:
        x = np.column_stack([rng.normal(size=(b, 2)), rng.uniform(-3, 3, b)])
        A = rng.normal(size=(b, 3, 3))
        P = 1e-2 * A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
        v, w, dt = rng.uniform(0, 1, b), rng.uniform(-1, 1, b), np.full(b, 0.1)
        for got, want in zip(jx.predict(x, P, v, w, dt), ref.predict(x, P, v, w, dt), strict=True):
            assert got.shape == want.shape
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        got = jx.pose_update(x, P, x[::-1], P[::-1], x, P)
        want = ref.pose_update(x, P, x[::-1], P[::-1], x, P)
        for g, r in zip(got, want, strict=True):
            np.testing.assert_allclose(g, r, rtol=0, atol=1e-9)
        jx.absolute_update(x, P, x + 0.1, P)
    buckets = {max(8, 1 << (int(b) - 1).bit_length()) for b in [*sizes[:60].tolist(), 1, 8, 9, 300]}
    assert len(buckets) <= 7
    assert jx.compiles == {"predict": len(buckets), "pose": len(buckets), "absolute": len(buckets)}
    x, P, v, w, dt = x[:8], P[:8], v[:8], w[:8], dt[:8]  # a full bucket: nothing padded
    jx.predict(x, P, v.astype(np.float32), w, dt)  # another dtype is cast, not compiled again
    jx.predict(x, P, (100 * v).astype(np.int64), w, dt)
    assert jx.compiles["predict"] == len(buckets)
