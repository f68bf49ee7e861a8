"""Binary registration and PMR multiple registration of anonymous observations (slides 45-60): the rotational-
symmetry theorems, the (n-1)! bound, noise-level recovery, clutter, misses and range limits, the belief gate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarmloc.association import (
    binary_register,
    multiple_registration,
    rotational_symmetry_order,
    solution_count_theory,
    symmetry_metric,
)
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, between_xyt, compose_xyt

pytestmark = pytest.mark.unit


def observe(poses: np.ndarray, rng: np.random.Generator, sigma: float = 0.0, max_range: float = np.inf) -> dict:
    """Every robot's anonymous observation of the others (its own frame), shuffled, with isotropic noise."""
    out = {}
    for i in range(len(poses)):
        rel = np.delete(between_xyt(poses[i], poses)[:, :2], i, 0)
        rel = rel[np.hypot(rel[:, 0], rel[:, 1]) <= max_range]
        out[i] = rng.permutation(rel + sigma * rng.standard_normal(rel.shape))
    return out


def relative(poses: np.ndarray, i: int, j: int) -> np.ndarray:
    return between_xyt(poses[i], poses[j])


def polygon(k: int, radius: float = 1.0, phase: float = 0.3, centre: bool = False) -> np.ndarray:
    a = phase + 2 * np.pi * np.arange(k) / k
    P = np.column_stack([radius * np.cos(a), radius * np.sin(a)])
    return np.vstack([P, [[0.0, 0.0]]]) if centre else P


def spread(rng: np.random.Generator, n: int, half: float = 2.0, min_sep: float = 0.3) -> np.ndarray:
    """``n`` random points in a square of half-width ``half`` [m], at least ``min_sep`` [m] apart (robots have a
    body: two anonymous robots closer than the noise cannot be told apart, and PMR rightly returns both)."""
    while True:
        P = rng.uniform(-half, half, (n, 2))
        d = np.hypot(*(P[:, None] - P[None]).transpose(2, 0, 1)) + np.eye(n) * 9
        if d.min() >= min_sep:
            return P


def with_headings(P: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return np.column_stack([P + [0.7, -0.4], rng.uniform(-np.pi, np.pi, len(P))])


def pose_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    d = between_xyt(a, b)
    return float(np.hypot(d[0], d[1])), float(abs(d[2]))


# ------------------------------------------------------------------------------------------ binary registration
def test_binary_registration_recovers_a_known_transform_and_its_error_scales_with_the_noise():
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(-2, 2, (6, 2)), rng.uniform(-np.pi, np.pi, 6)])
    truth = relative(poses, 0, 1)
    rms = {}
    for sigma in (0.002, 0.02):
        errs, nees = [], []
        for _ in range(200):
            o = observe(poses, rng, sigma)
            regs = binary_register(o[0], o[1], sigma)
            assert len(regs) == 1
            y = SE2.log(SE2.from_xytheta(between_xyt(regs[0].pose, truth)))
            errs.append(y)
            nees.append(y @ np.linalg.solve(regs[0].cov, y))
        errs = np.array(errs)
        rms[sigma] = np.sqrt((errs**2).mean(0))
        # the first-order covariance is the right size: mean NEES within the 99% band of chi2(600)/200
        assert 2.61 < np.mean(nees) < 3.42, (sigma, np.mean(nees))
    ratio = rms[0.02] / rms[0.002]
    assert np.all((ratio > 8) & (ratio < 12)), ratio  # error linear in the noise (x10)
    assert rms[0.002][:2].max() < 0.004  # to noise level: a few millimetres


def test_binary_registration_of_a_generic_pair_is_unique_and_noise_free_exact():
    rng = np.random.default_rng(1)
    poses = np.column_stack([rng.uniform(-2, 2, (5, 2)), rng.uniform(-np.pi, np.pi, 5)])
    o = observe(poses, rng)
    regs = binary_register(o[2], o[4], 1e-6)
    assert len(regs) == 1
    assert np.allclose(regs[0].pose, relative(poses, 2, 4), atol=1e-9)
    assert np.allclose(o[2][regs[0].a], relative(poses, 2, 4)[:2])


def test_binary_registration_tolerates_clutter_and_misses_only_when_allowed():
    rng = np.random.default_rng(2)
    poses = np.column_stack([rng.uniform(-2, 2, (6, 2)), rng.uniform(-np.pi, np.pi, 6)])
    truth = relative(poses, 0, 1)
    o = observe(poses, rng, 0.005)
    oi = np.vstack([o[0], [[3.1, -2.7]]])  # a pillar seen by robot 0 only
    oj = o[1][np.hypot(*(o[1] - relative(poses, 1, 2)[:2]).T) > 0.05]  # robot 1 missed robot 2
    assert binary_register(oi, oj, 0.005) == []
    # robot 0's side leaves two points unmatched: the pillar and robot 2 (which robot 1 missed)
    assert binary_register(oi, oj, 0.005, max_unmatched=1) == []
    regs = binary_register(oi, oj, 0.005, max_unmatched=2)
    assert len(regs) >= 1
    assert pose_error(regs[0].pose, truth)[0] < 0.02


