"""The ``swarmloc`` argument parser: every command, its options and its help, each bound to its function."""

from __future__ import annotations

import argparse
import math

from swarmloc import __version__
from swarmloc.cli.data import add_parser as add_data_parser
from swarmloc.cli.network import cmd_keys, cmd_node, cmd_server, cmd_team
from swarmloc.cli.offline import (
    ASSOCIATION_CHOICES,
    ASSOCIATION_HELP,
    EST_DEFAULT,
    cmd_compare,
    cmd_config,
    cmd_demo,
    cmd_evaluate,
    cmd_reproduce,
    cmd_simulate,
)

NET_DEFAULT = "diekf"
"""The estimator ``team`` and ``node`` run by default: the recommended distributed filter."""


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
    k.set_defaults(func=cmd_keys)


def _view_args(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--view", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                   help=f"live view {what} for Foxglove or Lichtblick (Foxglove WebSocket) on ws://127.0.0.1:PORT "
                   "(default 8765; 0: a free port)")  # fmt: skip
    p.add_argument("--record", default=None, metavar="FILE.mcap",
                   help="record the view as MCAP of ROS 2 messages (Foxglove, Lichtblick, ros2 bag play)")  # fmt: skip
    p.add_argument("--linger", type=float, nargs="?", const=math.inf, default=None, metavar="SECONDS",
                   help="keep the live view up after the run ends: SECONDS, or until Ctrl-C without a number; 0: "
                   "stop with the run (default: until Ctrl-C when run from a terminal, else 0)")  # fmt: skip


def _timeout_args(p: argparse.ArgumentParser) -> None:
    from swarmloc.net.timeouts import ANSWER_RETRIES, TIMEOUTS

    for name, (default, meaning) in TIMEOUTS.items():
        p.add_argument(
            f"--{name.replace('_', '-')}", type=float, default=default, help=f"{meaning} (default {default:g})"
        )
    p.add_argument("--answer-retries", type=int, default=ANSWER_RETRIES,
                   help="how many more times a node asks a query that went unanswered, while its robot is alive "
                        f"(default {ANSWER_RETRIES}); more while within the lost timeout of the first ask")  # fmt: skip


def _source_args(p: argparse.ArgumentParser, default: str | None) -> None:
    p.add_argument("--source", default=default, required=default is None,
                   help="sim:SCENARIO (random, range_bearing), mrclam:PATH or events:PATH; swarmloc node also "
                        "zenoh:SPEC or ros2:SPEC (inputs live, the team from SPEC)")  # fmt: skip
    p.add_argument("--estimator", default=NET_DEFAULT,
                   help=f"a distributed estimator (diekf, expfusion, dekf, ci, rdl, irdl) or a centralized one the "
                        f"belief server hosts (cekf, iekf, fej); default {NET_DEFAULT}, the recommended distributed "
                        "filter")  # fmt: skip
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
    d.set_defaults(func=cmd_demo)

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
    r.set_defaults(func=cmd_reproduce)

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
    e.add_argument("--calibrate-yaw", action="store_true",
                   help="mrclam: yaw diffusion scaled as the recording's landmark snapshots say")  # fmt: skip
    e.add_argument("--engine", action="store_true",
                   help="mrclam: dekf, cekf, iekf, rdl, diekf by the engine's compiled replays (numba)")  # fmt: skip
    e.add_argument("--truth", default=None, help="events: folder of truth_robot<N>.tum (default: beside the file)")
    e.add_argument("--skip-bad-lines", action="store_true", help="events: skip bad records (listed) instead of stop")
    e.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    e.add_argument("--out", default=None, help="output folder for JSON, Markdown, figures, TUM files")
    e.add_argument("--quiet", action="store_true", help="no progress bar")
    e.set_defaults(func=cmd_evaluate)

    s = sub.add_parser("simulate", help="simulate a random team and write it as an event file + TUM truth")
    s.add_argument("--robots", type=int, default=4)
    s.add_argument("--duration", type=float, default=60.0, help="seconds (default 60)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--format", choices=["csv", "jsonl"], default="csv")
    s.add_argument("--out", required=True, help="output folder")
    s.set_defaults(func=cmd_simulate)

    c = sub.add_parser("config", help="print the default configuration, or check a TOML file")
    c.add_argument("--defaults", action="store_true", help="print every default as TOML")
    c.add_argument("--check", metavar="FILE", help="read FILE and print the full configuration it gives")
    c.set_defaults(func=cmd_config)

    n = sub.add_parser("node", help="run one robot of a team as a Zenoh peer (one process per robot)")
    n.add_argument("--robot", type=int, required=True, help="this robot's id in the source")
    _net_args(n)
    _source_args(n, None)
    n.add_argument("--use-server", action="store_true", help="ask the belief server when a neighbour is silent")
    n.add_argument("--resume", action="store_true", help="start from this robot's latest belief on the server")
    n.add_argument("--wait-for", default=None, help="robot ids to wait for before starting (default: the team)")
    n.add_argument("--input-listen", default=None,
                   help="ros2: the loopback endpoints the robot's ROS 2 publishers connect to, comma-separated "
                        "(default tcp/127.0.0.1:7448; only this host can reach them)")  # fmt: skip
    n.add_argument("--input-connect", default=None,
                   help="ros2: loopback endpoints to connect the input session to (a local rmw_zenoh router "
                        "listening on loopback only)")  # fmt: skip
    _timeout_args(n)
    n.add_argument("--out", default=None, help="folder for robot<N>.tum (final beliefs) and robot<N>.json (report)")
    _view_args(n, "of this robot (and the server's map)")
    _auth_args(n)
    n.set_defaults(func=cmd_node)

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
    sv.set_defaults(func=cmd_server)
    _keys_parser(sub)

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
    cp.add_argument("--duration", type=float, default=None, help="seconds (sim default 30; dataset: all)")
    cp.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    cp.add_argument("--out", default=None, help="output folder for compare.md / compare.json")
    cp.add_argument("--association", choices=ASSOCIATION_CHOICES, default="tags", help=ASSOCIATION_HELP)
    cp.add_argument("--clutter", type=float, default=0.0, help="false robot detections per scan, Poisson (default 0)")
    cp.add_argument("--p-detect", type=float, default=1.0, help="robot detection probability (default 1)")
    cp.add_argument("--quiet", action="store_true", help="no progress bar")
    cp.set_defaults(func=cmd_compare)

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
    mp.add_argument("--quiet", action="store_true", help="no progress bar")
    mp.set_defaults(func=_map)

    from swarmloc.cli import ros

    ros.add_parser(sub)
    t = sub.add_parser("team", help="start a live team on this machine (127.0.0.1), collect and score it")
    _source_args(t, "sim:random")
    t.add_argument("--server", action="store_true", help="also start the belief server")
    _view_args(t, "of the team")
    t.add_argument("--team", default=None, help="the team's name (default team<PID>); each run also has an id of its "
                   "own in every key, so that two teams of one name never hear each other")  # fmt: skip
    _timeout_args(t)
    t.add_argument("--connect", default=None, help="endpoints every process also connects to (a Zenoh router)")
    t.add_argument("--bag", default=None, help="record the beliefs as a rosbag2 (folder to create)")
    t.add_argument("--max-wall", "--timeout", dest="max_wall", type=float, default=600.0,
                   help="stop every process after this many wall-clock seconds (default 600)")  # fmt: skip
    t.add_argument("--out", required=True, help="output folder (report, figures, TUM files, logs)")
    t.add_argument("--verbose", action="store_true", help="nodes log their state every 2 s (in OUT/logs)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=cmd_team)
    add_data_parser(sub)
    return p
