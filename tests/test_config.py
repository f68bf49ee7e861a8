"""TOML configuration: defaults, exact round trip through to_toml, partial files, every kind of error."""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

import swarmloc.config as config_module
from swarmloc.config import (
    DEFAULTS,
    Config,
    ConfigError,
    FilterConfig,
    InitialConfig,
    MotionConfig,
    RecordConfig,
    SensorConfig,
    config_markdown,
    load_config,
)
from swarmloc.motion import UnicycleNoise

pytestmark = pytest.mark.unit


def _write(tmp_path: Path, text: str, name: str = "swarm.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_defaults_are_the_mrclam_evaluation_defaults() -> None:
    """The MRCLAM evaluation's numbers (motion noise, camera std, initial std, gate, rate)."""
    assert DEFAULTS == Config()
    mrclam_noise = UnicycleNoise(q_v0=1e-4, q_v2=0.05, q_lat0=1e-4, q_lat1=0.01, q_w0=1e-3, q_w2=0.05, q_wv=0.02)
    assert DEFAULTS.motion.noise() == mrclam_noise
    # a-priori camera std, and the correlated-error model of swarmloc.sensors.decorrelate (no fitted constant)
    assert (DEFAULTS.sensors.range_std, DEFAULTS.sensors.bearing_std) == (0.1, 0.035)
    assert DEFAULTS.sensors.decorrelate == "calibrate"
    assert (DEFAULTS.initial.std_xy, DEFAULTS.initial.std_theta) == (0.01, 0.01)
    assert DEFAULTS.filter.gate == 0.997
    assert DEFAULTS.record.rate == 4.0
    assert DEFAULTS.filter.horizon == 5.0
    assert (DEFAULTS.filter.order, DEFAULTS.filter.iterations, DEFAULTS.filter.point_iterations) == (2, 2, 3)
    s = DEFAULTS.sensors
    assert (s.pose_xy_std, s.pose_theta_std, s.absolute_xy_std, s.absolute_theta_std) == (0.05, 0.0175, 0.01, 0.01)


def test_defaults_round_trip_through_to_toml(tmp_path: Path) -> None:
    text = DEFAULTS.to_toml()
    assert Config.from_dict(tomllib.loads(text)) == DEFAULTS
    assert load_config(_write(tmp_path, text)) == DEFAULTS
    # every key is written, with a comment
    for sec, body in DEFAULTS.to_dict().items():
        assert f"[{sec}]" in text
        for key in body:
            assert re.search(rf"^{key} = \S+  # ", text, re.M), key
    assert "\norder = 2  # order of the SE(2) convolution; 1 or 2 (an integer)\n" in text
    assert "\nrate = 4.0  # [Hz] rate at which beliefs are recorded" in text


def test_non_default_config_round_trips_exactly(tmp_path: Path) -> None:
    c = Config(
        motion=MotionConfig(q_v0=1 / 3, q_v1=1e-7, q_v2=0.0, q_lat0=2.5e-5, q_lat1=0.1 + 0.2, q_wv=1e-300),
        sensors=SensorConfig(range_std=0.123456789012345, bearing_std=math.pi / 180),
        filter=FilterConfig(
            gate=None,
            horizon=0.25,
            order=1,
            iterations=5,
            point_iterations=1,
            delayed_output=True,
            association="joint",
            quarantine=None,
        ),
        record=RecordConfig(rate=10),
        initial=InitialConfig(std_xy=2.0, std_theta=math.pi),
    )
    text = c.to_toml()
    assert "gate = false" in text and "delayed_output = true" in text and "quarantine = false" in text
    assert load_config(_write(tmp_path, text)) == c
    back = Config.from_dict(tomllib.loads(text))
    assert back.motion.q_lat1 == 0.1 + 0.2 and back.motion.q_wv == 1e-300
    assert isinstance(back.record.rate, float) and back.record.rate == 10.0


def test_module_docstring_example_is_a_valid_file() -> None:
    doc = config_module.__doc__
    assert doc is not None
    block = doc.split("::", 1)[1].split("Each key", 1)[0]
    c = Config.from_dict(tomllib.loads(block))
    assert (c.filter.gate, c.filter.horizon, c.record.rate) == (0.99, 3.0, 10.0)


def _table(markdown: str, section: str) -> dict[str, list[str]]:
    """``{key: cells}`` of a section's table in :func:`config_markdown`'s page (``\\|`` kept escaped)."""
    body = markdown.split(f"### `[{section}]`", 1)[1].split("###", 1)[0]
    rows = [re.split(r"(?<!\\) \| ", line.strip("| ")) for line in body.strip().splitlines()[2:]]
    return {cells[0].strip("`"): cells for cells in rows}


def test_docs_table_lists_every_key_with_its_default_range_and_unit() -> None:
    md = config_markdown()
    for sec, body in DEFAULTS.to_dict().items():
        table = _table(md, sec)
        assert list(table) == list(body), sec
        for key, value in body.items():
            _, _, default, _, meaning = table[key]
            assert tomllib.loads(f"x = {default.strip('`')}")["x"] == value, (sec, key)
            assert meaning, (sec, key)
    f = _table(md, "filter")
    assert f["gate"][1] == "a probability in (0, 1), or false (or 0) to turn it off"
    assert f["order"][1] == "1 or 2 (an integer)" and f["clock_jump_inputs"][1] == "an integer in [1, 100]"
    assert f["association"][1] == 'one of "tags", "nearest", "joint", "anonymous"'
    assert _table(md, "record")["rate"][1:4] == ["a number in (0, 1000]", "`4.0`", "Hz"]
    q_v0 = _table(md, "motion")["q_v0"]
    assert q_v0[1:4] == ["a finite number >= 0", "`0.0001`", "m^2/s"] and "q_v1 abs(v)" in q_v0[4]


def test_partial_file_overrides_only_what_it_sets(tmp_path: Path) -> None:
    c = load_config(_write(tmp_path, "[filter]\ngate = 0.99\n\n[sensors]\nrange_std = 0.2\n[record]\nrate = 10\n"))
    assert c.filter.gate == 0.99
    assert c.sensors.range_std == 0.2
    assert c.record.rate == 10.0
    assert c.filter.horizon == DEFAULTS.filter.horizon
    assert c.sensors.bearing_std == DEFAULTS.sensors.bearing_std
    assert c.motion == DEFAULTS.motion and c.initial == DEFAULTS.initial
    assert load_config(_write(tmp_path, "# nothing\n", "empty.toml")) == DEFAULTS


@pytest.mark.parametrize(("literal", "gate"), [("false", None), ("0", None), ("0.0", None), ("0.5", 0.5)])
def test_gate_values(tmp_path: Path, literal: str, gate: float | None) -> None:
    assert load_config(_write(tmp_path, f"[filter]\ngate = {literal}\n")).filter.gate == gate


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[filtr]\ngate = 0.9\n", ["unknown section [filtr]", "did you mean 'filter'"]),
        ("gate = 0.9\n", ["unknown top-level key 'gate'"]),
        ("filter = 3\n", ["'filter' must be a section [filter]"]),
        ("[filter]\ngaet = 0.9\n", ["[filter] unknown key 'gaet'", "did you mean 'gate'", "known keys: gate"]),
        ("[sensors]\nrange_std = true\n", ["[sensors] range_std", "a finite number > 0", "boolean"]),
        ("[sensors]\nrange_std = '0.3'\n", ["[sensors] range_std", "a string"]),
        ("[sensors]\nbearing_std = -0.1\n", ["[sensors] bearing_std", "a finite number > 0", "-0.1"]),
        ("[sensors]\npose_xy_std = 0\n", ["[sensors] pose_xy_std", "> 0"]),
        ("[sensors]\ndecorrelate = 'yes'\n", ["[sensors] decorrelate", '"calibrate", "weights", "off"', "'yes'"]),
        ("[sensors]\ndecorrelate = true\n", ["[sensors] decorrelate", "boolean"]),
        ("[sensors]\nrange_std = nan\n", ["[sensors] range_std", "finite"]),
        ("[initial]\nstd_theta = inf\n", ["[initial] std_theta", "finite"]),
        ("[motion]\nq_w2 = -1e-3\n", ["[motion] q_w2", ">= 0"]),
        ("[motion]\nq_v0 = [1, 2]\n", ["[motion] q_v0", "a list"]),
        ("[filter]\ngate = 1.0\n", ["[filter] gate", "probability in (0, 1)"]),
        ("[filter]\ngate = 1.5\n", ["[filter] gate", "probability in (0, 1)"]),
        ("[filter]\ngate = -0.2\n", ["[filter] gate", "probability in (0, 1)"]),
        ("[filter]\ngate = true\n", ["[filter] gate", "boolean"]),
        ("[filter]\nhorizon = 0\n", ["[filter] horizon", "> 0"]),
        ("[filter]\nsmoother_lag = 0\n", ["[filter] smoother_lag", "> 0"]),
        ("[filter]\nsmoother_lag = inf\n", ["[filter] smoother_lag", "finite"]),
        ("[filter]\ndelayed_output = 1\n", ["[filter] delayed_output", "true or false", "got 1"]),
        ("[filter]\ndelayed_output = 'yes'\n", ["[filter] delayed_output", "true or false", "'yes'"]),
        ("[filter]\nhorizon = -5.0\n", ["[filter] horizon", "> 0"]),
        ("[filter]\norder = 3\n", ["[filter] order", "1 or 2", "got 3"]),
        ("[filter]\norder = 2.0\n", ["[filter] order", "1 or 2"]),
        ("[filter]\niterations = 0\n", ["[filter] iterations", "integer >= 1"]),
        ("[filter]\npoint_iterations = false\n", ["[filter] point_iterations", "boolean"]),
        ("[record]\nrate = 0.0\n", ["[record] rate", "(0, 1000]"]),
        ("[filter]\nquarantine = true\n", ["[filter] quarantine", "an integer >= 1, or false (or 0)", "boolean"]),
        ("[filter]\nquarantine = 0.5\n", ["[filter] quarantine", "an integer >= 1", "got 0.5"]),
        ("[filter]\nclock_jump_inputs = 101\n", ["[filter] clock_jump_inputs", "an integer in [1, 100]", "101"]),
        ("[filter]\nassociation = 'psychic'\n", ["[filter] association", '"tags", "nearest"', "'psychic'"]),
    ],
)
def test_errors_name_file_section_key(tmp_path: Path, text: str, expected: list[str]) -> None:
    p = _write(tmp_path, text, "bad.toml")
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    msg = str(ei.value)
    assert msg.startswith(str(p) + ": ")
    assert "\n" not in msg
    for part in expected:
        assert part in msg


