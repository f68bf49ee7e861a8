"""The engine's compiled replay (numba, ``dekf``: a whole timeline of stamps in one compiled loop) equals the nodes;
its in-place kernel, numpy's structure-of-arrays path and JAX fuse a robot's range-bearing as numpy's general path
and the nodes do, on every outcome; the bulk odometry check files and counts exactly what the record-by-record check
does."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_engine import _assert_same, _nodes, _source, mixed_targets, step_both_and_compare

from swarmloc.engine import Detections, Engine, run_engine
from swarmloc.engine.checks import Checked
from swarmloc.engine.codes import UNKNOWN_ROBOT
from swarmloc.engine.core import Engine as CoreEngine
from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.lie import SE2, wrap_angle
from swarmloc.motion import UnicycleNoise
from swarmloc.sensors.models import KIND_ORDER

# slow: the first test of the module compiles the engine's numba/JAX kernels
pytestmark = [pytest.mark.data, pytest.mark.slow]


RB = KIND_ORDER["range_bearing"]


def _count_steps(monkeypatch: pytest.MonkeyPatch) -> dict[str, int]:
    """Count :meth:`Engine.step` (the per-stamp path) and the compiled calls."""
    calls = {"step": 0, "compiled": 0}
    step, compiled = CoreEngine.step, CoreEngine.replay_timeline

    def counted_step(self, *a, **k):
        calls["step"] += 1
        return step(self, *a, **k)

    def counted_compiled(self, *a, **k):
        calls["compiled"] += 1
        return compiled(self, *a, **k)

    monkeypatch.setattr(CoreEngine, "step", counted_step)
    monkeypatch.setattr(CoreEngine, "replay_timeline", counted_compiled)
    return calls


def _rb_mix(x: np.ndarray, m: int, rng: np.random.Generator) -> Detections:
    """Range-bearing detections of robots at ``x (n, 3)`` with every outcome: near the truth (a fifth 5 m off, for
    the gate), of the observer itself, of an unusable target, of an unknown robot, and (robots 1 and 2 stand on one
    spot) degenerate; canonically sorted."""
    obs, tgt, special = mixed_targets(x.shape[0], m, rng)
    pair = (special > 0.25) & (special < 0.35)
    obs, tgt = np.where(pair, 1, obs), np.where(pair, 2, tgt)
    j = np.where(tgt >= 0, tgt, obs)
    dx, dy = x[j, 0] - x[obs, 0], x[j, 1] - x[obs, 1]
    z = np.zeros((m, 3))
    z[:, 0] = np.hypot(dx, dy) + rng.normal(scale=0.03, size=m) + np.where(rng.random(m) < 0.2, 5.0, 0.0)
    z[:, 1] = wrap_angle(np.arctan2(dy, dx) - x[obs, 2] + rng.normal(scale=0.02, size=m))
    R = np.zeros((m, 3, 3))
    A = rng.normal(size=(m, 2, 2))
    R[:, :2, :2] = 1e-3 * A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(2)
    return Detections(obs, tgt, np.full(m, RB, dtype=np.int64), z, R).canonical()


@pytest.mark.parametrize("parallel", [False, True])
def test_numba_robot_range_bearing_equals_numpy_on_every_outcome(monkeypatch: pytest.MonkeyPatch, parallel) -> None:
    """A robot's range-bearing in numba's in-place kernel (the landmark kernel at the neighbour's position and
    covariance) and on its level path equals numpy's stacked-matrix path: states, clocks, outcomes, reasons."""
    from swarmloc.engine import numba_ops

    if parallel:
        monkeypatch.setattr(numba_ops, "PARALLEL_MIN", 0)
    rng = np.random.default_rng(11)
    n = 9
    xyt = np.column_stack([rng.normal(size=(n, 2)), rng.uniform(-3, 3, n)])
    xyt[2, :2] = xyt[1, :2]  # robots 1 and 2 on one spot: their detections of each other are degenerate
    A = rng.normal(size=(n, 3, 3))
    cov = 1e-2 * A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
    t0 = np.zeros(n)
    t0[7], t0[8] = 2.5, np.inf  # starts late; never starts
    noise = UnicycleNoise(q_v0=1e-3, q_lat0=1e-4, q_w0=1e-3)
    engines = {b: Engine("dekf", SE2.from_xytheta(xyt), cov, noise=noise, t0=t0, gate=0.99, backend=b)
               for b in ("numpy", "numba")}  # fmt: skip
    for k in range(1, 7):
        t = 0.5 * k
        det = _rb_mix(engines["numpy"].a, 25, rng)
        det = det.take(np.flatnonzero(~np.isin(det.observer, [1, 2]) | ~np.isin(det.target, [1, 2]) | (k < 4)))
        some = np.sort(rng.choice(np.arange(3, n), 4, replace=False))  # robots 1 and 2 keep still
        step_both_and_compare(engines, t, det, (some, rng.uniform(0, 1, 4), rng.uniform(-1, 1, 4)))
    assert engines["numpy"].counts == engines["numba"].counts
    reasons = engines["numba"].reasons
    assert engines["numpy"].reasons == reasons
    assert reasons["rejected: degenerate geometry: the target is at the observer's position"] > 0
    assert all(engines["numba"].counts[k] >= 5 for k in ("fused", "gated", "rejected", "unknown"))


