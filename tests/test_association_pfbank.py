"""The bank of particle filters (slides 61-63): consistency (NEES against chi-square bounds), ambiguity from a
symmetric start that motion resolves, kidnapping resets, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from swarmloc.association import multiple_registration
from swarmloc.association.pfbank import BankSettings, ParticleFilterBank
from swarmloc.lie import SE2, between_xyt, compose_xyt, exp_xyt

pytestmark = pytest.mark.unit


def nees(est, truth: np.ndarray) -> float:
    y = SE2.log(SE2.from_xytheta(between_xyt(SE2.to_xytheta(est.gaussian.mean), truth)))
    return float(y @ np.linalg.solve(est.gaussian.cov, y))


def test_nees_of_the_bank_estimate_is_within_chi_square_bounds():
    R = np.diag([0.03**2, 0.03**2, 0.05**2])
    Qi = np.diag([0.01**2, 0.005**2, 0.02**2])
    Qj = np.diag([0.01**2, 0.005**2, 0.02**2])
    di, dj = np.array([0.1, 0.0, 0.05]), np.array([0.08, 0.01, -0.04])
    runs, steps = 60, 8
    rng = np.random.default_rng(0)
    values = []
    for run in range(runs):
        bank = ParticleFilterBank(BankSettings.checked(n_particles=1000), rng=run)
        q = np.array([1.0, 0.5, 0.3])
        assert bank.update(7, [(compose_xyt(q, exp_xyt(rng.multivariate_normal(np.zeros(3), R))), R)]) == "initialized"
        for _ in range(steps):
            step_i = compose_xyt(di, exp_xyt(rng.multivariate_normal(np.zeros(3), Qi)))
            step_j = compose_xyt(dj, exp_xyt(rng.multivariate_normal(np.zeros(3), Qj)))
            q = compose_xyt(between_xyt(step_i, q), step_j)
            bank.predict_ego(di, Qi)
            bank.predict_neighbour(7, dj, Qj)
            h = compose_xyt(q, exp_xyt(rng.multivariate_normal(np.zeros(3), R)))
            assert bank.update(7, [(h, R)]) == "updated"
        est = bank.estimate(7)
        assert not est.ambiguous
        values.append(nees(est, q))
    anees = np.mean(values)
    lo, hi = chi2.ppf([0.005, 0.995], 3 * runs) / runs
    assert lo < anees < hi, (anees, lo, hi)


def triangle(phase: float = 0.2) -> np.ndarray:
    a = phase + 2 * np.pi * np.arange(3) / 3
    return np.column_stack([np.cos(a), np.sin(a), [0.4, -1.0, 2.5]])


def observations(poses: np.ndarray, rng: np.random.Generator, sigma: float) -> dict[int, np.ndarray]:
    out = {}
    for i in range(len(poses)):
        rel = np.delete(between_xyt(poses[i], poses)[:, :2], i, 0)
        out[i] = rng.permutation(rel + sigma * rng.standard_normal(rel.shape))
    return out


def test_a_symmetric_start_is_ambiguous_until_motion_breaks_the_symmetry():
    sigma = 0.005
    rng = np.random.default_rng(1)
    world = triangle()
    bank = ParticleFilterBank(BankSettings.checked(n_particles=1000), rng=1)
    res = multiple_registration(observations(world, rng, sigma), 0, sigma)
    assert len(res.solutions) == 2  # (n - 1)! for the equilateral triangle
    for j in (1, 2):
        bank.update(j, res.hypotheses(j))
        est = bank.estimate(j)
        assert est.ambiguous and len(est.modes) == 2
        assert all(0.35 < m < 0.65 for _, m in est.modes)
    # ego stands still; robot 1 drives forward, robot 2 turns on the spot: the triangle loses its symmetry
    Q = np.diag([0.003**2, 0.003**2, 0.005**2])
    moves = {0: np.zeros(3), 1: np.array([0.06, 0.0, 0.0]), 2: np.array([0.0, 0.0, 0.2])}
    solutions = []
    for _ in range(5):
        world = np.array([compose_xyt(world[r], moves[r]) for r in range(3)])
        bank.predict_ego(moves[0], Q)
        for j in (1, 2):
            bank.predict_neighbour(j, moves[j], Q)
        res = multiple_registration(observations(world, rng, sigma), 0, sigma)
        solutions.append(len(res.solutions))
        for j in (1, 2):
            bank.update(j, res.hypotheses(j))
    assert solutions[-1] == 1
    for j in (1, 2):
        est = bank.estimate(j)
        truth = between_xyt(world[0], world[j])
        assert not est.ambiguous, j
        mean = SE2.to_xytheta(est.gaussian.mean)
        assert np.hypot(*(mean[:2] - truth[:2])) < 0.02
        assert nees(est, truth) < chi2.ppf(0.999, 3)


def test_ambiguity_persists_while_the_formation_stays_symmetric():
    sigma = 0.005
    rng = np.random.default_rng(2)
    world = triangle()
    Q = np.diag([0.003**2, 0.003**2, 0.005**2])
    # headings symmetric too (tangent to the circle) and the same body-frame move for all: the formation turns
    # about its centre, still symmetric, and every robot's odometry is the same -- nothing can tell 1 from 2
    world[:, 2] = np.arctan2(world[:, 1], world[:, 0]) + np.pi / 2
    move = np.array([0.05, 0.0, 0.05])
    bank = ParticleFilterBank(BankSettings.checked(n_particles=1000), rng=2)
    res = multiple_registration(observations(world, rng, sigma), 0, sigma)
    for j in (1, 2):
        bank.update(j, res.hypotheses(j))
    for _ in range(5):
        world = np.array([compose_xyt(world[r], move) for r in range(3)])
        bank.predict_ego(move, Q)
        for j in (1, 2):
            bank.predict_neighbour(j, move, Q)
        res = multiple_registration(observations(world, rng, sigma), 0, sigma)
        assert len(res.solutions) == 2
        for j in (1, 2):
            bank.update(j, res.hypotheses(j))
    assert all(bank.estimate(j).ambiguous for j in (1, 2))


def test_a_kidnapped_robot_resets_its_filter():
    R = np.diag([0.01**2, 0.01**2, 0.02**2])
    bank = ParticleFilterBank(BankSettings.checked(n_particles=500), rng=3)
    bank.update(4, [(np.array([1.0, 0.0, 0.0]), R)])
    assert bank.update(4, [(np.array([1.0, 0.01, 0.0]), R)]) == "updated"
    assert bank.update(4, [(np.array([-2.0, 1.0, 2.0]), R)]) == "reset"
    est = bank.estimate(4)
    assert np.allclose(SE2.to_xytheta(est.gaussian.mean), [-2.0, 1.0, 2.0], atol=0.01)
    assert bank.counts == {"initialized": 1, "updated": 1, "reset": 1}
    assert bank.update(4, []) == "none"
    patient = ParticleFilterBank(BankSettings.checked(n_particles=500, reset_after=3), rng=3)
    patient.update(4, [(np.array([1.0, 0.0, 0.0]), R)])
    far = [(np.array([-2.0, 1.0, 2.0]), R)]
    assert [patient.update(4, far) for _ in range(3)] == ["unexplained", "unexplained", "reset"]
    assert patient.update(4, [(np.array([1.0, 0.0, 0.0]), R)]) == "unexplained"  # the count starts again


def test_bank_rejects_bad_input():
    with pytest.raises(ValueError, match="n_particles"):
        BankSettings.checked(n_particles=3)
    with pytest.raises(ValueError, match="mode_radius"):
        BankSettings.checked(n_particles=100, mode_radius=0.0)
    with pytest.raises(ValueError, match="mode_radius"):
        BankSettings.checked(mode_radius=float("inf"))
    with pytest.raises(ValueError, match="reset_after"):
        BankSettings.checked(reset_after=True)
    with pytest.raises(ValueError, match="unknown field"):
        BankSettings.checked(modes=3)
    with pytest.raises(ValueError, match="n_particles"):  # built directly, unchecked: the bank checks it
        ParticleFilterBank(BankSettings(n_particles=3))
    with pytest.raises(TypeError, match="settings must be a BankSettings"):  # the count the bank took before
        ParticleFilterBank(1000)  # type: ignore[arg-type]
    bank = ParticleFilterBank(BankSettings.checked(n_particles=100), rng=0)
    with pytest.raises(KeyError, match="no filter"):
        bank.estimate(1)
    with pytest.raises(ValueError, match="symmetric"):
        bank.update(1, [(np.zeros(3), np.array([[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]]))])
    bank.update(1, [(np.zeros(3), np.eye(3) * 1e-4)])
    with pytest.raises(ValueError, match="positive definite"):
        bank.predict_ego(np.zeros(3), -np.eye(3))


def test_a_scattered_filter_is_ambiguous_not_an_error():
    """Particles spread so thin that no mode holds ``ambiguity_mass`` (seen on MRCLAM dataset 6): the estimate is
    the heaviest mode's, flagged ambiguous (it raised IndexError before)."""
    bank = ParticleFilterBank(BankSettings.checked(n_particles=400), rng=1)
    R = np.diag([0.01**2, 0.01**2, 0.02**2])
    bank.update(2, [(np.array([1.0, 0.0, 0.0]), R)])
    rng = np.random.default_rng(0)
    bank.particles[2] = np.column_stack([rng.uniform(-20, 20, (400, 2)), rng.uniform(-np.pi, np.pi, 400)])
    est = bank.estimate(2)
    assert est.ambiguous and np.all(np.isfinite(est.gaussian.cov))
