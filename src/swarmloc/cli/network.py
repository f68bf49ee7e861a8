"""``swarmloc node | server | team | keys``: a robot's process, the belief server, a team on this machine, keys."""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

from swarmloc.cli.offline import run_config


def _ids(text: str | None) -> list[int] | None:
    """``"1,2,3"`` -> ``[1, 2, 3]``; ``"none"`` -> ``[]``; None -> None."""
    if text is None:
        return None
    if text.strip().lower() == "none":
        return []
    return [int(x) for x in text.split(",") if x.strip()]


def _endpoints(text: str | None) -> list[str]:
    return [x.strip() for x in (text or "").split(",") if x.strip()]


def _net_logging(verbose: bool) -> None:
    import logging

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s")  # fmt: skip


def _auth(args: argparse.Namespace, member: int):  # noqa: ANN202
    """The process's :class:`~swarmloc.net.auth.Auth` from ``--key`` and ``--roster``; None with ``--no-auth``."""
    from swarmloc.net.auth import Auth

    if args.no_auth:
        if args.key or args.roster:
            raise ValueError("--no-auth takes neither --key nor --roster")
        print("warning: --no-auth: any process on the network can speak in any member's name (and write a "
              "zenoh: source's live inputs)", file=sys.stderr)  # fmt: skip
        return None
    if not (args.key and args.roster):
        raise ValueError("give this process's --key FILE and the team's --roster FILE (make them with "
                         "'swarmloc keys'), or --no-auth on a trusted network")  # fmt: skip
    return Auth.load(args.key, args.roster, member)


def _die_with_launcher(args: argparse.Namespace) -> None:
    if args.parent_pid is not None:  # first thing: a launcher killed meanwhile must not leave this process running
        from swarmloc.net.lifeline import die_with_parent

        die_with_parent(args.parent_pid)