def test_binary_registration_ignores_points_beyond_the_range_limit():
    rng = np.random.default_rng(3)
    poses = np.column_stack([rng.uniform(-2.5, 2.5, (8, 2)), rng.uniform(-np.pi, np.pi, 8)])
    d = np.hypot(*(poses[0, :2] - poses[1, :2]))
    rmax = max(2.0, d + 0.3)
    o = observe(poses, rng, 0.003, max_range=rmax)
    assert not np.isclose(len(o[0]), 7) or not np.isclose(len(o[1]), 7)  # the range limit does cut
    regs = binary_register(o[0], o[1], 0.003, max_range=rmax)
    assert regs, "the true transform is feasible under the range limit"
    assert pose_error(regs[0].pose, relative(poses, 0, 1))[0] < 0.02


def test_relative_headings_remove_the_ambiguity_of_a_symmetric_pair():
    rng = np.random.default_rng(4)
    poses = with_headings(polygon(4), rng)
    o = observe(poses, rng)
    assert len(binary_register(o[0], o[1], 1e-6)) > 1
    # the same points, each with the measured heading of the robot it is
    hd = {}
    for i in (0, 1):
        rel = np.delete(between_xyt(poses[i], poses), i, 0)
        o[i], hd[i] = rel[:, :2], rel[:, 2]
    regs = binary_register(o[0], o[1], 1e-6, headings_i=hd[0], headings_j=hd[1])
    assert len(regs) == 1
    assert np.allclose(regs[0].pose, relative(poses, 0, 1), atol=1e-9)


def test_binary_registration_rejects_bad_input():
    with pytest.raises(ValueError, match="shape"):
        binary_register(np.zeros((3, 3)), np.zeros((2, 2)), 0.01)
    with pytest.raises(ValueError, match="finite"):
        binary_register([[np.nan, 0.0]], [[1.0, 0.0]], 0.01)
    with pytest.raises(ValueError, match="sigma"):
        binary_register([[1.0, 0.0]], [[1.0, 0.0]], 0.0)
    assert binary_register(np.zeros((0, 2)), [[1.0, 0.0]], 0.01) == []


# ------------------------------------------------------------------------------------------ PMR: the theorems
@pytest.mark.parametrize("k", [3, 4, 5, 6])
def test_regular_polygon_gives_k_minus_1_factorial_solutions_and_with_a_centre_k_factorial(k: int):
    """Slide 45 remark: the maximum (n-1)! is reached by a regular n-gon and by a regular (n-1)-gon with a robot
    at its centre (whichever robot is ego)."""
    rng = np.random.default_rng(k)
    for centre, egos in ((False, [0]), (True, [0, k])):
        P = polygon(k, centre=centre)
        n = len(P)
        poses = with_headings(P, rng)
        o = observe(poses, rng)
        assert rotational_symmetry_order(P) == k
        for ego in egos:
            res = multiple_registration(o, ego, 1e-6)
            assert len(res.solutions) == solution_count_theory(P, ego) == math.factorial(n - 1)
            assert res.registrations == n * (n - 1) // 2
            # every solution puts the robots exactly on the configuration, the truth among them
            truth = {j: relative(poses, ego, j) for j in range(n)}
            assert any(all(np.allclose(s.poses[j], truth[j], atol=1e-7) for j in truth) for s in res.solutions)
            P_ego = np.array([truth[j][:2] for j in range(n)])
            for s in res.solutions:
                placed = np.array([s.poses[j][:2] for j in range(n)])
                d = np.hypot(*(placed[:, None] - P_ego[None]).transpose(2, 0, 1))
                assert np.allclose(np.sort(d.min(1)), 0, atol=1e-7)
                assert len({s.features[j] for j in range(n) if j != ego}) == n - 1


def test_symmetric_configurations_are_ambiguous_and_asymmetric_ones_unique():
    rng = np.random.default_rng(7)
    inner = polygon(3, radius=0.6, phase=1.0)
    cases = {
        "two concentric squares": np.vstack([polygon(4), polygon(4, radius=0.5, phase=0.7)]),
        "triangle and hexagon": np.vstack([polygon(6, radius=1.3), inner]),
        "centre and antipodal pair": np.array([[0.0, 0.0], [1.0, 0.2], [-1.0, -0.2]]),
        "rectangle": np.array([[1.0, 0.5], [-1.0, 0.5], [-1.0, -0.5], [1.0, -0.5]]),
    }
    for name, P in cases.items():
        assert symmetry_metric(P) < 1e-9, name
        poses = with_headings(P, rng)
        o = observe(poses, rng)
        for ego in range(len(P)):
            res = multiple_registration(o, ego, 1e-6)
            want = solution_count_theory(P, ego)
            assert len(res.solutions) == want > 1, (name, ego, len(res.solutions), want)
            assert want <= math.factorial(len(P) - 1)
    for trial in range(40):
        P = spread(rng, int(rng.integers(3, 9)))
        assert symmetry_metric(P) > 1e-3
        poses = with_headings(P, rng)
        sigma = (0.002, 0.01)[trial % 2]
        res = multiple_registration(observe(poses, rng, sigma), 0, sigma)
        assert len(res.solutions) == 1, trial
        for j in range(1, len(P)):
            assert pose_error(res.solutions[0].poses[j], relative(poses, 0, j))[0] < 15 * sigma


