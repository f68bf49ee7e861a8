"""``swarmloc consistency``: Monte Carlo ANEES per estimator against the 95% chi-square band
(:mod:`swarmloc.experiments.consistency`)."""

from __future__ import annotations

import argparse
import json
import sys

from swarmloc.cli.common import refuse
from swarmloc.cli.options import add_sweep_args, real


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``consistency`` command: its options and help."""
    cs = sub.add_parser("consistency", help="Monte Carlo ANEES per estimator vs the 95%% chi-square band, a simulated "
                        "team without and with landmarks: table, JSON and NEES-over-time figure")  # fmt: skip
    cs.add_argument("--estimators", default=None, help="comma-separated names (default: all registered but mcl, dr)")
    cs.add_argument("--seeds", type=int, default=50, help="independent simulated teams (default 50)")
    cs.add_argument("--robots", type=int, default=5, help="team size (default 5)")
    cs.add_argument("--duration", type=real, default=60.0, help="seconds per run (default 60)")
    cs.add_argument("--landmarks", default="off,on", help="off, on or off,on (default off,on)")
    add_sweep_args(cs)
    cs.add_argument("--out", default=None, help="output folder for consistency.md / .json / .png")
    cs.add_argument("--json", action="store_true", help="print the summary as JSON instead of the table")
    cs.add_argument("--quiet", action="store_true", help="no progress bar")
    cs.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the study and print the table (or JSON); 0, or 2 on bad input."""
    from swarmloc.experiments.consistency import consistency, consistency_table, default_estimators
    from swarmloc.runner.fanout import ClusterUnavailable

    names = default_estimators() if args.estimators is None else [e.strip() for e in args.estimators.split(",")
                                                                   if e.strip()]  # fmt: skip
    marks = {"off": False, "on": True}
    try:
        settings = [marks[w.strip()] for w in args.landmarks.split(",") if w.strip()]
    except KeyError as exc:
        return refuse("consistency", f"--landmarks takes off, on or off,on; got {exc.args[0]!r}")
    try:
        summary = consistency(names, seeds=args.seeds, robots=args.robots, duration=args.duration,
                              landmarks=settings, jobs=args.jobs, out=args.out, progress=not args.quiet,
                              cluster=args.cluster)  # fmt: skip
    except (ValueError, OSError, ClusterUnavailable) as exc:
        return refuse("consistency", exc)
    print(json.dumps(summary, indent=2) if args.json else consistency_table(summary))
    if args.out:
        print(f"written to {args.out}/consistency.md, consistency.json and consistency.png", file=sys.stderr)
    return 0
