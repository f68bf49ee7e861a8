"""The replay speed-ups' kernels against the plain computations they replace."""

from __future__ import annotations

import numpy as np
import pytest

from swarmloc.kernels import cartesian as C
from swarmloc.motion import UnicycleNoise

pytestmark = pytest.mark.unit


def test_block_update_equals_the_full_joseph_update() -> None:
    """A Jacobian zero outside two 3-column blocks: the O(n^2 m) form equals the full Joseph form."""
    rng = np.random.default_rng(0)
    n = 15
    A = rng.normal(size=(n, n))
    P = A @ A.T / n + 0.1 * np.eye(n)
    x = rng.normal(size=n)
    cols = np.r_[3:6, 9:12]
    Hb = rng.normal(size=(2, 6))
    H = np.zeros((2, n))
    H[:, cols] = Hb
    R = np.diag([0.05, 0.02])
    r = rng.normal(size=2)
    angles = (2, 5, 8, 11, 14)
    xf, Pf, nisf, okf = C.kalman_update(x, P, r, H, R, angles)
    xb, Pb, nisb, okb = C.kalman_update_blocks(x, P, r, Hb, cols, R, angles)
    assert okf and okb
    np.testing.assert_allclose(xb, xf, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Pb, Pf, rtol=0, atol=1e-12)
    assert abs(float(nisb) - float(nisf)) < 1e-12 * max(1.0, float(nisf))


def test_predict_run_gives_the_bits_of_one_prediction_per_command() -> None:
    rng = np.random.default_rng(1)
    noise = UnicycleNoise(q_v0=1e-4, q_v2=0.05, q_lat0=1e-4, q_lat1=0.01, q_w0=1e-3, q_w2=0.05, q_wv=0.02)
    x = np.array([0.3, -1.2, 2.9])
    P = np.diag([0.01, 0.02, 0.003])
    t, v, w = 0.0, 0.2, 0.1
    cmds = []
    for k in range(1, 40):
        cmds.append((0.1 * k + rng.choice([0.0, 0.013]), float(rng.uniform(0, 0.4)), float(rng.uniform(-1, 1))))
    a = b = 0.0
    xs, Ps, vs, ws, ts = x.copy(), P.copy(), v, w, t
    for tk, vk, wk in cmds:  # the reference: one predict_one per command
        if tk > ts:
            xs, Ps, dx, dy = C.predict_one(xs, Ps, vs, ws, tk - ts, noise)
            a, b, ts = a - dy, b + dx, tk
        vs, ws = vk, wk
    p = (P[0, 0], P[0, 1], P[0, 2], P[1, 1], P[1, 2], P[2, 2])
    xr, pr, tr, cmdr, shear = C.predict_run(tuple(x.tolist()), p, t, (v, w), (0.0, 0.0), cmds, noise)
    assert xr == tuple(xs.tolist())
    assert pr == (Ps[0, 0], Ps[0, 1], Ps[0, 2], Ps[1, 1], Ps[1, 2], Ps[2, 2])
    assert tr == ts and cmdr == (vs, ws)
    assert shear == (a, b)
