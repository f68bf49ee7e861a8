"""What the benchmark scripts share (they import it by name, as they import each other, when run from
``benchmarks/``): where the MRCLAM recordings are and the ``--mrclam`` option that names them."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def mrclam_root() -> Path:
    """The folder of the ``MRCLAM_DatasetN`` folders: ``$SWARMLOC_MRCLAM``, else ``shared/data/mrclam`` beside this
    checkout (read when called)."""
    return Path(os.environ.get("SWARMLOC_MRCLAM", ROOT.parent / "shared/data/mrclam"))


def add_mrclam(ap: argparse.ArgumentParser, **kwargs: Any) -> None:
    """``--mrclam``, a path, by default :func:`mrclam_root`; ``kwargs`` (``default``, ``help``) go to
    ``add_argument``."""
    ap.add_argument("--mrclam", type=Path, **{"default": mrclam_root(), **kwargs})
