"""``swarmloc ros``: a robot's localization as a ROS 2 node (run), a recording localized offline (replay), and the
parameters with their defaults (params). ROS's own arguments follow ``--ros-args`` as with ``ros2 run``::

    swarmloc ros --ros-args --params-file team.yaml -r __ns:=/robot1 -r odom:=wheel/odom -p robot_id:=1
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from swarmloc.cli.common import net_logging, refuse
from swarmloc.cli.options import real, seed

HINT = "swarmloc ros needs the ROS extra: pip install 'swarmloc[ros]'"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``ros`` command and its subcommands."""
    r = sub.add_parser("ros", help="a robot's localization as a ROS 2 node (DDS or rmw_zenoh), or a bag replayed",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    r.add_argument("action", nargs="?", default="run", choices=("run", "replay", "params", "sim"),
                   help="run (default): the live node, until Ctrl-C; replay BAG: localize a rosbag2 offline for every "
                   "node of the params file; params: print every parameter with its default; sim: simulated robots "
                   "publishing their odometry and detections (write the nodes' params with --params-out)")  # fmt: skip
    r.add_argument("--robots", type=int, default=3, help="sim: robots (default 3)")
    r.add_argument("--duration", type=real, default=60.0, help="sim: seconds of driving (default 60)")
    r.add_argument("--seed", type=seed, default=1, help="sim: the simulation's seed")
    r.add_argument("--params-out", default=None, metavar="FILE", help="sim: write the nodes' params file (team, "
                   "initial poses, frames, keys beside it) and exit")  # fmt: skip
    r.add_argument("bag", nargs="?", default=None, help="replay: the rosbag2 folder (or .mcap) to read")
    r.add_argument("--out", default=None, help="replay: write the outputs to this new rosbag2")
    r.add_argument("--max-wall", type=real, default=None, help="run: stop after this many wall-clock seconds")
    r.add_argument("--verbose", action="store_true", help="log the team node's state every 2 s")
    r.add_argument("--view", type=int, default=None, metavar="PORT",
                   help="run: serve this robot's beliefs to Foxglove or Lichtblick on ws://127.0.0.1:PORT (0: a free "
                        "port), as long as the node runs")  # fmt: skip
    r.add_argument("--record", default=None, metavar="FILE.mcap",
                   help="run: record this robot's beliefs as ROS 2 messages in an MCAP file")  # fmt: skip
    r.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run, replay, simulate or list the parameters of the ROS 2 node; 0, or 2 on bad input, 130."""
    from swarmloc.ros.args import RosArgs, RosArgsError
    from swarmloc.ros.params import ParamsError

    ros: RosArgs = getattr(args, "ros_args", None) or RosArgs()
    try:
        if args.action == "params":
            from swarmloc.ros.params import defaults_yaml

            print(defaults_yaml(ros.node or "swarmloc"), end="")
            return 0
        if args.action == "replay":
            return _replay(args, ros)
        if args.action == "sim":
            return _sim(args, ros)
        return _run_node(args, ros)
    except ModuleNotFoundError as exc:
        if exc.name in ("cyclonedds", "yaml"):
            print(f"{HINT} ({exc.name} is missing)", file=sys.stderr)
            return 2
        raise
    except (ParamsError, RosArgsError, ValueError, OSError, RuntimeError) as exc:
        return refuse("ros", exc)
    except KeyboardInterrupt:
        return 130


def _replay(args: argparse.Namespace, ros: Any) -> int:
    from swarmloc.ros.replay import replay_bag

    if not args.bag or not ros.params_files:
        raise ValueError("replay needs the BAG and --ros-args --params-file FILE (a section per node)")
    res = replay_bag(args.bag, ros.params_files[0], args.out, ros)
    for r in sorted(res.times):
        tl = res.timelines[r]
        print(f"robot {r}: {len(res.times[r])} outputs from {dict(tl.counts)}; refused {dict(tl.reasons) or 'none'}")
    print(f"fused {res.stats.get('fused', 0)}, gated {res.stats.get('gated', 0)}, unknown {res.stats.get('unknown', 0)}"
          + (f"; outputs in {args.out}" if args.out else ""))  # fmt: skip
    return 0


def _sim(args: argparse.Namespace, ros: Any) -> int:
    """``ros sim``: with ``--params-out``, write the nodes' params file and exit; else play the robots' inputs."""
    from pathlib import Path

    from swarmloc.experiments.sources import load_source

    src = load_source("sim:random", robots=args.robots, duration=args.duration, seed=args.seed)
    if args.params_out:
        import yaml

        from swarmloc.net.auth import make_team_keys
        from swarmloc.net.transport import free_ports
        from swarmloc.ros.simulate import node_params

        out = Path(args.params_out).resolve()
        roster, keys = make_team_keys(out.with_suffix(".keys"), src.robots)
        doc, eps = node_params(src), [f"tcp/127.0.0.1:{p}" for p in free_ports(len(src.robots))]
        doc["/**"]["ros__parameters"].update(team="sim", roster_file=str(roster))
        for k, r in enumerate(src.robots):
            doc[f"/robot{r}/swarmloc"]["ros__parameters"].update(key_file=str(keys[r]), team_listen=[eps[k]],
                                                                 team_connect=eps[:k])  # fmt: skip
        out.write_text(yaml.safe_dump(doc, sort_keys=False))
        print(f"swarmloc ros sim: the params of {len(src.robots)} nodes in {out} (team keys in {roster.parent})")
        return 0
    from swarmloc.rmw import open_middleware
    from swarmloc.ros.params import load_params
    from swarmloc.ros.simulate import play

    p = load_params(ros.params_files, {**ros.params, "no_auth": True}, "swarmloc_sim", "/")  # the ROS graph only
    mw = open_middleware(p.middleware, domain=p.domain_id, scope=p.discovery_range, node_name="swarmloc_sim",
                         endpoints=tuple(p.ros_endpoints))  # fmt: skip
    try:
        print(f"swarmloc ros sim: {len(src.robots)} robots on /robot<N>/odom and /robot<N>/detections "
              f"({p.middleware}, domain {p.domain_id}); waiting for their nodes", flush=True)  # fmt: skip
        n, _ = play(mw, src)
    finally:
        mw.close()
    print(f"swarmloc ros sim: published {n} messages over {args.duration:g} s")
    return 0 if n else 1


def _view(args: argparse.Namespace, params: Any) -> Any:
    """The robot's :class:`~swarmloc.net.view.TeamView` (``--view``/``--record``), or None; its stamps are ROS time."""
    if args.view is None and not args.record:
        return None
    from swarmloc.net.view import LAYOUT, TeamView, require_view

    require_view(args.view is not None, bool(args.record))
    view = TeamView(port=args.view, mcap=args.record, roster=params.team_ids, name=f"swarmloc ros {params.robot_id}",
                    epoch=0.0)  # fmt: skip
    if view.url:
        print(f"live view: open {view.url} in Foxglove or Lichtblick; layout {LAYOUT}", flush=True)
    return view


def _run_node(args: argparse.Namespace, ros: Any) -> int:
    import json
    import signal

    from swarmloc.ros.node import RosNode
    from swarmloc.ros.params import load_params

    net_logging(args.verbose)
    name, ns = ros.node or "swarmloc", ros.namespace or "/"
    params = load_params(ros.params_files, ros.params, name, ns)
    view = _view(args, params)
    node = RosNode(params, name=name, namespace=ns, args=ros, on_belief=None if view is None else view.observe)
    signal.signal(signal.SIGTERM, lambda *_: node.stop())
    signal.signal(signal.SIGINT, lambda *_: node.stop())
    t = node.topics
    outs = [t["odometry_topic"], t["pose_topic"], *(["/tf"] if params.publish_tf else []), t["diagnostics_topic"]]
    print(f"swarmloc ros: robot {params.robot_id} of team {params.team} ({params.estimator}, {params.middleware}, "
          f"domain {params.domain_id}): in {t['odom_topic']}, {t['detections_topic']}, {t['initialpose_topic']}; "
          f"out {', '.join(outs)}; waiting for the first odometry", flush=True)  # fmt: skip
    try:
        report = node.run(max_wall=args.max_wall)
    finally:
        if view is not None:
            view.close()
    d = node.diagnostics()
    print(f"swarmloc ros: robot {params.robot_id}: {d.get('output_odometry', 0)} outputs; {d.get('fused', 0)} "
          f"detections fused, {d.get('gated', 0)} gated, {d.get('unknown', 0)} unknown"
          + ("" if report else "; no odometry came"))  # fmt: skip
    counts = {k[6:]: v for k, v in d.items() if k.startswith("input_")}
    refused = {k: v for k, v in d.items() if k.startswith(("refused_", "late_", "frames_")) and v}
    print(f"swarmloc ros: robot {params.robot_id}: inputs {counts}; refused {refused or 'none'}; waits given up: "
          f"{d.get('queries_unanswered', 0)} queries unanswered, {d.get('updates_not_received', 0)} updates not "
          "received")  # fmt: skip
    print(f"swarmloc ros: robot {params.robot_id}: refused inputs {json.dumps(node.refused_inputs())}")
    return 0