def cmd_node(args: argparse.Namespace) -> int:
    _die_with_launcher(args)
    from swarmloc.config import ConfigError
    from swarmloc.experiments.association import with_association
    from swarmloc.experiments.sources import load_source
    from swarmloc.live.source import live_inputs, split_live
    from swarmloc.net.entry import node_main
    from swarmloc.net.transport import team_scope

    _net_logging(args.verbose)
    view, ran = None, False
    try:
        _check_view(args)
        team_scope(args.team, args.run_id)  # a bad name or run id is refused before the source is loaded
        auth = _auth(args, args.robot)
        config = run_config(args) if args.config else None
        live_kind, spec = split_live(args.source)
        src = load_source(spec, robots=args.robots, duration=args.duration, seed=args.seed, config=config)
        src = with_association(src, args.association)
        live = None
        if live_kind is not None:
            live = live_inputs(live_kind, team=args.team, run_id=args.run_id, domain=args.ros_domain or 0,
                               roster=None if auth is None else auth.roster, input_listen=_endpoints(args.input_listen),
                               input_connect=_endpoints(args.input_connect))  # fmt: skip
        view = _node_view(args, src, live_kind is not None)
        report = node_main(
            src=src, robot=args.robot, team=args.team, estimator=args.estimator, speed=args.speed, lag=args.lag,
            listen=_endpoints(args.listen), connect=_endpoints(args.connect), zenoh_config=args.zenoh_config,
            use_server=args.use_server, resume=args.resume, faults=args.faults, wait_for=_ids(args.wait_for),
            ros_domain=args.ros_domain, max_wall=args.max_wall, out=args.out, run_id=args.run_id, auth=auth,
            live=live, view=view, **_timeouts(args),
        )  # fmt: skip
        ran = True
    except (ConfigError, ValueError, OSError, RuntimeError) as exc:
        print(f"swarmloc node: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    finally:
        if view is not None and not ran:
            view.close()
    rc = _node_summary(args, src, report)
    if view is not None:
        _linger(view, args)
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
        print(f"swarmloc node: robot {args.robot}: no teammate ever answered: none of robots {others} was seen "
              f"(waited {args.start_timeout:g} s at the start, then ran alone; {s['unknown']} detections unknown); "
              "check --connect and --team", file=sys.stderr)  # fmt: skip
        return 3
    return 0


def _node_view(args: argparse.Namespace, src: Any, live: bool) -> Any:
    """``node --view/--record``: a :class:`~swarmloc.net.view.TeamView` of this robot (its beliefs, detections, ground
    truth where the source has it, its lines and the belief server's map), or None. ``live``: the source's stamps
    are Unix times already (no epoch added)."""
    if args.view is None and not args.record:
        return None
    from swarmloc.events import Detection

    dets = [e for e in src.own_events(args.robot) if isinstance(e, Detection) and e.observer == args.robot]
    return _open_view(args, src, dets, f"swarmloc node {args.robot}", epoch=0.0 if live else None)


def _check_view(args: argparse.Namespace) -> None:
    """Refuse a bad ``--linger``, and ``--view``/``--record`` without the ``view`` extra (one line naming the
    install command), before anything starts."""
    if args.linger is not None and not args.linger >= 0:
        raise ValueError(f"--linger: seconds >= 0 (or none: until Ctrl-C), got {args.linger:g}")
    if args.view is not None or args.record:
        from swarmloc.net.view import require_view

        require_view(args.view is not None, bool(args.record))


def _open_view(args: argparse.Namespace, src: Any, detections: Any, name: str, epoch: float | None = None) -> Any:
    """The :class:`~swarmloc.net.view.TeamView` of ``--view``/``--record`` (truth and NEES where the source has
    truth); prints where to connect and where the layout is."""
    from swarmloc.evaluation.metrics import errors
    from swarmloc.net.view import LAYOUT, TeamView

    view = TeamView(port=args.view, mcap=args.record, truth=src.truth, score=errors, detections=detections,
                    roster=src.robots, name=name, epoch=epoch)  # fmt: skip
    if view.url:
        print(f"live view: open {view.url} in Foxglove or Lichtblick (Open connection > Foxglove WebSocket); "
              f"layout: {LAYOUT}", flush=True)  # fmt: skip
    return view


def _linger(view: Any, args: argparse.Namespace) -> None:
    """After the run: finish the recording, keep the live view up for ``--linger`` seconds (default: until Ctrl-C
    when stdin and stdout are a terminal, else not at all), then close it. Ctrl-C (or SIGTERM) ends the wait."""
    try:
        view.end_recording()
        seconds = args.linger
        if seconds is None:
            seconds = math.inf if sys.stdin.isatty() and sys.stdout.isatty() else 0.0
        if view.url is None or seconds <= 0:
            return
        until = "until Ctrl-C" if math.isinf(seconds) else f"for {seconds:g} s (Ctrl-C ends it sooner)"
        print(f"live view: the run has ended; still serving {view.url} {until}", flush=True)
        try:
            view.wait(seconds)
            print("live view: closed", flush=True)
        except KeyboardInterrupt:
            print("live view: stopped", flush=True)
    finally:
        view.close()


def cmd_server(args: argparse.Namespace) -> int:
    _die_with_launcher(args)
    from swarmloc.config import ConfigError
    from swarmloc.net.entry import server_main
    from swarmloc.net.schema import SERVER

    _net_logging(args.verbose)
    try:
        if args.roster and not args.key and all(c.isdigit() or c == "," for c in args.roster):
            raise ValueError("--roster is the team's roster FILE (with --key); the robot ids go to --robots")
        auth = _auth(args, SERVER)
        robots = _ids(args.robots) if args.robots else (auth.roster.robots if auth is not None else None)
        if not robots:
            raise ValueError("--robots: the team's robot ids, comma-separated (default: the roster's robots)")
        src = None
        if args.estimator is not None:
            from swarmloc.experiments.sources import load_source

            if args.source is None:
                raise ValueError("--estimator needs --source (the team's initial beliefs and configuration)")
            config = run_config(args) if args.config else None
            src = load_source(args.source, robots=len(robots), duration=args.duration, seed=args.seed, config=config)
            from swarmloc.experiments.association import with_association

            src = with_association(src, args.association)
        server_main(
            team=args.team, roster=[int(r) for r in robots], listen=_endpoints(args.listen),
            connect=_endpoints(args.connect), zenoh_config=args.zenoh_config, max_wall=args.max_wall, auth=auth,
            run_id=args.run_id, src=src, estimator=args.estimator, start_timeout=args.start_timeout,
            lost_timeout=args.lost_timeout, map_out=args.map_out,
        )  # fmt: skip
    except (ConfigError, ValueError, OSError) as exc:
        print(f"swarmloc server: {exc}", file=sys.stderr)
        return 2
    return 0


def cmd_team(args: argparse.Namespace) -> int:
    from swarmloc.config import ConfigError
    from swarmloc.experiments.association import with_association
    from swarmloc.experiments.evaluate import markdown_table
    from swarmloc.experiments.progress import progress_bar
    from swarmloc.experiments.sources import load_source
    from swarmloc.experiments.team import run_team, write_team_report

    _net_logging(args.verbose)
    import signal

    def _terminate(*_: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _terminate)  # so that `kill` and time limits also stop every process started
    view, ran = None, False
    try:
        _check_view(args)
        config = run_config(args) if args.config else None
        src = load_source(args.source, robots=args.robots, duration=args.duration, seed=args.seed, config=config)
        src = with_association(src, args.association)
        if args.view is not None or args.record:
            view = _open_view(args, src, src.events, "swarmloc team")
        with progress_bar(not args.quiet) as start:
            run = run_team(
                src=src, robots=args.robots, source=args.source, estimator=args.estimator, duration=args.duration,
                seed=args.seed, config_file=args.config, server=args.server, faults=args.faults, speed=args.speed,
                lag=args.lag, max_wall=args.max_wall, ros_domain=args.ros_domain, log_dir=f"{args.out}/logs",
                association=src.config.filter.association,
                team=args.team, verbose=args.verbose, connect_extra=_endpoints(args.connect), view=view,
                progress=start(f"team {args.source}, {args.estimator}: beliefs") if start is not None else None,
                **_timeouts(args),
            )  # fmt: skip
        if view is not None:
            view.end_recording()
        extra = {"faults": args.faults or "", "exit_codes": run.exit_codes}
        report = write_team_report(run, src, args.estimator, args.out, extra)
        if run.map is not None:
            from swarmloc.net.server import linemap_of

            linemap_of(run.map).save_geojson(f"{args.out}/map.geojson")
        if args.bag:
            from swarmloc.net.ros import BagWriter

            with BagWriter(args.bag) as bag:
                for (r, t), b in sorted(run.beliefs.items()):
                    import numpy as np

                    bag.write(f"/swarmloc/robot{r}/pose", t, np.reshape(b.mean, (3, 3)), np.reshape(b.cov, (3, 3)))
        ran = True
    except (ConfigError, ValueError, OSError, RuntimeError) as exc:
        print(f"swarmloc team: {exc}", file=sys.stderr)
        return 2
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
        _linger(view, args)
    bad = {n: c for n, c in run.exit_codes.items() if c not in (0, -15, None) and not n == "server"}
    return 1 if bad or run.counts.get("timed_out") else 0


def cmd_keys(args: argparse.Namespace) -> int:
    import base64

    from swarmloc.net import auth

    try:
        if args.keys_command == "new":
            public = auth.new_key(args.file)
            b64 = base64.b64encode(public).decode()
            print(f"private key {args.file} (mode 0600); public key {args.file}.pub: {b64}")
        elif args.keys_command == "roster":
            members = dict(m.split("=", 1) for m in args.members if "=" in m)
            if len(members) != len(args.members):
                raise ValueError("members are MEMBER=KEY: 0=robot0.key.pub, server=server.key.pub ...")
            keys = {auth.member_id(k.strip()): auth.public_key(v) for k, v in members.items()}
            r = auth.Roster(keys, args.max_age)
            r.save(args.out)
            print(f"roster {args.out}: robots {r.robots}" + ", server" * (-1 in keys) + ", collector" * (-2 in keys))
        else:
            roster, files = auth.make_team_keys(args.out, _ids(args.robots) or [], args.max_age)
            print(f"keys of robots {args.robots}, the server and the collector in {args.out}/; roster {roster}")
    except (ValueError, OSError) as exc:
        print(f"swarmloc keys: {exc}", file=sys.stderr)
        return 2
    return 0


def _timeouts(args: argparse.Namespace) -> dict[str, float]:
    """The node's waits [s] and its ``answer_retries`` (a count) from the command line."""
    from swarmloc.net.timeouts import TIMEOUTS

    return {**{name: getattr(args, name) for name in TIMEOUTS}, "answer_retries": args.answer_retries}
