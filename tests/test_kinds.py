"""Measurement kinds are typed (:class:`swarmloc.events.Kind`): no code outside the measurement models compares a
kind with a string literal, and the type changes no byte of what is written or sent."""

from __future__ import annotations

import ast
from pathlib import Path

import msgspec
import numpy as np
import pytest

from swarmloc.datasets.eventfile import load_events
from swarmloc.datasets.eventwrite import write_events
from swarmloc.events import Detection, Kind, Odometry
from swarmloc.live.zenoh_input import encode_event
from swarmloc.net.schema import RawDetection
from swarmloc.sensors.models import MODELS
from swarmloc.sensors.models3 import MODELS3

pytestmark = pytest.mark.unit

SRC = Path(__file__).resolve().parents[1] / "src" / "swarmloc"
MODEL_MODULES = ("sensors/models.py", "sensors/models3.py")
"""Where a kind's behaviour is defined: the only modules allowed to spell kinds as strings in a comparison."""
NAMES = frozenset(k.value for k in Kind)


def _kind_literals(node: ast.AST) -> list[str]:
    """The measurement-kind names a string literal (or a tuple/list/set of them) spells."""
    elts = node.elts if isinstance(node, (ast.Tuple, ast.List, ast.Set)) else [node]
    return [e.value for e in elts if isinstance(e, ast.Constant) and isinstance(e.value, str) and e.value in NAMES]


def kind_string_comparisons(tree: ast.AST) -> list[tuple[int, str]]:
    """``(line, source)`` of every comparison with a measurement kind's name as a string literal (``d.kind ==
    "pose"``, ``kind in ("range", "bearing")``, ``"pose" in sensor.kinds``), every ``match`` case on such a literal
    and every dispatch through a dict display keyed by kind names (``{"range": ..., "bearing": ...}[kind]``)."""
    hits = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare) and any(_kind_literals(o) for o in (node.left, *node.comparators)):
            hits.append((node.lineno, ast.unparse(node)))
        elif isinstance(node, ast.match_case) and any(
            isinstance(p, ast.MatchValue) and _kind_literals(p.value) for p in ast.walk(node.pattern)
        ):
            hits.append((node.pattern.lineno, ast.unparse(node.pattern)))
        elif (isinstance(node, ast.Subscript) and isinstance(node.value, ast.Dict)
              and any(k is not None and _kind_literals(k) for k in node.value.keys)):  # fmt: skip
            hits.append((node.lineno, ast.unparse(node)))
    return hits


def test_the_scanner_finds_each_form_of_kind_string_comparison():
    """Each form the scanner is meant to catch is caught; members of the type and other strings are not."""
    caught = [
        'd.kind == "pose"',
        'kind != "absolute"',
        'kind in ("range_bearing", "range")',
        '"range_bearing" not in sensor.kinds',
        'target[0] == "absolute"',
        'h = {"range": a, "bearing": b}[kind]',
        'match d.kind:\n    case "pose3":\n        pass',
    ]
    for src in caught:
        assert len(kind_string_comparisons(ast.parse(src))) == 1, src
    clean = ['d.kind == Kind.POSE', 'kind in (Kind.RANGE, Kind.BEARING)', 'f.kind == "unary"', 'a.dtype.kind in "fi"',
             'MODELS[d.kind].ranged', 'topic = robot_topic(r, "pose")']  # fmt: skip
    for src in clean:
        assert kind_string_comparisons(ast.parse(src)) == [], src


def test_no_kind_string_comparison_outside_the_models():
    """0 comparisons of a measurement kind with a string literal in src/ outside the models modules."""
    found = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        if rel in MODEL_MODULES:
            continue
        found += [f"{rel}:{line}: {text}" for line, text in kind_string_comparisons(ast.parse(path.read_text()))]
    assert found == [], "compare with swarmloc.events.Kind members or ask the kind's model:\n" + "\n".join(found)


def test_every_model_is_keyed_by_its_kind_member():
    """The registries hold exactly the kinds of the type, keyed by members, each model naming its own member."""
    assert set(MODELS) | set(MODELS3) == set(Kind)
    for table in (MODELS, MODELS3):
        for k, m in table.items():
            assert type(k) is Kind and m.kind is k
    assert {k for k, m in MODELS.items() if m.ranged} == {Kind.RANGE_BEARING, Kind.RANGE}
    assert {k for k, m in MODELS.items() if m.bearing_last} == {Kind.RANGE_BEARING, Kind.BEARING}


def _detections(kinds: dict[str, str]) -> list[Odometry | Detection]:
    z = {"pose": [1.0, 0.5, 0.25], "range_bearing": [2.0, -0.5], "range": [1.5], "bearing": [3.0],
         "absolute": [0.1, 0.2, 0.3]}  # fmt: skip
    out: list[Odometry | Detection] = [Odometry(0, 0.0, 1.0, 0.5, 0.1), Odometry(1, 0.0, 1.0, 0.5, 0.1)]
    for name, kind in kinds.items():
        m = len(z[name])
        target = None if name == Kind.ABSOLUTE else 1
        out.append(Detection(0, 1.0, kind, np.array(z[name]), 0.01 * np.eye(m), target=target))  # type: ignore[arg-type]
    return out


@pytest.mark.parametrize("ext", ["csv", "jsonl"])
def test_members_write_and_send_the_bytes_of_the_names(tmp_path: Path, ext: str):
    """A detection built with a member and one built with its name: the same event file, input message and raw
    forward (JSON and MessagePack), the same ``repr``; the file reads back equal."""
    named = _detections({k.value: k.value for k in MODELS})
    typed = _detections({k.value: k for k in MODELS})
    a = write_events(tmp_path / f"named.{ext}", named).read_bytes()
    b = write_events(tmp_path / f"typed.{ext}", typed).read_bytes()
    assert a == b
    assert (b'"kind": "range_bearing"' if ext == "jsonl" else b",range_bearing,") in a
    for x, y in zip(named[2:], typed[2:], strict=True):
        assert type(y.kind) is Kind and type(x.kind) is str  # type: ignore[union-attr]
        assert encode_event(x) == encode_event(y)
        rx, ry = (RawDetection(1.0, e.kind, [1.0], [1.0], 1) for e in (x, y))  # type: ignore[union-attr]
        assert msgspec.json.encode(rx) == msgspec.json.encode(ry)
        assert msgspec.msgpack.encode(rx) == msgspec.msgpack.encode(ry)
        assert repr(x) == repr(y) and f"kind='{x.kind}'" in repr(y)  # type: ignore[union-attr]
    back = load_events(tmp_path / f"typed.{ext}")
    assert [e.kind for e in back.events if isinstance(e, Detection)] == list(MODELS)
