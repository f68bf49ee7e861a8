"""``swarmloc node``: one robot of a team as a Zenoh peer (one process per robot)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from swarmloc.cli.common import die_with_launcher, endpoints, ids, load_auth, net_logging, refuse, team_source, timeouts
from swarmloc.cli.liveview import check_view, linger, open_view
from swarmloc.cli.options import add_auth_args, add_net_args, add_source_args, add_timeout_args, add_view_args


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``node`` command: its options and help."""
    n = sub.add_parser("node", help="run one robot of a team as a Zenoh peer (one process per robot)")
    n.add_argument("--robot", type=int, required=True, help="this robot's id in the source")
    add_net_args(n)
    add_source_args(n, None)
    n.add_argument("--use-server", action="store_true", help="ask the belief server when a neighbour is silent")
    n.add_argument("--resume", action="store_true", help="start from this robot's latest belief on the server")
    n.add_argument("--wait-for", default=None, help="robot ids to wait for before starting (default: the team)")
    n.add_argument("--input-listen", default=None,
                   help="ros2: the loopback endpoints the robot's ROS 2 publishers connect to, comma-separated "
                        "(default tcp/127.0.0.1:7448; only this host can reach them)")  # fmt: skip
    n.add_argument("--input-connect", default=None,
                   help="ros2: loopback endpoints to connect the input session to (a local rmw_zenoh router "
                        "listening on loopback only)")  # fmt: skip
    add_timeout_args(n)
    n.add_argument("--out", default=None, help="folder for robot<N>.tum (final beliefs) and robot<N>.json (report)")
    add_view_args(n, "of this robot (and the server's map)")
    add_auth_args(n)
    n.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run one robot until its source ends; 0, 2 on bad input, 3 when no teammate answered, 130 on Ctrl-C."""
    die_with_launcher(args)
    from swarmloc.config import ConfigError
    from swarmloc.live.source import live_inputs, split_live
    from swarmloc.net.entry import node_main
    from swarmloc.net.transport import team_scope

    net_logging(args.verbose)
    view, ran = None, False
    try:
        check_view(args)
        team_scope(args.team, args.run_id)  # a bad name or run id is refused before the source is loaded
        auth = load_auth(args, args.robot)
        live_kind, spec = split_live(args.source)
        src = team_source(args, spec, args.robots)
        live = None
        if live_kind is not None:
            live = live_inputs(live_kind, team=args.team, run_id=args.run_id, domain=args.ros_domain or 0,
                               roster=None if auth is None else auth.roster, input_listen=endpoints(args.input_listen),
                               input_connect=endpoints(args.input_connect))  # fmt: skip
        view = _node_view(args, src, live_kind is not None)
        report = node_main(
            src=src, robot=args.robot, team=args.team, estimator=args.estimator, speed=args.speed, lag=args.lag,
            listen=endpoints(args.listen), connect=endpoints(args.connect), zenoh_config=args.zenoh_config,
            use_server=args.use_server, resume=args.resume, faults=args.faults, wait_for=ids(args.wait_for),
            ros_domain=args.ros_domain, max_wall=args.max_wall, out=args.out, run_id=args.run_id, auth=auth,
            live=live, view=view, **timeouts(args),
        )  # fmt: skip
        ran = True
    except (ConfigError, ValueError, OSError, RuntimeError) as exc:
        return refuse("node", exc)
    except KeyboardInterrupt:
        return 130
    finally:
        if view is not None and not ran:
            view.close()
    rc = _node_summary(args, src, report)
    if view is not None:
        linger(view, args)
    return rc


def _node_summary(args: argparse.Namespace, src: Any, report: Any) -> int:
    """Print a node's result; its exit status (3: nothing forwarded, or no teammate ever answered)."""
    s = report.stats
    if "forwards" in report.net or not s:  # a server-hosted estimator: this process forwards its measurements
        n = report.net
        print(f"robot {report.robot}: forwarded {n.get('forwarded_detections', 0)} detections and "
              f"{n.get('forwarded_odometry', 0)} odometry records in {n.get('forwards', 0)} forwards "
              f"({n.get('lost', 0)} lost on the way by faults); {report.wall_s:.1f} s")  # fmt: skip
        return 0 if "forwards" in n else 3
    print(f"robot {report.robot}: {s['detections']} detections: {s['fused']} fused, {s['gated']} gated, "
          f"{s['rejected']} rejected, {s['unknown']} unknown; {report.net.get('rejected', 0)} messages dropped; "
          f"{report.wall_s:.1f} s")  # fmt: skip
    others = sorted(set(src.robots) - {args.robot})
    if others and report.net.get("teammates_seen") == 0:  # the node counted them: it saw none
        waited, hint = _start_wait(args)
        print(f"swarmloc node: robot {args.robot}: no teammate ever answered: none of robots {others} was seen "
              f"({waited}, then ran alone; {s['unknown']} detections unknown); {hint}", file=sys.stderr)  # fmt: skip
        return 3
    return 0


def _start_wait(args: argparse.Namespace) -> tuple[str, str]:
    """What a node that saw no teammate waited for at its start, and what to check. A joiner (``--wait-for none``,
    as ``swarmloc team`` starts a late or restarted robot) waits for nobody: it may have come up after its team
    ended (at ``--speed 0`` a team reads a short source in about a second)."""
    wait_for = ids(args.wait_for)
    check = "check --connect and --team"
    if wait_for == []:
        return "it waited for nobody at the start (--wait-for none)", \
            f"joining a running team, it may have come up after the team ended; else {check}"  # fmt: skip
    whom = "its teammates" if wait_for is None else f"robots {wait_for}"
    return f"it waited up to {args.start_timeout:g} s for {whom} at the start (--start-timeout)", check


def _node_view(args: argparse.Namespace, src: Any, live: bool) -> Any:
    """``node --view/--record``: a :class:`~swarmloc.net.view.TeamView` of this robot (its beliefs, detections, ground
    truth where the source has it, its lines and the belief server's map), or None. ``live``: the source's stamps
    are Unix times already (no epoch added)."""
    if args.view is None and not args.record:
        return None
    from swarmloc.events import Detection

    dets = [e for e in src.own_events(args.robot) if isinstance(e, Detection) and e.observer == args.robot]
    return open_view(args, src, dets, f"swarmloc node {args.robot}", epoch=0.0 if live else None)
