"""``swarmloc simulate``: a random team written as an event file and TUM truth."""

from __future__ import annotations

import argparse

from swarmloc.cli.common import refuse
from swarmloc.cli.options import real, seed


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``simulate`` command: its options and help."""
    s = sub.add_parser("simulate", help="simulate a random team and write it as an event file + TUM truth")
    s.add_argument("--robots", type=int, default=4)
    s.add_argument("--duration", type=real, default=60.0, help="seconds (default 60)")
    s.add_argument("--seed", type=seed, default=0, help="the simulation's seed (default 0)")
    s.add_argument("--format", choices=["csv", "jsonl"], default="csv")
    s.add_argument("--out", required=True, help="output folder")
    s.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write a simulated team's event file, TUM truth and configuration; 0, or 2 on bad input."""
    from swarmloc.experiments.own_robots import simulate_to_files

    if args.robots < 1 or args.duration <= 0:
        return refuse("simulate", "--robots must be >= 1 and --duration > 0")
    try:
        paths = simulate_to_files(args.out, robots=args.robots, duration=args.duration, seed=args.seed,
                                  fmt=args.format)  # fmt: skip
    except (ValueError, OSError) as exc:
        return refuse("simulate", exc)
    print(f"wrote {paths['events']}, {len(paths) - 2} truth_robot*.tum files and {paths['config']}")
    return 0
