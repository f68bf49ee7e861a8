"""Tests for swarmloc.sensors.models: predictions against SE(2) geometry, Jacobians against central finite
differences (robot and landmark targets), residual wrapping across +-pi and the pose-noise conversion; the one source
of the models (swarmloc.sensors.planar) compiled as the engine's replays run it."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from swarmloc.engine import numba_xp
from swarmloc.events import Kind
from swarmloc.lie import SE2, wrap_angle
from swarmloc.sensors import models, planar

pytestmark = pytest.mark.unit


EPS = 1e-6
ATOL = 1e-7


def _angles(kind: str) -> tuple[bool, ...]:
    return models.MODELS[kind].angular


def _fd(f, x: np.ndarray, ang: tuple[bool, ...]) -> np.ndarray:
    """Central finite-difference Jacobian of ``f`` at ``x``; angular outputs differenced modulo 2 pi."""
    cols = []
    for j in range(x.size):
        dx = np.zeros_like(x)
        dx[j] = EPS
        d = np.asarray(f(x + dx), dtype=float) - np.asarray(f(x - dx), dtype=float)
        for i, a in enumerate(ang):
            if a:
                d[i] = wrap_angle(d[i])
        cols.append(d / (2 * EPS))
    return np.stack(cols, axis=-1)


def _configs(n: int, seed: int, landmark: bool) -> list[tuple[np.ndarray, np.ndarray]]:
    """Random observer/target pairs at ranges in [0.3, 3] m, headings anywhere (including near +-pi)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        xi = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-np.pi, np.pi)])
        r, phi = rng.uniform(0.3, 3.0), rng.uniform(-np.pi, np.pi)
        pk = xi[:2] + r * np.array([np.cos(phi), np.sin(phi)])
        xk = pk if landmark else np.array([*pk, rng.uniform(-np.pi, np.pi)])
        out.append((xi, xk))
    # headings and bearings straddling +-pi
    xi = np.array([0.5, -0.2, np.pi - 1e-3])
    out.append((xi, np.array([-1.0, -0.2]) if landmark else np.array([-1.0, -0.2, -np.pi + 2e-3])))
    out.append((np.array([0.0, 0.0, 0.0]), np.array([-2.0, 1e-4]) if landmark else np.array([-2.0, 1e-4, 3.1])))
    return out


FUNCS = {
    "pose": lambda xi, xk: models.relative_pose(xi, xk),
    "range_bearing": lambda xi, xk: models.range_bearing(xi, xk, len(xk)),
    "range": lambda xi, xk: models.range_only(xi, xk, len(xk)),
    "bearing": lambda xi, xk: models.bearing_only(xi, xk, len(xk)),
}


@pytest.mark.parametrize(
    ("kind", "landmark"),
    [(k, False) for k in FUNCS] + [(k, True) for k in FUNCS if k != "pose"],  # a pose needs a robot target
)
def test_jacobians_match_central_differences(kind: str, landmark: bool):
    f = FUNCS[kind]
    ang = _angles(kind)
    for xi, xk in _configs(25, seed=11 if landmark else 12, landmark=landmark):
        h, Hi, Hk = f(xi, xk)
        m = len(ang)
        assert h.shape == (m,)
        assert Hi.shape == (m, 3)
        assert Hk.shape == (m, len(xk))
        np.testing.assert_allclose(Hi, _fd(lambda x, xk=xk: f(x, xk)[0], xi, ang), atol=ATOL, rtol=1e-6)
        np.testing.assert_allclose(Hk, _fd(lambda x, xi=xi: f(xi, x)[0], xk, ang), atol=ATOL, rtol=1e-6)
        # the dispatcher gives the same answer
        h2, Hi2, Hk2 = models.predict(kind, xi, xk)
        np.testing.assert_array_equal(h, h2)
        np.testing.assert_array_equal(Hi, Hi2)
        np.testing.assert_array_equal(Hk, Hk2)


