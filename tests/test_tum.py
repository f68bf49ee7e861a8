"""TUM trajectory files: exact round trip, planar yaw from quaternions, every bad line reported."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from swarmloc.datasets.tum import TUMError, read_tum, write_tum

pytestmark = pytest.mark.unit


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * a))


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


GOOD = "1.0 0 0 0 0 0 0 1\n"


def test_round_trip_to_1e9_including_yaw_near_pi(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    n = 2000
    theta = rng.uniform(-math.pi, math.pi, n)
    theta[:8] = [math.pi, -math.pi, math.pi - 1e-9, -math.pi + 1e-9, math.pi - 1e-4, -math.pi + 1e-4, 0.0, -0.0]
    xy = rng.uniform(-500.0, 500.0, (n, 2))
    times = 1.248e9 + np.cumsum(rng.uniform(1e-3, 0.5, n))
    xyt = np.column_stack([xy, theta])
    p = write_tum(tmp_path / "traj.tum", times, xyt)
    t2, xyt2 = read_tum(p)
    assert t2.shape == (n,) and xyt2.shape == (n, 3)
    assert np.abs(t2 - times).max() <= 1e-9
    assert np.abs(xyt2[:, :2] - xy).max() <= 1e-9
    assert np.abs(_wrap(xyt2[:, 2] - theta)).max() <= 1e-9
    # yaw is returned in (-pi, pi]: -pi comes back as +pi
    assert np.all(xyt2[:, 2] > -math.pi) and np.all(xyt2[:, 2] <= math.pi)
    assert xyt2[1, 2] == pytest.approx(math.pi, abs=1e-9)


def test_written_file_is_evo_style(tmp_path: Path) -> None:
    p = write_tum(tmp_path / "a.tum", np.array([0.5, 1.5]), np.array([[1.0, 2.0, 0.0], [3.0, 4.0, math.pi / 2]]))
    lines = p.read_text().splitlines()
    assert lines[0] == "# timestamp tx ty tz qx qy qz qw"
    cols = lines[2].split()
    assert len(cols) == 8
    assert float(cols[3]) == 0.0 and float(cols[4]) == 0.0 and float(cols[5]) == 0.0  # z, qx, qy
    assert float(cols[6]) == pytest.approx(math.sin(math.pi / 4), abs=1e-12)
    assert float(cols[7]) == pytest.approx(math.cos(math.pi / 4), abs=1e-12)
    assert cols[1] == "3.000000000"  # %.9f


def test_yaw_from_general_quaternion_and_comments(tmp_path: Path) -> None:
    yaw = -2.5
    qz, qw = math.sin(yaw / 2), math.cos(yaw / 2)
    text = (
        "# produced elsewhere\n\n"
        f"10.0 1.5 -2.5 0.0 0.0 0.0 {qz} {qw}\n"
        "   # indented comment\n"
        f"11.0 1.5 -2.5 0.0 0.0 0.0 {1.0005 * qz} {1.0005 * qw}\n"  # not quite unit: normalized
    )
    t, xyt = read_tum(_write(tmp_path / "g.tum", text))
    np.testing.assert_array_equal(t, [10.0, 11.0])
    np.testing.assert_allclose(xyt[:, :2], [[1.5, -2.5], [1.5, -2.5]])
    np.testing.assert_allclose(xyt[:, 2], [yaw, yaw], atol=1e-12)


@pytest.mark.parametrize(
    ("line", "problem"),
    [
        ("2.0 0 0 0.1 0 0 0 1", "not planar"),  # z
        ("2.0 0 0 0 0.01 0 0 0.99995", "not planar"),  # roll
        ("2.0 0 0 0 0 0.01 0 0.99995", "not planar"),  # pitch
        ("2.0 0 0 0 1 0 0 0", "not planar"),  # upside down
        ("2.0 0 0 0 0 0 0 2", "unit norm"),
        ("2.0 0 0 0 0 0 0 0", "unit norm"),
        ("2.0 0 0 0 0 0 1", "expected 8 numbers"),
        ("2.0 0 0 0 0 0 0 1 5", "expected 8 numbers"),
        ("2.0 0 zero 0 0 0 0 1", "non-numeric"),
        ("2.0 nan 0 0 0 0 0 1", "finite"),
        ("1.0 0 0 0 0 0 0 1", "strictly increasing"),  # equal time
        ("0.5 0 0 0 0 0 0 1", "strictly increasing"),  # earlier time
    ],
)
def test_bad_line_names_file_line_and_problem(tmp_path: Path, line: str, problem: str) -> None:
    p = _write(tmp_path / "bad.tum", "# header\n" + GOOD + line + "\n")
    with pytest.raises(TUMError) as ei:
        read_tum(p)
    msg = str(ei.value)
    assert "bad.tum line 3:" in msg
    assert problem in msg
    assert line.split()[1] in msg  # the line's content is quoted


def test_every_bad_line_is_listed(tmp_path: Path) -> None:
    text = GOOD + "2.0 0 0 0.5 0 0 0 1\n" + "3.0 0 0 0 0 0 0 1\n" + "x\n" + "3.0 0 0 0 0 0 0 1\n"
    with pytest.raises(TUMError) as ei:
        read_tum(_write(tmp_path / "many.tum", text))
    msg = str(ei.value)
    assert "3 bad lines" in msg
    for n in (2, 4, 5):
        assert f"many.tum line {n}:" in msg
    assert "many.tum line 3:" not in msg


def test_missing_and_empty_files(tmp_path: Path) -> None:
    with pytest.raises(TUMError, match="TUM file not found: .*nope.tum"):
        read_tum(tmp_path / "nope.tum")
    with pytest.raises(TUMError, match="empty.tum: no poses"):
        read_tum(_write(tmp_path / "empty.tum", "# timestamp tx ty tz qx qy qz qw\n\n"))


def test_write_tum_rejects_what_read_tum_would_reject(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="strictly increasing"):
        write_tum(tmp_path / "a.tum", np.array([0.0, 0.0]), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"shape \(2, 3\)"):
        write_tum(tmp_path / "a.tum", np.array([0.0, 1.0]), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="finite"):
        write_tum(tmp_path / "a.tum", np.array([0.0, 1.0]), np.array([[0, 0, 0], [np.nan, 0, 0]]))
    assert not (tmp_path / "a.tum").exists()
