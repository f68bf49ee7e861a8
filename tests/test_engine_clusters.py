"""``diekf`` in clusters on the engine (``run_engine(source, "diekf", backend="numba", cluster=K)``,
:mod:`swarmloc.engine.joint_clusters`) equals the ``diekf`` nodes with ``cluster=K``: every recorded belief (1e-10
on simulated teams, 1e-9 relative on MRCLAM), every outcome count and reason, with detections inside a cluster
(the exact filter), of robots outside it (covariance intersection) and of landmarks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_engine import _source, fixed_noise
from test_engine_cekf import _same, _same_on_mrclam, _with, robot_extras

from swarmloc.engine import run_engine
from swarmloc.engine.joint_clusters import joint_weight
from swarmloc.estimators import make_team, node_options
from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.kernels import ci as KCI
from swarmloc.runner import RunResult, run

# slow: the first test of the module compiles the engine's numba/JAX kernels
pytestmark = [pytest.mark.data, pytest.mark.slow]


def _nodes(src, **options) -> RunResult:
    opts = {**node_options("diekf", src.config, src.landmarks), **options}
    return run(make_team("diekf", src.initial, **opts), src.events, record_times=src.record_times(), truth=src.truth)


def _outside(src, cluster: int) -> int:
    """Detections of a robot of the team outside the observer's cluster (ids are rows: 0 .. n-1)."""
    team = set(src.initial)
    return sum(isinstance(e, Detection) and e.target_is_robot and e.target in team and e.target != e.observer
               and e.target // cluster != e.observer // cluster for e in src.events)  # fmt: skip


@pytest.mark.parametrize("cluster", [1, 2, 3])
def test_clusters_on_the_engine_equal_the_nodes_on_robots_of_every_kind(cluster) -> None:
    """Relative poses, range-bearing, range-only, bearing-only of robots and absolute fixes, with a robot outside the
    team, the observer itself, no target id and far-off readings (gated); clusters of 1 (every robot detection an
    outside one), 2 and 3 of 5 robots (the last cluster smaller)."""
    src = _with(_source(5, 10.0, 17, kinds=("pose", "range_bearing"), fixes=True), robot_extras())
    ref, eng = _nodes(src, cluster=cluster), run_engine(src, "diekf", backend="numba", cluster=cluster)
    _same(ref, eng)
    assert _outside(src, cluster) > 250
    assert eng.stats["gated"] >= 2 and eng.stats["fused"] > 700
    assert eng.reasons["rejected: the target is the observer itself"] == 1


def test_clusters_as_large_as_the_team_are_the_exact_filter() -> None:
    src = _source(5, 10.0, 17, kinds=("pose", "range_bearing"))
    exact, whole = run_engine(src, "diekf", backend="numba"), run_engine(src, "diekf", backend="numba", cluster=7)
    for r, a in exact.tracks.items():
        np.testing.assert_array_equal(whole.tracks[r].mean, a.mean)
        np.testing.assert_array_equal(whole.tracks[r].cov, a.cov)
    two = run_engine(src, "diekf", backend="numba", cluster=2)
    assert max(np.abs(two.tracks[r].mean - a.mean).max() for r, a in exact.tracks.items()) > 1e-4


def test_clusters_on_the_engine_equal_the_nodes_with_landmarks() -> None:
    """Landmarks on, off, and relative measurements off (landmarks only), clusters of 2 of 5 robots."""
    src = fixed_noise(load_source("sim:landmarks", robots=5, duration=12.0, seed=5))
    for opts in ({}, {"use_landmarks": False}, {"use_relative": False}):
        ref, eng = _nodes(src, cluster=2, **opts), run_engine(src, "diekf", backend="numba", cluster=2, **opts)
        _same(ref, eng)
        assert eng.stats["fused"] > 300
    assert _outside(src, 2) > 100


def test_clusters_on_the_engine_equal_the_nodes_when_a_cluster_mate_starts_late() -> None:
    """Robot 2's inputs begin at 4 s: before, its node takes no broadcast, so an outside update of its cluster mate 3
    does not inflate robot 2's covariance (an engine that divided the whole cluster by the weight was 1e-2 m off)."""
    src = _source(5, 10.0, 23, kinds=("pose", "range_bearing"))
    own = [(isinstance(e, Odometry) and e.robot == 2) or (isinstance(e, Detection) and e.observer == 2)
           for e in src.events]  # fmt: skip
    src = dataclasses.replace(src, events=[e for e, mine in zip(src.events, own, strict=True)
                                           if not (mine and e.stamp < 4.0)])  # fmt: skip
    for cluster in (2, 3):
        ref, eng = _nodes(src, cluster=cluster), run_engine(src, "diekf", backend="numba", cluster=cluster)
        _same(ref, eng)
        assert sum(v for k, v in eng.reasons.items() if k.startswith("unknown: robot 2: stamp")) > 10
        assert eng.tracks[2].times.min() >= 4.0


def test_clusters_on_the_engine_equal_the_nodes_on_mrclam6(mrclam6) -> None:
    """The first 120 s of MRCLAM dataset 6, clusters of 2 (robots 1-2, 3-4, 5), landmarks on."""
    src = fixed_noise(load_source(f"mrclam:{mrclam6}", duration=120.0))
    ref, eng = _nodes(src, cluster=2), run_engine(src, "diekf", backend="numba", cluster=2)
    _same_on_mrclam(ref, eng)
    assert eng.stats["fused"] > 2000


def test_compiled_joint_weight_equals_the_library() -> None:
    """The compiled weight search against :func:`swarmloc.kernels.ci.joint_weight` on random 1-, 2- and 3-row
    measurements, clusters of 1 to 20 robots, the outsider's share from negligible to dominant."""
    rng = np.random.default_rng(0)
    seen = []
    for _ in range(300):
        m = int(rng.integers(1, 4))
        a = rng.normal(size=(3, m, m)) * 10.0 ** rng.uniform(-3, 1, (3, 1, 1))
        A, B, R = a @ a.transpose(0, 2, 1) + 1e-4 * np.eye(m)
        dof = 3 * int(rng.integers(1, 21))
        w = joint_weight(A, B, R, dof)
        assert w == pytest.approx(KCI.joint_weight(A, B, R, dof), rel=1e-12, abs=1e-14)
        seen.append(w)
    assert min(seen) < 0.2 and max(seen) > 0.99  # inner minima and the upper bound both taken


def test_clusters_run_on_a_compiled_backend_and_only_for_diekf() -> None:
    src = _source(4, 2.0, 3)
    with pytest.raises(ValueError, match="'rdl' has no clusters"):
        run_engine(src, "rdl", backend="numba", cluster=2)
    with pytest.raises(ValueError, match="backend='numba'"):
        run_engine(src, "diekf", cluster=2)
    for bad in (-1, 2.5, True, "2"):
        with pytest.raises(ValueError, match="'cluster' must be an integer >= 1"):
            run_engine(src, "diekf", backend="numba", cluster=bad)
