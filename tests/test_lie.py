"""Tests for swarmloc.lie: SE(2)/SE(3) identities, Jacobians, BCH, and input validation.

Every identity is checked on random elements of several batch shapes whose rotation angles cover three regimes:
near zero (1e-12 .. 1e-3), near pi (pi - 1e-9 .. pi - 1e-3) and generic; the (1000,) batch mixes all of them
with exact zeros. References are independent of swarmloc's closed forms: scipy.linalg.expm/logm, numpy inverses,
matrix commutators, central finite differences and the integral formula of the Jacobian.
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmloc.lie import SE2, SE3, between_xyt, compose_xyt, exp_xyt, invert_xyt, log_xyt

pytestmark = pytest.mark.unit


GROUPS = [SE2, SE3]
TOL = 1e-10  # max abs error of every exact identity
FD_TOL = 1e-6  # Jacobians vs central finite differences
FD_STEP = 1e-6
SHAPES = [(), (7,), (4, 5)]
REGIMES = ["small", "near_pi", "generic"]
ELEMENT_CASES = [(shape, regime) for shape in SHAPES for regime in REGIMES] + [((1000,), "mixed")]


def _gid(G: type) -> str:
    return G.__name__


def _cid(case: tuple) -> str:
    shape, regime = case
    return f"{regime}{list(shape)}".replace(" ", "")


def _rng(*key: object) -> np.random.Generator:
    return np.random.default_rng(zlib.crc32(repr(key).encode()))


def _angles(regime: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """Rotation angles (>= 0) of one regime; 'mixed' draws each element's regime at random (zeros included)."""
    if regime == "small":
        return 10.0 ** rng.uniform(-12, -3, n)
    if regime == "near_pi":
        return np.pi - 10.0 ** rng.uniform(-9, -3, n)
    if regime == "generic":
        return rng.uniform(1e-3, np.pi - 1e-3, n)
    assert regime == "mixed"
    kind = rng.integers(0, 4, n)
    out = np.zeros(n)
    for k, name in enumerate(REGIMES):
        out[kind == k] = _angles(name, int((kind == k).sum()), rng)
    return out  # kind == 3: exactly zero


def random_tangent(G: type, shape: tuple[int, ...], regime: str, rng: np.random.Generator) -> np.ndarray:
    """Exponential coordinates of shape ``shape + (dim,)``: translation ~ 2 N(0, I), rotation angle by regime."""
    n = int(np.prod(shape, dtype=int))
    ang = _angles(regime, n, rng)
    v = 2.0 * rng.standard_normal((n, G.n))
    if G is SE2:
        w = (rng.choice([-1.0, 1.0], n) * ang)[:, None]
    else:
        axis = rng.standard_normal((n, 3))
        w = axis / np.linalg.norm(axis, axis=1, keepdims=True) * ang[:, None]
    return np.concatenate([v, w], axis=1).reshape(*shape, G.dim)


def rotation_angle(G: type, x: np.ndarray) -> np.ndarray:
    return np.abs(x[..., 2]) if G is SE2 else np.linalg.norm(x[..., 3:], axis=-1)


