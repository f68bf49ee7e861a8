"""Tests for swarmloc.motion: differential-drive SDE, increment covariances, closed forms, Euler-Maruyama."""

from __future__ import annotations

import numpy as np
import pytest

from swarmloc.lie import SE2
from swarmloc.motion import (
    DiffDrive,
    UnicycleNoise,
    _stable,
    circular_cov,
    circular_mean,
    constant_twist_cov,
    euler_maruyama,
    increment_cov,
    increment_mean,
    increment_mean_second_order,
    odometry_increment,
    straight_line_cov,
    straight_line_mean,
    thesis_circular_cov,
    thesis_straight_cov,
    unicycle_cov,
)

pytestmark = pytest.mark.unit


DD = DiffDrive(r=0.033, l=0.2, D=5.0)
# thesis sec. 5.1
STRAIGHT = (0.5 / 0.033, 0.5 / 0.033, 1.3)
CIRCULAR = (26.166, 21.408, 2.0)


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# ---------------------------------------------------------------------------------------------- DiffDrive
def test_diffdrive_model():
    h = DD.twist(*CIRCULAR[:2])
    assert h.shape == (3,)
    assert h[0] == pytest.approx(0.785, abs=1e-3)  # 1 m radius ...
    assert h[2] == pytest.approx(np.pi / 4, abs=1e-3)  # ... at 45 deg/s (needs the fixed r/l, eq. 5.1 misprint)
    assert h[0] / h[2] == pytest.approx(1.0, abs=1e-3)
    r, l, D = DD.r, DD.l, DD.D
    np.testing.assert_allclose(DD.H(), np.sqrt(D) * np.array([[r / 2, r / 2], [0, 0], [r / l, -r / l]]))
    np.testing.assert_allclose(DD.diffusion(), D * np.diag([r**2 / 2, 0, 2 * r**2 / l**2]), atol=1e-18)
    w1, w2 = np.array([1.0, 3.0, -2.0]), np.array([0.5, 3.0, 4.0])
    v, w = DD.to_unicycle(w1, w2)
    np.testing.assert_allclose(np.stack([v, 0 * v, w], -1), DD.twist(w1, w2))
    b1, b2 = DD.from_unicycle(v, w)
    np.testing.assert_allclose(b1, w1)
    np.testing.assert_allclose(b2, w2)
    assert DD.twist(np.ones((4, 5)), np.zeros((4, 5))).shape == (4, 5, 3)


# ---------------------------------------------------------------------------------------------- increments
def test_increment_mean_shapes_and_values():
    h = DD.twist(*CIRCULAR[:2])
    g = increment_mean(h, 2.0)
    np.testing.assert_allclose(g, circular_mean(h[0], h[2], 2.0), atol=1e-14)
    np.testing.assert_allclose(increment_mean(np.array([0.5, 0, 0]), 1.3), straight_line_mean(0.5, 1.3), atol=1e-15)
    hs = np.random.default_rng(0).standard_normal((4, 3))
    assert increment_mean(hs, np.linspace(0.1, 1, 4)).shape == (4, 3, 3)
    assert increment_mean(h, np.linspace(0.1, 1, 6)).shape == (6, 3, 3)


def test_second_order_mean_error_is_third_order():
    h = DD.twist(*CIRCULAR[:2])
    errs = []
    for dt in (0.04, 0.02, 0.01):
        e = np.abs(increment_mean_second_order(h, dt) - increment_mean(h, dt)).max()
        errs.append(e)
        assert e < np.linalg.norm(h * dt) ** 3  # O(|dt h|^3) with constant < 1
    ratios = np.array(errs[:-1]) / np.array(errs[1:])
    assert np.all((ratios > 7.0) & (ratios < 9.0)), ratios  # halving dt divides the error by ~8
    # (5.11) is not exactly in SE(2): the rotation block is orthonormal only to O(a^3)
    R = increment_mean_second_order(h, 0.5)[:2, :2]
    assert np.abs(R.T @ R - np.eye(2)).max() > 1e-4


