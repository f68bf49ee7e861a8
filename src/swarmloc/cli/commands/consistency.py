"""``swarmloc consistency``: Monte Carlo ANEES per estimator against the 95% chi-square band
(:mod:`swarmloc.experiments.consistency`)."""

from __future__ import annotations

import argparse

from swarmloc.cli.options import add_sweep_args


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``consistency`` command: its options and help."""
    cs = sub.add_parser("consistency", help="Monte Carlo ANEES per estimator vs the 95%% chi-square band, a simulated "
                        "team without and with landmarks: table, JSON and NEES-over-time figure")  # fmt: skip
    cs.add_argument("--estimators", default=None, help="comma-separated names (default: all registered but mcl, dr)")
    cs.add_argument("--seeds", type=int, default=50, help="independent simulated teams (default 50)")
    cs.add_argument("--robots", type=int, default=5, help="team size (default 5)")
    cs.add_argument("--duration", type=float, default=60.0, help="seconds per run (default 60)")
    cs.add_argument("--landmarks", default="off,on", help="off, on or off,on (default off,on)")
    add_sweep_args(cs)
    cs.add_argument("--out", default=None, help="output folder for consistency.md / .json / .png")
    cs.add_argument("--json", action="store_true", help="print the summary as JSON instead of the table")
    cs.add_argument("--quiet", action="store_true", help="no progress bar")
    cs.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the study; its exit status."""
    from swarmloc.experiments.consistency import run_command

    return run_command(args)