def bvec(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...ij,...j->...i", M, v)


def maxabs(a: np.ndarray) -> float:
    return float(np.max(np.abs(a))) if np.size(a) else 0.0


# ------------------------------------------------------------------------------------------------- identities
# Each returns the max abs error of one identity on the tangents x (and independent tangents y of the same shape).
def err_exp_log(G, x, y):
    g = G.exp(x)
    return maxabs(G.exp(G.log(g)) - g)


def err_log_exp(G, x, y):  # all angles here are < pi
    return maxabs(G.log(G.exp(x)) - x)


def err_exp_expm(G, x, y):
    return maxabs(G.exp(x) - scipy.linalg.expm(G.hat(x)))


def err_log_logm(G, x, y):  # logm is well conditioned away from pi
    keep = rotation_angle(G, x) < np.pi - 1e-3
    g = G.exp(x[keep])
    ref = np.array([G.vee(scipy.linalg.logm(gi).real) for gi in g]).reshape(-1, G.dim)
    return maxabs(G.log(g) - ref)


def err_Ad_expm(G, x, y):
    return maxabs(G.Ad(G.exp(x)) - scipy.linalg.expm(G.ad(x)))


def err_Ad_conjugation(G, x, y):
    g = G.exp(x)
    return maxabs(bvec(G.Ad(g), y) - G.vee(g @ G.hat(y) @ np.linalg.inv(g)))


def err_ad_bracket(G, x, y):
    X, Y = G.hat(x), G.hat(y)
    return maxabs(bvec(G.ad(x), y) - G.vee(X @ Y - Y @ X))


def err_Ad_homomorphism(G, x, y):
    g1, g2 = G.exp(x), G.exp(y)
    return maxabs(G.Ad(g1 @ g2) - G.Ad(g1) @ G.Ad(g2))


def err_inverse_compose(G, x, y):
    g1, g2 = G.exp(x), G.exp(y)
    eye = np.eye(G.n + 1)
    return max(
        maxabs(G.inverse(g1) - np.linalg.inv(g1)),
        maxabs(G.compose(g1, G.inverse(g1)) - eye),
        maxabs(G.compose(G.inverse(g1), g1) - eye),
        maxabs(G.compose(g1, g2) - g1 @ g2),
        maxabs(G.between(g1, g2) - np.linalg.inv(g1) @ g2),
        maxabs(G.inverse(G.compose(g1, g2)) - G.inverse(g2) @ G.inverse(g1)),
    )


def _integral_jacobian(A: np.ndarray) -> np.ndarray:
    """``sum_k A^k / (k+1)!`` = top-right block of ``expm([[A, I], [0, 0]])`` (independent of the closed forms)."""
    d = A.shape[-1]
    Z = np.zeros((*A.shape[:-2], 2 * d, 2 * d))
    Z[..., :d, :d] = A
    Z[..., :d, d:] = np.eye(d)
    return scipy.linalg.expm(Z)[..., :d, d:]


def err_jacobian_integral(G, x, y):
    ad = G.ad(x)
    return max(
        maxabs(G.left_jacobian(x) - _integral_jacobian(ad)),
        maxabs(G.right_jacobian(x) - _integral_jacobian(-ad)),
    )


def err_jacobian_relations(G, x, y):
    Jl, Jr = G.left_jacobian(x), G.right_jacobian(x)
    return max(maxabs(Jr - G.left_jacobian(-x)), maxabs(Jl - G.Ad(G.exp(x)) @ Jr))


def err_jacobian_inverse(G, x, y):
    eye = np.eye(G.dim)
    Jl, Jr = G.left_jacobian(x), G.right_jacobian(x)
    Jli, Jri = G.left_jacobian_inv(x), G.right_jacobian_inv(x)
    return max(maxabs(Jl @ Jli - eye), maxabs(Jli @ Jl - eye), maxabs(Jr @ Jri - eye), maxabs(Jri @ Jr - eye))


def err_jacobian_fd(G, x, y):
    """exp(x + dx) = exp(Jl dx) exp(x) = exp(x) exp(Jr dx): central differences of the logs, column by column."""
    ginv = np.linalg.inv(G.exp(x))
    Jl_fd = np.zeros((*x.shape, G.dim))
    Jr_fd = np.zeros((*x.shape, G.dim))
    for j in range(G.dim):
        e = np.zeros(G.dim)
        e[j] = FD_STEP
        gp, gm = G.exp(x + e), G.exp(x - e)
        Jl_fd[..., :, j] = (G.log(gp @ ginv) - G.log(gm @ ginv)) / (2 * FD_STEP)
        Jr_fd[..., :, j] = (G.log(ginv @ gp) - G.log(ginv @ gm)) / (2 * FD_STEP)
    return max(maxabs(G.left_jacobian(x) - Jl_fd), maxabs(G.right_jacobian(x) - Jr_fd))


IDENTITIES = {
    "exp_log": (err_exp_log, TOL),
    "log_exp": (err_log_exp, TOL),
    "exp_expm": (err_exp_expm, TOL),
    "log_logm": (err_log_logm, TOL),
    "Ad_expm": (err_Ad_expm, TOL),
    "Ad_conjugation": (err_Ad_conjugation, TOL),
    "ad_bracket": (err_ad_bracket, TOL),
    "Ad_homomorphism": (err_Ad_homomorphism, TOL),
    "inverse_compose": (err_inverse_compose, TOL),
    "jacobian_integral": (err_jacobian_integral, TOL),
    "jacobian_relations": (err_jacobian_relations, TOL),
    "jacobian_inverse": (err_jacobian_inverse, TOL),
    "jacobian_fd": (err_jacobian_fd, FD_TOL),
}


def identity_inputs(G: type, case: tuple) -> tuple[np.ndarray, np.ndarray]:
    shape, regime = case
    rng = _rng(G.__name__, shape, regime)
    return random_tangent(G, shape, regime, rng), random_tangent(G, shape, "mixed", rng)


def test_enough_elements():
    assert sum(int(np.prod(s, dtype=int)) for s, _ in ELEMENT_CASES) >= 1000


@pytest.mark.parametrize("case", ELEMENT_CASES, ids=_cid)
@pytest.mark.parametrize("G", GROUPS, ids=_gid)
@pytest.mark.parametrize("name", list(IDENTITIES))
def test_identity(name, G, case):
    fn, tol = IDENTITIES[name]
    x, y = identity_inputs(G, case)
    assert fn(G, x, y) <= tol


@pytest.mark.parametrize("case", ELEMENT_CASES, ids=_cid)
@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_batch_shapes(G, case):
    x, y = identity_inputs(G, case)
    b = x.shape[:-1]
    N, d = G.n + 1, G.dim
    g = G.exp(x)
    assert g.shape == (*b, N, N)
    assert G.hat(x).shape == (*b, N, N)
    assert G.vee(G.hat(x)).shape == (*b, d)
    np.testing.assert_array_equal(G.vee(G.hat(x)), x)
    assert G.log(g).shape == (*b, d)
    assert G.inverse(g).shape == g.shape
    assert G.Ad(g).shape == (*b, d, d)
    for f in (G.ad, G.left_jacobian, G.right_jacobian, G.left_jacobian_inv, G.right_jacobian_inv):
        assert f(x).shape == (*b, d, d)
    for order in (1, 2, 3):
        assert G.bch(x, y, order=order).shape == (*b, d)
    # a batch is the stack of its elements
    flat = x.reshape(-1, d)
    np.testing.assert_allclose(G.exp(x).reshape(-1, N, N), np.stack([G.exp(xi) for xi in flat]), rtol=0, atol=1e-13)
    one_by_one = np.stack([G.log(gi) for gi in g.reshape(-1, N, N)])
    np.testing.assert_allclose(G.log(g).reshape(-1, d), one_by_one, rtol=0, atol=1e-13)


@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_log_principal_range(G):
    """Angles of log in (-pi, pi] (SE2) / [0, pi] (SE3), also for exp of angles up to 3 pi; exp(log g) = g."""
    rng = _rng("range", G.__name__)
    x = random_tangent(G, (500,), "generic", rng)
    if G is SE2:
        x[:, 2] *= 3.0
    else:
        x[:, 3:] *= 3.0
    g = G.exp(x)
    z = G.log(g)
    ang = z[:, 2] if G is SE2 else np.linalg.norm(z[:, 3:], axis=-1)
    assert np.all(ang <= np.pi) and np.all(ang > -np.pi)
    assert maxabs(G.exp(z) - g) <= TOL
    if G is SE2:  # the angle is wrapped, nothing else changes its meaning
        wrapped = np.mod(x[:, 2] + np.pi, 2 * np.pi) - np.pi
        assert maxabs(np.abs(np.angle(np.exp(1j * (z[:, 2] - wrapped))))) <= TOL


# ------------------------------------------------------------------------------------------------- exactly pi
def test_se2_exactly_pi():
    for off in (0.0, -0.0):
        g = np.array([[-1.0, off, 0.7], [-off, -1.0, -1.3], [0.0, 0.0, 1.0]])
        z = SE2.log(g)
        assert z[2] == np.pi  # (-pi, pi]: +pi, also for the -0.0 sine
        assert maxabs(SE2.exp(z) - g) <= TOL
    g = SE2.from_xytheta(np.array([0.3, -2.0]), np.array([1.0, 0.5]), np.array([np.pi, -np.pi]))
    assert maxabs(SE2.exp(SE2.log(g)) - g) <= TOL
    assert maxabs(np.abs(SE2.log(g)[:, 2]) - np.pi) <= 1e-15
    x = np.array([1.0, -2.0, np.pi])
    assert maxabs(SE2.exp(SE2.log(SE2.exp(x))) - SE2.exp(x)) <= TOL


def _se3_pi_axes() -> np.ndarray:
    rng = _rng("pi-axes")
    axes = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [0, -1, 1], [1, 1, 1], [-1, 2, -3]]
    axes = np.vstack([np.array(axes, float), rng.standard_normal((50, 3))])
    return axes / np.linalg.norm(axes, axis=1, keepdims=True)