CASES = [  # (v, omega, t, q_v, q_lat, q_w)
    (0.5, 0.0, 1.3, None, 0.0, None),  # thesis straight
    (None, None, 2.0, None, 0.0, None),  # thesis circular (filled below)
    (0.3, 1e-7, 0.7, 1e-3, 0.0, 2e-2),
    (0.3, 1e-3, 5.0, 1e-3, 1e-4, 2e-2),
    (0.3, -0.4, 2.5, 1e-3, 0.0, 2e-2),
    (1.2, 0.99 / 0.8, 0.8, 2e-3, 5e-4, 1e-1),  # turn angle just below the series threshold
    (1.2, 1.01 / 0.8, 0.8, 2e-3, 5e-4, 1e-1),  # ... and just above
    (0.2, 2.0, 12.0, 1e-4, 0.0, 1e-3),  # ~4 turns
    (-0.4, 0.3, 3.0, 1e-3, 1e-3, 1e-2),  # reversing
    (0.0, 0.8, 2.0, 1e-3, 0.0, 1e-2),  # turning on the spot
]


def _case(i: int) -> tuple[float, float, float, float, float, float]:
    v, w, t, qv, ql, qw = CASES[i]
    Q = DD.diffusion()
    if v is None:
        h = DD.twist(*CIRCULAR[:2])
        v, w = float(h[0]), float(h[2])
    qv = Q[0, 0] if qv is None else qv
    qw = Q[2, 2] if qw is None else qw
    return v, w, t, qv, ql, qw


@pytest.mark.parametrize("i", range(len(CASES)))
def test_closed_forms_match_quadrature(i: int):
    v, w, t, qv, ql, qw = _case(i)
    h = np.array([v, 0.0, w])
    Q = np.diag([qv, ql, qw])
    ref = increment_cov(h, Q, t, method="quad")
    assert rel(constant_twist_cov(h, Q, t), ref) < 1e-8
    assert rel(unicycle_cov(v, w, t, qv, qw, ql), ref) < 1e-8
    assert rel(increment_cov(h, Q, t, method="gauss"), ref) < 1e-12
    assert rel(increment_cov(h, Q, t, method="closed"), ref) < 1e-8
    if w == 0.0:
        assert rel(straight_line_cov(v, t, qv, qw, ql), ref) < 1e-8
    elif abs(w * t) > 1e-2:  # the direct trigonometric form cancels for tiny turn angles
        assert rel(circular_cov(v, w, t, qv, qw, ql), ref) < 1e-8
    mean, cov = odometry_increment(v, w, t, UnicycleNoise(q_v0=qv, q_lat0=ql, q_w0=qw))
    assert rel(cov, ref) < 1e-8
    np.testing.assert_allclose(mean, increment_mean(h, t), atol=1e-14)


def test_thesis_closed_forms_in_thesis_notation():
    D, r, l = DD.D, DD.r, DD.l
    w = STRAIGHT[0]
    ref = increment_cov(DD.twist(w, w), DD.diffusion(), STRAIGHT[2], method="quad")
    assert rel(thesis_straight_cov(D, r, l, w, STRAIGHT[2]), ref) < 1e-10  # (5.6) as printed is right
    h = DD.twist(*CIRCULAR[:2])
    ref = increment_cov(h, DD.diffusion(), CIRCULAR[2], method="quad")
    assert rel(thesis_circular_cov(D, r, l, h[0] / h[2], h[2], CIRCULAR[2]), ref) < 1e-10  # corrected (5.9)


def printed_eq_5_9(D: float, r: float, l: float, a: float, ad: float, t: float) -> np.ndarray:
    """Eq. (5.9) exactly as printed in the thesis (sigma_22 is not given: left 0)."""
    c = D * r * r / (l * l * ad)
    th = ad * t
    S = np.zeros((3, 3))
    S[0, 0] = c / 8 * ((4 * a * a + l * l) * (2 * th + np.sin(2 * th)) + 16 * a * a * (th - np.sin(2 * th)))
    S[0, 1] = -c / 2 * (4 * a * a * (-1 + np.cos(2 * th)) + l * l) * np.sin(th / 2) ** 2
    S[0, 2] = 2 * c * a * (th - np.sin(2 * th))
    S[1, 2] = -2 * c * a * (-1 + np.cos(th))
    S[2, 2] = 2 * c * ad
    return S + np.triu(S, 1).T


