"""Plain event files (CSV / JSON Lines): exact round trips, every validation rule, strictness, order, defaults."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import swarmloc.datasets.eventfile as eventfile_module
from swarmloc.config import DEFAULTS
from swarmloc.datasets.eventfile import COLUMNS, EventFileError, load_events, load_truth_dir
from swarmloc.datasets.eventwrite import write_events
from swarmloc.datasets.tum import TUMError, write_tum
from swarmloc.events import Detection, Odometry, Truth
from swarmloc.gaussian import GroupGaussian

pytestmark = pytest.mark.unit


HEADER = ",".join(COLUMNS)
ODO = "odometry,1.0,1,0.0,0.5,0.1,,,,,,"  # a good line


def _csv(tmp_path: Path, *lines: str, name: str = "events.csv") -> Path:
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def _jsonl(tmp_path: Path, *records: dict | str, name: str = "events.jsonl") -> Path:
    p = tmp_path / name
    p.write_text("\n".join(r if isinstance(r, str) else json.dumps(r) for r in records) + "\n")
    return p


def _same(a: Odometry | Detection, b: Odometry | Detection) -> None:
    assert type(a) is type(b)
    if isinstance(a, Odometry):
        assert a == b
        return
    fields = ("observer", "t", "kind", "target", "target_is_robot")
    assert [getattr(a, f) for f in fields] == [getattr(b, f) for f in fields]
    np.testing.assert_array_equal(a.z, b.z)
    np.testing.assert_array_equal(a.cov, b.cov)


def _det(observer, t, kind, z, cov, target=None, is_robot=True) -> Detection:
    return Detection(observer, t, kind, np.array(z, float), np.array(cov, float), target, is_robot)


def _all_kinds() -> list[Odometry | Detection]:
    """Every record kind, with floats that only an exact format reproduces; already in load order."""
    full = np.array([[0.04, 0.001, -0.002], [0.001, 0.03, 0.0005], [-0.002, 0.0005, 1 / 300]])
    return [
        Odometry(2, 0.0, 0.1 + 0.2, 1 / 3, -0.07),
        _det(1, 0.3, "pose", [1.5, -0.2, 0.1], full, 2, True),
        _det(1, 0.3, "range_bearing", [4.2, 0.55], np.diag([0.01, 0.035**2]), 7, False),
        _det(2, 0.3, "range", [2.0 / 3], [[0.1 * 0.1]], 1, True),
        Odometry(1, 0.3, 0.4, 0.25, 1e-17),
        _det(1, 0.35, "bearing", [-math.pi], [[0.0012]], 9, False),
        _det(2, 0.35, "absolute", [4.0e5 + 0.1, -3.0, math.pi], np.diag([1e-4, 2e-4, 3e-4])),
        Odometry(2, 1.248e3, 1.248e3 + 0.05, -0.2, 0.0),
    ]


LANDMARKS = {7: (4.0, 2.5, 0.01, 0.02), 9: (-1.0 / 3, 1e6, 0.5, 0.5)}
INITIAL = {
    1: (np.array([0.0, 0.0, 0.1]), np.diag([1e-4, 1e-4, 1e-3])),
    2: (np.array([1.0, -2.0, -math.pi / 3]), np.array([[0.01, 0.002, 0], [0.002, 0.01, 0], [0, 0, 0.001]])),
}


@pytest.mark.parametrize("ext", [".csv", ".jsonl"])
def test_round_trip_every_record_and_kind(tmp_path: Path, ext: str) -> None:
    events = _all_kinds()
    p = write_events(tmp_path / f"ev{ext}", events, LANDMARKS, INITIAL, initial_times={2: 0.0})
    ef = load_events(p)
    assert ef.path == p and ef.problems == []
    assert len(ef.events) == len(events)
    for a, b in zip(ef.events, events, strict=True):
        _same(a, b)
    assert ef.landmarks == LANDMARKS
    assert set(ef.initial) == {1, 2}
    for r, (pose, cov) in INITIAL.items():
        np.testing.assert_array_equal(ef.initial[r][0], pose)
        np.testing.assert_array_equal(ef.initial[r][1], cov)
    assert ef.initial_times == {2: 0.0}
    assert ef.robots == [1, 2]
    # writing what was read gives the same text
    q = write_events(tmp_path / f"again{ext}", ef.events, ef.landmarks, ef.initial, ef.initial_times)
    assert q.read_text() == p.read_text()


def test_written_csv_is_human_readable(tmp_path: Path) -> None:
    p = write_events(tmp_path / "ev.csv", [Odometry(1, 0.0, 0.1, 0.5, 0.02)], {7: (4.0, 2.5, 0.01, 0.01)})
    lines = [x for x in p.read_text().splitlines() if not x.startswith("#")]
    assert lines == [HEADER, "landmark,,,,,,7,landmark,,4.0 2.5,0.01 0.01,", "odometry,0.1,1,0.0,0.5,0.02,,,,,,"]


def test_std_written_only_when_exact(tmp_path: Path) -> None:
    """A diagonal covariance goes out as std only when std**2 gives back the variance exactly, else as cov."""
    assert math.sqrt(2.0) ** 2 != 2.0 and math.sqrt(0.0625) ** 2 == 0.0625
    p = write_events(
        tmp_path / "ev.jsonl",
        [Odometry(1, 0, 1, 0, 0), _det(1, 0.5, "range_bearing", [1.0, 0.1], np.diag([0.25, 0.0625]), 2)],
        initial={1: (np.zeros(3), np.diag([2.0, 1.0, 1.0]))},
    )
    recs = [json.loads(x) for x in p.read_text().splitlines() if not x.startswith("#")]
    det = next(r for r in recs if r["type"] == "detection")
    assert det["std"] == [0.5, 0.25] and "cov" not in det
    init = next(r for r in recs if r["type"] == "initial")
    assert "std" not in init and init["cov"] == [2.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    np.testing.assert_array_equal(load_events(p).initial[1][1], np.diag([2.0, 1.0, 1.0]))


def test_docstring_example_loads() -> None:
    doc = eventfile_module.__doc__
    assert doc is not None
    block = doc.split("Example (``events.csv``)::", 1)[1].split("The same range-bearing detection", 1)[0]
    lines = [x.strip() for x in block.strip().splitlines()]
    assert lines[0] == HEADER and len(lines) == 6
    jline = doc.split("``events.jsonl``::", 1)[1].split("(on one line)", 1)[0]
    rec = json.loads(" ".join(jline.split()))
    assert rec["kind"] == "range_bearing"


def test_docstring_example_content(tmp_path: Path) -> None:
    doc = eventfile_module.__doc__
    block = doc.split("Example (``events.csv``)::", 1)[1].split("The same range-bearing detection", 1)[0]
    p = _csv(tmp_path, *[x.strip() for x in block.strip().splitlines()])
    ef = load_events(p)
    assert ef.landmarks == {7: (4.0, 2.5, 0.01, 0.01)}
    assert ef.robots == [1, 2]
    kinds = [e.kind if isinstance(e, Detection) else "odometry" for e in ef.events]
    assert kinds == ["odometry", "range_bearing", "pose"]  # odometry stamped by t0 = 0.0
    pose = ef.events[2]
    np.testing.assert_array_equal(pose.cov, np.diag([0.0025, 0.0025, 0.0003]))
    assert pose.target == 2 and pose.target_is_robot
    rb = ef.events[1]
    assert rb.target == 7 and not rb.target_is_robot
    np.testing.assert_array_equal(rb.cov, np.diag([0.1**2, 0.035**2]))
    (g,) = ef.initial_beliefs().values()
    assert isinstance(g, GroupGaussian)
    np.testing.assert_array_equal(g.cov, np.diag([0.01**2] * 3))


# ------------------------------------------------------------------------------------------------ validation

BAD_CSV = [
    ("odometry,1.0,1,0.0,nan,0.1,,,,,,", "'v' must be finite"),
    ("odometry,1.0,1,0.0,fast,0.1,,,,,,", "'v' must be a number"),
    ("odometry,0.5,1,1.0,0.5,0.1,,,,,,", "odometry must have t >= t0"),
    ("odometry,1.0,-1,0.0,0.5,0.1,,,,,,", "'robot' must be a non-negative integer id"),
    ("odometry,1.0,1.5,0.0,0.5,0.1,,,,,,", "'robot' must be a non-negative integer id"),
    ("odometry,1.0,1,,0.5,0.1,,,,,,", "'t0' is required"),
    ("odometry,1.0,1,0.0,0.5,0.1,,,pose,,,", "'kind' does not apply to odometry records"),
    ("odom,1.0,1,0.0,0.5,0.1,,,,,,", "unknown record type 'odom'"),
    (",1.0,1,0.0,0.5,0.1,,,,,,", "'type' is required"),
    ("odometry,1.0,1,0.0,0.5,0.1,,,,,,,,", "expected at most 12 cells (as in the header row), got 14"),
    ('odometry,1.0,1,0.0,0.5,0.1,"', "not a CSV row"),
    ("detection,1.0,1,,,,2,robot,rangebearing,1 0.1,0.1 0.1,", "unknown detection kind 'rangebearing'"),
    ("detection,1.0,1,,,,2,robot,range_bearing,1 0.1 3,0.1 0.1,", "must have 2 numbers, got 3"),
    ("detection,1.0,1,,,,2,robot,range,1 0.1,0.1,", "'z' of a range detection must have 1 number, got 2"),
    ("detection,1.0,1,,,,2,robot,pose,1 0.1,0.1 0.1 0.1,", "must have 3 numbers, got 2"),
    ("detection,1.0,1,,,,2,robot,range_bearing,1 x,0.1 0.1,", "'z' must be numbers separated by spaces"),
    ("detection,1.0,1,,,,2,robot,range_bearing,1 inf,0.1 0.1,", "'z' must be finite"),
    ("detection,1.0,1,,,,2,robot,range_bearing,1 0.1,0.1 -0.1,", "'std' must be positive"),
    ("detection,1.0,1,,,,2,robot,range_bearing,1 0.1,0.1 0,", "'std' must be positive"),
    ("detection,1.0,1,,,,2,robot,range_bearing,1 0.1,0.1,", "'std' of a range_bearing detection must have 2"),
    ("detection,1.0,1,,,,2,robot,range_bearing,1 0.1,,1 0.5 0 1", "'cov' is not symmetric"),
    ("detection,1.0,1,,,,2,robot,range_bearing,1 0.1,,1 2 2 1", "'cov' is not positive definite"),
    ("detection,1.0,1,,,,2,robot,range_bearing,1 0.1,,1 0 1", "must have 2*2 = 4 numbers (row-major), got 3"),
    ("detection,1.0,1,,,,2,robot,range_bearing,1 0.1,0.1 0.1,1 0 0 1", "either 'std' or 'cov', not both"),
    ("detection,1.0,1,,,,2,robot,range_bearing,0 0.1,0.1 0.1,", "range must be positive"),
    ("detection,1.0,1,,,,2,robot,range,-2,0.1,", "range must be positive"),
    ("detection,1.0,1,,,,2,robot,bearing,45,0.1,", "bearing must be in [-pi, pi] rad"),
    ("detection,1.0,1,,,,2,robot,range_bearing,1 -90,0.1 0.1,", "bearing must be in [-pi, pi] rad"),
    ("detection,1.0,1,,,,2,robto,range,1,0.1,", "'target_type' must be 'robot' or 'landmark', got 'robto'"),
    ("detection,1.0,1,,,,2,,range,1,0.1,", "'target_type' is required"),
    ("detection,1.0,1,,,,,robot,range,1,0.1,", "'target' is required"),
    ("detection,1.0,1,,,,-3,robot,range,1,0.1,", "'target' must be a non-negative integer id"),
    ("detection,1.0,1,,,,7,landmark,pose,1 0 0,0.1 0.1 0.1,", "a landmark is a point"),
    ("detection,1.0,1,,,,2,robot,absolute,1 0 0,0.1 0.1 0.1,", "an absolute detection"),
    ("detection,1.0,1,,,,,robot,absolute,1 0 0,0.1 0.1 0.1,", "has no 'target' or 'target_type'"),
    ("detection,1.0,1,,,,1,robot,range,1,0.1,", "robot 1 cannot detect itself"),
    ("detection,1.0,1,0.5,,,2,robot,range,1,0.1,", "'t0' does not apply to detection records"),
    ("detection,,1,,,,2,robot,range,1,0.1,", "'t' is required"),
    ("detection,1.0,1,,,,2,robot,range,1,,", "has neither 'std' nor 'cov' and no default applies"),
    ("landmark,,,,,,7,landmark,,1 2 3,0.1 0.1,", "'z' of a landmark must be 'x y' (2 numbers), got 3"),
    ("landmark,,,,,,7,landmark,,1 2,,1 0 0 1", "a landmark record takes 'std' (sx sy), not 'cov'"),
    ("landmark,,,,,,7,landmark,,1 2,0.1,", "'std' of a landmark must be 'sx sy' (2 numbers), got 1"),
    ("landmark,,,,,,7,landmark,,1 2,0.1 -1,", "'std' must be positive"),
    ("landmark,,,,,,7,landmark,,1 2,,", "a landmark has no 'std' and no default applies"),
    ("landmark,,,,,,7,robot,,1 2,0.1 0.1,", "'target_type' of a landmark record must be 'landmark' or empty"),
    ("landmark,1.0,,,,,7,,,1 2,0.1 0.1,", "'t' does not apply to landmark records"),
    ("landmark,,1,,,,7,,,1 2,0.1 0.1,", "'robot' does not apply to landmark records"),
    ("initial,0.0,1,,,,,,,0 0,0.1 0.1 0.1,", "'z' of an initial belief must be 'x y theta' (3 numbers), got 2"),
    ("initial,0.0,1,,,,,,,0 0 0,,1 0 0 0 1 0 0 0 -1", "'cov' is not positive definite"),
    ("initial,0.0,1,,,,,,,0 0 0,,", "an initial belief has neither 'std' nor 'cov' and no default applies"),
    ("initial,0.0,1,,,,2,robot,,0 0 0,0.1 0.1 0.1,", "'target', 'target_type' do not apply to initial records"),
]


@pytest.mark.parametrize(("line", "problem"), BAD_CSV)
def test_bad_csv_line_names_file_line_and_problem(tmp_path: Path, line: str, problem: str) -> None:
    p = _csv(tmp_path, "# my robots", HEADER, ODO, line, ODO.replace("1.0,1,0.0", "2.0,1,1.0"))
    with pytest.raises(EventFileError) as ei:
        load_events(p)
    msg = str(ei.value)
    assert "events.csv: 1 bad line" in msg
    assert "events.csv line 4: " in msg
    assert problem in msg
    assert f"; the line: {line!r}" in msg
    assert ei.value.problems == [msg.splitlines()[1].strip()]
    # the same file loads with strict=False, without that line
    ef = load_events(p, strict=False)
    assert len(ef.problems) == 1 and ef.problems[0].startswith("events.csv line 4: ")
    assert [e.t0 for e in ef.events] == [0.0, 1.0]


def _dj(kind: str, z: object, **fields: object) -> dict:
    """A JSON detection record of robot 1 (target robot 2 at t = 1.0 unless ``fields`` say otherwise)."""
    return {
        "type": "detection",
        "t": 1.0,
        "robot": 1,
        "target": 2,
        "target_type": "robot",
        "kind": kind,
        "z": z,
    } | fields


BAD_JSONL = [
    ('{"type": "odometry", "t": 1.0, "robot": 1, "t0": 0.0, "v": 0.5, "w": 0.1', "not valid JSON"),
    ("[1, 2, 3]", "expected a JSON object, got a list"),
    ({"type": "odometry", "t": 1.0, "robot": 1, "t0": 0.0, "v": 0.5, "w": 0.1, "speed": 3}, "unknown field(s) 'speed'"),
    ({"type": "odometry", "t": 1.0, "robot": 1, "t0": 0.0, "v": "0.5", "w": 0.1}, "'v' must be a number"),
    ({"type": "odometry", "t": 1.0, "robot": True, "t0": 0.0, "v": 0.5, "w": 0.1}, "'robot' must be a non-negative"),
    ({"type": "odometry", "t": 1.0, "robot": 1, "t0": 0.0, "v": 0.5, "w": None}, "'w' is required"),
    ('{"type": "odometry", "t": NaN, "robot": 1, "t0": 0.0, "v": 0.5, "w": 0.1}', "'t' must be finite"),
    (_dj("range", "1.0", std=[0.1]), "'z' must be an array of numbers"),
    (_dj("range_bearing", [1.0, 0.1], cov=[[1, 0], [0, 1]]), "'cov' must be an array of numbers"),
    ({"type": 3}, "'type' must be a string"),
]


@pytest.mark.parametrize(("record", "problem"), BAD_JSONL)
def test_bad_jsonl_line_names_file_line_and_problem(tmp_path: Path, record: dict | str, problem: str) -> None:
    good = {"type": "odometry", "t": 1.0, "robot": 1, "t0": 0.0, "v": 0.5, "w": 0.1}
    p = _jsonl(tmp_path, "# comment", good, "", record)
    with pytest.raises(EventFileError) as ei:
        load_events(p)
    msg = str(ei.value)
    assert "events.jsonl line 4: " in msg
    assert problem in msg


def test_jsonl_numbers_for_single_values_and_integral_float_ids(tmp_path: Path) -> None:
    p = _jsonl(
        tmp_path,
        {"type": "odometry", "t": 1.0, "robot": 1.0, "t0": 0.0, "v": 1, "w": 0},
        _dj("RANGE", 2.5, t=0.5, target=4, target_type="Landmark", std=0.2),
    )
    ef = load_events(p)
    d = ef.events[1]
    assert isinstance(d, Detection) and d.kind == "range" and d.target == 4 and not d.target_is_robot
    np.testing.assert_array_equal(d.z, [2.5])
    np.testing.assert_allclose(d.cov, [[0.04]])
    assert ef.events[0] == Odometry(1, 0.0, 1.0, 1.0, 0.0)


def test_csv_short_rows_byte_order_mark_and_crlf(tmp_path: Path) -> None:
    """Trailing empty cells may be left out; a UTF-8 byte-order mark and CRLF line ends (Excel) are fine."""
    p = tmp_path / "excel.csv"
    text = HEADER + "\r\nodometry,0.1,1,0.0,0.5,0.02\r\ndetection,0.2,1,,,,2,robot,range,1.5,0.1\r\n"
    p.write_bytes(text.encode("utf-8-sig"))
    ef = load_events(p)
    assert ef.events[0] == Odometry(1, 0.0, 0.1, 0.5, 0.02)
    d = ef.events[1]
    assert isinstance(d, Detection) and d.target == 2 and d.z.tolist() == [1.5]
    q = tmp_path / "bom.jsonl"
    rec = {"type": "odometry", "t": 1, "robot": 0, "t0": 0, "v": 0, "w": 0}
    q.write_bytes(b"\xef\xbb\xbf" + json.dumps(rec).encode())
    assert load_events(q).robots == [0]


def test_csv_integral_float_ids_and_free_column_order(tmp_path: Path) -> None:
    """pandas writes integer columns with gaps as 3.0; columns may come in any order and may be left out."""
    p = _csv(tmp_path, "robot,type,v,w,t0,t", "3.0,odometry,0.5,0.1,0.0,1.0", "3,odometry,0.5,0.1,1.0,2.0")
    ef = load_events(p)
    assert [e.robot for e in ef.events] == [3, 3] and ef.robots == [3]


def test_duplicate_landmark_and_initial(tmp_path: Path) -> None:
    lm = "landmark,,,,,,7,landmark,,1 2,0.1 0.1,"
    ini = "initial,0.0,1,,,,,,,0 0 0,0.1 0.1 0.1,"
    ef = load_events(_csv(tmp_path, HEADER, lm, lm, ini, ini, ODO))  # identical repeats are fine
    assert ef.landmarks == {7: (1.0, 2.0, 0.1, 0.1)} and set(ef.initial) == {1}
    p = _csv(tmp_path, HEADER, lm, ini, ODO, lm.replace("1 2", "1 2.5"), ini.replace("0.0,1", "0.5,1"), name="dup.csv")
    with pytest.raises(EventFileError) as ei:
        load_events(p)
    msg = str(ei.value)
    assert "dup.csv line 5: landmark 7 already defined on line 2 with different values" in msg
    assert "dup.csv line 6: initial belief of robot 1 already given on line 3 with different values" in msg


def test_strict_lists_every_bad_line(tmp_path: Path) -> None:
    p = _csv(
        tmp_path,
        HEADER,
        ODO,
        "odometry,1.0,1,0.0,x,0.1,,,,,,",
        "# a comment between",
        "",
        "detection,1.0,1,,,,2,robot,range,-1,0.1,",
        "odometry,2.0,1,1.0,0.5,0.1,,,,,,",
        "landmark,,,,,,7,landmark,,1,0.1 0.1,",
    )
    with pytest.raises(EventFileError) as ei:
        load_events(p)
    msg = str(ei.value)
    assert msg.startswith("events.csv: 3 bad lines")
    for n in (3, 6, 8):
        assert f"events.csv line {n}: " in msg
    assert len(ei.value.problems) == 3
    ef = load_events(p, strict=False)
    assert [x.split(":")[0] for x in ef.problems] == ["events.csv line 3", "events.csv line 6", "events.csv line 8"]
    assert len(ef.events) == 2 and all(isinstance(e, Odometry) for e in ef.events)
    assert ef.landmarks == {}


def test_many_bad_lines_first_20_in_full_then_the_rest_by_number(tmp_path: Path) -> None:
    bad = ["odometry,1.0,1,0.0,x,0.1,,,,,,"] * 25
    p = _csv(tmp_path, HEADER, ODO, *bad)
    with pytest.raises(EventFileError) as ei:
        load_events(p)
    msg = str(ei.value)
    assert "25 bad lines" in msg
    assert msg.count("'v' must be a number") == 20
    assert "... and 5 more (lines 23, 24, 25, 26, 27)" in msg
    assert len(ei.value.problems) == 21 and ei.value.n_bad == 25  # 20 messages, then one line for the others
    assert ei.value.problems[-1] == "... and 5 more (lines 23, 24, 25, 26, 27)"


def test_sort_order_and_ties(tmp_path: Path) -> None:
    lines = [
        HEADER,
        "odometry,2.0,2,1.0,0.1,0,,,,,,",  # A: odometry stamped 1.0 (t0), robot 2
        "detection,1.0,1,,,,2,robot,range,1.0,0.1,",  # B: detection at 1.0, robot 1
        "odometry,1.5,1,1.0,0.1,0,,,,,,",  # C: odometry stamped 1.0, robot 1
        "detection,1.0,0,,,,2,robot,range,2.0,0.1,",  # D: detection at 1.0, robot 0
        "odometry,2.0,3,0.5,0.1,0,,,,,,",  # E: odometry stamped 0.5 (ends after the others start)
        "detection,0.7,1,,,,2,robot,range,3.0,0.1,",  # F: detection at 0.7
        "detection,1.0,1,,,,2,robot,range,4.0,0.1,",  # G: same stamp, kind and robot as B: file order
    ]
    ef = load_events(_csv(tmp_path, *lines))
    tags = []
    for e in ef.events:
        if isinstance(e, Odometry):
            tags.append({(2, 1.0): "A", (1, 1.0): "C", (3, 0.5): "E"}[(e.robot, e.t0)])
        else:
            tags.append({1.0: "B", 2.0: "D", 3.0: "F", 4.0: "G"}[float(e.z[0])])
    assert tags == ["E", "F", "D", "B", "G", "C", "A"]


def test_defaults_apply_when_no_noise_is_given(tmp_path: Path) -> None:
    p = _csv(
        tmp_path,
        HEADER,
        ODO,
        "detection,0.5,1,,,,2,robot,range_bearing,1 0.1,,",
        "detection,0.6,1,,,,2,robot,pose,1 0 0.1,,",
        "detection,0.7,1,,,,,,absolute,1 0 0.1,,",
        "detection,0.8,1,,,,3,landmark,range,2,0.5,",  # its own std wins over the default
        "initial,,1,,,,,,,0 0 0,,",
        "landmark,,,,,,3,,,5 5,,",
    )
    defaults = {**DEFAULTS.event_defaults(), "landmark": [0.2, 0.3], "absolute": np.diag([1.0, 2.0, 3.0])}
    ef = load_events(p, defaults=defaults)
    rb, pose, ab, rng = (e for e in ef.events if isinstance(e, Detection))
    np.testing.assert_array_equal(rb.cov, np.diag([DEFAULTS.sensors.range_std**2, DEFAULTS.sensors.bearing_std**2]))
    np.testing.assert_array_equal(pose.cov, np.diag([0.05**2, 0.05**2, 0.0175**2]))
    np.testing.assert_array_equal(ab.cov, np.diag([1.0, 2.0, 3.0]))
    assert ab.target is None
    np.testing.assert_array_equal(rng.cov, [[0.25]])
    np.testing.assert_array_equal(ef.initial[1][1], np.diag([0.01**2] * 3))
    assert ef.initial_times == {}
    assert ef.landmarks == {3: (5.0, 5.0, 0.2, 0.3)}
    # a default for another kind does not apply
    with pytest.raises(EventFileError, match=r"events.csv line 3: a range_bearing detection has neither"):
        load_events(p, defaults={"range": [0.1]})


@pytest.mark.parametrize(
    ("defaults", "match"),
    [
        ({"rang": [0.1]}, "unknown key 'rang'"),
        ({"range": [0.1, 0.2]}, r"defaults\['range'\] must be a std vector of 1"),
        ({"range": [-0.1]}, "finite and positive"),
        ({"landmark": np.eye(2)}, r"defaults\['landmark'\] must be a std vector of 2"),
        ({"pose": np.ones((3, 3))}, "not positive definite"),
    ],
)
def test_bad_defaults_are_a_programming_error(tmp_path: Path, defaults: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        load_events(_csv(tmp_path, HEADER, ODO), defaults=defaults)


def test_file_level_errors(tmp_path: Path) -> None:
    with pytest.raises(EventFileError, match=r"^event file not found: .*absent\.csv$"):
        load_events(tmp_path / "absent.csv")
    with pytest.raises(EventFileError, match=r"ev\.txt: unknown event file extension '\.txt'; use \.csv or \.jsonl"):
        load_events(_csv(tmp_path, HEADER, ODO, name="ev.txt"))
    with pytest.raises(EventFileError, match="empty.csv: empty file: expected a header row"):
        load_events(_csv(tmp_path, "# only a comment", "", name="empty.csv"))
    with pytest.raises(EventFileError) as ei:
        load_events(_csv(tmp_path, "# c", HEADER + ",speed,colour", ODO + ",1,red", name="hdr.csv"))
    assert "hdr.csv line 2: bad header row: unknown column(s) 'speed', 'colour'" in str(ei.value)
    with pytest.raises(EventFileError, match="no 'type' column"):
        load_events(_csv(tmp_path, "t,robot,t0,v,w", "1,1,0,0,0", name="notype.csv"))
    with pytest.raises(EventFileError, match="repeated column"):
        load_events(_csv(tmp_path, "type,t,t", "odometry,1,1", name="rep.csv"))
    lm = "landmark,,,,,,7,landmark,,1 2,0.1 0.1,"
    with pytest.raises(EventFileError, match="noodo.csv: no odometry records"):
        load_events(_csv(tmp_path, HEADER, lm, name="noodo.csv"))
    with pytest.raises(EventFileError, match=r"no odometry records \(1 bad lines skipped\)"):
        load_events(_csv(tmp_path, HEADER, "odometry,1.0,1,0.0,x,0.1,,,,,,", name="allbad.csv"), strict=False)
    p = tmp_path / "latin1.csv"
    p.write_bytes((HEADER + "\n# caf\xe9\n").encode("latin-1"))
    with pytest.raises(EventFileError, match="latin1.csv: not UTF-8"):
        load_events(p)


def test_robots_are_every_id_named(tmp_path: Path) -> None:
    p = _csv(
        tmp_path,
        HEADER,
        "odometry,1.0,4,0.0,0.5,0.1,,,,,,",
        "detection,1.0,1,,,,2,robot,range,1,0.1,",
        "detection,1.0,1,,,,9,landmark,range,1,0.1,",  # landmark 9 is not a robot
        "initial,,6,,,,,,,0 0 0,0.1 0.1 0.1,",
    )
    assert load_events(p).robots == [1, 2, 4, 6]


def test_write_events_rejects_truth_and_bad_extension(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="only Odometry and Detection"):
        write_events(tmp_path / "a.csv", [Truth(1, 0.0, np.zeros(3))])
    with pytest.raises(EventFileError, match="unknown event file extension"):
        write_events(tmp_path / "a.json", [Odometry(1, 0.0, 1.0, 0.0, 0.0)])


def test_load_truth_dir(tmp_path: Path) -> None:
    xyt = np.array([[0.0, 1.0, 0.5], [0.1, 1.1, 0.6]])
    write_tum(tmp_path / "truth_robot1.tum", np.array([0.0, 1.0]), xyt)
    write_tum(tmp_path / "truth_robot3.tum", np.array([5.0, 6.0]), -xyt)
    out = load_truth_dir(tmp_path, [1, 2, 3])
    assert sorted(out) == [1, 3]
    np.testing.assert_allclose(out[1][1], xyt, atol=1e-9)
    np.testing.assert_array_equal(out[3][0], [5.0, 6.0])
    assert load_truth_dir(tmp_path, [2]) == {}
    with pytest.raises(EventFileError, match="truth folder not found"):
        load_truth_dir(tmp_path / "nope", [1])
    (tmp_path / "truth_robot2.tum").write_text("0 0 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n")
    with pytest.raises(TUMError, match="truth_robot2.tum line 2: times must be strictly increasing"):
        load_truth_dir(tmp_path, [2])


def test_a_team_given_refuses_detections_by_or_of_other_robots(tmp_path: Path) -> None:
    """``team=[ids]``: a detection by or of another robot is a bad line with its number; ``team="odometry"``: the
    robots with odometry; None (the reader's default): any robot."""
    p = _csv(tmp_path, HEADER, ODO, "detection,0.5,1,,,,2,robot,range,1.5,0.1,",
             "detection,0.6,3,,,,1,robot,range,1.5,0.1,")  # fmt: skip
    assert len(load_events(p).events) == 3
    with pytest.raises(EventFileError) as exc:
        load_events(p, team="odometry")
    assert exc.value.problems == [
        "events.csv line 3: a detection of robot 2, which is not in the team (robots [1]: the robots with odometry "
        "in the file)",
        "events.csv line 4: a detection by robot 3, which is not in the team (robots [1]: the robots with odometry "
        "in the file)",
    ]
    ef = load_events(p, team=[1, 2], strict=False)
    assert ef.n_bad == 1 and "line 4: a detection by robot 3" in ef.problems[0] and len(ef.events) == 2
    with pytest.raises(ValueError, match="team must be robot ids or 'odometry'"):
        load_events(p, team="all")
