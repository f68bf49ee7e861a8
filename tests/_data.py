"""Where the tests find the UTIAS MRCLAM dataset: one rule, used by the fixtures in conftest.py.

The dataset is *expected* when the environment variable SWARMLOC_MRCLAM is set (non-empty) or when the folder
``shared/data/mrclam`` lies beside the clone (``<repo>/../shared/data/mrclam``). Expected but missing, unreadable,
without any ``MRCLAM_Dataset*`` folder, or without a dataset a test asks for: the test fails, so a broken or moved
copy cannot pass as "skipped". Not expected: the tests that need it skip, saying where they looked.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import pytest

MRCLAM_ENV = "SWARMLOC_MRCLAM"
REPO_ROOT = Path(__file__).resolve().parents[1]
MRCLAM_DATASETS = (1, 2, 3, 4, 5, 6, 8, 9)
"""The datasets of the shared copy (its README.md): the tests that go through every dataset ask for these."""


class MrclamNotExpected(Exception):
    """Neither SWARMLOC_MRCLAM nor ``../shared/data/mrclam``: the tests that need the data skip."""


class MrclamBroken(Exception):
    """The data is expected but not usable: the tests that need it fail."""


def shared_mrclam(repo_root: Path) -> Path:
    """``<repo>/../shared/data/mrclam``: the shared copy beside the clone."""
    return repo_root.parent / "shared" / "data" / "mrclam"


def locate_mrclam(env: Mapping[str, str], repo_root: Path) -> Path:
    """The MRCLAM root (the folder holding ``MRCLAM_Dataset<N>``) by the rule of the module docstring.

    Raises :class:`MrclamNotExpected` (skip) or :class:`MrclamBroken` (fail).
    """
    value = env.get(MRCLAM_ENV, "")
    if value:
        root, why = Path(value).expanduser(), f"{MRCLAM_ENV}={value}"
    else:
        root = shared_mrclam(repo_root)
        if not os.path.lexists(root):
            raise MrclamNotExpected(f"MRCLAM data not found: {MRCLAM_ENV} is not set and {root} does not exist")
        why = "the shared copy beside the clone"
    if not root.is_dir():
        raise MrclamBroken(f"MRCLAM data expected at {root} ({why}), but that is not a directory")
    try:
        folders = [p for p in root.iterdir() if p.name.startswith("MRCLAM_Dataset") and p.is_dir()]
    except OSError as exc:
        raise MrclamBroken(f"MRCLAM data expected at {root} ({why}), but it cannot be read: {exc}") from exc
    if not folders:
        raise MrclamBroken(f"MRCLAM data expected at {root} ({why}), but it holds no MRCLAM_Dataset* folder")
    return root


def mrclam_dataset(root: Path, number: int) -> Path:
    """``root/MRCLAM_Dataset<number>``, a readable dataset folder (with its ``Barcodes.dat``), or MrclamBroken."""
    folder = root / f"MRCLAM_Dataset{number}"
    if not folder.is_dir():
        raise MrclamBroken(f"MRCLAM dataset {number} missing: {folder} is not a directory")
    try:
        with (folder / "Barcodes.dat").open("rb") as f:
            f.read(1)
    except OSError as exc:
        raise MrclamBroken(f"MRCLAM dataset {number} at {folder} cannot be read: {exc}") from exc
    return folder


def mrclam_root_or_none(env: Mapping[str, str], repo_root: Path) -> Path | None:
    """:func:`locate_mrclam` for a test: None when the data is not expected, ``pytest.fail`` when it is broken."""
    try:
        return locate_mrclam(env, repo_root)
    except MrclamNotExpected:
        return None
    except MrclamBroken as exc:
        pytest.fail(str(exc), pytrace=False)


def mrclam_root_or_skip(env: Mapping[str, str], repo_root: Path) -> Path:
    """:func:`locate_mrclam` for a test: ``pytest.skip`` when the data is not expected, ``pytest.fail`` when broken."""
    try:
        return locate_mrclam(env, repo_root)
    except MrclamNotExpected as exc:
        pytest.skip(str(exc))
    except MrclamBroken as exc:
        pytest.fail(str(exc), pytrace=False)


def mrclam_dataset_or_fail(root: Path, number: int) -> Path:
    """:func:`mrclam_dataset` for a test: ``pytest.fail`` when the dataset is missing or unreadable."""
    try:
        return mrclam_dataset(root, number)
    except MrclamBroken as exc:
        pytest.fail(str(exc), pytrace=False)
