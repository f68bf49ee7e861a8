"""The engine's ``dekf`` with a landmark map equals the per-robot nodes (to 1e-10, same counts and reasons) on
simulated teams with landmarks and on the first 60 s of MRCLAM dataset 6, on every backend; landmark detections
switched off, or of landmarks missing from the map, end as the nodes end them."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from swarmloc.engine import Detections, Engine, run_engine
from swarmloc.engine.codes import NO_LANDMARK, POSE, landmark_code
from swarmloc.estimators import make_team, node_options
from swarmloc.experiments.sources import load_source
from swarmloc.motion import UnicycleNoise
from swarmloc.runner import RunResult, run
from swarmloc.sensors.models import KIND_ORDER

sys.path.insert(0, str(Path(__file__).parent))
from test_engine import _assert_same  # noqa: E402


def _nodes(src, **options) -> RunResult:
    opts = {**node_options("dekf", src.config, src.landmarks), **options}
    return run(make_team("dekf", src.initial, **opts), src.events, record_times=src.record_times(), truth=src.truth)


def _landmark_detections(src) -> int:
    return sum(1 for e in src.events if getattr(e, "target_is_robot", True) is False)


@pytest.mark.parametrize("seed", [5, 6])
@pytest.mark.parametrize("backend", ["numpy", "numba", "jax"])
def test_engine_with_landmarks_equals_the_nodes_on_simulated_teams(seed, backend) -> None:
    src = load_source("sim:landmarks", robots=4, duration=15.0, seed=seed)
    assert _landmark_detections(src) > 300  # landmark detections are most of the input
    a, b = _nodes(src), run_engine(src, "dekf", backend=backend)
    _assert_same(a, b)
    detection_reasons = {k: v for k, v in a.reasons.items() if not k.startswith("message")}  # no messages in it
    assert detection_reasons == b.reasons
    assert b.stats["fused"] > 0.99 * b.stats["detections"]


def test_landmarks_switched_off_or_missing_from_the_map_end_as_in_the_nodes() -> None:
    """Off: every landmark detection rejected (the nodes' reason); a map without two landmarks: their detections
    ``unknown``, the rest fused; the beliefs equal the nodes' in both."""
    src = load_source("sim:landmarks", robots=3, duration=10.0, seed=7)
    n_lm = _landmark_detections(src)
    off_a, off_b = _nodes(src, use_landmarks=False), run_engine(src, "dekf", use_landmarks=False)
    _assert_same(off_a, off_b)
    assert off_b.reasons["rejected: landmark measurements are switched off"] == n_lm
    assert off_a.reasons["rejected: landmark measurements are switched off"] == n_lm

    ids = sorted(src.landmarks)
    part = {k: v for k, v in src.landmarks.items() if k not in ids[:2]}
    gone = sum(1 for e in src.events if getattr(e, "target_is_robot", True) is False and e.target in ids[:2])
    assert gone > 0
    pa, pb = _nodes(src, landmarks=part), run_engine(src, "dekf", landmarks=part)
    _assert_same(pa, pb)
    assert pb.stats["unknown"] == pa.stats["unknown"] == gone
    assert pb.reasons["unknown: the landmark is not in the map"] == gone


def test_engine_with_landmarks_equals_the_nodes_on_mrclam6_first_60s(mrclam6) -> None:
    src = load_source(f"mrclam:{mrclam6}", duration=60.0)
    assert len(src.landmarks) == 15
    a, b = _nodes(src), run_engine(src, "dekf")
    _assert_same(a, b)
    assert a.stats["fused"] == b.stats["fused"] > 1000 and a.stats["gated"] == b.stats["gated"]


def test_landmark_codes_sort_after_the_robots_in_id_order_and_only_dekf_takes_a_map() -> None:
    noise = UnicycleNoise()
    mean = np.broadcast_to(np.eye(3), (2, 3, 3))
    cov = np.broadcast_to(1e-3 * np.eye(3), (2, 3, 3))
    eng = Engine("dekf", mean, cov, noise=noise, landmarks={30: (1.0, 0.0, 0.1, 0.1), 12: (0.0, 2.0, 0.1, 0.1)})
    assert eng.landmark_code(12) == landmark_code(0) and eng.landmark_code(30) == landmark_code(1)
    assert eng.landmark_code(99) == NO_LANDMARK
    rb = KIND_ORDER["range_bearing"]
    tgt = np.array([landmark_code(1), 1, landmark_code(0), NO_LANDMARK])
    det = Detections(np.zeros(4, dtype=np.int64), tgt, np.full(4, rb), np.zeros((4, 3)), np.zeros((4, 3, 3)))
    assert det.canonical().target.tolist() == [1, NO_LANDMARK, landmark_code(0), landmark_code(1)]
    assert POSE < rb  # kinds first: a pose of robot 1 precedes every range-bearing detection
    for estimator in ("expfusion", "ci"):
        with pytest.raises(ValueError, match="landmarks run with 'dekf'"):
            Engine(estimator, mean, cov, noise=noise, landmarks={1: (0.0, 0.0, 0.1, 0.1)})
    with pytest.raises(ValueError, match="planar"):
        Engine("dekf", mean, cov, noise=noise, landmarks={1: (0.0, 0.0, 0.0, 0.1, 0.1, 0.1)})
