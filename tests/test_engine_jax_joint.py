"""The joint replays with JAX (``run_engine(source, "cekf" | "iekf" | "diekf", backend="jax")``,
:mod:`swarmloc.engine.jax_joint`): equal to the nodes and to numba's compiled loop (every recorded belief, every
outcome count and reason) on every detection kind of robots and landmarks, a robot that starts late and MRCLAM; one
compilation per bucket of events; many runs at once (``jax.vmap``) equal to each run alone."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_engine import _source
from test_engine_cekf import _same, _same_on_mrclam, _with, robot_extras
from test_engine_invariant import _nodes

from swarmloc.engine import jax_joint, joint_inputs, run_engine
from swarmloc.engine.jax_joint import replay_joint_batch, replay_joint_jax
from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source

JOINT = ("cekf", "iekf", "diekf")


@pytest.mark.parametrize("estimator", JOINT)
def test_jax_joint_equals_the_nodes_on_robots_of_every_kind(estimator) -> None:
    """Relative poses, range-bearing, range-only, bearing-only of robots and absolute fixes, a robot outside the
    team, the observer itself, no target id, far-off readings (gated); and relative measurements switched off."""
    src = _with(_source(5, 10.0, 17, kinds=("pose", "range_bearing"), fixes=True), robot_extras())
    ref, jx = _nodes(estimator, src), run_engine(src, estimator, backend="jax")
    _same(ref, jx)
    assert jx.estimator == f"{estimator}/engine"
    assert jx.stats["gated"] >= 2 and jx.stats["fused"] > 500
    assert jx.reasons["rejected: the target is the observer itself"] == 1
    off = run_engine(src, estimator, backend="jax", use_relative=False)
    _same(run_engine(src, estimator, backend="numba", use_relative=False), off)
    assert off.stats["fused"] > 0 and off.stats["rejected"] > 500


@pytest.mark.parametrize("estimator", ("cekf", "diekf"))
def test_jax_joint_equals_numba_with_landmarks(estimator) -> None:
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


@pytest.mark.parametrize("use_landmarks", [True, False])
def test_jax_diekf_equals_numba_on_mrclam6(mrclam6, use_landmarks) -> None:
    """The first 60 s of MRCLAM dataset 6."""
    src = load_source(f"mrclam:{mrclam6}", duration=60.0)
    ref = run_engine(src, "diekf", backend="numba", use_landmarks=use_landmarks)
    jx = run_engine(src, "diekf", backend="jax", use_landmarks=use_landmarks)
    _same_on_mrclam(ref, jx)
    assert jx.stats["fused"] > (1000 if use_landmarks else 150)


def _timeline(src) -> tuple:
    """``(timeline, x, P, starts, noise, keywords)`` of ``src`` for ``diekf``'s :func:`replay_joint_jax`."""
    inp = joint_inputs(src, "diekf")
    return inp.timeline, inp.x, inp.P, inp.t0, inp.noise, {**inp.options, "invariant": True}


def test_jax_joint_compiles_once_per_bucket_and_runs_many_teams_at_once() -> None:
    """Three simulated teams of 4 robots with different seeds and lengths in one bucket: one compilation for the
    three single runs; their batch (one vmapped call) equals each run alone."""
    runs = [_timeline(_source(4, T, seed, kinds=("pose", "range_bearing"))) for T, seed in
            ((5.5, 31), (6.0, 31), (6.0, 33))]  # fmt: skip
    sizes = {(jax_joint.bucket(len(r[0].det) + int(r[0].record.sum()) + 1), jax_joint.bucket(r[0].robot.size),
              jax_joint.bucket(int(r[0].record.sum()))) for r in runs}  # fmt: skip
    assert len(sizes) == 1  # one bucket of steps, commands and records for the three
    before = sum(jax_joint.COMPILES.values())
    alone = [replay_joint_jax(tl, x, P, starts, noise, **kw) for tl, x, P, starts, noise, kw in runs]
    assert sum(jax_joint.COMPILES.values()) - before <= 1  # none if an earlier test compiled this shape
    noise, kw = runs[0][4], runs[0][5]
    batch = replay_joint_batch([r[0] for r in runs], np.stack([r[1] for r in runs]), np.stack([r[2] for r in runs]),
                               [r[3] for r in runs], noise, **kw)  # fmt: skip
    assert len(batch) == 3
    for (s1, r1, rec1), (s2, r2, rec2) in zip(alone, batch, strict=True):
        np.testing.assert_array_equal(s1, s2)
        np.testing.assert_array_equal(r1, r2)
        assert (s1 == 1).sum() > 100  # fused
        for a, b in zip(rec1, rec2, strict=True):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    assert not np.array_equal(alone[0][2][2][:10], alone[1][2][2][:10])  # the runs differ


def test_jax_joint_takes_a_run_without_detections_and_refuses_rdl() -> None:
    """A timeline without detections (every robot dead-reckoned) equals numba's; ``rdl`` runs on numba only."""
    src = _source(3, 4.0, 41, kinds=("pose",))
    src = dataclasses.replace(src, events=[e for e in src.events if not isinstance(e, Detection)])
    ref, jx = run_engine(src, "diekf", backend="numba"), run_engine(src, "diekf", backend="jax")
    _same(ref, jx)
    assert jx.stats["detections"] == 0 and jx.tracks[0].times.size > 10
    with pytest.raises(ValueError, match="backend='numba'"):
        run_engine(src, "rdl", backend="jax")
