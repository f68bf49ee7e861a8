"""Tests for swarmloc.gaussian: GroupGaussian sampling, density, transformations, convolution, contours, validation.

The convolution is checked against 10^6-sample Monte Carlo (swarmloc.evaluation.montecarlo.convolution_mc) in
cases with rotation standard deviations >= 0.4 rad, where the first-order formula A + B is off by >= 3%.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.stats
from matplotlib.path import Path

from swarmloc import GroupGaussian
from swarmloc.evaluation.montecarlo import convolution_mc
from swarmloc.gaussian import check_covariance
from swarmloc.lie import SE2, SE3

pytestmark = pytest.mark.unit


GROUPS = [SE2, SE3]


def _gid(G: type) -> str:
    return G.__name__


def rel_frob(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.linalg.norm(a - ref) / np.linalg.norm(ref))


def random_spd(d: int, rng: np.random.Generator, scales: np.ndarray) -> np.ndarray:
    """Correlated SPD matrix with standard deviations ``scales`` (correlations up to about 0.5)."""
    A = rng.standard_normal((d, d))
    C = A @ A.T + d * np.eye(d)
    s = 1.0 / np.sqrt(np.diag(C))
    C = C * s[:, None] * s[None, :]
    return C * scales[:, None] * scales[None, :]


def gaussian(G: type, seed: int, t_std: float = 0.3, r_std: float = 0.3) -> GroupGaussian:
    rng = np.random.default_rng(seed)
    mean = G.exp(np.concatenate([rng.uniform(-2, 2, G.n), rng.uniform(-1, 1, G.dim - G.n)]))
    scales = np.array([t_std] * G.n + [r_std] * (G.dim - G.n))
    return GroupGaussian(G, mean, random_spd(G.dim, rng, scales))


def empirical_cov(G: type, mean: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample mean and second moment of ``log(mean^-1 g)``."""
    y = G.log(np.linalg.inv(mean) @ g)
    return y.mean(axis=0), y.T @ y / len(y)


# ------------------------------------------------------------------------------------------------- sampling
@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_sample_covariance(G):
    gg = gaussian(G, 1)
    g = gg.sample(100_000, np.random.default_rng(11))
    assert g.shape == (100_000, G.n + 1, G.n + 1)
    m, C = empirical_cov(G, gg.mean, g)
    assert rel_frob(C, gg.cov) <= 0.03
    assert np.all(np.abs(m) <= 5 * np.sqrt(np.diag(gg.cov) / 100_000))
    # reproducible from the seed, different for another seed
    np.testing.assert_array_equal(gg.sample(5, 3), gg.sample(5, np.random.default_rng(3)))
    assert not np.allclose(gg.sample(5, 3), gg.sample(5, 4))
    assert gg.sample(0, 1).shape == (0, G.n + 1, G.n + 1) and gg.sample(np.int64(2), 1).shape[0] == 2
    for n in (-1, 10**12, 2.0, True):  # numpy's own error, or a 22 TiB allocation attempt, before
        with pytest.raises(ValueError, match=r"GroupGaussian.sample: n must be an integer in \[0, "):
            gg.sample(n, 1)


@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_sample_batched(G):
    parts = [gaussian(G, s) for s in (1, 2)]
    gg = GroupGaussian(G, np.stack([p.mean for p in parts]), np.stack([p.cov for p in parts]))
    assert gg.batch_shape == (2,)
    g = gg.sample(50_000, np.random.default_rng(5))
    assert g.shape == (50_000, 2, G.n + 1, G.n + 1)
    for b, p in enumerate(parts):
        assert rel_frob(empirical_cov(G, p.mean, g[:, b])[1], p.cov) <= 0.03
        assert gg[b].cov.tobytes() == p.cov.tobytes()


