"""The batched kernels (swarmloc.kernels): every one-element fast path equals the batched path, a batch equals its
elements one at a time, the Kalman update equals the textbook and information forms, and the covariance
intersection weight search finds scipy's minimum."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from swarmloc.kernels import cartesian as C
from swarmloc.kernels import group as K
from swarmloc.kernels.ci import W_BOUNDS, ci_search
from swarmloc.lie import SE2
from swarmloc.motion import UnicycleNoise, _stable, odometry_increment

pytestmark = pytest.mark.unit


NOISE = UnicycleNoise(q_v0=1e-4, q_v2=0.05, q_lat0=1e-4, q_lat1=0.01, q_w0=1e-3, q_w2=0.05, q_wv=0.02)
N = 64


def _spd(rng: np.random.Generator, n: int, d: int, scale: float = 0.1) -> np.ndarray:
    A = rng.standard_normal((n, d, d)) * scale
    return A @ np.swapaxes(A, -1, -2) + 1e-3 * np.eye(d)


@pytest.fixture()
def rng() -> np.random.Generator:
    return np.random.default_rng(11)


def test_se2_one_element_paths_equal_the_batched_ones(rng):
    x = rng.standard_normal((N, 3)) * np.array([1.0, 1.0, 2.0])
    x[:8, 2] = rng.uniform(-0.04, 0.04, 8)  # the Taylor branch
    x[8, 2] = np.pi
    g = SE2.exp(x, validate=False)
    for i in range(N):
        np.testing.assert_allclose(SE2.exp(x[i], validate=False), g[i], rtol=0, atol=1e-15)
        np.testing.assert_allclose(SE2.log(g[i], validate=False), SE2.log(g[i : i + 1], validate=False)[0], atol=1e-14)
        np.testing.assert_allclose(SE2.inverse(g[i], validate=False), np.linalg.inv(g[i]), atol=1e-14)
        np.testing.assert_array_equal(SE2.Ad(g[i], validate=False), SE2.Ad(g[i : i + 1], validate=False)[0])


def test_motion_series_cut_to_the_needed_terms_equals_the_full_series():
    for x in np.concatenate([np.geomspace(1e-9, 0.999, 400), -np.geomspace(1e-9, 0.999, 50), [0.0]]):
        cut = _stable.scalar_terms(float(x))
        x2 = x * x
        full = [_stable.horner(_stable.SERIES[k], x2) for k in ("A", "B", "E")]
        np.testing.assert_allclose(cut[1:4], full, rtol=2e-16, atol=0)


def test_group_prediction_one_element_equals_batched(rng):
    mu = SE2.exp(rng.standard_normal((N, 3)), validate=False)
    cov = _spd(rng, N, 3)
    v, w, dt = rng.uniform(-1, 1, N), rng.uniform(-2, 2, N), rng.uniform(0.001, 1.0, N)
    inc_m, inc_c = odometry_increment(v, w, dt, NOISE)
    for order in (1, 2):
        bm, bc = K.predict(SE2, mu, cov, inc_m, inc_c, order)
        for i in range(N):
            m1, c1 = odometry_increment(float(v[i]), float(w[i]), float(dt[i]), NOISE)
            np.testing.assert_allclose(m1, inc_m[i], atol=1e-15)
            np.testing.assert_allclose(c1, inc_c[i], rtol=1e-12, atol=1e-18)
            pm, pc = K.predict(SE2, mu[i], cov[i], m1, c1, order)
            np.testing.assert_allclose(pm, bm[i], atol=1e-14)
            np.testing.assert_allclose(pc, bc[i], rtol=1e-12, atol=1e-16)


def test_cartesian_prediction_one_element_equals_batched(rng):
    x = rng.standard_normal((N, 3)) * np.array([3.0, 3.0, 3.0])
    P = _spd(rng, N, 3)
    v, w, dt = rng.uniform(-1, 1, N), rng.uniform(-2, 2, N), rng.uniform(0.001, 1.0, N)
    bx, bP, bPhi = C.predict(x, P, v, w, dt, NOISE)
    for i in range(N):
        x1, P1, dx, dy = C.predict_one(x[i], P[i], float(v[i]), float(w[i]), float(dt[i]), NOISE)
        np.testing.assert_allclose(x1, bx[i], atol=1e-14)
        np.testing.assert_allclose(P1, bP[i], rtol=1e-12, atol=1e-16)
        np.testing.assert_allclose([-dy, dx], bPhi[i, :2, 2], atol=1e-15)
        xi, Phi, Q = C.increment(x[i], float(v[i]), float(w[i]), float(dt[i]), NOISE)
        np.testing.assert_allclose(Phi @ P[i] @ Phi.T + Q, P1, rtol=1e-12, atol=1e-16)


def test_kalman_update_equals_textbook_and_information_forms(rng):
    """Joseph form = (I - KH) P for the optimal gain = (P^-1 + H^T R^-1 H)^-1; batched = one at a time."""
    n, m = 6, 2
    x = rng.standard_normal((N, n))
    P = _spd(rng, N, n, 0.3)
    H = rng.standard_normal((N, m, n))
    R = _spd(rng, N, m, 0.1)
    r = rng.standard_normal((N, m)) * 0.1
    xb, Pb, nis, ok = C.kalman_update(x, P, r, H, R, angles=(2, 5))
    assert ok.all()
    for i in range(N):
        S = H[i] @ P[i] @ H[i].T + R[i]
        K_ = P[i] @ H[i].T @ np.linalg.inv(S)
        xt = x[i] + K_ @ r[i]
        xt[[2, 5]] = np.pi - np.mod(np.pi - xt[[2, 5]], 2 * np.pi)
        np.testing.assert_allclose(xb[i], xt, atol=1e-12)
        np.testing.assert_allclose(Pb[i], (np.eye(n) - K_ @ H[i]) @ P[i], rtol=1e-9, atol=1e-12)
        info = np.linalg.inv(np.linalg.inv(P[i]) + H[i].T @ np.linalg.solve(R[i], H[i]))
        np.testing.assert_allclose(Pb[i], info, rtol=1e-8, atol=1e-12)
        assert nis[i] == pytest.approx(r[i] @ np.linalg.solve(S, r[i]), rel=1e-10)
        one = C.kalman_update(x[i], P[i], r[i], H[i], R[i], angles=(2, 5))
        np.testing.assert_allclose(one[0], xb[i], atol=1e-14)
        np.testing.assert_allclose(one[1], Pb[i], atol=1e-14)
    bad = C.kalman_update(x[0], P[0], np.array([np.inf, 0.0]), H[0], R[0])
    assert not bad[3]


def test_point_update_batched_equals_one_at_a_time(rng):
    for robot in (True, False):
        mu = SE2.from_xytheta(np.column_stack([rng.uniform(-1, 1, (N, 2)), rng.uniform(-3, 3, N)]))
        cov = _spd(rng, N, 3, 0.1)
        if robot:
            tm = SE2.from_xytheta(np.column_stack([rng.uniform(2, 4, (N, 2)), rng.uniform(-3, 3, N)]))
            tc = _spd(rng, N, 3, 0.1)
        else:
            tm, tc = rng.uniform(2, 4, (N, 2)), _spd(rng, N, 2, 0.1)
        for kind, m in (("range_bearing", 2), ("range", 1), ("bearing", 1)):
            z = np.column_stack([rng.uniform(2, 5, N), rng.uniform(-1, 1, N)])[:, : 2 if m == 2 else 1]
            if kind == "bearing":
                z = rng.uniform(-1, 1, (N, 1))
            R = _spd(rng, N, m, 0.05)
            bm, bc, ok = K.point_update(mu, cov, K.PointMeasurement(kind, z, R, tm, tc, robot))
            nis = K.point_nis(mu, cov, K.PointMeasurement(kind, z, R, tm, tc, robot))
            assert ok.all()
            for i in range(0, N, 7):
                one = K.PointMeasurement(kind, z[i], R[i], tm[i], tc[i], robot)
                m1, c1, ok1 = K.point_update(mu[i], cov[i], one)
                assert ok1
                np.testing.assert_allclose(m1, bm[i], atol=1e-12)
                np.testing.assert_allclose(c1, bc[i], rtol=1e-9, atol=1e-14)
                assert float(K.point_nis(mu[i], cov[i], one)) == pytest.approx(nis[i], rel=1e-10)


def test_point_update_refuses_a_target_on_the_observer():
    mu = SE2.from_xytheta([1.0, 2.0, 0.3])
    target = np.array([1.0, 2.0]), 1e-4 * np.eye(2)
    meas = K.PointMeasurement("range_bearing", np.array([1.0, 0.2]), 1e-2 * np.eye(2), *target, robot=False)
    m, c, ok = K.point_update(mu, 1e-2 * np.eye(3), meas)
    assert not ok and np.isfinite(m).all() and np.isfinite(c).all()
    meas = K.PointMeasurement("range", np.array([1.0]), np.eye(1), *target, robot=False)
    assert np.isnan(K.point_nis(mu, 1e-2 * np.eye(3), meas))


def test_ci_weight_search_finds_the_minimum_scipy_finds(rng):
    """Per element of a batch of CI fusions (point updates of a robot target), the chosen weight's log det is no
    more than 1e-6 above scipy's bounded minimizer's (xatol 1e-6), and the batched search equals the
    one-element search."""
    n = 12
    mu = SE2.from_xytheta(np.column_stack([rng.uniform(-1, 1, (n, 2)), rng.uniform(-3, 3, n)]))
    cov, tc = _spd(rng, n, 3, 0.2), _spd(rng, n, 3, 0.2)
    tm = SE2.from_xytheta(np.column_stack([rng.uniform(2, 4, (n, 2)), rng.uniform(-3, 3, n)]))
    z = np.column_stack([rng.uniform(2, 5, n), rng.uniform(-1, 1, n)])
    R = np.broadcast_to(np.diag([0.05, 0.01]), (n, 2, 2))

    def fuse_batch(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        wc = w[..., None, None]
        m2, c2, _ = K.point_update(mu, cov / wc, K.PointMeasurement("range_bearing", z, R, tm, tc / (1 - wc), True))
        return m2, c2

    bm, bc, bw = ci_search(fuse_batch, (n,))
    for i in range(n):

        def cost(w: float, i: int = i) -> float:
            meas = K.PointMeasurement("range_bearing", z[i], R[i], tm[i], tc[i] / (1 - w), True)
            return float(np.linalg.slogdet(K.point_update(mu[i], cov[i] / w, meas)[1])[1])

        ref = minimize_scalar(cost, bounds=W_BOUNDS, method="bounded", options={"xatol": 1e-6})
        assert cost(float(bw[i])) <= ref.fun + 1e-6, (i, bw[i], ref.x)

        def fuse_one(w: np.ndarray, i: int = i) -> tuple[np.ndarray, np.ndarray]:
            wc = w[..., None, None]
            meas = K.PointMeasurement("range_bearing", z[i], R[i], tm[i], tc[i] / (1 - wc), True)
            m2, c2, _ = K.point_update(np.broadcast_to(mu[i], (*w.shape, 3, 3)), cov[i] / wc, meas)
            return m2, c2

        om, oc, ow = ci_search(fuse_one)
        assert float(ow) == pytest.approx(bw[i], abs=1e-12)
        np.testing.assert_allclose(oc, bc[i], rtol=1e-9, atol=1e-14)


def test_conversions_between_cartesian_and_group_are_inverse(rng):
    x = np.column_stack([rng.uniform(-5, 5, (N, 2)), rng.uniform(-np.pi, np.pi, N)])
    P = _spd(rng, N, 3)
    g, S = C.to_group(x, P)
    np.testing.assert_allclose(g, SE2.from_xytheta(x), atol=1e-15)
    x2, P2 = C.from_group(g, S)
    np.testing.assert_allclose(x2, x, atol=1e-14)
    np.testing.assert_allclose(P2, P, atol=1e-14)
    for i in range(0, N, 9):
        g1, S1 = C.to_group(x[i], P[i])
        np.testing.assert_allclose(g1, g[i], atol=1e-15)
        np.testing.assert_allclose(S1, S[i], atol=1e-15)
        x1, P1 = C.from_group(g1, S1)
        np.testing.assert_allclose(x1, x2[i], atol=1e-14)
        np.testing.assert_allclose(P1, P2[i], atol=1e-14)