def test_se3_exactly_pi():
    rng = _rng("pi-t")
    axes = _se3_pi_axes()
    g = np.zeros((len(axes), 4, 4))
    g[:, :3, :3] = 2.0 * axes[:, :, None] * axes[:, None, :] - np.eye(3)  # rotation by exactly pi
    g[:, :3, 3] = 2.0 * rng.standard_normal((len(axes), 3))
    g[:, 3, 3] = 1.0
    z = SE3.log(g)
    assert maxabs(np.linalg.norm(z[:, 3:], axis=1) - np.pi) <= 1e-12
    assert maxabs(SE3.exp(z) - g) <= TOL
    # and from the tangent side: |w| = pi exactly
    x = np.concatenate([2.0 * rng.standard_normal((len(axes), 3)), np.pi * axes], axis=1)
    assert maxabs(SE3.exp(SE3.log(SE3.exp(x))) - SE3.exp(x)) <= TOL


# ------------------------------------------------------------------------------------------------- hat / vee / basis
@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_hat_vee_basis(G):
    rng = _rng("hat", G.__name__)
    x = rng.standard_normal((10, G.dim))
    X = G.hat(x)
    np.testing.assert_array_equal(G.vee(X), x)
    np.testing.assert_allclose(X, np.einsum("ni,iab->nab", x, G.basis()), atol=1e-15)
    assert np.all(X[..., G.n, :] == 0)
    R = X[..., : G.n, : G.n]
    np.testing.assert_array_equal(R, -np.swapaxes(R, -1, -2))
    np.testing.assert_array_equal(G.ad_basis(), G.ad(np.eye(G.dim)))
    # structure constants: ad(E_i) e_j = [E_i, E_j]^v
    E = G.basis()
    for i in range(G.dim):
        for j in range(G.dim):
            np.testing.assert_allclose(G.ad_basis()[i][:, j], G.vee(E[i] @ E[j] - E[j] @ E[i]), atol=1e-15)


