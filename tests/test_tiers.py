"""The test tiers: every test has a kind (unit, data, network), a test that reads MRCLAM is marked data, and the
markers are registered with --strict-markers and xdist in pyproject's addopts (what README's command runs)."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from conftest import KINDS, tier_problems

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]


@dataclass
class _Mark:
    name: str


@dataclass
class _Item:
    nodeid: str
    marks: tuple[str, ...]
    fixturenames: tuple[str, ...] = field(default=())

    def iter_markers(self):
        return iter([_Mark(m) for m in self.marks])


def test_a_test_without_a_kind_or_reading_mrclam_unmarked_is_named():
    items = [
        _Item("t.py::ok", ("unit",)),
        _Item("t.py::slow_only", ("slow",)),
        _Item("t.py::reads", ("unit",), ("tmp_path", "mrclam6")),
        _Item("t.py::reads_ok", ("data", "slow"), ("mrclam_root",)),
        _Item("t.py::net", ("network",)),
    ]
    assert tier_problems(items) == [
        "t.py::slow_only: no tier marker (pytestmark = pytest.mark.unit, data or network)",
        "t.py::reads: reads MRCLAM but is not marked data",
    ]


def test_markers_are_registered_strict_and_xdist_runs_in_readmes_command():
    ini = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    names = {m.split(":", 1)[0] for m in ini["markers"]}
    assert names == {*KINDS, "slow"}
    opts = ini["addopts"].split()
    assert "--strict-markers" in opts and "-n" in opts and "--dist" in opts and "--durations=25" in opts
    dev = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["dev"]
    assert any(d.startswith("pytest-xdist") for d in dev)
