"""The compiled replays with JAX (``run_engine(source, "cekf" | "iekf" | "diekf" | "rdl", backend="jax")``,
:mod:`swarmloc.engine.jax_joint`, :mod:`swarmloc.engine.jax_pairs`): equal to the nodes and to numba's compiled
loops (every recorded belief, every outcome count and reason) on every detection kind of robots and landmarks, a
robot that starts late and MRCLAM; ``rdl``'s pair prior equal to the node's on every branch; one compilation per
bucket of events; many runs at once (``jax.vmap``) equal to each run alone."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_engine import _source
from test_engine_cekf import _same, _same_on_mrclam, _with, robot_extras
from test_engine_invariant import _nodes
from test_engine_rdl import _nodes as _rdl_nodes
from test_engine_rdl import pair_cases

from swarmloc.engine import jax_replay, joint_inputs, run_engine
from swarmloc.engine.jax_joint import replay_joint_batch, replay_joint_jax
from swarmloc.engine.jax_pairs import _prior, replay_rdl_batch, replay_rdl_jax
from swarmloc.engine.jax_stamp import import_jax
from swarmloc.estimators.rdl import joint_prior
from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source

# slow: the first test of the module compiles the engine's numba/JAX kernels
pytestmark = [pytest.mark.data, pytest.mark.slow]


import_jax()  # float64
import jax.numpy as jnp  # noqa: E402

COMPILED = ("cekf", "iekf", "diekf", "rdl")


@pytest.mark.parametrize("estimator", COMPILED)
def test_jax_replay_equals_the_nodes_on_robots_of_every_kind(estimator) -> None:
    """Relative poses, range-bearing, range-only, bearing-only of robots and absolute fixes, a robot outside the
    team, the observer itself, no target id, far-off readings (gated); and relative measurements switched off."""
    src = _with(_source(5, 10.0, 17, kinds=("pose", "range_bearing"), fixes=True), robot_extras())
    ref = _rdl_nodes(src) if estimator == "rdl" else _nodes(estimator, src)
    jx = run_engine(src, estimator, backend="jax")
    _same(ref, jx)
    assert jx.estimator == f"{estimator}/engine"
    assert jx.stats["gated"] >= 2 and jx.stats["fused"] > 500
    assert jx.reasons["rejected: the target is the observer itself"] == 1
    off = run_engine(src, estimator, backend="jax", use_relative=False)
    _same(run_engine(src, estimator, backend="numba", use_relative=False), off)
    assert off.stats["fused"] > 0 and off.stats["rejected"] > 500


@pytest.mark.parametrize("estimator", ("cekf", "diekf", "rdl"))
def test_jax_replay_equals_numba_with_landmarks(estimator) -> None:
    """Landmarks' range-bearing, range and bearing, two of them missing from the map (``unknown``), one at an
    observer's position (degenerate), the pose of a landmark; landmarks switched off."""
    src = load_source("sim:landmarks", robots=4, duration=12.0, seed=5)
    ids = sorted(src.landmarks)
    x0, y0 = src.initial[0].mean[:2, 2]
    eye = 0.01 * np.eye(3)
    extra = [
        Detection(0, src.t_start, "range_bearing", np.array([0.5, 0.0]), eye[:2, :2], target=999,
                  target_is_robot=False),
        Detection(1, 2.0, "pose", np.array([1.0, 0.0, 0.0]), eye, target=ids[3], target_is_robot=False),
    ]  # fmt: skip
    part = {k: v for k, v in src.landmarks.items() if k not in ids[:2]}
    src = _with(src, extra, landmarks={**part, 999: (float(x0), float(y0), 0.0, 0.0)})
    for use in (True, False):
        ref = run_engine(src, estimator, backend="numba", use_landmarks=use)
        jx = run_engine(src, estimator, backend="jax", use_landmarks=use)
        _same(ref, jx)
        assert jx.stats["fused"] > (350 if use else 100)
    assert jx.reasons["rejected: landmark measurements are switched off"] > 400


def test_jax_diekf_equals_the_nodes_when_a_robot_starts_late() -> None:
    """Robot 2's inputs begin at 4 s: ``diekf``'s teammates get ``unknown`` before, ``iekf`` starts it with the
    team."""
    src = _source(4, 10.0, 23, kinds=("pose", "range_bearing"))
    own = [(isinstance(e, Odometry) and e.robot == 2) or (isinstance(e, Detection) and e.observer == 2)
           for e in src.events]  # fmt: skip
    src = dataclasses.replace(src, events=[e for e, mine in zip(src.events, own, strict=True)
                                           if not (mine and e.stamp < 4.0)])  # fmt: skip
    for estimator in ("iekf", "diekf"):
        jx = run_engine(src, estimator, backend="jax")
        _same(_nodes(estimator, src), jx)
        early = sum(v for k, v in jx.reasons.items() if k.startswith("unknown: robot 2: stamp"))
        assert (early > 10) if estimator == "diekf" else (early == 0)