def test_syntax_error_names_line_and_column(tmp_path: Path) -> None:
    p = _write(tmp_path, "[filter]\ngate = 0.9\nhorizon 5\n", "syntax.toml")
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    msg = str(ei.value)
    assert msg.startswith(f"{p} line 3, column ")
    assert "TOML syntax error" in msg


def test_missing_and_undecodable_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="config file not found: .*absent.toml"):
        load_config(tmp_path / "absent.toml")
    p = tmp_path / "latin1.toml"
    p.write_bytes(b"# caf\xe9\n[filter]\n")
    with pytest.raises(ConfigError, match="latin1.toml"):
        load_config(p)


def test_direct_construction_is_validated() -> None:
    with pytest.raises(ConfigError, match=r"\[filter\] gate"):
        FilterConfig(gate=2.0)
    with pytest.raises(ConfigError, match=r"\[motion\] q_v0"):
        MotionConfig(q_v0=-1.0)
    with pytest.raises(ConfigError, match="source.toml: "):
        Config.from_dict({"record": {"rate": -1}}, source="source.toml")
    assert FilterConfig(gate=0).gate is None and FilterConfig(quarantine=0).quarantine is None
    # numpy scalars (a fitted model's numbers) are taken as Python's, as a TOML integer is where a float is declared
    m = MotionConfig(q_v0=np.float64(0.5), q_v1=2)
    assert type(m.q_v0) is float and m.q_v0 == 0.5 and type(m.q_v1) is float
    assert type(FilterConfig(diekf_cluster=np.int64(2)).diekf_cluster) is int
    with pytest.raises(ConfigError, match=r"\[filter\] order: expected 1 or 2"):
        dataclasses.replace(DEFAULTS.filter, order=3)


