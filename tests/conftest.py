"""Shared test configuration.

One BLAS thread: the tests run numpy/scipy on many tiny matrices (batched 3x3..12x12 expm/logm, slogdet, solve),
where OpenBLAS worker threads only spin. On the 2-core development machine under load this made
tests/test_lie.py alone take ~50 s instead of ~3 s. Must run before numpy is first imported; an explicit
setting in the environment wins.

Also: hypothesis' storage under pytest's temporary directory, and the fixtures through which every test finds the
MRCLAM dataset (mrclam_root, mrclam_dataset, mrclam6; the rule is in tests/_data.py).
"""

import functools
import os
from collections.abc import Callable
from pathlib import Path

import pytest  # does not import numpy
from _data import REPO_ROOT, mrclam_dataset_or_fail, mrclam_root_or_none, mrclam_root_or_skip

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


@pytest.hookimpl(trylast=True)  # after pytest's tmpdir plugin has made the factory behind tmp_path
def pytest_configure(config: pytest.Config) -> None:
    """Tests write only under pytest's temporary directory: hypothesis' storage (its example database and the
    constants it caches while collecting) goes there instead of .hypothesis/ in the working directory, unless
    HYPOTHESIS_STORAGE_DIRECTORY says otherwise."""
    factory = getattr(config, "_tmp_path_factory", None)  # what tmp_path and tmp_path_factory use
    if factory is None or os.environ.get("HYPOTHESIS_STORAGE_DIRECTORY"):
        return
    try:
        from hypothesis.configuration import set_hypothesis_home_dir
    except ImportError:  # pragma: no cover - hypothesis is a test dependency
        return
    set_hypothesis_home_dir(factory.mktemp("hypothesis"))


# ------------------------------------------------------------------------------------------------ MRCLAM data
# One rule for every test that reads the UTIAS MRCLAM dataset (tests/_data.py): SWARMLOC_MRCLAM, else
# <repo>/../shared/data/mrclam; expected but missing or unreadable fails, not expected skips.
@pytest.fixture(scope="session")
def mrclam_root() -> Path:
    """The MRCLAM root folder (holding MRCLAM_Dataset<N>)."""
    return mrclam_root_or_skip(os.environ, REPO_ROOT)


@pytest.fixture(scope="session")
def mrclam_root_if_expected() -> Path | None:
    """The MRCLAM root, or None when the data is not expected (for tests that also run without it)."""
    return mrclam_root_or_none(os.environ, REPO_ROOT)


@pytest.fixture(scope="session")
def mrclam_dataset(mrclam_root: Path) -> Callable[[int], Path]:
    """``mrclam_dataset(n)``: the folder of dataset ``n``; the test fails when it is missing or unreadable."""
    return functools.partial(mrclam_dataset_or_fail, mrclam_root)


@pytest.fixture(scope="session")
def mrclam6(mrclam_dataset: Callable[[int], Path]) -> Path:
    """Dataset 6, the one with ground truth for every robot."""
    return mrclam_dataset(6)


# ------------------------------------------------------------------------------------------------ progress bars
@pytest.fixture
def terminal_progress(monkeypatch: pytest.MonkeyPatch) -> None:
    """The commands' progress bars (swarmloc.experiments.progress) drawn as on a terminal, on stderr: under pytest
    stderr is no terminal, where rich draws nothing; read them with ``capsys.readouterr().err``."""
    from rich.console import Console

    monkeypatch.setattr("swarmloc.experiments.progress.stderr_console",
                        lambda: Console(stderr=True, force_terminal=True, width=120))  # fmt: skip