def test_predictions_match_group_geometry():
    """h is the target's pose/position in the observer's body frame (x forward, y left), angles in (-pi, pi]."""
    for xi, xk in _configs(30, seed=3, landmark=False):
        rel = SE2.to_xytheta(SE2.inverse(SE2.from_xytheta(xi)) @ SE2.from_xytheta(xk))
        h, _, _ = models.relative_pose(xi, xk)
        np.testing.assert_allclose(h[:2], rel[:2], atol=1e-12)
        assert abs(wrap_angle(h[2] - rel[2])) < 1e-12
        assert -np.pi < h[2] <= np.pi
        rb, _, _ = models.range_bearing(xi, xk)
        np.testing.assert_allclose(rb[0], np.hypot(rel[0], rel[1]), atol=1e-12)
        np.testing.assert_allclose(rb[1], np.arctan2(rel[1], rel[0]), atol=1e-12)
        r, _, _ = models.range_only(xi, xk[:2], 2)
        b, _, _ = models.bearing_only(xi, xk[:2], 2)
        np.testing.assert_array_equal(np.concatenate([r, b]), rb)
    # a target straight ahead, to the left, behind
    x0 = np.array([1.0, 2.0, np.pi / 2])
    np.testing.assert_allclose(models.range_bearing(x0, np.array([1.0, 3.0]), 2)[0], [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(models.range_bearing(x0, np.array([0.0, 2.0]), 2)[0], [1.0, np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(models.range_bearing(x0, np.array([1.0, 1.0]), 2)[0], [1.0, np.pi], atol=1e-12)


def test_wrap_range():
    """The residuals' wrap (:func:`swarmloc.lie.wrap_angle`): to (-pi, pi], the same angle."""
    a = np.array([-3 * np.pi, -np.pi, -np.pi + 1e-12, 0.0, np.pi, 3 * np.pi, 7.0, -7.0])
    w = wrap_angle(a)
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    assert wrap_angle(-np.pi) == pytest.approx(np.pi)


def test_residual_wraps_only_angular_components():
    # bearing just above -pi measured, predicted just below +pi: residual is +2e-2, not ~-2 pi
    r = models.residual("bearing", np.array([-np.pi + 0.01]), np.array([np.pi - 0.01]))
    np.testing.assert_allclose(r, [0.02], atol=1e-12)
    r = models.residual("bearing", np.array([np.pi - 0.01]), np.array([-np.pi + 0.01]))
    np.testing.assert_allclose(r, [-0.02], atol=1e-12)
    r = models.residual("range_bearing", np.array([10.0, -np.pi + 0.01]), np.array([1.0, np.pi - 0.01]))
    np.testing.assert_allclose(r, [9.0, 0.02], atol=1e-12)  # the range (9 > pi) is not wrapped
    r = models.residual("range", np.array([8.0]), np.array([1.0]))
    np.testing.assert_allclose(r, [7.0], atol=1e-12)
    r = models.residual("pose", np.array([5.0, -5.0, np.pi - 0.05]), np.array([-1.0, 1.0, -np.pi + 0.05]))
    np.testing.assert_allclose(r, [6.0, -6.0, -0.1], atol=1e-12)
    # does not modify its inputs
    z = np.array([0.0, 0.0, 3.0])
    models.residual("pose", z, np.array([0.0, 0.0, -3.0]))
    np.testing.assert_array_equal(z, [0.0, 0.0, 3.0])


def test_predict_rejects_bad_kinds():
    xi = np.zeros(3)
    with pytest.raises(ValueError, match="robot target"):
        models.predict("pose", xi, np.array([1.0, 0.0]))
    with pytest.raises(ValueError, match="sonar"):
        models.predict("sonar", xi, np.array([1.0, 0.0, 0.0]))


def test_pose_noise_to_cartesian_is_the_first_order_map():
    """d xytheta(m exp(n)) / dn at n = 0 is B = diag(R(theta_z), 1), so the Cartesian covariance is B C B^T."""
    rng = np.random.default_rng(5)
    for _ in range(10):
        z = np.array([*rng.uniform(-2, 2, 2), rng.uniform(-np.pi, np.pi)])
        m = SE2.from_xytheta(z)
        J = _fd(lambda n, m=m: SE2.to_xytheta(m @ SE2.exp(n)), np.zeros(3), (False, False, True))
        A = rng.standard_normal((3, 3))
        C = A @ A.T + 0.1 * np.eye(3)
        np.testing.assert_allclose(models.pose_noise_to_cartesian(z, C), J @ C @ J.T, atol=1e-7)


def test_the_planar_models_compiled_for_the_replays_are_the_nodes():
    """The one source of the planar models (:mod:`swarmloc.sensors.planar`) compiled by numba on scalars, as the
    engine's replays run it, gives the nodes' batched numpy predictions, Jacobians, noise rotation and degenerate
    rule (1e-12: the two libm's may differ in a last bit), for robot and landmark targets and over batches."""
    P = planar.build(numba_xp, njit)
    rng = np.random.default_rng(7)
    xi, xk = rng.normal(0, 4, (40, 3)), rng.normal(0, 4, (40, 3))
    xk[0, :2] = xi[0, :2] + 1e-7  # degenerate
    C = np.array([[0.3, 0.1, 0.02], [0.1, 0.2, -0.01], [0.02, -0.01, 0.05]])
    want = {"pose": models.relative_pose(xi, xk), "rb": models.range_bearing(xi, xk),
            "noise": (models.pose_noise_to_cartesian(xk, C),)}  # fmt: skip
    for n in range(1, 40):
        (h, Hi, Hk), (g, Gi, Gk) = P.pose(*xi[n], *xk[n]), P.range_bearing(*xi[n], *xk[n, :2])
        B = np.array(P.rotation(xk[n, 2]))
        got = {"pose": (h, Hi, Hk), "rb": (g, Gi, np.pad(np.array(Gk), ((0, 0), (0, 1)))), "noise": (B @ C @ B.T,)}
        for key, parts in got.items():
            for a, b in zip(parts, want[key], strict=True):
                np.testing.assert_allclose(np.array(a, dtype=float), b[n], rtol=1e-12, atol=1e-12, err_msg=key)
    near = models.degenerate(Kind.RANGE, xi, xk)
    assert [P.degenerate(*xi[n, :2], *xk[n, :2]) for n in range(40)] == list(near)
    assert near[0] and not near[1:].any()