def test_printed_eq_5_9_is_wrong():
    """Documents the misprint: at the thesis' circular parameters the printed (5.9) is far from quadrature of (5.4)
    in sigma_11 (+550%), sigma_12 (+101%), sigma_13 (+175%), sigma_22 (missing) and sigma_33 (-50%: lacks t);
    only sigma_23 is right."""
    h = DD.twist(*CIRCULAR[:2])
    ref = increment_cov(h, DD.diffusion(), CIRCULAR[2], method="quad")
    P = printed_eq_5_9(DD.D, DD.r, DD.l, h[0] / h[2], h[2], CIRCULAR[2])
    err = (P - ref) / ref
    assert err[0, 0] > 5.0
    assert err[0, 1] > 0.9
    assert err[0, 2] > 1.5
    assert err[1, 1] == -1.0
    assert err[2, 2] == pytest.approx(-0.5, abs=1e-12)  # 2 c alpha_dot = Sigma_33 / t with t = 2
    assert abs(err[1, 2]) < 1e-12
    assert rel(P, ref) > 1.0


def test_simpson38_accuracy():
    Q = DD.diffusion()
    hs = DD.twist(*STRAIGHT[:2])
    ref = increment_cov(hs, Q, STRAIGHT[2], method="gauss")
    assert rel(increment_cov(hs, Q, STRAIGHT[2], method="simpson38"), ref) < 1e-14  # cubic integrand: exact
    hc = DD.twist(*CIRCULAR[:2])
    ref = increment_cov(hc, Q, CIRCULAR[2], method="gauss")
    e = rel(increment_cov(hc, Q, CIRCULAR[2], method="simpson38"), ref)
    assert 1e-3 < e < 1e-2  # measured 5.3e-3 at the thesis' 90-degree arc
    # fourth order in the turn angle: at an odometry step of 0.1 s it is negligible
    errs = [rel(increment_cov(hc, Q, dt, method="simpson38"), increment_cov(hc, Q, dt)) for dt in (0.2, 0.1)]
    assert errs[1] < 1e-6
    assert 12 < errs[0] / errs[1] < 20


def test_increment_cov_batched():
    rng = np.random.default_rng(1)
    h = rng.normal(size=(5, 3))
    t = rng.uniform(0.1, 3.0, size=5)
    A = rng.normal(size=(5, 3, 3))
    Q = A @ np.swapaxes(A, -1, -2) * 0.01  # full SPD Q, general twists (v2 != 0)
    ref = increment_cov(h, Q, t, method="quad")
    assert ref.shape == (5, 3, 3)
    for m in ("gauss", "closed"):
        got = increment_cov(h, Q, t, method=m)
        assert max(rel(got[i], ref[i]) for i in range(5)) < 1e-10
    # scalar twist with a vector of times, and per-element loop agreement
    hc = DD.twist(*CIRCULAR[:2])
    ts = np.array([0.1, 1.0, 2.0])
    got = increment_cov(hc, DD.diffusion(), ts)
    for k, tk in enumerate(ts):
        assert rel(got[k], increment_cov(hc, DD.diffusion(), tk)) < 1e-13
    with pytest.raises(ValueError):
        increment_cov(hc, DD.diffusion(), 1.0, method="trapezoid")  # type: ignore[arg-type]


def test_gram_matches_quadrature_on_both_branches():
    t = 1.3
    u, wts = np.polynomial.legendre.leggauss(60)
    tau = 0.5 * t * (u + 1)
    for x in (0.0, 1e-5, 0.4, 0.999, 1.001, 3.0, -7.0):
        w = x / t
        if w == 0.0:
            phi = np.stack([np.ones_like(tau), np.ones_like(tau), 0 * tau, tau, 0 * tau])
        else:
            phi = np.stack(
                [
                    np.ones_like(tau),
                    np.cos(w * tau),
                    np.sin(w * tau),
                    np.sin(w * tau) / w,
                    2 * np.sin(w * tau / 2) ** 2 / w,
                ]
            )
        ref = 0.5 * t * np.einsum("k,ik,jk->ij", wts, phi, phi)
        got = _stable.gram(np.array(x), np.array(t))
        assert np.abs(got - ref).max() < 1e-13 * np.abs(ref).max(), x
    # scalar fast path equals the array path on both branches
    for x in (0.0, 1e-6, 0.3, 0.999, 1.001, 4.0, -2.5):
        s2, A, B, E, s1, h2, h4 = _stable.scalar_terms(x)
        xa = np.array(x)
        assert s2 == pytest.approx(float(_stable.sinc(2 * xa)), rel=1e-14, abs=1e-300)
        assert A == pytest.approx(float(_stable.series_fn("A", xa)), rel=1e-14)
        assert B == pytest.approx(float(_stable.series_fn("B", xa)), rel=1e-14)
        assert E == pytest.approx(float(_stable.series_fn("E", xa)), rel=1e-14)