def test_se2_conventions():
    """DESIGN.md: Ad = [[R, M t], [0, 1]], ad = [[-alpha M, M v], [0, 0]], M = [[0, 1], [-1, 0]]."""
    M = np.array([[0.0, 1.0], [-1.0, 0.0]])
    g = SE2.from_xytheta(1.5, -0.5, 0.7)
    A = np.eye(3)
    A[:2, :2] = g[:2, :2]
    A[:2, 2] = M @ g[:2, 2]
    np.testing.assert_allclose(SE2.Ad(g), A, atol=1e-15)
    x = np.array([0.3, -1.2, 0.8])
    a = np.zeros((3, 3))
    a[:2, :2] = -x[2] * M
    a[:2, 2] = M @ x[:2]
    np.testing.assert_allclose(SE2.ad(x), a, atol=1e-15)
    np.testing.assert_allclose(SE2.to_xytheta(g), [1.5, -0.5, 0.7], atol=1e-15)
    np.testing.assert_allclose(SE2.from_xytheta(np.array([1.5, -0.5, 0.7])), g)


def test_planar_rows_are_the_matrix_forms():
    """swarmloc.lie.planar on pose rows (x, y, theta): the products, inverses and relative poses of SE2's matrices,
    broadcast; log/exp those of SE2 (exp's translation bit for bit: the same coefficient functions); angles wrapped to
    (-pi, pi]."""
    rng = np.random.default_rng(0)
    a = np.column_stack([rng.normal(size=(500, 2)), rng.uniform(-4, 4, 500)])
    b = np.column_stack([rng.normal(size=(500, 2)), rng.uniform(-4, 4, 500)])
    A, B = SE2.from_xytheta(a), SE2.from_xytheta(b)
    np.testing.assert_allclose(SE2.from_xytheta(compose_xyt(a, b)), A @ B, atol=1e-12)
    np.testing.assert_allclose(SE2.from_xytheta(invert_xyt(a)), np.linalg.inv(A), atol=1e-12)
    np.testing.assert_allclose(SE2.from_xytheta(between_xyt(a, b)), np.linalg.inv(A) @ B, atol=1e-12)
    assert np.array_equal(between_xyt(a[0], b), between_xyt(a[:1], b))  # one pose against many
    assert between_xyt(a[:, None], b[None, :7]).shape == (500, 7, 3)
    for out in (compose_xyt(a, b), invert_xyt(a), between_xyt(a, b)):
        assert np.all((out[:, 2] > -np.pi) & (out[:, 2] <= np.pi))
    y = rng.normal(size=(500, 3))
    y[:50, 2] *= 1e-3  # the Taylor branch
    y[50:60, 2] = 0.0
    assert np.array_equal(exp_xyt(y)[:, :2], SE2.exp(y)[:, :2, 2])
    np.testing.assert_allclose(exp_xyt(y)[:, 2], SE2.to_xytheta(SE2.exp(y))[:, 2], atol=1e-12)
    q = np.column_stack([rng.normal(size=(500, 2)), rng.uniform(-np.pi, np.pi, 500)])
    q[:50, 2] *= 1e-3
    np.testing.assert_allclose(log_xyt(q), SE2.log(SE2.from_xytheta(q)), atol=1e-12)
    y[:, 2] = np.clip(y[:, 2], -3.0, 3.0)  # principal angles: log inverts exp
    np.testing.assert_allclose(log_xyt(exp_xyt(y)), y, atol=1e-12)


