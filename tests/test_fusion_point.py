"""Range/bearing updates on SE(2) (fuse_point_measurement) against importance sampling, with the target's
uncertainty (an uncertain neighbour robot or a landmark with known position and std)."""

from __future__ import annotations

import numpy as np
import pytest

from swarmloc import SE2, GroupGaussian
from swarmloc.evaluation.montecarlo import importance_posterior_point
from swarmloc.fusion import fuse_point_measurement, point_innovation, point_measurement

pytestmark = pytest.mark.unit


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def _case(seed: int, kind: str, robot: bool, s: float):
    rng = np.random.default_rng(seed)
    mu = SE2.from_xytheta([0.0, 0.0, 0.3])
    P = np.diag([s, s, s / 2])
    gi = mu @ SE2.exp(rng.multivariate_normal(np.zeros(3), P))
    if robot:
        mk = SE2.from_xytheta([2.0, 1.0, 1.0])
        Pk = np.diag([0.02, 0.03, 0.01])
        gk = mk @ SE2.exp(rng.multivariate_normal(np.zeros(3), Pk))
        target, tm, tc, pk = GroupGaussian(SE2, mk, Pk), mk, Pk, gk[:2, 2]
    else:
        p, C = np.array([2.0, -1.5]), np.diag([0.01, 0.02])
        pk = rng.multivariate_normal(p, C)
        target, tm, tc = (p, C), p, C
    q = gi[:2, :2].T @ (pk - gi[:2, 2])
    Rf = np.diag([0.05**2, 0.03**2])
    z = np.array([np.hypot(*q), np.arctan2(q[1], q[0])]) + rng.multivariate_normal(np.zeros(2), Rf)
    sel = {"range_bearing": [0, 1], "range": [0], "bearing": [1]}[kind]
    prior = GroupGaussian(SE2, mu, P)
    ref = importance_posterior_point(prior, kind, z[sel], Rf[np.ix_(sel, sel)], target, 10**6, rng)
    return (mu, P, kind, z[sel], Rf[np.ix_(sel, sel)], tm, tc), ref


@pytest.mark.parametrize(
    ("kind", "robot", "s"),
    [("range_bearing", True, 0.05), ("range_bearing", False, 0.05), ("range_bearing", True, 0.2),
     ("range_bearing", False, 0.2)],
)  # fmt: skip
def test_range_bearing_update_matches_importance_sampling(kind: str, robot: bool, s: float):
    args, (m_is, c_is, ess) = _case(3, kind, robot, s)
    assert ess > 10_000
    m, c = fuse_point_measurement(*args)  # default: 3 iterations, second order
    assert np.linalg.norm(SE2.log(np.linalg.inv(m_is) @ m)) <= 0.03
    assert _rel(c, c_is) <= 0.06
    # one EKF step on the group is measurably worse when the prior is wide
    m1, c1 = fuse_point_measurement(*args, iterations=1)
    if s >= 0.2:
        assert np.linalg.norm(SE2.log(np.linalg.inv(m_is) @ m1)) > 3 * np.linalg.norm(SE2.log(np.linalg.inv(m_is) @ m))
        assert _rel(c1, c_is) > 2 * _rel(c, c_is)


@pytest.mark.parametrize(("kind", "cov_tol"), [("range", 0.15), ("bearing", 0.03)])
def test_range_only_and_bearing_only_small_uncertainty(kind: str, cov_tol: float):
    """Mean within 0.02; the range-only posterior is a ring segment, not a Gaussian: its covariance is matched
    only to 13% (measured), the bearing-only one to 1%."""
    args, (m_is, c_is, ess) = _case(3, kind, kind == "range", 0.05)
    assert ess > 10_000
    m, c = fuse_point_measurement(*args)
    assert np.linalg.norm(SE2.log(np.linalg.inv(m_is) @ m)) <= 0.02
    assert _rel(c, c_is) <= cov_tol


def test_second_order_recentring_beats_first_order_in_one_step():
    args, (m_is, c_is, _) = _case(3, "range_bearing", True, 0.2)
    _, c2 = fuse_point_measurement(*args, iterations=1, order=2)
    _, c1 = fuse_point_measurement(*args, iterations=1, order=1)
    assert _rel(c2, c_is) < _rel(c1, c_is)


def test_point_innovation_is_chi_square_distributed():
    rng = np.random.default_rng(0)
    mu, P = SE2.from_xytheta([0, 0, 0]), np.diag([1e-3, 1e-3, 1e-4])
    p, C, R = np.array([3.0, 1.0]), np.diag([1e-4, 1e-4]), np.diag([0.05**2, 0.02**2])
    nis = []
    for _ in range(3000):
        g = mu @ SE2.exp(rng.multivariate_normal(np.zeros(3), P))
        pk = rng.multivariate_normal(p, C)
        q = g[:2, :2].T @ (pk - g[:2, 2])
        z = np.array([np.hypot(*q), np.arctan2(q[1], q[0])]) + rng.multivariate_normal(np.zeros(2), R)
        nis.append(point_innovation(mu, P, point_measurement("range_bearing", z, R, p, C)))
    assert abs(np.mean(nis) - 2.0) < 0.15  # chi-square with 2 dof has mean 2