def test_symmetry_metric_is_zero_only_at_symmetry_and_grows_with_the_distortion():
    P = polygon(5)
    assert symmetry_metric(P) < 1e-12
    d = [symmetry_metric(P + [[e, 0.0], [0, 0], [0, 0], [0, 0], [0, 0]]) for e in (0.01, 0.05, 0.2)]
    assert 0 < d[0] < d[1] < d[2]
    assert symmetry_metric(np.zeros((1, 2))) == 0.0


def test_noisy_near_symmetric_configuration_keeps_every_solution():
    rng = np.random.default_rng(8)
    P = polygon(4)
    poses = with_headings(P, rng)
    res = multiple_registration(observe(poses, rng, 0.005), 0, 0.005)
    assert len(res.solutions) == 6


def test_belief_gate_keeps_only_the_solutions_near_the_current_belief():
    rng = np.random.default_rng(9)
    poses = with_headings(polygon(5), rng)
    o = observe(poses, rng, 0.003)
    free = multiple_registration(o, 0, 0.003)
    assert len(free.solutions) == 24
    beliefs = {
        j: GroupGaussian(SE2, SE2.from_xytheta(relative(poses, 0, j)), np.diag([0.05**2, 0.05**2, 0.1**2]))
        for j in (1, 2)
    }
    gated = multiple_registration(o, 0, 0.003, beliefs=beliefs)
    # with robots 1 and 2 pinned, 3 and 4 can still swap: 2 solutions, and far fewer partial solutions
    assert len(gated.solutions) == 2
    assert gated.branches < free.branches / 4
    full = {j: GroupGaussian(SE2, SE2.from_xytheta(relative(poses, 0, j)), np.diag([0.05**2] * 3)) for j in range(1, 5)}
    one = multiple_registration(o, 0, 0.003, beliefs=full)
    assert len(one.solutions) == 1
    for j in range(1, 5):
        assert pose_error(one.solutions[0].poses[j], relative(poses, 0, j))[0] < 0.02


def test_pmr_chains_through_a_neighbour_for_a_robot_ego_cannot_see():
    rng = np.random.default_rng(10)
    P = np.array([[0.0, 0.0], [1.2, 0.1], [2.3, 0.5], [3.1, -0.4], [1.0, 1.3]])
    poses = with_headings(P, rng)
    o = observe(poses, rng, 0.003, max_range=2.5)
    res = multiple_registration(o, 0, 0.003, max_range=2.5)
    assert len(res.solutions) == 1 and not res.unreached
    s = res.solutions[0]
    assert s.features[3] is None  # robot 3 is 3.1 m from ego: placed through a neighbour's registration
    for j in range(1, 5):
        assert pose_error(s.poses[j], relative(poses, 0, j))[0] < 0.05


def test_pmr_reports_unreachable_robots_and_rejects_bad_input():
    o = {0: [[1.0, 0.0]], 1: [[1.0, 0.0]], 2: np.zeros((0, 2))}
    res = multiple_registration(o, 0, 0.01)
    assert res.unreached == [2] and len(res.solutions) == 1
    with pytest.raises(ValueError, match="ego"):
        multiple_registration(o, 5, 0.01)
    with pytest.raises(ValueError, match="max_solutions"):
        multiple_registration(o, 0, 0.01, max_solutions=0)
    big = observe(with_headings(polygon(6), np.random.default_rng(0)), np.random.default_rng(0))
    cut = multiple_registration(big, 0, 1e-6, max_solutions=10)
    assert cut.truncated and len(cut.solutions) == 10


def test_a_prior_keeps_only_the_registrations_near_it():
    rng = np.random.default_rng(11)
    poses = with_headings(polygon(5), rng)
    o = observe(poses, rng, 0.003)
    assert len(binary_register(o[0], o[1], 0.003)) == 4  # the regular pentagon: 4 places for robot 1
    truth = relative(poses, 0, 1)
    near = binary_register(o[0], o[1], 0.003, prior=(truth + [0.02, -0.02, 0.03], np.diag([0.05**2] * 3)))
    assert len(near) == 1 and pose_error(near[0].pose, truth)[0] < 0.01
    far = compose_xyt(truth, np.array([0.0, 0.0, np.pi]))
    assert binary_register(o[0], o[1], 0.003, prior=(far, np.diag([0.05**2] * 3))) == []