def test_se3_conventions():
    """DESIGN.md: x = (v, w); Ad = [[R, t^ R], [0, R]], ad = [[w^, v^], [0, w^]]."""

    def sk(w):
        return np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])

    x = np.array([0.3, -1.2, 0.8, 0.2, -0.4, 0.9])
    X = SE3.hat(x)
    np.testing.assert_array_equal(X[:3, :3], sk(x[3:]))
    np.testing.assert_array_equal(X[:3, 3], x[:3])
    g = SE3.exp(x)
    R, t = g[:3, :3], g[:3, 3]
    np.testing.assert_allclose(SE3.Ad(g), np.block([[R, sk(t) @ R], [np.zeros((3, 3)), R]]), atol=1e-15)
    np.testing.assert_allclose(SE3.ad(x), np.block([[sk(x[3:]), sk(x[:3])], [np.zeros((3, 3)), sk(x[3:])]]), atol=1e-15)


# ------------------------------------------------------------------------------------------------- BCH
BCH_SCALES = (0.05, 0.025, 0.0125)


def bch_errors(G: type, order: int, n: int = 200) -> np.ndarray:
    """``|bch(s x, s y) - log(exp(s x) exp(s y))|`` for ``n`` random pairs at each scale in BCH_SCALES."""
    rng = _rng("bch", G.__name__)
    x, y = rng.standard_normal((n, G.dim)), rng.standard_normal((n, G.dim))
    errs = []
    for s in BCH_SCALES:
        exact = G.log(G.exp(s * x) @ G.exp(s * y))
        errs.append(np.linalg.norm(G.bch(s * x, s * y, order=order) - exact, axis=-1))
    return np.array(errs)


@pytest.mark.parametrize("G", GROUPS, ids=_gid)
@pytest.mark.parametrize(("order", "rate"), [(1, 4.0), (2, 8.0), (3, 16.0)])
def test_bch_convergence_rate(G, order, rate):
    """Truncation error of order k is O(|x|^(k+1)): halving x and y divides it by 2^(k+1) (4, 8, 16)."""
    errs = bch_errors(G, order)
    ratios = errs[:-1] / errs[1:]
    med = np.median(ratios, axis=1)
    assert np.all(np.abs(med - rate) <= 0.03 * rate), med
    # the median over pairs is robust; nearly every pair shows the rate at the smallest scales
    assert np.mean(np.abs(ratios[-1] - rate) <= 0.1 * rate) >= 0.95


