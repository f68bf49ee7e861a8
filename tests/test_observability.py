"""Observability (lecture slide 20, thesis Fig. 5.22): without absolute information the team's absolute error grows
while the robots' relative poses stay as accurate as they started; one robot with absolute fixes bounds everyone.

The claims are checked on the centralized EKF (consistent without landmarks), 4 simulated robots, 300 s, errors
pooled (RMS) over 4 seeds, first sixth of the run against the last sixth."""

from __future__ import annotations

import numpy as np
import pytest

from swarmloc_studies.observability import observability_figure, observability_run

# slow: its module fixture simulates the long runs every test reads (20 s)
pytestmark = [pytest.mark.unit, pytest.mark.slow]


SEEDS = range(4)


def _rms_first_last(anchored: tuple[int, ...], key: str) -> tuple[float, float]:
    first, last = [], []
    for s in SEEDS:
        r = observability_run(seed=s, anchored=anchored, duration=300.0)
        e = r[key]
        k = e.shape[0] // 6
        first.append(np.mean(e[:k] ** 2))
        last.append(np.mean(e[-k:] ** 2))
    return float(np.sqrt(np.mean(first))), float(np.sqrt(np.mean(last)))


@pytest.fixture(scope="module")
def runs() -> dict[str, tuple[float, float]]:
    return {
        "abs_free": _rms_first_last((), "absolute"),
        "rel_free": _rms_first_last((), "relative"),
        "abs_anchored": _rms_first_last((0,), "absolute"),
    }


def test_absolute_error_grows_without_absolute_information(runs):
    first, last = runs["abs_free"]
    assert last > 2.0 * first, runs


def test_relative_error_stays_bounded(runs):
    first, last = runs["rel_free"]
    assert last < 1.6 * first, runs
    assert last < 0.6 * runs["abs_free"][1]  # relative poses end far better known than absolute ones


def test_one_anchored_robot_bounds_everyone(runs):
    first, last = runs["abs_anchored"]
    assert last < 0.5 * runs["abs_free"][1], runs
    assert last < 2.0 * first, runs


def test_figure(tmp_path):
    p = observability_figure(tmp_path / "obs.png", seeds=1, duration=30.0)
    assert p.exists() and p.stat().st_size > 10_000
