"""The rule by which the tests find the MRCLAM dataset (tests/_data.py, the fixtures in conftest.py): expected
(SWARMLOC_MRCLAM set, or ../shared/data/mrclam beside the clone) but broken fails; not expected skips."""

from __future__ import annotations

from pathlib import Path

import pytest
from _data import (
    MRCLAM_ENV,
    REPO_ROOT,
    MrclamBroken,
    MrclamNotExpected,
    locate_mrclam,
    mrclam_dataset,
    mrclam_dataset_or_fail,
    mrclam_root_or_none,
    mrclam_root_or_skip,
    shared_mrclam,
)

pytestmark = pytest.mark.unit


def _dataset(root: Path, number: int = 6) -> Path:
    folder = root / f"MRCLAM_Dataset{number}"
    folder.mkdir(parents=True)
    (folder / "Barcodes.dat").write_text("# subject barcode\n1 5\n")
    return folder


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    """A clone at tmp_path/clone with nothing beside it."""
    (tmp_path / "clone").mkdir()
    return tmp_path / "clone"


def test_the_shared_copy_is_beside_the_clone() -> None:
    assert shared_mrclam(Path("/work/project")) == Path("/work/shared/data/mrclam")
    assert REPO_ROOT == Path(__file__).resolve().parents[1] and (REPO_ROOT / "tests" / "conftest.py").is_file()


def test_neither_env_nor_shared_copy_skips(repo: Path) -> None:
    with pytest.raises(MrclamNotExpected, match=rf"{MRCLAM_ENV} is not set and .*shared/data/mrclam does not exist"):
        locate_mrclam({}, repo)
    with pytest.raises(MrclamNotExpected):
        locate_mrclam({MRCLAM_ENV: ""}, repo)  # set but empty: as if unset
    assert mrclam_root_or_none({}, repo) is None
    with pytest.raises(pytest.skip.Exception, match="does not exist"):
        mrclam_root_or_skip({}, repo)


def test_shared_copy_beside_the_clone_is_used(repo: Path) -> None:
    shared = shared_mrclam(repo)
    _dataset(shared)
    assert locate_mrclam({}, repo) == shared
    assert mrclam_root_or_skip({}, repo) == shared == mrclam_root_or_none({}, repo)


@pytest.mark.parametrize("broken", ["empty", "file", "no dataset folder"])
def test_shared_copy_present_but_broken_fails(repo: Path, broken: str) -> None:
    shared = shared_mrclam(repo)
    shared.parent.mkdir(parents=True)
    if broken == "file":
        shared.write_text("not a folder")
    else:
        shared.mkdir()
        if broken == "no dataset folder":
            (shared / "README.md").write_text("# UTIAS MRCLAM data\n")
    with pytest.raises(MrclamBroken, match="beside the clone"):
        locate_mrclam({}, repo)
    for located in (mrclam_root_or_skip, mrclam_root_or_none):
        with pytest.raises(pytest.fail.Exception, match=str(shared)):
            located({}, repo)


def test_env_set_but_missing_fails_even_with_a_shared_copy(repo: Path, tmp_path: Path) -> None:
    _dataset(shared_mrclam(repo))
    env = {MRCLAM_ENV: str(tmp_path / "moved")}
    with pytest.raises(MrclamBroken, match=f"{MRCLAM_ENV}=.*moved.*not a directory"):
        locate_mrclam(env, repo)
    with pytest.raises(pytest.fail.Exception):
        mrclam_root_or_skip(env, repo)


def test_env_wins_over_the_shared_copy(repo: Path, tmp_path: Path) -> None:
    _dataset(shared_mrclam(repo))
    mine = tmp_path / "my-mrclam"
    _dataset(mine, 1)
    assert locate_mrclam({MRCLAM_ENV: str(mine)}, repo) == mine


def test_a_dataset_asked_for_must_be_there_and_readable(tmp_path: Path) -> None:
    folder = _dataset(tmp_path, 6)
    assert mrclam_dataset(tmp_path, 6) == folder == mrclam_dataset_or_fail(tmp_path, 6)
    with pytest.raises(MrclamBroken, match="MRCLAM dataset 7 missing"):
        mrclam_dataset(tmp_path, 7)
    with pytest.raises(pytest.fail.Exception, match="MRCLAM dataset 7 missing"):
        mrclam_dataset_or_fail(tmp_path, 7)
    (tmp_path / "MRCLAM_Dataset2").mkdir()  # no Barcodes.dat: not a dataset
    with pytest.raises(MrclamBroken, match="MRCLAM dataset 2 at .* cannot be read"):
        mrclam_dataset(tmp_path, 2)
