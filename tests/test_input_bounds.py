"""Inputs from outside are bounded before anything is allocated, and bad ones get a clear error naming where:
record grids (durations x rates), values, numbers that only Python's ``float`` reads, overlapping odometry or
odometry before the initial stamp in a file, and event files with many bad lines (streamed, bounded memory)."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import pytest

from swarmloc.config import ConfigError, load_config
from swarmloc.datasets.eventfile import COLUMNS, EventFileError, load_events
from swarmloc.experiments.own_robots import evaluate_event_file

pytestmark = pytest.mark.unit


HEADER = ",".join(COLUMNS)
INIT = "initial,0.0,1,,,,,,,0 0 0,0.01 0.01 0.01,"


def _csv(tmp_path: Path, *lines: str) -> Path:
    p = tmp_path / "events.csv"
    p.write_text("\n".join([HEADER, *lines]) + "\n")
    return p


def _config(tmp_path: Path, rate: str):  # noqa: ANN202
    p = tmp_path / "c.toml"
    p.write_text(f"[record]\nrate = {rate}\n")
    return load_config(p)


def test_a_span_of_1e9_s_is_refused_before_its_record_grid_is_allocated(tmp_path: Path) -> None:
    p = _csv(tmp_path, INIT, "odometry,0.5,1,0.0,0.1,0.0,,,,,,", "odometry,1e9,1,0.5,0.1,0.0,,,,,,")
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=r"more than 2000000 records .* lower \[record\] rate or shorten"):
            evaluate_event_file(p, estimators=["dr"])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 50e6  # 4e9 record times would take 30 GiB


def test_a_record_rate_of_1e9_hz_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"\[record\] rate: expected a number in \(0, 1000\] Hz"):
        _config(tmp_path, "1e9")


def test_a_record_rate_too_low_to_score_anything_is_refused_not_scored_zero(tmp_path: Path) -> None:
    p = _csv(tmp_path, INIT, "odometry,0.5,1,0.0,0.1,0.0,,,,,,", "odometry,1.0,1,0.5,0.1,0.0,,,,,,")
    with pytest.raises(ValueError, match=r"nothing to score .*raise \[record\] rate above 1 Hz"):
        evaluate_event_file(p, estimators=["dr"], config=_config(tmp_path, "1e-300"))


@pytest.mark.parametrize(
    ("line", "problem"),
    [
        ("odometry,1.0,1,0.0,1e308,0.0,,,,,,", "'v'"),
        ("odometry,1e11,1,0.0,0.1,0.0,,,,,,", "'t'"),
        ("detection,1.0,1,,,,,,absolute,1e308 0 0,0.1 0.1 0.1,", "'z'"),
        ("detection,1.0,1,,,,2,robot,range,1.0,1e-300,", "'std'"),
        ("odometry,1.0,1,0.0,1_0,0.0,,,,,,", "'v' must be a number"),
        ("odometry,1.0,1,0.0,0.5,٣,,,,,,", "'w' must be a number"),
    ],
)
def test_values_beyond_their_bounds_and_odd_numbers_are_bad_lines(tmp_path: Path, line: str, problem: str) -> None:
    p = _csv(tmp_path, INIT, line)
    with pytest.raises(EventFileError) as ei:
        load_events(p)
    msg = str(ei.value)
    assert "events.csv line 3" in msg and problem in msg


def test_the_hint_names_the_command_line_flag(tmp_path: Path) -> None:
    p = _csv(tmp_path, INIT, "odometry,1.0,1,0.0,x,0.0,,,,,,")
    with pytest.raises(EventFileError, match="--skip-bad-lines"):
        load_events(p)


def test_overlapping_odometry_in_a_file_names_both_lines(tmp_path: Path) -> None:
    p = _csv(tmp_path, INIT, "odometry,1.0,1,0.0,0.5,0.0,,,,,,", "odometry,1.5,1,0.5,0.5,0.0,,,,,,")
    with pytest.raises(EventFileError) as ei:
        load_events(p)
    msg = str(ei.value)
    assert "line 4" in msg and "overlaps its odometry on line 3" in msg


def test_odometry_before_the_initial_stamp_is_a_bad_line(tmp_path: Path) -> None:
    p = _csv(tmp_path, INIT, "odometry,1.0,1,-5.0,0.5,0.0,,,,,,")
    with pytest.raises(EventFileError, match=r"line 3.*starts at t0 = -5.0 s, before its initial stamp 0.0 s"):
        load_events(p)


def test_bad_lines_are_streamed_in_bounded_memory(tmp_path: Path) -> None:
    """50 000 bad lines (10 MB): the reader keeps 20 messages and a count, not every line."""
    bad = "odometry,1.0,1,0.0,not-a-number" + "," * 6 + "x" * 160
    p = tmp_path / "events.csv"
    with p.open("w") as f:
        f.write(HEADER + "\n" + INIT + "\n" + "odometry,1.0,1,0.0,0.5,0.0,,,,,,\n")
        for _ in range(50_000):
            f.write(bad + "\n")
    assert p.stat().st_size > 9e6
    tracemalloc.start()
    try:
        ef = load_events(p, strict=False)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert ef.n_bad == 50_000 and len(ef.problems) == 21
    assert peak < 3e6


@pytest.mark.parametrize(
    ("robots", "duration", "match"),
    [
        (3, 1e9, "more than 50000000"),
        (10**6, 30.0, "more than 50000000"),
        (3, float("nan"), "finite"),
        (0, 30.0, "positive"),
    ],
)
def test_a_simulation_too_large_or_ill_posed_is_refused_before_it_allocates(
    robots: int, duration: float, match: str
) -> None:
    from swarmloc.experiments.sources import load_source

    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=match):
            load_source("sim:random", robots=robots, duration=duration)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 20e6