@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_bch_orders_improve(G):
    e1, e2, e3 = (np.median(bch_errors(G, k, 50)[-1]) for k in (1, 2, 3))
    assert e3 < 0.1 * e2 < 0.01 * e1
    rng = _rng("bch1", G.__name__)
    x, y = rng.standard_normal((2, 5, G.dim))
    np.testing.assert_array_equal(G.bch(x, y, order=1), x + y)
    np.testing.assert_allclose(G.bch(x, y, order=2), x + y + 0.5 * bvec(G.ad(x), y), atol=1e-15)


# ------------------------------------------------------------------------------------------------- hypothesis
_coord = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
_angle = st.floats(0.0, np.pi - 1e-6, allow_nan=False)
_any_angle = st.floats(-4 * np.pi, 4 * np.pi, allow_nan=False)
_axis = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda a: np.linalg.norm(a) > 1e-3)


@st.composite
def se2_tangents(draw, angle=_angle):
    sign = draw(st.sampled_from([-1.0, 1.0]))
    return np.array([draw(_coord), draw(_coord), sign * draw(angle)])


@st.composite
def se3_tangents(draw, angle=_angle):
    axis = np.array(draw(_axis))
    return np.concatenate([[draw(_coord) for _ in range(3)], draw(angle) * axis / np.linalg.norm(axis)])


_HYP = settings(max_examples=300, deadline=None, database=None)


@_HYP
@given(x=se2_tangents())
def test_hypothesis_se2_roundtrip(x):
    g = SE2.exp(x)
    assert maxabs(SE2.log(g) - x) <= TOL
    assert maxabs(SE2.exp(SE2.log(g)) - g) <= TOL


@_HYP
@given(x=se3_tangents())
def test_hypothesis_se3_roundtrip(x):
    g = SE3.exp(x)
    assert maxabs(SE3.log(g) - x) <= TOL
    assert maxabs(SE3.exp(SE3.log(g)) - g) <= TOL


@_HYP
@given(x=st.one_of(se2_tangents(_any_angle), se3_tangents(_any_angle)))
def test_hypothesis_exp_log_any_angle(x):
    G = SE2 if x.shape[-1] == 3 else SE3
    g = G.exp(x)
    assert maxabs(G.exp(G.log(g)) - g) <= TOL
    assert maxabs(G.inverse(g) @ g - np.eye(G.n + 1)) <= TOL


# ------------------------------------------------------------------------------------------------- bad inputs
def _bad_elements(G: type) -> list[tuple[str, np.ndarray, str]]:
    """(label, array, regex of the problem) for inputs that are not elements of G."""
    n = G.n
    g = G.exp(np.linspace(0.3, 0.9, G.dim))
    R = g[:n, :n]

    def with_R(Rn):
        h = g.copy()
        h[:n, :n] = Rn
        return h

    shear = np.eye(n)
    shear[0, 1] = 0.2
    flip = np.eye(n)
    flip[-1, -1] = -1.0
    nan, inf, bottom = g.copy(), g.copy(), g.copy()
    nan[0, 0] = np.nan
    inf[0, n] = np.inf
    bottom[n, 0] = 0.5
    grp = rf"is not in SE\({n}\)"
    return [
        ("shape", np.eye(n + 2), rf"must have shape \(\.\.\., {n + 1}, {n + 1}\), got \({n + 2}, {n + 2}\)"),
        ("vector", np.ones(n + 1), rf"must have shape \(\.\.\., {n + 1}, {n + 1}\)"),
        ("nan", nan, r"contains NaN or inf"),
        ("inf", inf, r"contains NaN or inf"),
        ("text", "abc", r"is not a numeric array"),
        ("scaled", with_R(1.1 * R), grp + r": its rotation block is not orthonormal"),
        ("shear", with_R(R @ shear), grp + r": its rotation block is not orthonormal"),
        ("reflection", with_R(R @ flip), grp + r": its rotation block has det -1 \(a reflection"),
        ("bottom_row", bottom, grp + r": bottom row must be \[0\.0, "),
    ]


