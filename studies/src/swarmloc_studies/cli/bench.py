"""``swarmloc-studies bench``: speed on this machine; the options are :mod:`swarmloc_studies.bench_command`'s own."""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``bench`` command: its options (:func:`swarmloc_studies.bench_command.add_arguments`) and help."""
    from swarmloc_studies.bench_command import add_arguments

    bp = sub.add_parser("bench", help="speed on this machine: fusion step (engine vs filterpy), memory and FLOP "
                        "fractions, swarms of 100 to 10,000 robots, MRCLAM replay x real time")  # fmt: skip
    add_arguments(bp)
    bp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the benchmarks; their exit status."""
    from swarmloc_studies.bench_command import run_command

    return run_command(args)
