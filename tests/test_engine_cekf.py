"""The centralized EKF on the engine (``run_engine(source, "cekf", backend="numba")``: the joint state replayed in
one compiled loop, :mod:`swarmloc.engine.joint`) equals the ``cekf`` node: every recorded belief (1e-10 on simulated
teams, 1e-9 relative on MRCLAM), every outcome count and every reason in the node's words, over every detection
kind, robots and landmarks, and the outcomes decided before a state is read or by the update (gated, degenerate)."""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np
import pytest
from test_engine import _assert_same, _source

from swarmloc.engine import run_engine
from swarmloc.estimators import make_team, node_options
from swarmloc.events import Detection
from swarmloc.experiments.sources import load_source
from swarmloc.runner import RunResult, run

# slow: the first test of the module compiles the engine's numba/JAX kernels
pytestmark = [pytest.mark.data, pytest.mark.slow]


def _node(src, **options) -> RunResult:
    opts = {**node_options("cekf", src.config, src.landmarks), **options}
    return run(make_team("cekf", src.initial, **opts), src.events, record_times=src.record_times(), truth=src.truth)


def _split_kinds(events: list) -> list:
    """Every 5th range-bearing as a range-only and every 7th as a bearing-only detection (the same reading)."""
    out, k = [], 0
    for e in events:
        if isinstance(e, Detection) and e.kind == "range_bearing":
            k += 1
            if k % 5 == 0:
                e = dataclasses.replace(e, kind="range", z=e.z[:1].copy(), cov=e.cov[:1, :1].copy())
            elif k % 7 == 0:
                e = dataclasses.replace(e, kind="bearing", z=e.z[1:].copy(), cov=e.cov[1:, 1:].copy())
        out.append(e)
    return out


def _with(src, extra: list, **changes):
    events = sorted([*_split_kinds(src.events), *extra], key=lambda e: e.stamp)
    return dataclasses.replace(src, events=events, **changes)


def robot_extras(far_pose: bool = True) -> list[Detection]:
    """Detections for a 5-robot team (ids 0-4) that end before any update: of a robot outside the team (42), of the
    observer itself, without a target id; and far off (gated): a fix and, with ``far_pose``, a relative pose."""
    eye = 0.01 * np.eye(3)
    return [
        Detection(1, 3.0, "pose", np.array([1.0, 0.0, 0.0]), eye, target=42),  # not in the team
        Detection(2, 4.0, "pose", np.array([0.0, 0.0, 0.0]), eye, target=2),  # itself
        Detection(3, 5.0, "range_bearing", np.array([1.0, 0.1]), eye[:2, :2], target=None),  # no target id
        *([Detection(0, 6.0, "pose", np.array([9.0, -9.0, 3.0]), eye, target=1)] if far_pose else []),  # gated
        Detection(4, 7.0, "absolute", np.array([-9.0, 9.0, 0.0]), eye),  # far off: gated
    ]


def _reasons(res: RunResult) -> Counter[str]:
    """The detections' reasons (nodes also count refused messages, e.g. revisions under late input), zeros dropped."""
    return +Counter({k: v for k, v in res.reasons.items() if not k.startswith("message")})


def _same(ref: RunResult, eng: RunResult) -> None:
    _assert_same(ref, eng)
    assert _reasons(ref) == _reasons(eng)


def _same_on_mrclam(ref: RunResult, eng: RunResult) -> None:
    """Beliefs equal to 1e-9 relative (without landmarks the covariances grow large), the same outcome counts and
    reasons."""
    for r, a in ref.tracks.items():
        b = eng.tracks[r]
        np.testing.assert_array_equal(a.times, b.times)
        np.testing.assert_allclose(b.mean, a.mean, rtol=1e-9, atol=1e-11)
        np.testing.assert_allclose(b.cov, a.cov, rtol=1e-9, atol=1e-13)
    counts = ("detections", "fused", "gated", "rejected", "unknown", "odometry", "odometry_used", "recorded")
    assert {k: ref.stats[k] for k in counts} == {k: eng.stats[k] for k in counts}
    assert _reasons(ref) == _reasons(eng)


