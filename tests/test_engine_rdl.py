"""Recursive decentralized localization on the engine (``run_engine(source, "rdl", backend="numba")``: every
robot's filter, factors and pairwise exchanges replayed in one compiled loop, :mod:`swarmloc.engine.pairs`) equals
the ``rdl`` nodes exchanging messages through the in-process runner: every recorded belief, every outcome count and
reason, over every detection kind, robots and landmarks; its pair prior (tracked cross-covariance or covariance
intersection) equals the node's on every branch."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_engine import _source
from test_engine_cekf import _same, _same_on_mrclam, _with, robot_extras
from test_engine_invariant import _nodes as _invariant_nodes

from swarmloc.engine import run_engine
from swarmloc.engine.pairs import K, _kalman
from swarmloc.estimators import make_team, node_options
from swarmloc.events import Detection
from swarmloc.experiments.sources import load_source
from swarmloc.kernels import cartesian as C
from swarmloc.kernels.pairs import CI_WEIGHTS, PAIRS
from swarmloc.runner import RunResult, run

# slow: the first test of the module compiles the engine's numba/JAX kernels
pytestmark = [pytest.mark.data, pytest.mark.slow]


def _nodes(src, **options) -> RunResult:
    opts = {**node_options("rdl", src.config, src.landmarks), **options}
    return run(make_team("rdl", src.initial, **opts), src.events, record_times=src.record_times(), truth=src.truth)


def test_rdl_engine_equals_the_nodes_on_robots_of_every_kind() -> None:
    """Relative poses, range-bearing, range-only, bearing-only of robots and absolute fixes (the exchanges revised
    under late input in the nodes: their final state is the engine's), with a robot outside the team, the observer
    itself and a far-off fix; and with relative measurements off."""
    src = _with(_source(5, 10.0, 17, kinds=("pose", "range_bearing"), fixes=True), robot_extras(far_pose=False))
    ref, eng = _nodes(src), run_engine(src, "rdl", backend="numba")
    _same(ref, eng)
    assert eng.reasons["unknown: robot 42: robot 42 is not in the team"] == 1
    assert eng.reasons["rejected: robot detection without a target id"] == 1
    assert eng.stats["gated"] >= 1 and eng.stats["fused"] > 500
    off_ref, off = _nodes(src, use_relative=False), run_engine(src, "rdl", backend="numba", use_relative=False)
    _same(off_ref, off)
    assert off.reasons["rejected: relative measurements are switched off"] > 500


def test_rdl_engine_equals_the_nodes_with_landmarks() -> None:
    """Landmarks' range-bearing, range and bearing (private updates, factors rescaled), a map without two of them,
    a landmark at the observer's position (degenerate), and landmarks switched off."""
    src = load_source("sim:landmarks", robots=4, duration=12.0, seed=6)
    ids = sorted(src.landmarks)
    x0, y0 = src.initial[0].mean[:2, 2]
    rb = np.array([0.5, 0.0])
    extra = [Detection(0, src.t_start, "range_bearing", rb, 0.01 * np.eye(2), target=999, target_is_robot=False)]
    part = {k: v for k, v in src.landmarks.items() if k not in ids[:2]}
    src = _with(src, extra, landmarks={**part, 999: (float(x0), float(y0), 0.0, 0.0)})
    ref, eng = _nodes(src), run_engine(src, "rdl", backend="numba")
    _same(ref, eng)
    assert eng.reasons["rejected: degenerate geometry: the target is at the observer's position"] == 1
    assert sum(v for k, v in eng.reasons.items() if k.startswith("unknown: landmark")) > 10
    assert eng.stats["fused"] > 350
    off_ref, off = _nodes(src, use_landmarks=False), run_engine(src, "rdl", backend="numba", use_landmarks=False)
    _same(off_ref, off)


@pytest.mark.parametrize("use_landmarks", [True, False])
def test_rdl_engine_equals_the_nodes_on_mrclam6(mrclam6, use_landmarks) -> None:
    src = load_source(f"mrclam:{mrclam6}", duration=120.0)
    ref = _nodes(src, use_landmarks=use_landmarks)
    eng = run_engine(src, "rdl", backend="numba", use_landmarks=use_landmarks)
    _same_on_mrclam(ref, eng)
    assert eng.stats["fused"] > (2000 if use_landmarks else 300)


def _spd(rng: np.random.Generator, scale: float) -> np.ndarray:
    A = rng.normal(size=(3, 3))
    return scale * (A @ A.T + 0.1 * np.eye(3))


def pair_cases(count: int):
    """``count`` pair-prior cases ``(Pi, Pj, fi, fj, met, H, R)`` (seeded): a tracked cross-covariance, one far too
    large to be positive definite, a met pair whose observer dropped its factor, a pair the observer never met; two-
    and three-row measurements of noise from 1e-3 to 1e3."""
    rng = np.random.default_rng(3)
    for k in range(count):
        Pi, Pj = _spd(rng, 0.05), _spd(rng, 0.05 * 10 ** rng.uniform(-2, 2))
        case = k % 4
        fi, fj = rng.normal(scale=0.1, size=(3, 3)), rng.normal(scale=0.1, size=(3, 3))
        if case == 1:
            fi *= 30.0  # far too large a cross-covariance: not positive definite
        elif case == 2:
            fi = np.zeros((3, 3))  # the observer dropped its factor
        m = 2 + k % 2
        H = rng.normal(size=(m, 6))
        yield Pi, Pj, fi, fj, case != 3, H, (10 ** rng.uniform(-3, 3)) * np.eye(m)


def test_pair_prior_equals_the_nodes_on_every_branch() -> None:
    """The compiled pair prior (the replay's, :data:`swarmloc.engine.pairs.K`) against the nodes' plain numpy one
    (:data:`swarmloc.kernels.pairs.PAIRS`, one source): a tracked positive-definite cross-covariance, a tracked one
    that is not (covariance intersection), a met pair with a dropped factor, a target tracking a pair the observer
    never met; both gain, only the observer, neither (a weak measurement)."""
    seen = {"tracked": 0, 1: 0, 0: 0, -1: 0}
    for Pi, Pj, fi, fj, met, H, R in pair_cases(300):
        ref, ref_flag = PAIRS.pair_prior(Pi, Pj, fi, fj, met, H, R)
        P, flag = K.pair_prior(Pi, Pj, fi, fj, met, H, R)
        assert flag == ref_flag
        np.testing.assert_allclose(P, ref, rtol=1e-12, atol=1e-15)
        if flag == 1 and np.allclose(P[:3, 3:], fi @ fj.T):
            seen["tracked"] += 1
            continue
        seen[flag] += 1
    assert min(seen.values()) >= 5, seen


def test_ci_prior_picks_the_weight_the_joint_update_itself_would() -> None:
    """Covariance intersection's weight, computed in measurement space (the determinant lemma, every weight at once),
    against the 6x6 joint update for each weight: both robots' posterior blocks from the Kalman form and their log
    determinants, the max-min (or the observer's own) gain picked from them; the same weight and flag every time."""
    seen = {1: 0, 0: 0, -1: 0}
    for Pi, Pj, _, _, _, H, R in pair_cases(200):
        gains = []
        for w in CI_WEIGHTS:
            P = np.zeros((6, 6))
            P[:3, :3], P[3:, 3:] = Pi / w, Pj / (1.0 - w)
            K_ = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
            Pn = P - K_ @ H @ P
            gains.append([np.linalg.slogdet(Pi)[1] - np.linalg.slogdet(Pn[:3, :3])[1],
                          np.linalg.slogdet(Pj)[1] - np.linalg.slogdet(Pn[3:, 3:])[1]])  # fmt: skip
        g = np.array(gains)
        k = int(np.argmax(g.min(axis=1)))
        want = 1
        if g[k].min() < 0.0:
            k = int(np.argmax(g[:, 0]))
            want = 0 if g[k, 0] > 0.0 else -1
        P, flag = PAIRS.ci_prior(Pi, Pj, H, R)
        assert flag == want
        np.testing.assert_allclose(P[:3, :3], Pi / CI_WEIGHTS[k], rtol=1e-12)
        np.testing.assert_allclose(P[3:, 3:], Pj / (1.0 - CI_WEIGHTS[k]), rtol=1e-12)
        assert not P[:3, 3:].any()
        seen[flag] += 1
    assert min(seen.values()) >= 5, seen


def test_rescaled_factors_equal_the_nodes() -> None:
    """The compiled rescaling of a robot's factors after its update (pending shear applied, a zero factor kept
    zero; none non-zero: unchanged) against the nodes' plain numpy one."""
    rng = np.random.default_rng(5)
    for k in range(40):
        P_old, P_new = _spd(rng, 0.05), _spd(rng, 0.01)
        sig = rng.normal(scale=0.1, size=(4, 3, 3))
        sig[k % 4] = 0.0
        if k % 10 == 0:
            sig[:] = 0.0
        sa, sb = rng.normal(size=2)
        ref = PAIRS.rescaled(P_new, P_old, sig, sa, sb)
        np.testing.assert_allclose(K.rescaled(P_new, P_old, sig, sa, sb), ref, rtol=1e-12, atol=1e-15)
        assert not ref[k % 4].any()
        if k % 10 == 0:
            assert ref is sig
        else:
            f = sig[(k + 1) % 4]
            sheared = np.array([f[0] + sa * f[2], f[1] + sb * f[2], f[2]])
            np.testing.assert_allclose(ref[(k + 1) % 4], P_new @ np.linalg.solve(P_old, sheared), rtol=1e-9)


def test_compiled_kalman_equals_the_nodes() -> None:
    """The replay's Kalman update (:func:`swarmloc.kernels.cartesian.kalman_one` compiled) against the nodes'
    (:func:`~swarmloc.kernels.cartesian.kalman_update`): one robot's and a pair's state, one to three rows, headings
    far outside (-pi, pi] wrapped; a singular innovation covariance of two and of three rows refused."""
    rng = np.random.default_rng(7)
    for k in range(60):
        n, m = (3, 6)[k % 2], 1 + k % 3
        P = _spd(rng, 0.1) if n == 3 else np.kron(np.eye(2), _spd(rng, 0.1)) + 0.01
        x, H, r = rng.normal(scale=5.0, size=n), rng.normal(size=(m, n)), rng.normal(size=m)
        R = 10 ** rng.uniform(-3, 1) * np.eye(m)
        angles = tuple(range(2, n, 3))
        xn, Pn, nis, ok = C.kalman_update(x, P, r, H, R, angles=angles)
        cx, cP, cnis, cok = _kalman(x, P, r, H, R, angles)
        assert cok == bool(ok) and np.abs(cx[list(angles)]).max() <= np.pi
        np.testing.assert_allclose(cx, xn, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(cP, Pn, rtol=1e-10, atol=1e-14)
        assert cnis == pytest.approx(float(nis), rel=1e-10)
    for m in (2, 3):
        res = _kalman(np.zeros(3), np.zeros((3, 3)), np.ones(m), np.ones((m, 3)), np.zeros((m, m)), (2,))
        assert not res[3] and np.isnan(res[2])


def test_rdl_engine_refuses_what_it_does_not_run() -> None:
    src = _source(3, 2.0, 3)
    with pytest.raises(ValueError, match="backend='numba'"):
        run_engine(src, "rdl")
    with pytest.raises(ValueError, match="association"):
        run_engine(src, "rdl", backend="numba", association="nearest")


def test_replays_dead_reckon_a_run_without_detections() -> None:
    """A timeline without detections (every robot dead-reckoned): ``diekf``'s and ``rdl``'s replays equal their
    nodes."""
    src = _source(3, 4.0, 41, kinds=("pose",))
    src = dataclasses.replace(src, events=[e for e in src.events if not isinstance(e, Detection)])
    for estimator, ref in (("diekf", _invariant_nodes("diekf", src)), ("rdl", _nodes(src))):
        eng = run_engine(src, estimator, backend="numba")
        _same(ref, eng)
        assert eng.stats["detections"] == 0 and eng.tracks[0].times.size > 10
