"""The test tiers: every test has a kind (unit, data, network), a test that reads MRCLAM is marked data, and the
markers are registered with --strict-markers and xdist in pyproject's addopts (what README's command runs)."""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from _tiers import node_id, read_list, update
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
    assert "--strict-markers" in opts and "-n" in opts and "loadfile" in opts and "--durations=25" in opts
    dev = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["dev"]
    assert any(d.startswith("pytest-xdist") for d in dev)


def test_every_listed_slow_test_is_a_test_of_its_file():
    """tests/slow_tests.txt names tests that exist (a renamed or removed one: regenerate it, tests/_tiers.py)."""
    listed = read_list()
    assert len(listed) > 100
    for nid in sorted(listed):
        path, _, name = nid.partition("::")
        func = name.split("[", 1)[0]
        src = (ROOT / path).read_text()
        assert re.search(rf"^def {re.escape(func)}\(", src, re.M), f"{nid}: no such test"


def test_the_list_is_made_from_a_runs_durations(tmp_path):
    xml = tmp_path / "run.xml"
    case = '<testcase classname="tests.test_a" name="{}" time="{}"/>'
    xml.write_text(f"<testsuites><testsuite>{case.format('test_x[1]', 3.5)}{case.format('test_y', 0.2)}"
                   "</testsuite></testsuites>")  # fmt: skip
    lst = tmp_path / "slow.txt"
    lst.write_text("# old\ntests/test_a.py::test_y\ntests/test_b.py::test_z\n")
    assert node_id("tests.test_a", "test_x[1]") == "tests/test_a.py::test_x[1]"
    assert update(xml, lst) == (2, 1)  # test_y ran fast: off the list; test_z did not run: kept
    assert read_list(lst) == {"tests/test_a.py::test_x[1]", "tests/test_b.py::test_z"}