def test_cekf_engine_equals_the_node_on_robots_of_every_kind() -> None:
    """Relative poses, range-bearing, range-only, bearing-only of robots and absolute fixes, with detections of a
    robot outside the team, of the observer itself, without a target id, and far off (gated)."""
    src = _with(_source(5, 10.0, 17, kinds=("pose", "range_bearing"), fixes=True), robot_extras())
    kinds = {e.kind for e in src.events if isinstance(e, Detection)}
    assert kinds == {"pose", "range_bearing", "range", "bearing", "absolute"}
    ref, eng = _node(src), run_engine(src, "cekf", backend="numba")
    _same(ref, eng)
    assert eng.reasons["unknown: robot 42 is not in the team"] == 1
    assert eng.reasons["rejected: the target is the observer itself"] == 1
    assert eng.reasons["rejected: robot detection without a target id"] == 1
    assert eng.stats["gated"] >= 2 and eng.stats["fused"] > 500
    off_ref, off = _node(src, use_relative=False), run_engine(src, "cekf", backend="numba", use_relative=False)
    _same(off_ref, off)
    assert off.reasons["rejected: relative measurements are switched off"] > 500


def test_cekf_engine_equals_the_node_with_landmarks() -> None:
    """Landmarks' range-bearing, range and bearing, a map without two of them (``unknown``), the pose of a landmark
    (a point: rejected), one at the observer's position (degenerate), and landmarks switched off."""
    src = load_source("sim:landmarks", robots=4, duration=12.0, seed=5)
    ids = sorted(src.landmarks)
    x0, y0 = src.initial[0].mean[:2, 2]
    eye = 0.01 * np.eye(3)
    rb = np.array([0.5, 0.0])
    extra = [
        Detection(0, src.t_start, "range_bearing", rb, eye[:2, :2], target=999, target_is_robot=False),
        Detection(1, 2.0, "pose", np.array([1.0, 0.0, 0.0]), eye, target=ids[0], target_is_robot=False),
    ]  # fmt: skip
    part = {k: v for k, v in src.landmarks.items() if k not in ids[:2]}
    src = _with(src, extra, landmarks={**part, 999: (float(x0), float(y0), 0.0, 0.0)})
    gone = sum(1 for e in src.events if not getattr(e, "target_is_robot", True) and e.target in ids[:2])
    gone -= 1  # the pose of a landmark is rejected before the map is read
    ref, eng = _node(src), run_engine(src, "cekf", backend="numba")
    _same(ref, eng)
    assert eng.reasons["rejected: degenerate geometry: the target is at the observer's position"] == 1
    assert eng.reasons["rejected: a landmark is a point: it has no relative pose"] == 1
    assert sum(v for k, v in eng.reasons.items() if k.startswith("unknown: landmark")) == gone > 10
    assert eng.stats["fused"] > 350
    off_ref, off = _node(src, use_landmarks=False), run_engine(src, "cekf", backend="numba", use_landmarks=False)
    _same(off_ref, off)
    assert off.reasons["rejected: landmark measurements are switched off"] > 400


@pytest.mark.parametrize("use_landmarks", [True, False])
def test_cekf_engine_equals_the_node_on_mrclam6(mrclam6, use_landmarks) -> None:
    """The first 120 s of MRCLAM dataset 6."""
    src = load_source(f"mrclam:{mrclam6}", duration=120.0)
    ref = _node(src, use_landmarks=use_landmarks)
    eng = run_engine(src, "cekf", backend="numba", use_landmarks=use_landmarks)
    _same_on_mrclam(ref, eng)
    assert eng.stats["fused"] > (2000 if use_landmarks else 300)


def test_cekf_engine_refuses_what_it_does_not_run() -> None:
    src = _source(3, 2.0, 3)
    with pytest.raises(ValueError, match="backend='numba'"):
        run_engine(src, "cekf")
    with pytest.raises(TypeError, match="sensor_range"):
        run_engine(src, "cekf", backend="numba", sensor_range=3.0)
    se3 = load_source("sim:3d", robots=2, duration=1.0)
    with pytest.raises(ValueError, match="planar"):
        run_engine(se3, "cekf", backend="numba")
