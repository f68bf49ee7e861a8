"""``swarmloc-studies bench`` as a script: the same code (:mod:`swarmloc_studies.bench`), the same options.

    python benchmarks/bench.py --quick              # under a minute
    python benchmarks/bench.py                      # full: swarms up to 10,000 robots, all of MRCLAM dataset 6
    python benchmarks/bench.py --json > bench.json

The MRCLAM dataset is looked for with ``--mrclam``, then ``$SWARMLOC_MRCLAM``, then ``../shared/data/mrclam``
beside this checkout.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from _common import mrclam_root

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "src"), str(ROOT / "studies" / "src")]  # this checkout: swarmloc and its studies
os.environ.setdefault("SWARMLOC_MRCLAM", str(mrclam_root()))

from swarmloc_studies.bench_command import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
