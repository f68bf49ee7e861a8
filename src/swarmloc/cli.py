"""Command line: ``swarmloc demo | reproduce | evaluate | simulate | config | compare | node | server | team | keys``.

Every command writes its results (Markdown, JSON, PNG, TUM) to an output folder and prints a short summary; errors in
the input (a missing dataset file, a malformed line, an unknown estimator, a bad configuration) are reported in
one line (or one line per bad record) with exit status 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from swarmloc import __version__

EST_DEFAULT = "dr,dekf,cekf,expfusion,ci,rdl"


def _demo(args: argparse.Namespace) -> int:
    from swarmloc.experiments.thesis_static import run_demo

    t = time.perf_counter()
    run_demo(Path(args.out), seed=args.seed, progress=not args.quiet)
    print(f"demo written to {args.out}/ in {time.perf_counter() - t:.1f} s")
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    if args.what == "tables":
        from swarmloc.experiments.thesis_static.pooled import pooled_tables

        try:
            reps = 20_000 if args.reps is None else args.reps
            res = pooled_tables(args.out, seeds=args.seeds, reps=reps, first_seed=args.first_seed)
        except ValueError as exc:
            print(f"swarmloc reproduce tables: {exc}", file=sys.stderr)
            return 2
        print((Path(args.out) / "pooled.md").read_text())
        print(f"written to {args.out}/pooled.md and pooled.json in {res['runtime_s']:.0f} s")
        return 0
    if args.what != "thesis":
        print(f"swarmloc reproduce: unknown target {args.what!r} ('thesis' or 'tables')", file=sys.stderr)
        return 2
    from swarmloc.experiments.thesis_dynamic import run_dynamic
    from swarmloc.experiments.thesis_static import run_demo, run_tables

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    progress = not args.quiet
    report = {
        "demo": run_demo(out / "demo", seed=0, progress=progress),
        "tables": run_tables(out / "tables", reps=5 if args.quick else args.reps or 60, progress=progress),
        "dynamic": run_dynamic(out / "dynamic", seeds=args.seeds, progress=progress, quick=args.quick),
    }
    report["wall_time_s"] = time.perf_counter() - t
    from swarmloc.experiments.evaluate import json_default

    (out / "thesis.json").write_text(json.dumps(report, indent=2, default=json_default))
    parts = ["# Reproducing the thesis (swarmloc)", ""]
    for sub, name in (("demo", "demo.md"), ("tables", "tables.md"), ("dynamic", "dynamic.md")):
        f = out / sub / name
        if f.exists():
            parts += [f.read_text(), ""]
    parts.append(f"Total wall time: {report['wall_time_s']:.0f} s")
    (out / "thesis.md").write_text("\n".join(parts))
    print(f"thesis reproduction written to {out}/thesis.md and thesis.json in {report['wall_time_s']:.0f} s")
    return 0


def _config(args: argparse.Namespace):  # noqa: ANN202
    from swarmloc.config import DEFAULTS, load_config

    return load_config(args.config) if args.config else DEFAULTS


def _with_gate(config, gate: float | None):  # noqa: ANN001, ANN202
    """``--gate`` overrides the configuration's gate (0 disables it)."""
    if gate is None:
        return config
    import dataclasses

    return dataclasses.replace(config, filter=dataclasses.replace(config.filter, gate=None if gate <= 0 else gate))


ASSOCIATION_CHOICES = ("tags", "nearest", "joint", "anonymous")
ASSOCIATION_HELP = (
    "robot detections' identities: tags (given); nearest, joint (robot ids hidden, chosen from the beliefs by every "
    "estimator; dr fuses no detection); anonymous (ids hidden, PMR + particle-filter bank per robot hands tagged "
    "relative poses to any estimator; range-bearing detections)"
)


def _with_association(config, association: str | None):  # noqa: ANN001, ANN202
    """``--association`` overrides the configuration's ``[filter] association``."""
    if association is None:
        return config
    import dataclasses

    return dataclasses.replace(config, filter=dataclasses.replace(config.filter, association=association))


