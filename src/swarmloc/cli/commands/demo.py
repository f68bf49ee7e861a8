"""``swarmloc demo``: thesis sec. 5.1, a team of 4, prior vs fused posterior, figures."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from swarmloc.cli.options import seed


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``demo`` command: its options and help."""
    d = sub.add_parser("demo", help="thesis sec. 5.1: a team of 4, prior vs fused posterior, figures")
    d.add_argument("--out", default="swarmloc-demo", help="output folder (default: swarmloc-demo)")
    d.add_argument("--seed", type=seed, default=0, help="the simulation's seed (default 0)")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the demo's figures and tables to ``--out``; 0."""
    from swarmloc.experiments.thesis_demo import run_demo

    t = time.perf_counter()
    run_demo(Path(args.out), seed=args.seed, progress=not args.quiet)
    print(f"demo written to {args.out}/ in {time.perf_counter() - t:.1f} s")
    return 0
