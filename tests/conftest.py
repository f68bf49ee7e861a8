"""Shared test configuration.

One BLAS thread: the tests run numpy/scipy on many tiny matrices (batched 3x3..12x12 expm/logm, slogdet, solve),
where OpenBLAS worker threads only spin. On the 2-core development machine under load this made
tests/test_lie.py alone take ~50 s instead of ~3 s. Must run before numpy is first imported; an explicit
setting in the environment wins.

Also: hypothesis' storage under pytest's temporary directory, the fixtures through which every test finds the
MRCLAM dataset (mrclam_root, mrclam_dataset, mrclam6; the rule is in tests/_data.py), and the tiers.

Tiers (markers, registered in pyproject.toml; ``--strict-markers``): every test is ``unit`` (no data, no network),
``data`` (reads MRCLAM) or ``network`` (starts Zenoh peers or processes), one of them at least, most by its
module's ``pytestmark``; ``slow`` marks those that took over 2 s in a measured run (listed in tests/slow_tests.txt,
made by tests/_tiers.py) or are marked so in their module. ``python -m pytest -q -m "not slow"`` is the quick tier
(under 3 minutes on two cores). Under pytest-xdist (``-n``, ``--dist loadfile`` in pyproject's addopts) the
tests of one module run in one worker, so its module-scoped fixtures are built once. Each worker picks the free
ports of its teams in a range of its own (``SWARMLOC_PORT_RANGE``, :func:`swarmloc.net.transport.free_ports`),
below the OS's ephemeral range: two teams starting at once in two workers never take each other's ports, nor a
port the OS hands to an outgoing connection. (``--dist loadgroup`` would keep the network tests in one worker, but
pytest-xdist 3.8's groups are lost with pytest 9.2's node ids: they ran spread over both workers.)
"""

import functools
import os
from collections.abc import Callable
from pathlib import Path

import pytest  # does not import numpy
from _data import REPO_ROOT, mrclam_dataset_or_fail, mrclam_root_or_none, mrclam_root_or_skip
from _tiers import read_list

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


# ------------------------------------------------------------------------------------------------ tiers
KINDS = ("unit", "data", "network")
MRCLAM_FIXTURES = frozenset({"mrclam_root", "mrclam_root_if_expected", "mrclam_dataset", "mrclam6"})


def tier_problems(items: list[pytest.Item]) -> list[str]:
    """Tests without a kind (unit, data, network), and tests that read MRCLAM (a fixture of tests/_data.py) without
    the ``data`` marker."""
    problems = []
    for item in items:
        kinds = {m.name for m in item.iter_markers()} & set(KINDS)
        if not kinds:
            problems.append(f"{item.nodeid}: no tier marker (pytestmark = pytest.mark.unit, data or network)")
        elif MRCLAM_FIXTURES & set(getattr(item, "fixturenames", ())) and "data" not in kinds:
            problems.append(f"{item.nodeid}: reads MRCLAM but is not marked data")
    return problems


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Refuse a run with a test that has no tier; mark the measured slow ones (module docstring)."""
    problems = tier_problems(items)
    if problems:
        more = f"\n... and {len(problems) - 20} more" if len(problems) > 20 else ""
        raise pytest.UsageError("tests without their tier:\n" + "\n".join(problems[:20]) + more)
    slow = read_list()
    for item in items:
        if item.nodeid in slow:
            item.add_marker(pytest.mark.slow)


PORTS_FROM, PORTS_PER_WORKER = 10_000, 500
"""Worker ``gwK`` picks its ports in ``[10000 + 500 K, 10000 + 500 K + 499]``: 45 workers stay below 32768, where
Linux's ephemeral range starts by default."""


def worker_port_range(worker: str) -> str:
    """``LO-HI`` of an xdist worker (``gw3``)."""
    k = int(worker.removeprefix("gw"))
    lo = PORTS_FROM + PORTS_PER_WORKER * (k % 45)
    return f"{lo}-{lo + PORTS_PER_WORKER - 1}"


_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")
if _WORKER.startswith("gw") and _WORKER[2:].isdigit():  # set before any test (or process it starts) picks a port
    os.environ.setdefault("SWARMLOC_PORT_RANGE", worker_port_range(_WORKER))
