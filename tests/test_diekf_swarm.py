"""The swarm benchmark's scene (benchmarks/swarm_scene.py, benchmarks/diekf_swarm.py): in the ``bounded`` arena a
robot detects as many teammates per second in a team of 10 as in a team of 40, and so sends as many messages with
``diekf`` in clusters; in the ``spread`` arena (the previous scene: it grows with the team but the robots may leave
it) it does not. Short seeded runs, the same number of robots on each side (many seeds of the small team)."""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from _benchmarks import load_benchmark

from swarmloc.events import Detection

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def bench() -> tuple[ModuleType, ModuleType]:
    return load_benchmark("swarm_scene"), load_benchmark("diekf_swarm")


def detections_per_robot_s(scene: Callable[..., Any], n: int, seeds: range, arena: str, duration: float) -> float:
    counts = [sum(isinstance(e, Detection) for e in scene(n, duration, s, arena).events) for s in seeds]
    return float(np.mean(counts)) / n / duration


def test_arena_side_counts_the_edge(bench: tuple[ModuleType, ModuleType]) -> None:
    """The side is where ``(n - 1)`` times the chance that two uniform robots are within range is the target: the
    closed form ``(pi r^2 - 8 r^3 / (3 L) + r^4 / (2 L^2)) / L^2`` where it holds, a smaller square than the
    edge-free ``sqrt(pi r^2 (n - 1) / 2)`` (4.90 m against 5.64 m at 10 robots), a larger density for a smaller
    team."""
    scene_mod, _ = bench
    r = scene_mod.RANGE
    for n in (10, 50):
        side = scene_mod.arena_side(n)
        exact = (np.pi * r * r - 8 * r**3 / (3 * side) + r**4 / (2 * side * side)) / side**2
        assert abs((n - 1) * exact - scene_mod.NEIGHBOURS) < 1e-3, (n, side)
        assert side < np.sqrt(np.pi * r * r * (n - 1) / scene_mod.NEIGHBOURS)
    assert n / scene_mod.arena_side(50) ** 2 < 10 / scene_mod.arena_side(10) ** 2
    with pytest.raises(ValueError, match="cannot see"):
        scene_mod.arena_side(3)


def test_bounded_robots_stay_in_their_square(bench: tuple[ModuleType, ModuleType]) -> None:
    """The commands keep the noise-free path in the square; the wheels' noise moves the truth a few cm at most."""
    scene_mod, _ = bench
    src = scene_mod.scene(20, 10.0, 3, "bounded")
    side = scene_mod.arena_side(20)
    times = np.linspace(src.t_start, src.t_end, 101)
    xy = np.stack([src.truth(r, times)[:, :2] for r in src.robots])
    assert xy.min() > -0.1 and xy.max() < side + 0.1, (xy.min(), xy.max(), side)


def test_detections_and_traffic_per_robot_flat_in_the_bounded_arena_only(bench: tuple[ModuleType, ModuleType]) -> None:
    """Detections per robot and second: 10 robots (seeds 1-32) against 40 (seeds 1-8), 3 s each, within 15% of each
    other in the bounded arena (10.9 and 10.1), more than 20% apart in the spread one (12.1 and 17.5: there a robot
    of the larger team sees more, fewer robots being near an edge or gone out). Messages a robot sends per second
    with ``diekf`` in clusters of 2 (in process, seeds 1-8 and 1-2): within 20% in the bounded arena (32.6 and
    32.4; 37.6 and 64.0 in the spread one)."""
    scene_mod, swarm = bench
    small, large = (10, range(1, 33)), (40, range(1, 9))
    det = {a: [detections_per_robot_s(scene_mod.scene, n, s, a, 3.0) for n, s in (small, large)]
           for a in ("bounded", "spread")}  # fmt: skip
    assert abs(det["bounded"][0] / det["bounded"][1] - 1) < 0.15, det
    assert abs(det["spread"][0] / det["spread"][1] - 1) > 0.2, det
    sent = [np.mean([swarm.in_process(scene_mod.scene(n, 3.0, s, "bounded"), n, 2, 3.0)[0]["sent"] for s in seeds])
            for n, seeds in ((10, range(1, 9)), (40, range(1, 3)))]  # fmt: skip
    assert abs(sent[0] / sent[1] - 1) < 0.2, sent


def test_reformed_clusters_beat_fixed_ones_as_robots_drift_apart(bench: tuple[ModuleType, ModuleType]) -> None:
    """Over 30 s the robots of a grouped cluster drift apart; clusters re-formed every second from whom a robot sees
    (benchmarks/diekf_reform.py, ``"seen"``) come within 10% of the exact filter, fixed ones do not, and stay
    consistent (20 robots, clusters of 5, seed 2: RMSE 0.0133 against 0.0177 fixed and 0.0128 exact; ANEES/dof
    0.67)."""
    scene_mod, _ = bench
    reform = load_benchmark("diekf_reform")
    srcs = [scene_mod.scene(20, 30.0, 2, "grouped")]
    runs = {name: [reform.replay(src, K, p) for src in srcs] for name, K, p in
            (("exact", 20, 0.0), ("fixed", 5, 0.0), ("reformed", 5, 1.0))}  # fmt: skip
    rmse = {k: float(np.mean([r["rmse"] for r in v])) for k, v in runs.items()}
    anees = {k: float(np.mean([r["anees"] for r in v])) for k, v in runs.items()}
    assert rmse["reformed"] < 1.1 * rmse["exact"] < rmse["fixed"], rmse
    assert 0.5 <= anees["reformed"] <= 2.0, anees
    assert sum(r["moved"] for r in runs["reformed"]) > 0
    assert all(len(g) <= 7 for r in runs["reformed"] for g in r["groups"])  # at most 3K / 2
    assert sorted(x for g in runs["reformed"][0]["groups"] for x in g) == list(range(20))


def test_reformed_cluster_bounds_any_correlation_of_its_pieces(bench: tuple[ModuleType, ModuleType]) -> None:
    """A cluster made of pieces of two clusters starts from ``blockdiag(P_1 / w_1, P_2 / w_2)`` (sizes as weights):
    it bounds the pieces' joint covariance whatever their correlation (random joint covariances), and keeps each
    piece's own correlations."""
    scene_mod, _ = bench
    reform = load_benchmark("diekf_reform")
    src = scene_mod.scene(6, 1.0, 1, "grouped")
    rng = np.random.default_rng(0)
    for _ in range(20):
        f = reform.Clustered(src, None, 0.997, [[0, 1, 2], [3, 4, 5]])
        L = rng.normal(size=(18, 18))
        J = L @ L.T + 0.1 * np.eye(18)  # the true joint of robots 0..5 (3 rows each), cross-cluster part included
        f.P = [J[:9, :9].copy(), J[9:, 9:].copy()]
        f.reform([[0, 1, 3], [2, 4, 5]])
        for g, P in zip(f.groups, f.P, strict=True):
            rows = np.concatenate([np.arange(3 * r, 3 * r + 3) for r in g])
            assert np.linalg.eigvalsh(P - J[np.ix_(rows, rows)]).min() > -1e-9
        assert f.groups[0][:2] == [0, 1]
        np.testing.assert_allclose(f.P[0][:6, :6], J[:6, :6] * 3 / 2)  # w = 2 / 3 for the piece of 2
