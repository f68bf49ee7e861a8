"""Command line of the thesis sec. 5.1 experiments: ``python -m swarmloc_studies.thesis_static demo|tables|all
OUT_DIR [--seed S] [--reps R]``."""

from __future__ import annotations

import argparse
from pathlib import Path

from swarmloc.experiments.thesis_demo import run_demo
from swarmloc_studies.thesis_static.run import run_tables


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m swarmloc_studies.thesis_static",
        description="Thesis sec. 5.1 experiments (figures 5.2-5.5, Tables 5.1/5.2)",
    )
    ap.add_argument("what", choices=["demo", "tables", "all"])
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--reps", type=int, default=60)
    args = ap.parse_args(argv)
    if args.what in ("demo", "all"):
        run_demo(args.out_dir, seed=args.seed)
    if args.what in ("tables", "all"):
        run_tables(args.out_dir, reps=args.reps, seed=args.seed)


if __name__ == "__main__":
    main()