def test_compiled_replay_equals_the_nodes_and_steps_what_it_cannot_take(monkeypatch: pytest.MonkeyPatch) -> None:
    """Poses, range-bearings and absolute fixes run compiled; a stamp with a range-only or bearing-only detection
    (kinds the compiled kernel leaves to the general path) is stepped, and the compiled loop goes on after it. The
    result equals the nodes' (1e-10, the same counts and reasons: a detection of a robot outside the team is named
    as the nodes name it)."""
    src = _source(5, 10.0, 17, kinds=("pose", "range_bearing"), fixes=True)
    extra = [
        Detection(0, 2.25, "range", np.array([1.0]), np.array([[0.01]]), target=1),
        Detection(1, 3.0, "pose", np.array([1.0, 0.0, 0.0]), 0.01 * np.eye(3), target=42),  # not in the team
        Detection(3, 4.75, "bearing", np.array([0.3]), np.array([[0.01]]), target=4),
        Detection(2, 7.5, "range", np.array([2.0]), np.array([[0.04]]), target=0),
    ]
    src = dataclasses.replace(src, events=sorted([*src.events, *extra], key=lambda e: e.stamp))  # in time order
    calls = _count_steps(monkeypatch)
    ref, eng = _nodes(src, "dekf"), run_engine(src, "dekf", backend="numba")
    _assert_same(ref, eng)
    assert ref.reasons == eng.reasons
    assert eng.reasons["unknown: robot 42: robot 42 is not in the team"] == 1  # named as the nodes name it
    assert calls["step"] == 3 and calls["compiled"] == 4  # resumed after each stepped stamp
    assert ref.stats["fused"] > 100


@pytest.mark.parametrize("use_landmarks", [True, False])
def test_compiled_replay_equals_the_nodes_on_mrclam6(mrclam6, monkeypatch: pytest.MonkeyPatch, use_landmarks) -> None:
    """The first 120 s of MRCLAM dataset 6 (robots' and landmarks' range-bearings) in one compiled call."""
    src = load_source(f"mrclam:{mrclam6}", duration=120.0)
    calls = _count_steps(monkeypatch)
    ref = _nodes(src, "dekf") if use_landmarks else _nodes_off(src)
    eng = run_engine(src, "dekf", backend="numba", use_landmarks=use_landmarks)
    _assert_same(ref, eng)
    assert ref.reasons == eng.reasons
    assert calls == {"step": 0, "compiled": 1}
    assert eng.stats["fused"] > (2000 if use_landmarks else 300)


def _nodes_off(src):
    from swarmloc.estimators import make_team, node_options
    from swarmloc.runner import run

    opts = {**node_options("dekf", src.config, src.landmarks), "use_landmarks": False}
    return run(make_team("dekf", src.initial, **opts), src.events, record_times=src.record_times(), truth=src.truth)


