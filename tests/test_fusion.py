"""Tests for swarmloc.fusion against the importance-sampled posterior of the DESIGN.md measurement model.

Reference: swarmloc.evaluation.montecarlo.importance_posterior with 10^6 samples (2 adaptive stages), which only
samples, multiplies and takes logs. Each reference is computed once per module and shared by the tests using it.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from swarmloc import GroupGaussian, fuse_absolute, fuse_relative
from swarmloc.evaluation.montecarlo import importance_posterior
from swarmloc.lie import SE2, SE3

IS_SAMPLES = 1_000_000
IS_STAGES = 2
MIN_ESS = 10_000
MEAN_TOL = 0.05  # |log(mu_true^-1 mu)|
COV_TOL = 0.05  # relative Frobenius


def rel_frob(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.linalg.norm(a - ref) / np.linalg.norm(ref))


def mean_error(G: type, mu_ref: np.ndarray, mu: np.ndarray) -> float:
    return float(np.linalg.norm(G.log(np.linalg.inv(mu_ref) @ mu)))


# ------------------------------------------------------------------------------------------------- cases
# Moderate cases: prior cov diag(0.1 .. 0.3), neighbour cov 0.02 .. 0.1, measurement cov 0.01 .. 0.02.
# The true pose is the prior mean moved by `delta`; each neighbour's belief is centred on the true pose of the
# neighbour moved by `off` standard deviations, so the measurements disagree with each other and with the prior.
PRIORS = {
    SE2: (SE2.from_xytheta(0.5, -0.3, 0.4), (0.1, 0.2, 0.3), (0.15, -0.2, 0.25)),
    SE3: (
        SE3.exp(np.array([0.5, -0.3, 0.2, 0.1, -0.2, 0.3])),
        (0.1, 0.15, 0.2, 0.2, 0.15, 0.1),
        (0.15, -0.2, 0.1, 0.2, 0.15, -0.1),
    ),
}
# per neighbour: (m_ik tangent, neighbour cov diag, measurement cov diag, offset of the neighbour's belief in stds)
NEIGHBOURS = {
    SE2: [
        ((1.2, 0.4, 0.5), (0.05, 0.03, 0.04), (0.01, 0.015, 0.01), (0.5, -0.3, 0.4)),
        ((-0.6, 1.0, -0.4), (0.03, 0.08, 0.02), (0.02, 0.01, 0.015), (-0.4, 0.2, -0.5)),
        ((0.3, -1.3, 0.9), (0.1, 0.04, 0.06), (0.015, 0.02, 0.01), (0.2, 0.5, 0.3)),
    ],
    SE3: [
        (
            (1.2, 0.4, -0.3, 0.2, -0.1, 0.5),
            (0.05, 0.03, 0.04, 0.04, 0.02, 0.03),
            (0.01, 0.015, 0.01, 0.01, 0.02, 0.015),
            (0.5, -0.3, 0.4, -0.2, 0.3, 0.1),
        ),
        (
            (-0.6, 1.0, 0.2, -0.3, 0.2, -0.4),
            (0.03, 0.08, 0.05, 0.02, 0.03, 0.04),
            (0.02, 0.01, 0.015, 0.015, 0.01, 0.02),
            (-0.4, 0.2, -0.5, 0.3, -0.1, 0.2),
        ),
        (
            (0.3, -1.3, 0.5, 0.4, 0.3, 0.9),
            (0.1, 0.04, 0.06, 0.03, 0.05, 0.02),
            (0.015, 0.02, 0.01, 0.02, 0.015, 0.01),
            (0.2, 0.5, 0.3, 0.1, -0.4, -0.3),
        ),
    ],
}


def make_case(G: type, K: int, prior_cov=None, delta=None, neighbour_covs=None, meas_cov=None):
    """Prior and K (neighbour_belief, measurement) pairs; the optional arguments override the moderate case."""
    mu, pc, dl = PRIORS[G]
    prior = GroupGaussian(G, mu, np.diag(prior_cov if prior_cov is not None else pc))
    g_true = mu @ G.exp(np.array(delta if delta is not None else dl))
    pairs = []
    for k, (m, nc, mc, off) in enumerate(NEIGHBOURS[G][:K]):
        m = G.exp(np.array(m))
        nc = np.array(neighbour_covs[k] if neighbour_covs is not None else nc)
        mc = np.array(meas_cov if meas_cov is not None else mc)
        belief = GroupGaussian(G, g_true @ m @ G.exp(np.sqrt(nc) * np.array(off)), np.diag(nc))
        pairs.append((belief, GroupGaussian(G, m, np.diag(mc))))
    return prior, pairs


LARGE = {  # SE(3), large uncertainty: the first-order variant falls clearly behind
    "prior_cov": (0.3, 0.3, 0.3, 0.2, 0.2, 0.2),
    "delta": (0.3, -0.3, 0.2, 0.3, 0.25, -0.2),
    "neighbour_covs": [(0.1, 0.08, 0.06, 0.05, 0.07, 0.06)],
    "meas_cov": (0.02,) * 6,
}


@cache
def reference(group_name: str, K: int, large: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    G = {"SE2": SE2, "SE3": SE3}[group_name]
    prior, pairs = make_case(G, K, **(LARGE if large else {}))
    return importance_posterior(prior, pairs, IS_SAMPLES, np.random.default_rng(2024), stages=IS_STAGES)


def fusion_errors(G: type, K: int, large: bool = False, **kwargs) -> tuple[float, float, float]:
    """(mean error, relative covariance error, ESS) of fuse_relative(**kwargs) against importance sampling."""
    prior, pairs = make_case(G, K, **(LARGE if large else {}))
    mu_ref, cov_ref, ess = reference(G.__name__, K, large)
    post = fuse_relative(prior, pairs, **kwargs)
    return mean_error(G, mu_ref, post.mean), rel_frob(post.cov, cov_ref), ess


FUSION_CASES = [(G, K) for G in (SE2, SE3) for K in (1, 2, 3)]


def _fid(case) -> str:
    G, K = case
    return f"{G.__name__}-{K}nb"


# ------------------------------------------------------------------------------------------------- accuracy
@pytest.mark.parametrize("case", FUSION_CASES, ids=_fid)
def test_fusion_vs_importance_sampling(case):
    G, K = case
    merr, cerr, ess = fusion_errors(G, K)
    assert ess >= MIN_ESS  # the reference is trustworthy
    assert merr <= MEAN_TOL
    assert cerr <= COV_TOL


@pytest.mark.parametrize("case", FUSION_CASES, ids=_fid)
def test_closed_form_single_step_vs_importance_sampling(case):
    G, K = case
    merr, cerr, ess = fusion_errors(G, K, iterations=1)
    assert ess >= MIN_ESS
    assert merr <= MEAN_TOL
    assert cerr <= COV_TOL


def test_first_order_worse_with_large_uncertainty():
    m2, c2, ess = fusion_errors(SE3, 1, large=True)
    m1, c1, _ = fusion_errors(SE3, 1, large=True, order=1)
    assert ess >= MIN_ESS
    assert m2 <= MEAN_TOL and c2 <= COV_TOL
    assert m1 >= 4.0 * m2 and m1 - m2 >= 0.015  # a clear margin, far above the reference's noise
    assert c1 > c2


def test_fusion_shrinks_covariance():
    prior, pairs = make_case(SE3, 3)
    post = fuse_relative(prior, pairs)
    np.testing.assert_array_equal(post.cov, post.cov.T)
    assert np.linalg.eigvalsh(prior.cov - post.cov).min() > 0
    one = fuse_relative(prior, pairs[:1])
    assert np.trace(post.cov) < np.trace(one.cov) < np.trace(prior.cov)


# ------------------------------------------------------------------------------------------------- special cases
@pytest.mark.parametrize("G", [SE2, SE3], ids=lambda G: G.__name__)
def test_no_measurements_returns_prior(G):
    prior, _ = make_case(G, 0)
    for kwargs in ({}, {"order": 1}, {"iterations": 1}):
        post = fuse_relative(prior, [], **kwargs)
        np.testing.assert_array_equal(post.mean, prior.mean)
        np.testing.assert_array_equal(post.cov, prior.cov)


@pytest.mark.parametrize("iterations", [1, 2])
@pytest.mark.parametrize("G", [SE2, SE3], ids=lambda G: G.__name__)
def test_known_neighbour_pulls_mean_to_nu(G, iterations):
    """A perfectly known neighbour and a nearly exact measurement fix the pose at nu = mu_k m_ik^-1."""
    rng = np.random.default_rng(3)
    prior = GroupGaussian(G, G.exp(0.5 * rng.standard_normal(G.dim)), 0.2 * np.eye(G.dim))
    m = G.exp(rng.standard_normal(G.dim))
    mu_k = prior.mean @ G.exp(0.3 * rng.standard_normal(G.dim)) @ m
    nu = mu_k @ np.linalg.inv(m)
    assert mean_error(G, nu, prior.mean) > 0.3
    eps = 1e-10
    pair = (GroupGaussian(G, mu_k, eps * np.eye(G.dim)), GroupGaussian(G, m, eps * np.eye(G.dim)))
    post = fuse_relative(prior, [pair], iterations=iterations)
    assert mean_error(G, nu, post.mean) <= 1e-8
    assert np.abs(post.cov).max() <= 100 * eps


@pytest.mark.parametrize("G", [SE2, SE3], ids=lambda G: G.__name__)
def test_fuse_absolute_at_the_mean_is_information_sum(G):
    prior, _ = make_case(G, 0)
    W = np.diag(np.linspace(0.02, 0.05, G.dim))
    post = fuse_absolute(prior, [GroupGaussian(G, prior.mean, W)])
    np.testing.assert_allclose(post.mean, prior.mean, atol=1e-15)
    np.testing.assert_allclose(
        post.cov, np.linalg.inv(np.linalg.inv(prior.cov) + np.linalg.inv(W)), rtol=1e-12, atol=1e-15
    )


def test_batched_fusion_matches_one_by_one():
    cases = [make_case(SE2, 2), make_case(SE2, 2, delta=(-0.1, 0.3, -0.2))]
    prior = GroupGaussian(SE2, np.stack([c[0].mean for c in cases]), np.stack([c[0].cov for c in cases]))
    pairs = [
        tuple(
            GroupGaussian(SE2, np.stack([c[1][k][j].mean for c in cases]), np.stack([c[1][k][j].cov for c in cases]))
            for j in (0, 1)
        )
        for k in range(2)
    ]
    post = fuse_relative(prior, pairs)
    for b, (p, prs) in enumerate(cases):
        single = fuse_relative(p, prs)
        np.testing.assert_allclose(post.mean[b], single.mean, atol=1e-12)
        np.testing.assert_allclose(post.cov[b], single.cov, rtol=1e-10, atol=1e-15)


# ------------------------------------------------------------------------------------------------- bad inputs
def test_bad_measurements():
    prior, pairs = make_case(SE2, 2)
    nb, meas = pairs[0]
    prior3, pairs3 = make_case(SE3, 1)
    with pytest.raises(
        ValueError, match=r"^fuse_relative: measurements\[0\] must be a \(neighbour_belief, measurement\) pair"
    ):
        fuse_relative(prior, [nb])
    with pytest.raises(
        ValueError, match=r"^fuse_relative: measurements\[1\] must be a \(neighbour_belief, measurement\) pair"
    ):
        fuse_relative(prior, [(nb, meas), (nb, meas, meas)])
    with pytest.raises(ValueError, match=r"^fuse_relative: measurements\[0\] neighbour_belief is on SE3, prior on SE2"):
        fuse_relative(prior, [(pairs3[0][0], meas)])
    with pytest.raises(ValueError, match=r"^fuse_relative: measurements\[0\] measurement is on SE3, prior on SE2"):
        fuse_relative(prior, [(nb, pairs3[0][1])])
    with pytest.raises(
        ValueError, match=r"^fuse_relative: measurements\[1\] measurement must be a GroupGaussian, got ndarray"
    ):
        fuse_relative(prior, [(nb, meas), (nb, np.eye(3))])
    with pytest.raises(
        ValueError, match=r"^fuse_relative: measurements\[0\] neighbour_belief must be a GroupGaussian, got tuple"
    ):
        fuse_relative(prior, [((np.eye(3), np.eye(3)), meas)])
    with pytest.raises(ValueError, match=r"^fuse_relative: argument 'order' must be 1 or 2, got 3"):
        fuse_relative(prior, pairs, order=3)
    with pytest.raises(ValueError, match=r"^fuse_relative: argument 'iterations' must be >= 1, got 0"):
        fuse_relative(prior, pairs, iterations=0)
    with pytest.raises(ValueError, match=r"^fuse_relative: argument 'prior' must be a GroupGaussian, got ndarray"):
        fuse_relative(np.eye(3), pairs)
    batched = GroupGaussian(SE2, np.stack([nb.mean] * 2), np.stack([nb.cov] * 2))
    with pytest.raises(
        ValueError, match=r"^fuse_relative: measurements\[0\] neighbour_belief has batch shape \(2,\), prior \(\)"
    ):
        fuse_relative(prior, [(batched, meas)])
