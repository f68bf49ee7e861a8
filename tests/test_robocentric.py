"""Relative mutual localization (slides 22-28): Jacobians against finite differences, the prediction against exact
composition, the joint filter consistent and separate filters over-confident (Monte Carlo NEES against its chi-square
band), and absolute mutual localization's covariance against Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest

from swarmloc.estimators import robocentric as rc
from swarmloc_studies.robocentric import robocentric_monte_carlo

pytestmark = pytest.mark.unit


def _fd(f, x, eps=1e-6):
    x = np.asarray(x, float)
    cols = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = eps
        diff = f(x + d) - f(x - d)
        diff[2] = (diff[2] + np.pi) % (2 * np.pi) - np.pi
        cols.append(diff / (2 * eps))
    return np.column_stack(cols)


@pytest.mark.parametrize("seed", range(5))
def test_jacobians_match_finite_differences(seed):
    rng = np.random.default_rng(seed)
    a, b, u1, uj = (np.array([*rng.normal(size=2), rng.uniform(-3, 3)]) for _ in range(4))
    _, Ja, Jb = rc.compose(a, b)
    np.testing.assert_allclose(Ja, _fd(lambda x: rc.compose(x, b)[0], a), atol=1e-7)
    np.testing.assert_allclose(Jb, _fd(lambda x: rc.compose(a, x)[0], b), atol=1e-7)
    np.testing.assert_allclose(rc.inverse(a)[1], _fd(lambda x: rc.inverse(x)[0], a), atol=1e-7)
    _, Jq, J1, Jj = rc._predict_one(a, u1, uj)
    np.testing.assert_allclose(Jq, _fd(lambda x: rc._predict_one(x, u1, uj)[0], a), atol=1e-7)
    np.testing.assert_allclose(J1, _fd(lambda x: rc._predict_one(a, x, uj)[0], u1), atol=1e-7)
    np.testing.assert_allclose(Jj, _fd(lambda x: rc._predict_one(a, u1, x)[0], uj), atol=1e-7)
    q = rng.normal(size=(3, 3))
    for i, j in ((-1, 1), (2, -1), (0, 2)):
        _, Js = rc.relative_measurement(q, i, j)
        for k, J in Js.items():

            def f(x, k=k, i=i, j=j):
                qq = q.copy()
                qq[k] = x
                return rc.relative_measurement(qq, i, j)[0]

            np.testing.assert_allclose(J, _fd(f, q[k]), atol=1e-7)


def test_prediction_is_the_exact_composition():
    rng = np.random.default_rng(1)
    g1, gj, u1, uj = (np.array([*rng.normal(size=2), rng.uniform(-3, 3)]) for _ in range(4))
    q = rc.compose(rc.inverse(g1)[0], gj)[0]
    new = rc._predict_one(q, u1, uj)[0]
    g1n, gjn = rc.compose(g1, u1)[0], rc.compose(gj, uj)[0]
    np.testing.assert_allclose(new, rc.compose(rc.inverse(g1n)[0], gjn)[0], atol=1e-12)


@pytest.fixture(scope="module")
def mc():
    return robocentric_monte_carlo(runs=40, steps=60, robots=4, seed=0)


def test_joint_filter_is_consistent(mc):
    lo, hi = mc["band"]
    assert lo < mc["joint_mean_anees"] < hi
    assert mc["joint_in_band"] >= 0.8


def test_separate_filters_are_over_confident(mc):
    lo, hi = mc["band"]
    assert mc["separate_mean_anees"] > hi * 1.2  # the slides' claim: neglected cross-covariances
    assert mc["separate_in_band"] <= 0.2


def test_absolute_mutual_localization_covariance_matches_monte_carlo():
    rng = np.random.default_rng(4)
    q, p1, pj = np.array([1.0, 0.5, 0.4]), np.array([2.0, -1.0, 1.2]), np.array([-0.5, 0.7, -0.8])
    P = np.diag([0.01, 0.02, 0.005])
    mean, cov = rc.absolute_mutual(q, P, p1, P * 0.5, pj, P * 2.0)
    n = 100_000
    xs = np.array([
        rc.compose(rc.compose(p1 + e1, q + e2)[0], rc.inverse(pj + e3)[0])[0]
        for e1, e2, e3 in zip(rng.multivariate_normal(np.zeros(3), P * 0.5, n // 10),
                              rng.multivariate_normal(np.zeros(3), P, n // 10),
                              rng.multivariate_normal(np.zeros(3), P * 2.0, n // 10), strict=True)
    ])  # fmt: skip
    d = xs - mean
    d[:, 2] = (d[:, 2] + np.pi) % (2 * np.pi) - np.pi
    emp = d.T @ d / len(d)
    # first order: relative error of the sample covariance ~ sqrt(2/N) ~ 1.4% at N = 10^4, plus second-order terms
    np.testing.assert_allclose(emp, cov, rtol=0.1, atol=2e-3)
    np.testing.assert_allclose(d.mean(axis=0), 0.0, atol=0.02)