# ------------------------------------------------------------------------------------------------- density
@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_logpdf_formula(G):
    gg = gaussian(G, 2)
    g = gaussian(G, 3).sample(50, np.random.default_rng(0))
    y = np.array([G.vee(scipy.linalg.logm(np.linalg.inv(gg.mean) @ gi).real) for gi in g])
    ref = scipy.stats.multivariate_normal(np.zeros(G.dim), gg.cov).logpdf(y)
    np.testing.assert_allclose(gg.logpdf(g), ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(gg.mahalanobis2(g), np.einsum("ni,ij,nj->n", y, np.linalg.inv(gg.cov), y), rtol=1e-9)
    np.testing.assert_allclose(gg.tangent_of(g), y, atol=1e-9)
    # at the mean: the normalizer only
    assert gg.logpdf(gg.mean) == pytest.approx(-0.5 * np.log(np.linalg.det(2 * np.pi * gg.cov)), rel=1e-12)


# ------------------------------------------------------------------------------------------------- transformations
@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_left_multiply_vs_sampling(G):
    gg = gaussian(G, 4, r_std=0.4)
    h = G.exp(np.linspace(-1.0, 1.2, G.dim))
    out = gg.left_multiply(h)
    np.testing.assert_allclose(out.mean, h @ gg.mean, atol=1e-15)
    g = h @ gg.sample(100_000, np.random.default_rng(1))
    assert rel_frob(empirical_cov(G, out.mean, g)[1], out.cov) <= 0.03


@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_right_multiply_vs_sampling(G):
    gg = gaussian(G, 5, r_std=0.4)
    h = G.exp(np.linspace(1.5, -0.8, G.dim))
    out = gg.right_multiply(h)
    np.testing.assert_allclose(out.mean, gg.mean @ h, atol=1e-15)
    g = gg.sample(100_000, np.random.default_rng(2)) @ h
    C = empirical_cov(G, out.mean, g)[1]
    assert rel_frob(C, out.cov) <= 0.03
    assert rel_frob(C, gg.cov) > 0.1  # the covariance really is transformed here


@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_inverse_vs_sampling(G):
    gg = gaussian(G, 6, t_std=0.05, r_std=0.05)
    out = gg.inverse()
    np.testing.assert_allclose(out.mean, np.linalg.inv(gg.mean), atol=1e-14)
    g = np.linalg.inv(gg.sample(100_000, np.random.default_rng(3)))
    C = empirical_cov(G, out.mean, g)[1]
    assert rel_frob(C, out.cov) <= 0.03
    assert rel_frob(C, gg.cov) > 0.1


# ------------------------------------------------------------------------------------------------- convolution
# (group, mean1, cov1, mean2, cov2): rotation standard deviations 0.45 .. 0.5 rad
CONV_CASES = {
    "SE2-a": (
        SE2,
        SE2.from_xytheta(1.0, 0.5, 0.3),
        np.diag([0.02, 0.01, 0.25]),
        SE2.from_xytheta(2.0, -0.5, 0.5),
        np.diag([0.05, 0.02, 0.2]),
    ),
    "SE2-b": (
        SE2,
        SE2.from_xytheta(0.3, 0.2, -0.4),
        np.diag([0.04, 0.01, 0.25]),
        SE2.from_xytheta(2.0, 0.0, 0.0),
        np.diag([0.04, 0.01, 0.25]),
    ),
    "SE3-a": (
        SE3,
        SE3.exp(np.array([1.0, 0.5, 0.2, 0.1, 0.2, 0.3])),
        np.diag([0.02, 0.02, 0.02, 0.2, 0.2, 0.2]),
        SE3.exp(np.array([2.0, -0.5, 0.3, 0.2, -0.1, 0.4])),
        np.diag([0.05, 0.02, 0.02, 0.2, 0.16, 0.16]),
    ),
    "SE3-b": (
        SE3,
        SE3.identity(),
        np.diag([0.05, 0.05, 0.05, 0.25, 0.16, 0.16]),
        SE3.exp(np.array([2.0, 0.0, 0.0, 0.0, 0.0, 0.3])),
        np.diag([0.02, 0.02, 0.02, 0.16, 0.16, 0.25]),
    ),
}
MC_SAMPLES = 1_000_000


def convolution_errors(name: str) -> tuple[float, float]:
    """Relative Frobenius errors of the (second, first)-order convolution covariance against Monte Carlo."""
    G, m1, S1, m2, S2 = CONV_CASES[name]
    a, b = GroupGaussian(G, m1, S1), GroupGaussian(G, m2, S2)
    mc = convolution_mc(a, b, MC_SAMPLES, np.random.default_rng(42))
    return rel_frob(a.convolve(b).cov, mc), rel_frob(a.convolve(b, order=1).cov, mc)


@pytest.mark.parametrize("name", list(CONV_CASES))
def test_convolution_vs_monte_carlo(name):
    G, m1, S1, m2, S2 = CONV_CASES[name]
    assert min(np.sqrt(np.diag(S1)[G.n :]).max(), np.sqrt(np.diag(S2)[G.n :]).max()) >= 0.4
    second, first = convolution_errors(name)
    assert first >= 0.03  # the case is one where the second-order term matters ...
    assert second <= 0.015  # ... and the second-order formula captures it


@pytest.mark.parametrize("name", list(CONV_CASES))
def test_convolution_algebra(name):
    G, m1, S1, m2, S2 = CONV_CASES[name]
    a, b = GroupGaussian(G, m1, S1), GroupGaussian(G, m2, S2)
    c2, c1 = a.convolve(b), a.convolve(b, order=1)
    np.testing.assert_array_equal(c2.mean, m1 @ m2)
    np.testing.assert_array_equal(c1.mean, m1 @ m2)
    np.testing.assert_array_equal(c2.cov, c2.cov.T)
    np.testing.assert_array_equal(c1.cov, c1.cov.T)
    Ad = G.Ad(np.linalg.inv(m2))
    A = Ad @ S1 @ Ad.T
    np.testing.assert_allclose(c1.cov, A + S2, rtol=1e-14, atol=1e-16)  # order 1 is exactly A + B
    assert np.linalg.eigvalsh(c2.cov).min() > 0
    check_covariance(c2.cov, G.dim, "test")
    # F(A, B) is symmetric in A and B: convolving with the roles' covariances swapped (identity means) agrees
    ia, ib = GroupGaussian(G, G.identity(), A), GroupGaussian(G, G.identity(), S2)
    np.testing.assert_allclose(ia.convolve(ib).cov, ib.convolve(ia).cov, rtol=1e-13, atol=1e-16)
    np.testing.assert_allclose(ia.convolve(ib).cov, c2.cov, rtol=1e-12, atol=1e-16)


# ------------------------------------------------------------------------------------------------- banana contour
def _banana() -> GroupGaussian:
    """Start with heading std 0.55 rad, then drive 1 m: the classic banana (right perturbation)."""
    start = GroupGaussian(SE2, SE2.from_xytheta(0.5, -0.2, 0.3), np.diag([0.001, 0.01, 0.3]))
    return start.right_multiply(SE2.from_xytheta(1.0, 0.0, 0.0))


CONTOUR_CASES = {
    "banana": _banana,
    "diag": lambda: GroupGaussian(SE2, SE2.from_xytheta(0.5, -0.2, 0.3), np.diag([0.001, 0.01, 0.3])),
}


def contour_mass(name: str, mass: float) -> tuple[list[np.ndarray], float, bool]:
    gg = CONTOUR_CASES[name]()
    lines = gg.xy_contour(mass)
    xy = SE2.to_xytheta(gg.sample(100_000, np.random.default_rng(8)))[:, :2]
    path = Path(lines[0])
    return lines, float(path.contains_points(xy).mean()), bool(path.contains_point(gg.mean[:2, 2]))


@pytest.mark.parametrize("name", list(CONTOUR_CASES))
def test_xy_contour_mass(name):
    lines, inside, has_mean = contour_mass(name, 0.9)
    assert len(lines) == 1
    loop = lines[0]
    assert loop.ndim == 2 and loop.shape[1] == 2 and len(loop) >= 20
    np.testing.assert_array_equal(loop[0], loop[-1])  # closed
    assert has_mean
    assert abs(inside - 0.9) <= 0.03


def test_xy_contour_is_banana_shaped():
    """The banana's 0.9 contour is not convex: the midpoint of its tips lies outside it."""
    gg = _banana()
    loop = gg.xy_contour(0.9)[0]
    path = Path(loop)
    # the arc of radius 1 around the start position; its chord midpoint lies inside the bend, outside the banana
    start = np.array([0.5, -0.2])
    d = loop - start
    ang = np.arctan2(d[:, 1], d[:, 0])
    tips = loop[[np.argmin(ang), np.argmax(ang)]]
    assert not path.contains_point(tips.mean(axis=0))


# ------------------------------------------------------------------------------------------------- bad inputs
SIGMA_M_THESIS = np.array([[0.01, 0.02, 0.001], [0.02, 0.25, 0.015], [0.002, 0.0025, 0.15]])  # thesis sec. 5.1


def test_thesis_sigma_m_is_rejected_and_its_symmetrization_accepted():
    with pytest.raises(
        ValueError,
        match=r"^GroupGaussian: argument 'cov' is not symmetric: entry \(1, 2\) is 0\.015 but \(2, 1\) is 0\.0025",
    ):
        GroupGaussian(SE2, np.eye(3), SIGMA_M_THESIS)
    for fixed in (0.5 * (SIGMA_M_THESIS + SIGMA_M_THESIS.T), np.triu(SIGMA_M_THESIS) + np.triu(SIGMA_M_THESIS, 1).T):
        assert GroupGaussian(SE2, np.eye(3), fixed).cov.shape == (3, 3)


_BAD_COVS = {
    "not_pd": (np.diag([0.1, -0.01, 0.2]), r"argument 'cov' is not positive definite: smallest eigenvalue -0\.01"),
    "singular": (np.diag([0.1, 0.0, 0.2]), r"argument 'cov' is not positive definite: smallest eigenvalue 0"),
    "indefinite": (
        np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
        r"argument 'cov' is not positive definite: smallest eigenvalue -1",
    ),
    "nan": (np.diag([0.1, np.nan, 0.2]), r"argument 'cov' contains NaN or inf"),
    "inf": (np.diag([0.1, np.inf, 0.2]), r"argument 'cov' contains NaN or inf"),
    "shape": (np.eye(6), r"argument 'cov' must have shape \(\.\.\., 3, 3\), got \(6, 6\)"),
    "vector": (np.ones(3), r"argument 'cov' must have shape \(\.\.\., 3, 3\)"),
    "text": ("abc", r"argument 'cov' is not a numeric array"),
}


@pytest.mark.parametrize("label", list(_BAD_COVS))
def test_bad_covariance(label):
    cov, problem = _BAD_COVS[label]
    with pytest.raises(ValueError, match=r"^GroupGaussian: " + problem):
        GroupGaussian(SE2, np.eye(3), cov)


def test_bad_covariance_in_batch():
    cov = np.stack([np.eye(3)] * 4)
    cov[2, 0, 1] = 0.5
    with pytest.raises(ValueError, match=r"'cov' is not symmetric: entry \(0, 1\) .* at batch index \(2,\)"):
        GroupGaussian(SE2, np.eye(3), cov)


def _bad_means() -> dict[str, tuple[np.ndarray, str]]:
    g = SE2.from_xytheta(1.0, 2.0, 0.3)
    scaled, refl, bottom, nan = g.copy(), g.copy(), g.copy(), g.copy()
    scaled[:2, :2] *= 1.1
    refl[:, 1] *= -1
    bottom[2, 0] = 0.1
    nan[0, 2] = np.nan
    return {
        "shape": (np.eye(4), r"argument 'mean' must have shape \(\.\.\., 3, 3\), got \(4, 4\)"),
        "nan": (nan, r"argument 'mean' contains NaN or inf"),
        "scaled": (scaled, r"argument 'mean' is not in SE\(2\): its rotation block is not orthonormal"),
        "reflection": (refl, r"argument 'mean' is not in SE\(2\): its rotation block has det -1"),
        "bottom_row": (bottom, r"argument 'mean' is not in SE\(2\): bottom row must be"),
    }


@pytest.mark.parametrize("label", ["shape", "nan", "scaled", "reflection", "bottom_row"])
def test_bad_mean(label):
    mean, problem = _bad_means()[label]
    with pytest.raises(ValueError, match=r"^GroupGaussian: " + problem):
        GroupGaussian(SE2, mean, np.eye(3))


def test_bad_group_and_batch():
    with pytest.raises(ValueError, match=r"argument 'group' must be SE2 or SE3"):
        GroupGaussian(np.eye(3), np.eye(3), np.eye(3))
    with pytest.raises(ValueError, match=r"argument 'group' must be SE2 or SE3 .*got unknown name 'SO3'"):
        GroupGaussian("SO3", np.eye(3), np.eye(3))
    assert GroupGaussian("SE(3)", np.eye(4), np.eye(6)).group is SE3
    with pytest.raises(ValueError, match=r"GroupGaussian: batch shapes of 'mean' \(2,\) and 'cov' \(3,\) differ"):
        GroupGaussian(SE2, np.stack([np.eye(3)] * 2), np.stack([np.eye(3)] * 3))
    # broadcasting a single covariance over a batch of means is fine
    assert GroupGaussian(SE2, np.stack([np.eye(3)] * 2), np.eye(3)).cov.shape == (2, 3, 3)


def test_bad_convolve_and_contour_arguments():
    a = GroupGaussian(SE2, np.eye(3), 0.1 * np.eye(3))
    b = GroupGaussian(SE3, np.eye(4), 0.1 * np.eye(6))
    with pytest.raises(ValueError, match=r"GroupGaussian\.convolve: argument 'other' must be a GroupGaussian"):
        a.convolve(np.eye(3))
    with pytest.raises(ValueError, match=r"GroupGaussian\.convolve: groups differ \(SE2 vs SE3\)"):
        a.convolve(b)
    with pytest.raises(ValueError, match=r"GroupGaussian\.convolve: argument 'order' must be 1 or 2, got 3"):
        a.convolve(a, order=3)
    with pytest.raises(ValueError, match=r"GroupGaussian\.left_multiply: argument 'h' is not in SE\(2\)"):
        a.left_multiply(2.0 * np.eye(3))
    with pytest.raises(ValueError, match=r"GroupGaussian\.right_multiply: argument 'h' must have shape"):
        a.right_multiply(np.eye(4))
    with pytest.raises(ValueError, match=r"xy_contour: argument 'mass' must be in \(0, 1\), got 1\.5"):
        a.xy_contour(1.5)
    with pytest.raises(ValueError, match=r"xy_marginal_density: only for an unbatched SE\(2\) Gaussian"):
        b.xy_contour(0.5)
    with pytest.raises(ValueError, match=r"GroupGaussian\.tangent_of: argument 'g' contains NaN"):
        a.logpdf(np.full((3, 3), np.nan))
