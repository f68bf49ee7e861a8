"""Shared test configuration.

One BLAS thread: the tests run numpy/scipy on many tiny matrices (batched 3x3..12x12 expm/logm, slogdet, solve),
where OpenBLAS worker threads only spin. On the 2-core development machine under load this made
tests/test_lie.py alone take ~50 s instead of ~3 s. Must run before numpy is first imported; an explicit
setting in the environment wins.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
