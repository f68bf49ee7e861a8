"""Bearing-only anonymous registration (slide 70), the partial extension: exact solutions up to scale for
noise-free bearings, the mirror ambiguity of three robots, the symmetric polygons' counts, small noise."""

from __future__ import annotations

import numpy as np
import pytest
from test_association_pmr import polygon, relative, spread, with_headings

from swarmloc.association import solution_count_theory
from swarmloc.association.bearing import bearing_registration
from swarmloc.lie import between_xyt

pytestmark = pytest.mark.unit


def bearings(poses: np.ndarray, rng: np.random.Generator, sigma: float = 0.0) -> dict[int, np.ndarray]:
    out = {}
    for i in range(len(poses)):
        rel = np.delete(between_xyt(poses[i], poses)[:, :2], i, 0)
        out[i] = rng.permutation(np.arctan2(rel[:, 1], rel[:, 0]) + sigma * rng.standard_normal(len(rel)))
    return out


def shape_error(sol, poses: np.ndarray) -> float:
    """Largest position [in units of the true ego-to-first-neighbour distance] or heading [rad] error."""
    truth = {j: relative(poses, 0, j) for j in range(len(poses))}
    scale = np.hypot(*truth[1][:2])
    return max(
        max(np.hypot(*(sol.poses[j][:2] * scale - truth[j][:2])) / scale,
            abs((sol.poses[j][2] - truth[j][2] + np.pi) % (2 * np.pi) - np.pi))
        for j in truth
    )  # fmt: skip


def test_generic_configurations_have_one_solution_from_four_robots_and_two_mirror_images_with_three():
    rng = np.random.default_rng(0)
    for trial in range(12):
        n = 3 + trial % 4
        poses = with_headings(spread(rng, n), rng)
        sols = bearing_registration(bearings(poses, rng), 0, 1e-6)
        assert min(shape_error(s, poses) for s in sols) < 1e-6
        assert len(sols) == (2 if n == 3 else 1), (trial, n, len(sols))
        if n == 3:  # the other one is the mirror image: same angles, opposite orientation
            mirror = max(sols, key=lambda s: shape_error(s, poses))
            p1, p2 = mirror.poses[1][:2], mirror.poses[2][:2]
            t1, t2 = relative(poses, 0, 1)[:2], relative(poses, 0, 2)[:2]
            cross = lambda u, v: u[0] * v[1] - u[1] * v[0]  # noqa: E731
            assert np.sign(cross(p1, p2)) == -np.sign(cross(t1, t2))


@pytest.mark.parametrize("k", [3, 4, 5])
def test_regular_polygons_have_as_many_solutions_as_with_positions(k: int):
    rng = np.random.default_rng(k)
    poses = with_headings(polygon(k), rng)
    sols = bearing_registration(bearings(poses, rng), 0, 1e-6)
    assert len(sols) == solution_count_theory(polygon(k), 0)
    assert min(shape_error(s, poses) for s in sols) < 1e-6


def test_small_bearing_noise_keeps_the_truth_among_the_solutions():
    rng = np.random.default_rng(1)
    for trial in range(8):
        poses = with_headings(spread(rng, 4 + trial % 2), rng)
        sols = bearing_registration(bearings(poses, rng, 0.002), 0, 0.002)
        # (no least-squares refinement: the truth is the triangulation from ego and the first neighbour)
        assert sols and min(shape_error(s, poses) for s in sols) < 0.15, trial


def test_bearing_registration_rejects_bad_input():
    with pytest.raises(ValueError, match="ego"):
        bearing_registration({0: [0.1], 1: [0.2]}, 3, 0.01)
    with pytest.raises(ValueError, match="bearings"):
        bearing_registration({0: [0.1, 0.2], 1: [0.2]}, 0, 0.01)
    with pytest.raises(ValueError, match="sigma"):
        bearing_registration({0: [0.1], 1: [0.2]}, 0, 0.0)
