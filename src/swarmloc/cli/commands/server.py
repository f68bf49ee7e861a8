"""``swarmloc server``: the belief server of a team (stores every robot's Gaussian; can host a centralized
estimator fed by the robots' forwarded measurements)."""

from __future__ import annotations

import argparse

from swarmloc.cli.common import die_with_launcher, endpoints, ids, load_auth, net_logging, refuse, team_source
from swarmloc.cli.options import ASSOCIATION_CHOICES, ASSOCIATION_HELP, add_auth_args, add_net_args, real, seed


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``server`` command: its options and help."""
    sv = sub.add_parser("server", help="run the belief server of a team (stores every robot's Gaussian)")
    add_net_args(sv)
    sv.add_argument("--robots", default=None, help="the team's robot ids, comma-separated (default: the roster's)")
    sv.add_argument("--estimator", default=None, help="host a centralized estimator (cekf, iekf, fej) fed by the "
                    "robots' forwarded measurements ('swarmloc node --estimator' the same on every robot)")  # fmt: skip
    sv.add_argument("--source", default=None, help="with --estimator: the team's source (initial beliefs, landmarks, "
                    "configuration, record times; its events come from the robots)")  # fmt: skip
    sv.add_argument("--config", default=None, help="with --estimator: TOML file of model and filter settings")
    sv.add_argument("--duration", type=real, default=None, help="with --estimator: seconds of the source")
    sv.add_argument("--seed", type=seed, default=0, help="with --estimator, sim: seed")
    sv.add_argument("--association", choices=ASSOCIATION_CHOICES, default=None,
                    help="with --estimator: " + ASSOCIATION_HELP)  # fmt: skip
    sv.add_argument("--start-timeout", type=real, default=30.0,
                    help="with --estimator: seconds it waits for every robot's first forward (default 30)")  # fmt: skip
    sv.add_argument("--lost-timeout", type=real, default=10.0, help="with --estimator: seconds a robot's stream may "
                    "stay silent while the fusion waits on it before it is declared lost (default 10)")  # fmt: skip
    sv.add_argument("--map-out", default=None, help="save the fused line map there as GeoJSON when it stops")
    add_auth_args(sv)
    sv.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the belief server until ``--max-wall`` or Ctrl-C; 0, or 2 on bad input."""
    die_with_launcher(args)
    from swarmloc.config import ConfigError
    from swarmloc.net.entry import server_main
    from swarmloc.net.schema import SERVER

    net_logging(args.verbose)
    try:
        if args.roster and not args.key and all(c.isdigit() or c == "," for c in args.roster):
            raise ValueError("--roster is the team's roster FILE (with --key); the robot ids go to --robots")
        auth = load_auth(args, SERVER)
        robots = ids(args.robots) if args.robots else (auth.roster.robots if auth is not None else None)
        if not robots:
            raise ValueError("--robots: the team's robot ids, comma-separated (default: the roster's robots)")
        src = None
        if args.estimator is not None:
            if args.source is None:
                raise ValueError("--estimator needs --source (the team's initial beliefs and configuration)")
            src = team_source(args, args.source, len(robots))
        server_main(
            team=args.team, roster=[int(r) for r in robots], listen=endpoints(args.listen),
            connect=endpoints(args.connect), zenoh_config=args.zenoh_config, max_wall=args.max_wall, auth=auth,
            run_id=args.run_id, src=src, estimator=args.estimator, start_timeout=args.start_timeout,
            lost_timeout=args.lost_timeout, map_out=args.map_out,
        )  # fmt: skip
    except (ConfigError, ValueError, OSError) as exc:
        return refuse("server", exc)
    return 0