# ---------------------------------------------------------------------------------------------- unicycle
def test_unicycle_noise_and_odometry_increment():
    dd = DiffDrive(D=0.3)
    n = UnicycleNoise.from_diff_drive(dd)
    np.testing.assert_allclose(n.Q(0.3, 0.1), dd.diffusion(), atol=1e-18)
    n2 = UnicycleNoise(
        q_v0=1e-4, q_v1=2e-3, q_v2=1e-2, q_lat0=1e-5, q_lat1=1e-4, q_w0=1e-3, q_w1=1e-2, q_w2=3e-2, q_wv=5e-3
    )
    v, w = -0.4, 0.7
    np.testing.assert_allclose(
        np.diag(n2.Q(v, w)),
        [1e-4 + 2e-3 * 0.4 + 1e-2 * 0.16, 1e-5 + 1e-4 * 0.4, 1e-3 + 1e-2 * 0.7 + 3e-2 * 0.49 + 5e-3 * 0.4],
    )
    rng = np.random.default_rng(2)
    vs, ws = rng.uniform(-1, 1, 50), rng.normal(0, 1, 50) * np.logspace(-8, 0, 50)
    dts = rng.uniform(0.01, 0.2, 50)
    means, covs = odometry_increment(vs, ws, dts, n2)
    assert means.shape == covs.shape == (50, 3, 3)
    ref = increment_cov(np.stack([vs, 0 * vs, ws], -1), n2.Q(vs, ws), dts, method="gauss")
    for k in range(50):
        m, c = odometry_increment(float(vs[k]), float(ws[k]), float(dts[k]), n2)
        assert rel(c, ref[k]) < 1e-12
        assert rel(covs[k], ref[k]) < 1e-12
        np.testing.assert_allclose(m, means[k], atol=1e-15)
    m0, c0 = odometry_increment(0.5, 0.0, 0.1, n2)
    np.testing.assert_allclose(m0, straight_line_mean(0.5, 0.1), atol=1e-16)


# ---------------------------------------------------------------------------------------------- Euler-Maruyama
def test_euler_maruyama_noise_free_and_shapes():
    h = DD.twist(*CIRCULAR[:2])
    g0 = SE2.from_xytheta([1.0, 2.0, 0.3])
    g = euler_maruyama(g0, h, np.zeros((3, 2)), 2.0, 50, 3, np.random.default_rng(0))
    np.testing.assert_allclose(g, np.broadcast_to(g0 @ increment_mean(h, 2.0), (3, 3, 3)), atol=1e-13)
    g, path = euler_maruyama(
        g0, lambda t: h * (t < 1.0), DD.H(), 2.0, 40, 7, np.random.default_rng(0), return_path=True
    )
    assert g.shape == (7, 3, 3) and path.shape == (41, 7, 3, 3)
    np.testing.assert_allclose(path[-1], g)
    np.testing.assert_allclose(path[0], np.broadcast_to(g0, (7, 3, 3)))
    a = euler_maruyama(g0, h, DD.H(), 1.0, 10, 5, np.random.default_rng(3))
    b = euler_maruyama(g0, h, DD.H(), 1.0, 10, 5, np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    ("wheels", "D", "tol"),
    [
        (STRAIGHT, 5.0, 0.05),  # thesis parameters; measured ~0.3% (sampling error ~0.5%)
        (CIRCULAR, 5.0, 0.05),  # thesis parameters; measured ~1.8% (nonlinearity: heading std 0.74 rad)
        (CIRCULAR, 0.5, 0.02),  # smaller noise: measured ~0.2%
    ],
)
def test_euler_maruyama_matches_propagated_covariance(wheels: tuple[float, float, float], D: float, tol: float):
    dd = DiffDrive(D=D)
    w1, w2, T = wheels
    h = dd.twist(w1, w2)
    g = euler_maruyama(np.eye(3), h, dd.H(), T, 100, 100_000, np.random.default_rng(12345))
    y = SE2.log(SE2.inverse(increment_mean(h, T)) @ g)
    S = increment_cov(h, dd.diffusion(), T)
    C = np.cov(y.T)
    assert rel(C, S) < tol
    assert np.all(np.abs(y.mean(0)) < 3 * np.sqrt(np.diag(S) / len(y)) + 0.01 * np.sqrt(np.diag(S)))