def _evaluate(args: argparse.Namespace) -> int:
    from swarmloc.config import ConfigError
    from swarmloc.datasets.eventfile import EventFileError
    from swarmloc.datasets.mrclam import MRCLAMError
    from swarmloc.datasets.tum import TUMError
    from swarmloc.experiments.evaluate import markdown_table

    where = f"swarmloc evaluate {args.what}"
    names = [e.strip() for e in args.estimators.split(",") if e.strip()]
    try:
        config = _with_association(_with_gate(_config(args), args.gate), args.association)
        progress = not (args.quiet or args.json)
        if args.what == "mrclam":
            from swarmloc.experiments.mrclam import evaluate_mrclam

            report = evaluate_mrclam(
                args.path, estimators=names, landmarks=args.landmarks == "on", duration=args.duration,
                out_dir=args.out, config=config, progress=progress,
            )  # fmt: skip
        elif args.what == "events":
            from swarmloc.experiments.own_robots import evaluate_event_file

            report = evaluate_event_file(
                args.path, estimators=names, truth_dir=args.truth, config=config, out_dir=args.out,
                progress=progress, strict=not args.skip_bad_lines,
            )  # fmt: skip
            for problem in report["problems"]:
                print(f"skipped: {problem}", file=sys.stderr)
            if report["n_bad"]:
                n = report["n_bad"]
                print(f"{where}: skipped {n} bad line{'s' if n != 1 else ''} in all", file=sys.stderr)
        else:
            print(f"swarmloc evaluate: unknown kind {args.what!r} (use 'mrclam' or 'events')", file=sys.stderr)
            return 2
    except (MRCLAMError, EventFileError, TUMError, ConfigError, ValueError, OSError) as exc:
        print(f"{where}: {exc}", file=sys.stderr)
        return 2
    if args.json:
        from swarmloc.experiments.evaluate import json_default

        print(json.dumps(report, indent=2, default=json_default))
    else:
        print(markdown_table(report))
        if args.out:
            print(f"results, figures and TUM trajectories in {args.out}/")
    return 0


def _simulate(args: argparse.Namespace) -> int:
    from swarmloc.experiments.own_robots import simulate_to_files

    if args.robots < 1 or args.duration <= 0:
        print("swarmloc simulate: --robots must be >= 1 and --duration > 0", file=sys.stderr)
        return 2
    try:
        paths = simulate_to_files(args.out, robots=args.robots, duration=args.duration, seed=args.seed,
                                  fmt=args.format)  # fmt: skip
    except (ValueError, OSError) as exc:
        print(f"swarmloc simulate: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {paths['events']}, {len(paths) - 2} truth_robot*.tum files and {paths['config']}")
    return 0


def _config_cmd(args: argparse.Namespace) -> int:
    from swarmloc.config import DEFAULTS, ConfigError, load_config

    if args.check:
        try:
            cfg = load_config(args.check)
        except ConfigError as exc:
            print(f"swarmloc config: {exc}", file=sys.stderr)
            return 2
        print(cfg.to_toml(), end="")
        return 0
    if args.defaults:
        print(DEFAULTS.to_toml(), end="")
        return 0
    print("swarmloc config: say --defaults (print every default) or --check FILE", file=sys.stderr)
    return 2


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
        print("warning: --no-auth: any process on the network can speak in any member's name", file=sys.stderr)
        return None
    if not (args.key and args.roster):
        raise ValueError("give this process's --key FILE and the team's --roster FILE (make them with "
                         "'swarmloc keys'), or --no-auth on a trusted network")  # fmt: skip
    return Auth.load(args.key, args.roster, member)


def _die_with_launcher(args: argparse.Namespace) -> None:
    if args.parent_pid is not None:  # first thing: a launcher killed meanwhile must not leave this process running
        from swarmloc.net.lifeline import die_with_parent

        die_with_parent(args.parent_pid)


