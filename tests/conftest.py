"""Shared test configuration.

One BLAS thread: the tests run numpy/scipy on many tiny matrices (batched 3x3..12x12 expm/logm, slogdet, solve),
where OpenBLAS worker threads only spin. On the 2-core development machine under load this made
tests/test_lie.py alone take ~50 s instead of ~3 s. Must run before numpy is first imported; an explicit
setting in the environment wins.
"""

import os

import pytest  # does not import numpy

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
