"""The honest-filter spread study (benchmarks/nolm_spread.py): its scene scores landmark readings the filter never
fused, and ``diekf`` with the simulator's own model lands in the band there run by run (short seeded runs)."""

from __future__ import annotations

from types import ModuleType

import numpy as np
import pytest
from _benchmarks import load_benchmark

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def spread() -> ModuleType:
    return load_benchmark("nolm_spread")


def test_readings_are_scored_and_never_fused(spread: ModuleType) -> None:
    r = spread.one_seed(0, 40.0, 0.02, "diekf")
    assert r["readings"] > 100  # landmark readings scored
    assert 0 < r["fused"] <= r["mutual"]  # only robot detections reach the filter
    assert np.isfinite([r["nis_ratio"], r["anis"], r["anees"]]).all()


def test_an_honest_filter_is_in_band_run_by_run(spread: ModuleType) -> None:
    runs = [spread.one_seed(s, 60.0, 0.02, "diekf") for s in range(4)]
    for r in runs:
        assert 0.5 <= r["nis_ratio"] <= 2.0, r  # the held-out score, run by run
    assert 0.5 <= np.mean([r["anees"] for r in runs]) <= 2.0  # against the truth (one 60 s run says little alone)
    summary = spread.spread(np.array([r["nis_ratio"] for r in runs]))
    assert summary["in_band"] == 1.0 and summary["six_in_band"] == 1.0
    assert summary["min"] <= summary["median"] <= summary["max"]