def test_motion_noise_and_event_defaults() -> None:
    noise = UnicycleNoise(q_v0=1e-3, q_v1=0.1, q_v2=0.2, q_lat0=0.3, q_lat1=0.4, q_w0=0.5, q_w1=0.6, q_w2=0.7, q_wv=0.8)
    m = MotionConfig.from_noise(noise)
    assert m.noise() == noise
    d = DEFAULTS.event_defaults()
    assert set(d) == {"pose", "range_bearing", "range", "bearing", "absolute", "initial"}
    np.testing.assert_array_equal(d["range_bearing"], [0.1, 0.035])
    np.testing.assert_array_equal(d["pose"], [0.05, 0.05, 0.0175])
    np.testing.assert_array_equal(d["absolute"], [0.01, 0.01, 0.01])
    np.testing.assert_array_equal(d["initial"], [0.01, 0.01, 0.01])
    np.testing.assert_allclose(DEFAULTS.initial.cov(), np.diag([1e-4, 1e-4, 1e-4]))


def test_replace() -> None:
    c = DEFAULTS.replace(record=RecordConfig(rate=1.0))
    assert c.record.rate == 1.0 and c.filter == DEFAULTS.filter and DEFAULTS.record.rate == 4.0
    with pytest.raises(ConfigError, match="unknown section"):
        DEFAULTS.replace(recrd=RecordConfig())
    with pytest.raises(ConfigError, match="must be a RecordConfig"):
        DEFAULTS.replace(record=FilterConfig())