@pytest.mark.parametrize("estimator", ("diekf", "rdl"))
@pytest.mark.parametrize("use_landmarks", [True, False])
def test_jax_replay_equals_numba_on_mrclam6(mrclam6, estimator, use_landmarks) -> None:
    """The first 60 s of MRCLAM dataset 6."""
    src = load_source(f"mrclam:{mrclam6}", duration=60.0)
    ref = run_engine(src, estimator, backend="numba", use_landmarks=use_landmarks)
    jx = run_engine(src, estimator, backend="jax", use_landmarks=use_landmarks)
    _same_on_mrclam(ref, jx)
    assert jx.stats["fused"] > (1000 if use_landmarks else 150)


def test_jax_pair_prior_equals_the_nodes_on_every_branch() -> None:
    """``rdl``'s pair prior against :func:`swarmloc.estimators.rdl.joint_prior` (test_engine_rdl's cases for numba):
    a tracked positive-definite cross-covariance, one that is not (covariance intersection), a met pair with a
    dropped factor, a target tracking a pair the observer never met; both gain, only the observer, neither. Two-row
    measurements padded to three rows as the scan pads them."""
    seen = {"tracked": 0, 1: 0, 0: 0, -1: 0}
    for Pi, Pj, fi, fj, met, H, R in pair_cases(120):
        m = H.shape[0]
        H3, R3 = np.zeros((3, 6)), np.eye(3)
        H3[:m], R3[:m, :m] = H, R
        P, flag = (np.asarray(a) for a in _prior(jnp, Pi, Pj, fi, fj, met, H3, R3))
        ref = joint_prior(Pi, Pj, fi, fj, H, R, met)
        if ref is None:
            assert flag == -1
        else:
            np.testing.assert_allclose(P, ref[0], rtol=1e-12, atol=1e-15)
            assert flag == int(ref[1])
            if ref[1] and np.allclose(P[:3, 3:], fi @ fj.T):
                seen["tracked"] += 1
                continue
        seen[int(flag)] += 1
    assert min(seen.values()) >= 3, seen


def test_jax_pair_update_where_only_the_observer_gains() -> None:
    """An unknown correlation (the pair met, the observer's factor dropped) and a target far more certain than the
    measurement: covariance intersection gains the observer only. The observer takes the Joseph update of that prior
    (numpy here), drops its factor for the target; the target is untouched."""
    from swarmloc.engine.codes import FUSED, POSE
    from swarmloc.engine.jax_pairs import _pair
    from swarmloc.engine.swarm import SWARM_NOISE

    x = np.array([[0.0, 0.0, 0.1], [1.0, 0.2, -0.3]])
    P = np.stack([0.5 * np.eye(3), 1e-6 * np.eye(3)])
    met = np.array([[False, True], [True, False]])
    sig = np.zeros((2, 2, 3, 3))
    sig[1, 0] = np.eye(3)  # the target still tracks the pair, the observer does not
    st = tuple(jnp.asarray(a) for a in (x, P, np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2), met,
                                        sig))  # fmt: skip
    z, R = np.array([0.9, 0.5, -0.2]), 1e-2 * np.eye(3)
    const = tuple(jnp.asarray(a) for a in (np.zeros(2), np.full(5, np.inf), False, True, True, np.zeros((1, 2)),
                                           np.zeros((1, 2, 2))))  # fmt: skip
    ev = {"kind": jnp.asarray(POSE), "t": jnp.asarray(0.0), "z": jnp.asarray(z), "R": jnp.asarray(R)}
    out, code, why = _pair(jnp, SWARM_NOISE, st, jnp.asarray(0), jnp.asarray(1), ev, const)
    out = [np.asarray(a) for a in out]
    assert (int(code), int(why)) == (FUSED, 0)
    c, s_ = np.cos(x[0, 2]), np.sin(x[0, 2])
    d = x[1, :2] - x[0, :2]
    bx, by = c * d[0] + s_ * d[1], -s_ * d[0] + c * d[1]
    H = np.array([[-c, -s_, by, c, s_, 0], [s_, -c, -bx, -s_, c, 0], [0, 0, -1, 0, 0, 1.0]])
    B = np.array([[np.cos(z[2]), -np.sin(z[2]), 0], [np.sin(z[2]), np.cos(z[2]), 0], [0, 0, 1.0]])
    Rm = B @ R @ B.T
    prior, both = joint_prior(P[0], P[1], sig[0, 1], sig[1, 0], H, Rm, True)
    assert not both  # covariance intersection, the observer only
    r = np.array([z[0] - bx, z[1] - by, z[2] - (x[1, 2] - x[0, 2])])
    K = prior @ H.T @ np.linalg.inv(H @ prior @ H.T + Rm)
    IKH = np.eye(6) - K @ H
    np.testing.assert_allclose(out[0][0], x[0] + (K @ r)[:3], atol=1e-12)
    np.testing.assert_allclose(out[1][0], (IKH @ prior @ IKH.T + K @ Rm @ K.T)[:3, :3], atol=1e-12)
    np.testing.assert_array_equal(out[0][1], x[1])  # the target untouched
    np.testing.assert_array_equal(out[1][1], P[1])
    np.testing.assert_array_equal(out[8][0, 1], 0.0)  # the observer's factor for the target dropped
    np.testing.assert_array_equal(out[8][1, 0], np.eye(3))
    np.testing.assert_array_equal(out[7], met)


