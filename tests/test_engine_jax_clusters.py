"""``diekf`` in clusters replayed with JAX (``run_engine(source, "diekf", backend="jax", cluster=K)``,
:mod:`swarmloc.engine.jax_clusters`) equals the nodes and numba's cluster loop: every recorded belief, every outcome
count and reason, with detections inside a cluster, of robots outside it (covariance intersection), of landmarks,
a cluster mate that starts late and MRCLAM; the traced weight equals the library's; one compilation per bucket;
many runs at once (``jax.vmap``) equal to each run alone."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_engine import _source
from test_engine_cekf import _same, _same_on_mrclam, _with, robot_extras
from test_engine_clusters import _nodes, _outside
from test_engine_jax_joint import batch_equals_alone

from swarmloc.engine import jax_replay, joint_inputs, run_engine
from swarmloc.engine.jax_clusters import _weight, replay_clusters_batch, replay_clusters_jax
from swarmloc.engine.jax_stamp import import_jax
from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.kernels import ci as KCI

# slow: the first test of the module compiles the engine's numba/JAX kernels
pytestmark = [pytest.mark.data, pytest.mark.slow]


import_jax()  # float64
import jax.numpy as jnp  # noqa: E402


@pytest.mark.parametrize("cluster", [1, 2, 3])
def test_jax_clusters_equal_the_nodes_on_robots_of_every_kind(cluster) -> None:
    """Relative poses, range-bearing, range-only, bearing-only of robots and absolute fixes, with a robot outside the
    team, the observer itself, no target id and far-off readings (gated); clusters of 1, 2 and 3 of 5 robots (the last
    cluster smaller: padded on the device)."""
    src = _with(_source(5, 10.0, 17, kinds=("pose", "range_bearing"), fixes=True), robot_extras())
    jx = run_engine(src, "diekf", backend="jax", cluster=cluster)
    _same(_nodes(src, cluster=cluster), jx)
    _same(run_engine(src, "diekf", backend="numba", cluster=cluster), jx)
    assert _outside(src, cluster) > 250
    assert jx.stats["gated"] >= 2 and jx.stats["fused"] > 700
    assert jx.reasons["rejected: the target is the observer itself"] == 1


def test_jax_clusters_as_large_as_the_team_are_the_exact_replay() -> None:
    src = _source(5, 10.0, 17, kinds=("pose", "range_bearing"))
    exact, whole = run_engine(src, "diekf", backend="jax"), run_engine(src, "diekf", backend="jax", cluster=7)
    for r, a in exact.tracks.items():
        np.testing.assert_allclose(whole.tracks[r].mean, a.mean, rtol=0, atol=1e-12)
        np.testing.assert_allclose(whole.tracks[r].cov, a.cov, rtol=0, atol=1e-12)
    two = run_engine(src, "diekf", backend="jax", cluster=2)
    assert max(np.abs(two.tracks[r].mean - a.mean).max() for r, a in exact.tracks.items()) > 1e-4


def test_jax_clusters_equal_numba_with_landmarks_and_a_late_cluster_mate() -> None:
    """Landmarks on, off, and relative measurements off (landmarks only), clusters of 2 of 5 robots; then robot 2's
    inputs beginning at 4 s (its cluster mate's outside updates must not inflate it before: 1e-2 m off in numba's
    loop when they did)."""
    src = load_source("sim:landmarks", robots=5, duration=12.0, seed=5)
    for opts in ({}, {"use_landmarks": False}, {"use_relative": False}):
        jx = run_engine(src, "diekf", backend="jax", cluster=2, **opts)
        _same(run_engine(src, "diekf", backend="numba", cluster=2, **opts), jx)
        assert jx.stats["fused"] > 300
    late = _source(5, 10.0, 23, kinds=("pose", "range_bearing"))
    own = [(isinstance(e, Odometry) and e.robot == 2) or (isinstance(e, Detection) and e.observer == 2)
           for e in late.events]  # fmt: skip
    late = dataclasses.replace(late, events=[e for e, mine in zip(late.events, own, strict=True)
                                             if not (mine and e.stamp < 4.0)])  # fmt: skip
    for cluster in (2, 3):
        jx = run_engine(late, "diekf", backend="jax", cluster=cluster)
        _same(_nodes(late, cluster=cluster), jx)
        assert sum(v for k, v in jx.reasons.items() if k.startswith("unknown: robot 2: stamp")) > 10


def test_jax_clusters_equal_numba_on_mrclam6(mrclam6) -> None:
    """The first 120 s of MRCLAM dataset 6, clusters of 2 (robots 1-2, 3-4, 5), landmarks on."""
    src = load_source(f"mrclam:{mrclam6}", duration=120.0)
    ref, jx = run_engine(src, "diekf", backend="numba", cluster=2), run_engine(src, "diekf", backend="jax", cluster=2)
    _same_on_mrclam(ref, jx)
    assert jx.stats["fused"] > 2000


def test_traced_weight_equals_the_library_on_padded_measurements() -> None:
    """The traced weight search, on 1- and 2-row measurements padded to 3 rows as the replay pads them (zero rows of
    ``A`` and ``B``, one on the noise's diagonal), against :func:`swarmloc.kernels.ci.joint_weight` on the unpadded
    ones: clusters of 1 to 20 robots, the outsider's share from negligible to dominant."""
    rng = np.random.default_rng(1)
    seen = []
    for _ in range(200):
        m = int(rng.integers(1, 4))
        a = rng.normal(size=(3, m, m)) * 10.0 ** rng.uniform(-3, 1, (3, 1, 1))
        A, B, R = a @ a.transpose(0, 2, 1) + 1e-4 * np.eye(m)
        dof = 3 * int(rng.integers(1, 21))
        pad = [np.zeros((3, 3)) for _ in range(3)]
        for P, M in zip(pad, (A, B, R), strict=True):
            P[:m, :m] = M
        pad[2][m:, m:] = np.eye(3 - m)
        w = float(_weight(jnp, *(jnp.asarray(P) for P in pad), dof))
        assert w == pytest.approx(KCI.joint_weight(A, B, R, dof), rel=1e-12, abs=1e-14)
        seen.append(w)
    assert min(seen) < 0.2 and max(seen) > 0.99


def test_jax_clusters_compile_once_per_bucket_and_run_many_teams_at_once() -> None:
    """Three simulated teams of 5 robots with different seeds and lengths in one bucket, clusters of 2: at most one
    compilation for the three single runs; their batch (one vmapped call) equals each run alone."""
    runs = []
    for T, seed in ((5.5, 31), (6.0, 31), (6.0, 33)):
        inp = joint_inputs(_source(5, T, seed, kinds=("pose", "range_bearing")), "diekf")
        runs.append((inp.timeline, inp.x, inp.P, inp.t0, inp.noise, inp.options))
    sizes = {(jax_replay.bucket(len(r[0].det) + int(r[0].record.sum()) + 1), jax_replay.bucket(r[0].robot.size),
              jax_replay.bucket(int(r[0].record.sum()))) for r in runs}  # fmt: skip
    assert len(sizes) == 1
    before = sum(jax_replay.COMPILES.values())
    alone = [replay_clusters_jax(tl, x, P, starts, noise, 2, **kw) for tl, x, P, starts, noise, kw in runs]
    assert sum(jax_replay.COMPILES.values()) - before <= 1
    batch = replay_clusters_batch([r[0] for r in runs], np.stack([r[1] for r in runs]),
                                  np.stack([r[2] for r in runs]), [r[3] for r in runs], runs[0][4], 2,
                                  **runs[0][5])  # fmt: skip
    batch_equals_alone(alone, batch)
    with pytest.raises(ValueError, match="'cluster' must be an integer >= 1"):
        replay_clusters_jax(*runs[0][:5], 0, **runs[0][5])
