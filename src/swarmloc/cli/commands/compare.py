"""``swarmloc compare``: every estimator on identical events, one table (a simulated scenario or a dataset)."""

from __future__ import annotations

import argparse

from swarmloc.cli.common import refuse
from swarmloc.cli.options import ASSOCIATION_CHOICES, ASSOCIATION_HELP, EST_DEFAULT, add_sweep_args, real


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``compare`` command: its options and help."""
    cp = sub.add_parser("compare", help="every estimator on identical events: one table (sim scenario or dataset)")
    cp.add_argument("--scenario", default="sim:random",
                    help="any source swarmloc team takes: sim:SCENARIO (random, range_bearing, landmarks, corridor; "
                         "3-D: 3d, 3d_rot, 3d_rbe, 3d_bearing, 3d_landmarks), mrclam:PATH or events:PATH "
                         "(default sim:random)")  # fmt: skip
    cp.add_argument("--estimators", default=None,
                    help=f"comma-separated names (default {EST_DEFAULT}; on a 3-D scenario those of them with an "
                         "SE(3) form)")  # fmt: skip
    cp.add_argument("--runs", type=int, default=1, help="seeds of a simulated scenario (default 1)")
    cp.add_argument("--robots", type=int, default=4, help="sim: team size (default 4)")
    cp.add_argument("--duration", type=real, default=None, help="seconds (sim default 30; dataset: all)")
    add_sweep_args(cp)
    cp.add_argument("--out", default=None, help="output folder for compare.md / compare.json")
    cp.add_argument("--association", choices=ASSOCIATION_CHOICES, default="tags", help=ASSOCIATION_HELP)
    cp.add_argument("--clutter", type=real, default=0.0, help="false robot detections per scan, Poisson (default 0)")
    cp.add_argument("--p-detect", type=real, default=1.0, help="robot detection probability (default 1)")
    cp.add_argument("--quiet", action="store_true", help="no progress bar")
    cp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run every estimator on the same events and print the table; 0, or 2 on bad input."""
    from swarmloc.experiments.compare import compare, compare_table, is_3d
    from swarmloc.runner.fanout import ClusterUnavailable

    if args.estimators is None:  # the defaults; on a 3-D team, those with an SE(3) form
        from swarmloc.estimators import ESTIMATORS_SE3

        names = [e for e in EST_DEFAULT.split(",") if not is_3d(args.scenario) or e in ESTIMATORS_SE3]
    else:
        names = [e.strip() for e in args.estimators.split(",") if e.strip()]
    try:
        summary = compare(args.scenario, names, runs=args.runs, robots=args.robots, duration=args.duration,
                          out_dir=args.out, jobs=args.jobs, progress=not args.quiet, association=args.association,
                          clutter=args.clutter, p_detect=args.p_detect, cluster=args.cluster)  # fmt: skip
    except (ValueError, OSError, ClusterUnavailable) as exc:
        return refuse("compare", exc)
    print(compare_table(summary))
    if args.out:
        print(f"written to {args.out}/compare.md and compare.json")
    return 0
