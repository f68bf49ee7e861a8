"""``swarmloc team``: a live team on this machine (127.0.0.1), collected and scored."""

from __future__ import annotations

import argparse
import sys

from swarmloc.cli.common import endpoints, net_logging, refuse, team_source, timeouts
from swarmloc.cli.liveview import check_view, linger, open_view
from swarmloc.cli.options import add_source_args, add_timeout_args, add_view_args, real


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``team`` command: its options and help."""
    t = sub.add_parser("team", help="start a live team on this machine (127.0.0.1), collect and score it")
    add_source_args(t, "sim:random")
    t.add_argument("--server", action="store_true", help="also start the belief server")
    add_view_args(t, "of the team")
    t.add_argument("--team", default=None, help="the team's name (default team<PID>); each run also has an id of its "
                   "own in every key, so that two teams of one name never hear each other")  # fmt: skip
    add_timeout_args(t)
    t.add_argument("--connect", default=None, help="endpoints every process also connects to (a Zenoh router)")
    t.add_argument("--routers", type=int, default=0, metavar="N",
                   help="relay the team through N meshed Zenoh routers on 127.0.0.1, every process a client of "
                        "one (as robots on several machines would be); 0: every process a peer of the others "
                        "(default)")  # fmt: skip
    t.add_argument("--bag", default=None, help="record the beliefs as a rosbag2 (folder to create)")
    t.add_argument("--max-wall", "--timeout", dest="max_wall", type=real, default=600.0,
                   help="stop every process after this many wall-clock seconds (default 600)")  # fmt: skip
    t.add_argument("--out", required=True, help="output folder (report, figures, TUM files, logs)")
    t.add_argument("--verbose", action="store_true", help="nodes log their state every 2 s (in OUT/logs)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Start, collect and score a team; 0, 1 when a process failed or timed out, 2 on bad input, 130."""
    from swarmloc.config import ConfigError
    from swarmloc.experiments.evaluate import markdown_table
    from swarmloc.experiments.progress import progress_bar
    from swarmloc.experiments.team import run_team, write_team_report

    net_logging(args.verbose)
    import signal

    signal.signal(signal.SIGTERM, signal.default_int_handler)  # as Ctrl-C: `kill` also stops every process started
    view, ran = None, False
    try:
        check_view(args)
        src = team_source(args, args.source, args.robots)
        if args.view is not None or args.record:
            view = open_view(args, src, src.events, "swarmloc team")
        with progress_bar(not args.quiet) as start:
            result = run_team(
                src=src, robots=args.robots, source=args.source, estimator=args.estimator, duration=args.duration,
                seed=args.seed, config_file=args.config, server=args.server, faults=args.faults, speed=args.speed,
                lag=args.lag, max_wall=args.max_wall, ros_domain=args.ros_domain, log_dir=f"{args.out}/logs",
                association=src.config.filter.association, routers=args.routers,
                team=args.team, verbose=args.verbose, connect_extra=endpoints(args.connect), view=view,
                progress=start(f"team {args.source}, {args.estimator}: beliefs") if start is not None else None,
                **timeouts(args),
            )  # fmt: skip
        if view is not None:
            view.end_recording()
        extra = {"faults": args.faults or "", "exit_codes": result.exit_codes}
        report = write_team_report(result, src, args.estimator, args.out, extra)
        if result.map is not None:
            from swarmloc.net.server import linemap_of

            linemap_of(result.map).save_geojson(f"{args.out}/map.geojson")
        if args.bag:
            from swarmloc.net.ros import BagWriter

            with BagWriter(args.bag) as bag:
                for (r, t), b in sorted(result.beliefs.items()):
                    import numpy as np

                    bag.write(f"/swarmloc/robot{r}/pose", t, np.reshape(b.mean, (3, 3)), np.reshape(b.cov, (3, 3)))
        ran = True
    except (ConfigError, ValueError, OSError, RuntimeError) as exc:
        return refuse("team", exc)
    except KeyboardInterrupt:
        print("swarmloc team: interrupted; every process it started was stopped", file=sys.stderr)
        return 130
    finally:
        if view is not None and not ran:
            view.close()  # the view lingers only after a run that went through
    print(markdown_table(report))
    print(f"results, figures and TUM trajectories in {args.out}/" + (f"; rosbag2 in {args.bag}" if args.bag else "")
          + (f"; MCAP in {args.record}" if args.record else ""))  # fmt: skip
    if view is not None:
        linger(view, args)
    bad = {n: c for n, c in result.exit_codes.items() if c not in (0, -15, None) and not n == "server"}
    return 1 if bad or result.counts.get("timed_out") else 0
