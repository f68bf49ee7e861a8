"""The engine's float32 JAX backend, the plain-JAX team step and section e of ``swarmloc-studies bench``.

jax is in the dev extra: these run in CI (on its CPU), not skipped. On a GPU the same code runs unchanged.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from test_engine import COUNTS, _source

from swarmloc.engine import run_engine
from swarmloc.engine.backends import JaxOps, NumpyOps, jax_team_step, team_step
from swarmloc.engine.swarm import SWARM_NOISE, Swarm, device_step, neighbour_pairs
from swarmloc.lie import wrap_angle
from swarmloc_studies import bench as B
from swarmloc_studies.bench_report import format_report
from swarmloc_studies.cli import main

# slow: the first test of the module compiles the engine's numba/JAX kernels
pytestmark = [pytest.mark.unit, pytest.mark.slow]


def _worst(a, b) -> tuple[float, float]:
    """Largest mean difference [m or rad] and covariance difference relative to sqrt(P_ii P_jj) over all tracks."""
    dm = dc = 0.0
    for r, ta in a.tracks.items():
        tb = b.tracks[r]
        np.testing.assert_array_equal(ta.times, tb.times)
        dm = max(
            dm, np.abs(ta.mean[:, :2] - tb.mean[:, :2]).max(), np.abs(wrap_angle(ta.mean[:, 2] - tb.mean[:, 2])).max()
        )
        d = np.sqrt(np.einsum("...ii->...i", ta.cov))
        dc = max(dc, (np.abs(ta.cov - tb.cov) / (d[..., :, None] * d[..., None, :])).max())
    return dm, dc


def test_jax32_backend_equals_numpy_to_float32_rounding() -> None:
    """Same detections fused, gated and rejected; means within 1e-4 and covariances within 1e-4 of their scale
    (measured: 2e-6 m, 4e-6); and it does compute in float32: further from numpy than the float64 backend."""
    src = _source(5, 10.0, 13, fixes=True)
    ref, f64, f32 = (run_engine(src, "dekf", backend=b) for b in ("numpy", "jax", "jax32"))
    assert {k: ref.stats[k] for k in COUNTS} == {k: f32.stats[k] for k in COUNTS}
    dm32, dc32 = _worst(ref, f32)
    dm64, dc64 = _worst(ref, f64)
    assert dm32 <= 1e-4 and dc32 <= 1e-4, (dm32, dc32)
    assert dm64 <= 1e-10 and dm32 > 1e-8 > dm64, (dm32, dm64)
    assert all(t.mean.dtype == np.float64 and t.cov.dtype == np.float64 for t in f32.tracks.values())


def test_jax_ops_take_float64_or_float32_only() -> None:
    assert JaxOps(SWARM_NOISE, np.float32).name == "jax32" and JaxOps(SWARM_NOISE).name == "jax"
    with pytest.raises(ValueError, match="float64 or float32"):
        JaxOps(SWARM_NOISE, np.float16)


def _scene(n: int, k: int, seed: int = 1):
    sw = Swarm(n, seed=seed)
    obs, tgt = neighbour_pairs(sw.pose[:, :2], k, math.inf)
    det = sw.sense(k, math.inf, np.diag([0.05**2, 0.05**2, 1e-3]), (obs, tgt))
    v, w = sw.commands(0.1)
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, 3, 3))
    P = 1e-3 * A @ np.swapaxes(A, 1, 2) + 1e-4 * np.eye(3)
    return (
        sw.pose.copy(),
        P,
        v,
        w,
        np.full(n, 0.1),
        det.z.reshape(n, k, 3),
        det.R.reshape(n, k, 3, 3),
        tgt.reshape(n, k),
    )


def test_team_step_is_prediction_then_each_detection_position_on_the_updated_states() -> None:
    """numpy's team_step against the engine's numpy kernels composed by hand (predict all; for each position j,
    update every robot with its neighbour's state after position j-1); jax float64 to 1e-10 of it, float32 to
    float32 rounding."""
    x, P, v, w, dt, z, R, t = _scene(200, 3)
    ops = NumpyOps(SWARM_NOISE)
    xs, Ps = ops.predict(x, P, v, w, dt)
    for j in range(3):
        xs, Ps, *_ = ops.pose_update(xs, Ps, xs[t[:, j]], Ps[t[:, j]], z[:, j], R[:, j])
    xn, Pn = team_step(np, SWARM_NOISE, x, P, v, w, dt, z, R, t)
    np.testing.assert_allclose(xn, xs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Pn, Ps, rtol=0, atol=1e-14)
    assert not np.allclose(xn, x, atol=1e-6)  # the step moved the states

    f = jax_team_step(SWARM_NOISE)
    xj, Pj = (np.asarray(a) for a in f(x, P, v, w, dt, z, R, t))
    np.testing.assert_allclose(xj, xn, rtol=0, atol=1e-10)
    np.testing.assert_allclose(Pj, Pn, rtol=0, atol=1e-12)
    x32, P32 = (np.asarray(a) for a in f(*(a.astype(np.float32) for a in (x, P, v, w, dt, z, R)), t))
    assert x32.dtype == np.float32
    assert np.abs(wrap_angle(x32 - xn)).max() < 1e-3 and np.abs(P32 - Pn).max() < 1e-4 * np.abs(Pn).max()


def test_device_step_rates_and_bad_dtype() -> None:
    for dtype in ("float64", "float32"):
        r = device_step(64, dtype=dtype, repeats=2)
        assert r["n"] == 64 and r["dtype"] == dtype and r["device"]
        assert r["robot_updates_per_s"] > 0 and r["compile_s"] > 0
        assert r["robot_updates_per_s"] == pytest.approx(64 / r["step_s"])
    with pytest.raises(ValueError, match="float64"):
        device_step(8, dtype="float16")


def test_bench_section_e_alone_and_its_report(capsys) -> None:
    """``--sections e`` runs only section e (no machine rates, no replay); every size has every column and the
    ratios are the columns' quotients."""
    assert main(["bench", "--sections", "e", "--accelerator-sizes", "40,70", "--json", "--quiet"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert set(res) == {"machine", "config", "accelerator"}
    e = res["accelerator"]
    assert [r["n"] for r in e["rows"]] == [40, 70] and e["device"] and e["jax"]
    for r in e["rows"]:
        for key in ("engine_jax", "engine_jax32", "engine_numba", "plain_float64", "plain_float32"):
            assert math.isfinite(r[key]) and r[key] > 0, key
        assert r["engine_over_plain_f64"] == pytest.approx(r["engine_jax"] / r["plain_float64"])
        assert r["engine_over_plain_f32"] == pytest.approx(r["engine_jax32"] / r["plain_float32"])
    text = format_report(res)
    assert "e. accelerator" in text and "plain jax f32" in text and "a. fusion step" not in text
    assert "       70" in text


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--sections", "ax"], "--sections takes letters"),
        (["--sections", ""], "--sections takes letters"),
        (["--sections", "e", "--accelerator-sizes", "10,zero"], "comma-separated team sizes"),
        (["--sections", "e", "--accelerator-sizes", "0"], "1 to 100,000,000"),
    ],
)
def test_bench_refuses_bad_sections_and_sizes(capsys, args, message) -> None:
    assert main(["bench", "--quiet", *args]) == 2
    assert message in capsys.readouterr().err


def test_run_bench_refuses_unknown_sections() -> None:
    with pytest.raises(ValueError, match="letters of 'abcde'"):
        B.run_bench(B.QUICK, sections="z")