def _node(args: argparse.Namespace) -> int:
    _die_with_launcher(args)
    from swarmloc.config import ConfigError
    from swarmloc.experiments.association import with_association
    from swarmloc.experiments.sources import load_source
    from swarmloc.live.source import live_inputs, split_live
    from swarmloc.net.entry import node_main
    from swarmloc.net.transport import team_scope

    _net_logging(args.verbose)
    view = None
    try:
        team_scope(args.team, args.run_id)  # a bad name or run id is refused before the source is loaded
        auth = _auth(args, args.robot)
        config = _config(args) if args.config else None
        live_kind, spec = split_live(args.source)
        src = load_source(spec, robots=args.robots, duration=args.duration, seed=args.seed, config=config)
        src = with_association(src, args.association)
        live = None
        if live_kind is not None:
            live = live_inputs(live_kind, team=args.team, run_id=args.run_id, domain=args.ros_domain or 0)
        view = _node_view(args, src)
        report = node_main(
            src=src, robot=args.robot, team=args.team, estimator=args.estimator, speed=args.speed, lag=args.lag,
            listen=_endpoints(args.listen), connect=_endpoints(args.connect), zenoh_config=args.zenoh_config,
            use_server=args.use_server, resume=args.resume, faults=args.faults, wait_for=_ids(args.wait_for),
            ros_domain=args.ros_domain, max_wall=args.max_wall, out=args.out, run_id=args.run_id, auth=auth,
            live=live, view=view, **_timeouts(args),
        )  # fmt: skip
    except (ConfigError, ValueError, OSError, RuntimeError) as exc:
        print(f"swarmloc node: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    finally:
        if view is not None:
            view.close()
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


def _node_view(args: argparse.Namespace, src: Any) -> Any:
    """``node --view/--record``: a :class:`~swarmloc.net.view.TeamView` of this robot (its beliefs, detections, ground
    truth where the source has it, its lines and the belief server's map), or None."""
    if args.view is None and not args.record:
        return None
    from swarmloc.events import Detection
    from swarmloc.net.view import TeamView

    dets = [e for e in src.own_events(args.robot) if isinstance(e, Detection) and e.observer == args.robot]
    view = TeamView(port=args.view, mcap=args.record, truth=src.truth, detections=dets, roster=src.robots,
                    name=f"swarmloc node {args.robot}")  # fmt: skip
    if view.url:
        print(f"live view: open {view.url} in Foxglove (Open connection > Foxglove WebSocket)", flush=True)
    return view


def _server(args: argparse.Namespace) -> int:
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
            config = _config(args) if args.config else None
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


def _team(args: argparse.Namespace) -> int:
    from swarmloc.config import ConfigError
    from swarmloc.experiments.association import with_association
    from swarmloc.experiments.evaluate import markdown_table
    from swarmloc.experiments.sources import load_source
    from swarmloc.experiments.team import run_team, write_team_report

    _net_logging(args.verbose)
    import signal

    def _terminate(*_: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _terminate)  # so that `kill` and time limits also stop every process started
    view = None
    try:
        config = _config(args) if args.config else None
        src = load_source(args.source, robots=args.robots, duration=args.duration, seed=args.seed, config=config)
        src = with_association(src, args.association)
        if args.view is not None or args.record:
            from swarmloc.net.view import TeamView

            view = TeamView(port=args.view, mcap=args.record, truth=src.truth, detections=src.events,
                            roster=src.robots)  # fmt: skip
            if view.url:
                print(f"live view: open {view.url} in Foxglove (Open connection > Foxglove WebSocket)", flush=True)
        run = run_team(
            src=src, robots=args.robots, source=args.source, estimator=args.estimator, duration=args.duration,
            seed=args.seed, config_file=args.config, server=args.server, faults=args.faults, speed=args.speed,
            lag=args.lag, max_wall=args.max_wall, ros_domain=args.ros_domain, log_dir=f"{args.out}/logs",
            association=src.config.filter.association,
            team=args.team, verbose=args.verbose, connect_extra=_endpoints(args.connect), view=view,
            **_timeouts(args),
        )  # fmt: skip
        if view is not None:
            view.close()
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
    except (ConfigError, ValueError, OSError, RuntimeError) as exc:
        print(f"swarmloc team: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("swarmloc team: interrupted; every process it started was stopped", file=sys.stderr)
        return 130
    finally:
        if view is not None:
            view.close()
    print(markdown_table(report))
    print(f"results, figures and TUM trajectories in {args.out}/" + (f"; rosbag2 in {args.bag}" if args.bag else ""))
    bad = {n: c for n, c in run.exit_codes.items() if c not in (0, -15, None) and not n == "server"}
    return 1 if bad or run.counts.get("timed_out") else 0


def _compare(args: argparse.Namespace) -> int:
    from swarmloc.experiments.compare import compare, compare_table

    names = [e.strip() for e in args.estimators.split(",") if e.strip()]
    try:
        summary = compare(args.scenario, names, runs=args.runs, robots=args.robots, duration=args.duration,
                          out_dir=args.out, jobs=args.jobs, progress=not args.quiet, association=args.association,
                          clutter=args.clutter, p_detect=args.p_detect)  # fmt: skip
    except (ValueError, OSError) as exc:
        print(f"swarmloc compare: {exc}", file=sys.stderr)
        return 2
    print(compare_table(summary))
    if args.out:
        print(f"written to {args.out}/compare.md and compare.json")
    return 0


def _net_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--team", required=True, help="team name (letters, digits, '-', '_'): part of every key")
    p.add_argument("--listen", default=None, help="this peer's Zenoh endpoints, comma-separated (tcp/HOST:PORT)")
    p.add_argument("--connect", default=None, help="the other peers' endpoints, comma-separated")
    p.add_argument("--zenoh-config", default=None, help="a Zenoh JSON5 configuration file (TLS, access control)")
    p.add_argument("--max-wall", type=float, default=None, help="stop after this many wall-clock seconds")
    p.add_argument("--verbose", action="store_true", help="log the node's state every 2 s")
    p.add_argument("--run-id", default=None, help="this run's id, in every key with the team's name (swarmloc team "
                   "gives each run its own, so that two teams of one name never hear each other)")  # fmt: skip
    p.add_argument("--parent-pid", type=int, default=None,
                   help="stop when this process (the launcher that started this one) is gone")  # fmt: skip


def _auth_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--key", default=None, help="this process's private key file (swarmloc keys new)")
    p.add_argument("--roster", default=None, help="the team's roster file: member ids and public keys")
    p.add_argument("--no-auth", action="store_true", help="send unsigned, accept unsigned (a trusted network only)")


def _keys(args: argparse.Namespace) -> int:
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


def _keys_parser(sub: argparse._SubParsersAction) -> None:
    k = sub.add_parser("keys", help="make Ed25519 key pairs and the team's roster (authenticated senders)")
    ks = k.add_subparsers(dest="keys_command", required=True)
    n = ks.add_parser("new", help="a key pair: FILE (private, mode 0600) and FILE.pub (public, base64)")
    n.add_argument("file")
    r = ks.add_parser("roster", help="a roster from the members' public keys: 0=robot0.key.pub server=... ")
    r.add_argument("members", nargs="+", help="MEMBER=KEY: a robot id, 'server' or 'collector' = a .pub file, "
                   "a private key file or base64")  # fmt: skip
    r.add_argument("--out", required=True, help="the roster file to write")
    t = ks.add_parser("team", help="every key of a team and its roster in one folder (for one trusted machine)")
    t.add_argument("--robots", required=True, help="robot ids, comma-separated")
    t.add_argument("--out", required=True, help="folder for robot<id>.key, server.key, collector.key, roster.json")
    for p in (r, t):
        p.add_argument("--max-age", type=float, default=30.0, help="seconds a signed stamp may be old (default 30)")
    k.set_defaults(func=_keys)


def _timeout_args(p: argparse.ArgumentParser) -> None:
    from swarmloc.net.timeouts import TIMEOUTS

    for name, (default, meaning) in TIMEOUTS.items():
        p.add_argument(
            f"--{name.replace('_', '-')}", type=float, default=default, help=f"{meaning} (default {default:g})"
        )


def _timeouts(args: argparse.Namespace) -> dict[str, float]:
    from swarmloc.net.timeouts import TIMEOUTS

    return {name: getattr(args, name) for name in TIMEOUTS}


def _source_args(p: argparse.ArgumentParser, default: str | None) -> None:
    p.add_argument("--source", default=default, required=default is None,
                   help="sim:SCENARIO (random, range_bearing), mrclam:PATH or events:PATH; swarmloc node also "
                        "zenoh:SPEC or ros2:SPEC (inputs live, the team from SPEC)")  # fmt: skip
    p.add_argument(
        "--estimator",
        default="expfusion",
        help="a distributed estimator (expfusion, dekf, ci, rdl, "
        "irdl, diekf) or a centralized one the belief server hosts (cekf, iekf, fej)",
    )
    p.add_argument("--config", default=None, help="TOML file of model and filter settings")
    p.add_argument("--robots", type=int, default=3, help="sim: team size (default 3)")
    p.add_argument("--duration", type=float, default=None, help="seconds of the source (sim default 30)")
    p.add_argument("--seed", type=int, default=0, help="sim: seed")
    p.add_argument("--speed", type=float, default=0.0, help="x real time; 0: as fast as lockstep allows")
    p.add_argument("--lag", type=float, default=0.5, help="lockstep slack in seconds of data time")
    p.add_argument("--faults", default=None, help="loss=P,delay=S,reorder=P,dup=P,kill=R@T,late=R@T,seed=N")
    p.add_argument("--ros-domain", type=int, default=None, help="also publish ROS 2 poses (rmw_zenoh, this domain)")
    p.add_argument("--association", choices=ASSOCIATION_CHOICES, default=None,
                   help=ASSOCIATION_HELP + " (default: the configuration's [filter] association)")  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="swarmloc", description="Multi-robot cooperative localization on SE(2)/SE(3).")
    p.add_argument("--version", action="version", version=f"swarmloc {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("demo", help="thesis sec. 5.1: a team of 4, prior vs fused posterior, figures")
    d.add_argument("--out", default="swarmloc-demo", help="output folder (default: swarmloc-demo)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=_demo)

    r = sub.add_parser(
        "reproduce",
        help="reproduce a study: 'thesis' (chapter 5 and Table 6.1) or 'tables' (Tables 5.1/5.2 over many seeds)",
    )
    r.add_argument("what", help="thesis | tables")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--seeds", type=int, default=20, help="seeds per dynamic experiment, or pooled seeds (default 20)")
    r.add_argument(
        "--reps", type=int, default=None, help="repetitions for Tables 5.1/5.2 (60; with 'tables': per seed, 20000)"
    )
    r.add_argument("--first-seed", type=int, default=100, help="tables: first of the pooled seeds (default 100)")
    r.add_argument("--quick", action="store_true", help="few seeds and short runs (a smoke test)")
    r.add_argument("--quiet", action="store_true", help="no progress bars")
    r.set_defaults(func=_reproduce)

    e = sub.add_parser("evaluate", help="evaluate estimators on data: 'mrclam FOLDER' or 'events FILE'")
    e.add_argument("what", choices=["mrclam", "events"], help="mrclam (a UTIAS MRCLAM folder) or events (your file)")
    e.add_argument("path", help="an MRCLAM_DatasetN folder, or an event file (.csv or .jsonl)")
    e.add_argument("--estimators", default=EST_DEFAULT, help=f"comma-separated names (default {EST_DEFAULT})")
    e.add_argument("--config", default=None, help="TOML file of model and filter settings (swarmloc config)")
    e.add_argument("--gate", type=float, default=None, help="override the chi-square gate probability; 0 disables")
    e.add_argument("--landmarks", choices=["on", "off"], default="on", help="mrclam: use landmark measurements")
    e.add_argument("--association", choices=ASSOCIATION_CHOICES, default=None,
                   help=ASSOCIATION_HELP + " (default: the configuration's [filter] association)")  # fmt: skip
    e.add_argument("--duration", type=float, default=None, help="mrclam: seconds from the start (default: all)")
    e.add_argument("--truth", default=None, help="events: folder of truth_robot<N>.tum (default: beside the file)")
    e.add_argument("--skip-bad-lines", action="store_true", help="events: skip bad records (listed) instead of stop")
    e.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    e.add_argument("--out", default=None, help="output folder for JSON, Markdown, figures, TUM files")
    e.add_argument("--quiet", action="store_true", help="no progress bar")
    e.set_defaults(func=_evaluate)

    s = sub.add_parser("simulate", help="simulate a random team and write it as an event file + TUM truth")
    s.add_argument("--robots", type=int, default=4)
    s.add_argument("--duration", type=float, default=60.0, help="seconds (default 60)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--format", choices=["csv", "jsonl"], default="csv")
    s.add_argument("--out", required=True, help="output folder")
    s.set_defaults(func=_simulate)

    c = sub.add_parser("config", help="print the default configuration, or check a TOML file")
    c.add_argument("--defaults", action="store_true", help="print every default as TOML")
    c.add_argument("--check", metavar="FILE", help="read FILE and print the full configuration it gives")
    c.set_defaults(func=_config_cmd)

    n = sub.add_parser("node", help="run one robot of a team as a Zenoh peer (one process per robot)")
    n.add_argument("--robot", type=int, required=True, help="this robot's id in the source")
    _net_args(n)
    _source_args(n, None)
    n.add_argument("--use-server", action="store_true", help="ask the belief server when a neighbour is silent")
    n.add_argument("--resume", action="store_true", help="start from this robot's latest belief on the server")
    n.add_argument("--wait-for", default=None, help="robot ids to wait for before starting (default: the team)")
    _timeout_args(n)
    n.add_argument("--out", default=None, help="folder for robot<N>.tum (final beliefs) and robot<N>.json (report)")
    n.add_argument("--view", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                   help="live view of this robot (and the server's map) for Foxglove on ws://127.0.0.1:PORT "
                   "(default 8765; 0: a free port)")  # fmt: skip
    n.add_argument("--record", default=None, metavar="FILE.mcap", help="record the view as MCAP (Foxglove, ROS 2)")
    _auth_args(n)
    n.set_defaults(func=_node)

    sv = sub.add_parser("server", help="run the belief server of a team (stores every robot's Gaussian)")
    _net_args(sv)
    sv.add_argument("--robots", default=None, help="the team's robot ids, comma-separated (default: the roster's)")
    sv.add_argument(
        "--estimator",
        default=None,
        help="host a centralized estimator (cekf, iekf, fej) fed by the "
        "robots' forwarded measurements ('swarmloc node --estimator' the same on every robot)",
    )
    sv.add_argument(
        "--source",
        default=None,
        help="with --estimator: the team's source (initial beliefs, landmarks, "
        "configuration, record times; its events come from the robots)",
    )
    sv.add_argument("--config", default=None, help="with --estimator: TOML file of model and filter settings")
    sv.add_argument("--duration", type=float, default=None, help="with --estimator: seconds of the source")
    sv.add_argument("--seed", type=int, default=0, help="with --estimator, sim: seed")
    sv.add_argument("--association", choices=ASSOCIATION_CHOICES, default=None,
                    help="with --estimator: " + ASSOCIATION_HELP)  # fmt: skip
    sv.add_argument(
        "--start-timeout",
        type=float,
        default=30.0,
        help="with --estimator: seconds it waits for every robot's first forward (default 30)",
    )
    sv.add_argument(
        "--lost-timeout",
        type=float,
        default=10.0,
        help="with --estimator: seconds a robot's stream may "
        "stay silent while the fusion waits on it before it is declared lost (default 10)",
    )
    sv.add_argument("--map-out", default=None, help="save the fused line map there as GeoJSON when it stops")
    _auth_args(sv)
    sv.set_defaults(func=_server)
    _keys_parser(sub)

    cp = sub.add_parser("compare", help="every estimator on identical events: one table (sim scenario or dataset)")
    cp.add_argument("--scenario", default="sim:random", help="sim:random, sim:range_bearing, mrclam:PATH, events:PATH")
    cp.add_argument("--estimators", default=EST_DEFAULT, help=f"comma-separated names (default {EST_DEFAULT})")
    cp.add_argument("--runs", type=int, default=1, help="seeds of a simulated scenario (default 1)")
    cp.add_argument("--robots", type=int, default=4, help="sim: team size (default 4)")
    cp.add_argument("--duration", type=float, default=None, help="seconds (sim default 30; dataset: all)")
    cp.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    cp.add_argument("--out", default=None, help="output folder for compare.md / compare.json")
    cp.add_argument("--association", choices=ASSOCIATION_CHOICES, default="tags", help=ASSOCIATION_HELP)
    cp.add_argument("--clutter", type=float, default=0.0, help="false robot detections per scan, Poisson (default 0)")
    cp.add_argument("--p-detect", type=float, default=1.0, help="robot detection probability (default 1)")
    cp.add_argument("--quiet", action="store_true", help="no progress bar")
    cp.set_defaults(func=_compare)

    def _consistency(args: argparse.Namespace) -> int:
        from swarmloc.experiments.consistency import run_command

        return run_command(args)

    cs = sub.add_parser(
        "consistency",
        help="Monte Carlo ANEES per estimator vs the 95%% chi-square band, a simulated team without and with "
        "landmarks: table, JSON and NEES-over-time figure",
    )
    cs.add_argument("--estimators", default=None, help="comma-separated names (default: all registered but mcl, dr)")
    cs.add_argument("--seeds", type=int, default=50, help="independent simulated teams (default 50)")
    cs.add_argument("--robots", type=int, default=5, help="team size (default 5)")
    cs.add_argument("--duration", type=float, default=60.0, help="seconds per run (default 60)")
    cs.add_argument("--landmarks", default="off,on", help="off, on or off,on (default off,on)")
    cs.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    cs.add_argument("--out", default=None, help="output folder for consistency.md / .json / .png")
    cs.add_argument("--json", action="store_true", help="print the summary as JSON instead of the table")
    cs.add_argument("--quiet", action="store_true", help="no progress bar")
    cs.set_defaults(func=_consistency)

    def _bench(args: argparse.Namespace) -> int:
        from swarmloc.experiments.bench import run_command

        return run_command(args)

    from swarmloc.experiments.bench import add_arguments as _bench_arguments

    bp = sub.add_parser(
        "bench",
        help="speed on this machine: fusion step (engine vs filterpy), memory and FLOP fractions, swarms of 100 to "
        "10,000 robots, MRCLAM replay x real time",
    )
    _bench_arguments(bp)
    bp.set_defaults(func=_bench)

    def _map(args: argparse.Namespace) -> int:
        from swarmloc.experiments.mapping import run_command

        return run_command(args)

    mp = sub.add_parser(
        "map",
        help="the chapter's map-building experiment (robots H1, H2): line maps by dead reckoning, each robot alone "
        "and the cooperative team, their error against the true walls; table, figure, GeoJSON/DXF",
    )
    mp.add_argument("--seeds", type=int, default=3, help="simulated runs (default 3)")
    mp.add_argument("--first-seed", type=int, default=0, help="first seed (default 0)")
    mp.add_argument("--estimators", default="expfusion,diekf", help="cooperative estimators (default expfusion,diekf)")
    mp.add_argument("--order", type=int, choices=[1, 2], default=2, help="line propagation order (default 2)")
    mp.add_argument("--sigma", type=float, default=0.01, help="range noise std [m] (default 0.01)")
    mp.add_argument("--D", type=float, default=0.005, help="wheel-speed diffusion [rad^2/s] (default 0.005)")
    mp.add_argument("--out", default=None, help="folder for map.md, map.json, map.png, GeoJSON and DXF maps")
    mp.set_defaults(func=_map)

    t = sub.add_parser("team", help="start a live team on this machine (127.0.0.1), collect and score it")
    _source_args(t, "sim:random")
    t.add_argument("--server", action="store_true", help="also start the belief server")
    t.add_argument("--view", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                   help="live view for Foxglove on ws://127.0.0.1:PORT (default 8765; 0: a free port)")  # fmt: skip
    t.add_argument("--record", default=None, metavar="FILE.mcap", help="record the view as MCAP (Foxglove, ROS 2)")
    t.add_argument("--team", default=None, help="the team's name (default team<PID>); each run also has an id of its "
                   "own in every key, so that two teams of one name never hear each other")  # fmt: skip
    _timeout_args(t)
    t.add_argument("--connect", default=None, help="endpoints every process also connects to (a Zenoh router)")
    t.add_argument("--bag", default=None, help="record the beliefs as a rosbag2 (folder to create)")
    t.add_argument("--max-wall", "--timeout", dest="max_wall", type=float, default=600.0,
                   help="stop every process after this many wall-clock seconds (default 600)")  # fmt: skip
    t.add_argument("--out", required=True, help="output folder (report, figures, TUM files, logs)")
    t.add_argument("--verbose", action="store_true", help="nodes log their state every 2 s (in OUT/logs)")
    t.set_defaults(func=_team)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())