BAD_ELEMENTS = ["shape", "vector", "nan", "inf", "text", "scaled", "shear", "reflection", "bottom_row"]


@pytest.mark.parametrize("fn", ["log", "Ad", "inverse"])
@pytest.mark.parametrize("G", GROUPS, ids=_gid)
@pytest.mark.parametrize("label", BAD_ELEMENTS)
def test_bad_elements(G, fn, label):
    arr, problem = {lab: (a, p) for lab, a, p in _bad_elements(G)}[label]
    with pytest.raises(ValueError, match=rf"^{G.__name__}\.{fn}: argument 'g' " + problem):
        getattr(G, fn)(arr)


@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_bad_element_in_batch_names_index(G):
    g = G.exp(np.full((5, G.dim), 0.2))
    g[3, 0, 0] *= 1.1
    with pytest.raises(ValueError, match=r"rotation block is not orthonormal .* at batch index \(3,\)"):
        G.log(g)
    g = G.exp(np.full((2, 3, G.dim), 0.2))
    g[1, 2, :, :] = g[1, 2] @ np.diag([1.0] * (G.n - 1) + [-1.0, 1.0])
    with pytest.raises(ValueError, match=r"det -1 \(a reflection, not a rotation\) at batch index \(1, 2\)"):
        G.Ad(g)


@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_bad_elements_compose_between(G):
    g = G.exp(np.full(G.dim, 0.2))
    bad = g.copy()
    bad[G.n, 0] = 1.0
    for fn in ("compose", "between"):
        with pytest.raises(ValueError, match=rf"{G.__name__}\.{fn}: argument 'a' is not in SE\({G.n}\): bottom row"):
            getattr(G, fn)(bad, g)
        with pytest.raises(ValueError, match=rf"{G.__name__}\.{fn}: argument 'b' is not in SE\({G.n}\): bottom row"):
            getattr(G, fn)(g, bad)


_TANGENT_FNS = ["exp", "hat", "ad", "left_jacobian", "right_jacobian", "left_jacobian_inv", "right_jacobian_inv"]


@pytest.mark.parametrize("fn", _TANGENT_FNS)
@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_bad_tangents(G, fn):
    f = getattr(G, fn)
    d = G.dim
    where = rf"^{G.__name__}\.{fn}: argument 'x' "
    with pytest.raises(ValueError, match=where + rf"must have shape \(\.\.\., {d}\) .*got shape \({d + 1},\)"):
        f(np.zeros(d + 1))
    with pytest.raises(ValueError, match=where + rf"must have shape \(\.\.\., {d}\)"):
        f(0.5)
    x = np.zeros((4, d))
    x[2, 1] = np.nan
    with pytest.raises(ValueError, match=where + r"contains NaN or inf \(first at index \(2, 1\)\)"):
        f(x)
    x[2, 1] = -np.inf
    with pytest.raises(ValueError, match=where + r"contains NaN or inf"):
        f(x)
    with pytest.raises(ValueError, match=where + r"is not a numeric array"):
        f("abc")


@pytest.mark.parametrize("G", GROUPS, ids=_gid)
def test_bad_vee_and_bch(G):
    N, d = G.n + 1, G.dim
    with pytest.raises(ValueError, match=rf"{G.__name__}\.vee: argument 'X' must have shape \(\.\.\., {N}, {N}\)"):
        G.vee(np.zeros((N + 1, N + 1)))
    with pytest.raises(ValueError, match=rf"{G.__name__}\.vee: argument 'X' contains NaN or inf"):
        G.vee(np.full((N, N), np.nan))
    with pytest.raises(ValueError, match=rf"{G.__name__}\.bch: argument 'y' must have shape \(\.\.\., {d}\)"):
        G.bch(np.zeros(d), np.zeros(d - 1))
    with pytest.raises(ValueError, match=rf"{G.__name__}\.bch: argument 'x' contains NaN"):
        G.bch(np.full(d, np.nan), np.zeros(d))
    with pytest.raises(ValueError, match=rf"{G.__name__}\.bch: argument 'order' must be 1, 2 or 3, got 4"):
        G.bch(np.zeros(d), np.zeros(d), order=4)