def _messy_odometry(src):
    """``src``'s events with odometry no bulk check may take for robots 1-4 (a string speed, a NaN, an overlap in
    t0 order, an exact duplicate), an unknown robot's record, and robot 0's speeds as numpy floats with a gap
    (a stop) and a record of no length."""
    out, seen, last0 = [], set(), None
    for e in src.events:
        if not isinstance(e, Odometry):
            out.append(e)
            continue
        first = e.robot not in seen
        seen.add(e.robot)
        if e.robot == 0:
            if 3.0 <= e.t0 < 4.0:
                continue  # a gap: a stop at its start
            if 4.0 <= e.t0 and last0 is not None:  # the record before the gap lasts no time: no stop at its end
                out[last0] = dataclasses.replace(out[last0], t1=out[last0].t0)
                last0 = None
            e = dataclasses.replace(e, v=np.float64(e.v), w=np.float64(e.w))
            if e.t0 < 3.0:
                last0 = len(out)
        elif e.robot == 1 and first:
            e = dataclasses.replace(e, v="fast")
        elif e.robot == 2 and first:
            e = dataclasses.replace(e, w=math.nan)
        elif e.robot == 3 and first:  # in t0 order, but it ends after the next one starts
            e = dataclasses.replace(e, t1=e.t1 + 0.5 * (e.t1 - e.t0))
        elif e.robot == 4 and first:
            out.append(e)
        out.append(e)
    out.append(Odometry(99, 1.0, 1.1, 0.1, 0.0))
    return dataclasses.replace(src, events=out)


def test_bulk_odometry_check_files_and_counts_what_the_sequential_one_does(monkeypatch: pytest.MonkeyPatch) -> None:
    src = _messy_odometry(_source(5, 6.0, 23))
    col = {r: i for i, r in enumerate(src.robots)}
    one, bulk = Checked(col, lambda lid: UNKNOWN_ROBOT), Checked(col, lambda lid: UNKNOWN_ROBOT)
    for e in src.events:
        one.add(e)
    bulk.add_all(src.events)
    assert bulk.bulk_rows == {0}  # only robot 0's odometry is clean
    for c in (one, bulk):
        c.stops(6.0)
    assert one.counts == bulk.counts and one.reasons == bulk.reasons
    assert one.counts["odometry_stops"] >= 1 and one.counts["unknown_robot"] == 1
    for why in ("non-finite or non-numeric", "overlaps the odometry interval", "duplicate"):
        assert any(why in k for k in one.reasons), why
    assert one.by_stamp() == bulk.by_stamp()
    assert one.timeline.intervals() == bulk.timeline.intervals()
    first = np.full(len(col), math.inf)
    for e in src.events:
        r = e.robot if isinstance(e, Odometry) else e.observer if isinstance(e, Detection) else None
        s = e.stamp if isinstance(e, Odometry | Detection) else None
        if r in col and isinstance(s, float) and math.isfinite(s):
            first[col[r]] = min(first[col[r]], s)
    np.testing.assert_array_equal(bulk.start_times(), first)
    calls = _count_steps(monkeypatch)
    _assert_same(_nodes(src, "dekf"), run_engine(src, "dekf", backend="numba"))
    assert calls["step"] == 0


@pytest.mark.parametrize("backend", ["numpy", "jax"])
def test_fast_paths_fuse_a_robots_range_bearing_as_the_nodes(monkeypatch: pytest.MonkeyPatch, backend) -> None:
    """numpy's structure-of-arrays path (forced for every batch) and JAX's device stamp fuse a robot's range-bearing
    with the landmark formulas at the neighbour's position and covariance: equal to the nodes (1e-10, same counts)."""
    from swarmloc.engine import backends, fuse_ekf, jax_stamp
    from swarmloc.sensors.models import KIND_ORDER

    monkeypatch.setattr(fuse_ekf, "SOA_MIN_ROWS", 0)
    rows = []
    if backend == "numpy":  # the landmark kernel's rows
        kernel = backends.NumpyOps.landmark_update

        def counted(self, x, *a, **k):
            rows.append(x.shape[0])
            return kernel(self, x, *a, **k)

        monkeypatch.setattr(backends.NumpyOps, "landmark_update", counted)
    else:  # the device stamp's range-bearing rows
        stamp = jax_stamp.DeviceStamp.__call__

        def counted(self, state, t, move, det, *a, **k):
            rows.append(int((det.kind == KIND_ORDER["range_bearing"]).sum()))
            return stamp(self, state, t, move, det, *a, **k)

        monkeypatch.setattr(jax_stamp.DeviceStamp, "__call__", counted)
    src = _source(4, 10.0, 11, kinds=("pose", "range_bearing"), fixes=True)
    ref = _nodes(src, "dekf")
    _assert_same(ref, run_engine(src, "dekf", backend=backend))
    n_rb = sum(1 for e in src.events if isinstance(e, Detection) and e.kind == "range_bearing")
    assert 0.95 * n_rb <= sum(rows) <= n_rb  # the robots' range-bearings went through the landmark formulas