def _inputs(src, estimator: str) -> tuple:
    """``(timeline, x, P, starts, noise, keywords)`` of ``src`` for ``estimator``'s JAX replay."""
    inp = joint_inputs(src, estimator)
    kw = inp.options if estimator == "rdl" else {**inp.options, "invariant": True}
    return inp.timeline, inp.x, inp.P, inp.t0, inp.noise, kw


@pytest.mark.parametrize("estimator", ("diekf", "rdl"))
def test_jax_replay_compiles_once_per_bucket_and_runs_many_teams_at_once(estimator) -> None:
    """Three simulated teams of 4 robots with different seeds and lengths in one bucket: one compilation for the
    three single runs; their batch (one vmapped call) equals each run alone."""
    one, many = (replay_rdl_jax, replay_rdl_batch) if estimator == "rdl" else (replay_joint_jax, replay_joint_batch)
    runs = [_inputs(_source(4, T, seed, kinds=("pose", "range_bearing")), estimator) for T, seed in
            ((5.5, 31), (6.0, 31), (6.0, 33))]  # fmt: skip
    sizes = {(jax_replay.bucket(len(r[0].det) + int(r[0].record.sum()) + 1), jax_replay.bucket(r[0].robot.size),
              jax_replay.bucket(int(r[0].record.sum()))) for r in runs}  # fmt: skip
    assert len(sizes) == 1  # one bucket of steps, commands and records for the three
    before = sum(jax_replay.COMPILES.values())
    alone = [one(tl, x, P, starts, noise, **kw) for tl, x, P, starts, noise, kw in runs]
    assert sum(jax_replay.COMPILES.values()) - before <= 1  # none if an earlier test compiled this shape
    noise, kw = runs[0][4], runs[0][5]
    batch = many([r[0] for r in runs], np.stack([r[1] for r in runs]), np.stack([r[2] for r in runs]),
                 [r[3] for r in runs], noise, **kw)  # fmt: skip
    batch_equals_alone(alone, batch)


def batch_equals_alone(alone: list, batch: list) -> None:
    """Three runs' results from one vmapped call equal each run's alone: outcomes and reasons exactly, records to
    1e-12; each run fused more than 100 detections, and the runs differ."""
    assert len(batch) == 3
    for (s1, r1, rec1), (s2, r2, rec2) in zip(alone, batch, strict=True):
        np.testing.assert_array_equal(s1, s2)
        np.testing.assert_array_equal(r1, r2)
        assert (s1 == 1).sum() > 100  # fused
        for a, b in zip(rec1, rec2, strict=True):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    assert not np.array_equal(alone[0][2][2][:10], alone[1][2][2][:10])  # the runs differ


def test_jax_replay_takes_a_run_without_detections_and_needs_a_compiled_backend() -> None:
    """A timeline without detections (every robot dead-reckoned) equals numba's; numpy runs no compiled replay."""
    src = _source(3, 4.0, 41, kinds=("pose",))
    src = dataclasses.replace(src, events=[e for e in src.events if not isinstance(e, Detection)])
    for estimator in ("diekf", "rdl"):
        ref, jx = run_engine(src, estimator, backend="numba"), run_engine(src, estimator, backend="jax")
        _same(ref, jx)
        assert jx.stats["detections"] == 0 and jx.tracks[0].times.size > 10
    with pytest.raises(ValueError, match="backend='numba' or 'jax'"):
        run_engine(src, "rdl", backend="numpy")
