"""``swarmloc evaluate mrclam FOLDER | events FILE``: estimators scored on recorded or own data."""

from __future__ import annotations

import argparse
import json
import sys

from swarmloc.cli.common import refuse, run_config
from swarmloc.cli.options import ASSOCIATION_CHOICES, ASSOCIATION_HELP, EST_DEFAULT, real


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``evaluate`` command: its options and help."""
    e = sub.add_parser("evaluate", help="evaluate estimators on data: 'mrclam FOLDER' or 'events FILE'")
    e.add_argument("what", choices=["mrclam", "events"], help="mrclam (a UTIAS MRCLAM folder) or events (your file)")
    e.add_argument("path", help="an MRCLAM_DatasetN folder, or an event file (.csv or .jsonl)")
    e.add_argument("--estimators", default=EST_DEFAULT, help=f"comma-separated names (default {EST_DEFAULT})")
    e.add_argument("--config", default=None, help="TOML file of model and filter settings (swarmloc config)")
    e.add_argument("--gate", type=real, default=None, help="override the chi-square gate probability; 0 disables")
    e.add_argument("--landmarks", choices=["on", "off"], default="on", help="mrclam: use landmark measurements")
    e.add_argument("--association", choices=ASSOCIATION_CHOICES, default=None,
                   help=ASSOCIATION_HELP + " (default: the configuration's [filter] association)")  # fmt: skip
    e.add_argument("--duration", type=real, default=None, help="mrclam: seconds from the start (default: all)")
    e.add_argument("--calibrate-yaw", action="store_true",
                   help="mrclam: yaw diffusion scaled as the recording's landmark snapshots say")  # fmt: skip
    e.add_argument("--engine", action="store_true",
                   help="mrclam: dekf, cekf, iekf, rdl, diekf by the engine's compiled replays (numba)")  # fmt: skip
    e.add_argument("--truth", default=None, help="events: folder of truth_robot<N>.tum (default: beside the file)")
    e.add_argument("--skip-bad-lines", action="store_true", help="events: skip bad records (listed) instead of stop")
    e.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    e.add_argument("--out", default=None, help="output folder for JSON, Markdown, figures, TUM files")
    e.add_argument("--quiet", action="store_true", help="no progress bar")
    e.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Score the estimators on the recording or event file; 0, or 2 on bad input (one line each)."""
    from swarmloc.config import ConfigError
    from swarmloc.datasets.eventfile import EventFileError
    from swarmloc.datasets.mrclam import MRCLAMError
    from swarmloc.datasets.tum import TUMError
    from swarmloc.experiments.evaluate import markdown_table

    where = f"evaluate {args.what}"
    names = [e.strip() for e in args.estimators.split(",") if e.strip()]
    try:
        config = run_config(args)
        if args.gate is not None:  # --gate overrides the configuration's (0 disables it)
            if args.gate < 0:
                raise ConfigError(f"--gate: a probability in (0, 1), or 0 to turn the gate off, got {args.gate!r}")
            config = config.with_filter(gate=None if args.gate == 0 else args.gate)
        if args.association is not None:
            config = config.with_filter(association=args.association)
        progress = not (args.quiet or args.json)
        if args.what == "mrclam":
            from swarmloc.experiments.mrclam import evaluate_mrclam

            report = evaluate_mrclam(
                args.path, estimators=names, landmarks=args.landmarks == "on", duration=args.duration,
                out_dir=args.out, config=config, progress=progress, calibrate_yaw=args.calibrate_yaw,
                engine=args.engine,
            )  # fmt: skip
        elif args.calibrate_yaw or args.engine:
            flag = "--calibrate-yaw" if args.calibrate_yaw else "--engine"
            return refuse(where, f"{flag} needs an MRCLAM recording (evaluate mrclam)")
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
                print(f"swarmloc {where}: skipped {n} bad line{'s' if n != 1 else ''} in all", file=sys.stderr)
        else:
            return refuse("evaluate", f"unknown kind {args.what!r} (use 'mrclam' or 'events')")
    except (MRCLAMError, EventFileError, TUMError, ConfigError, ValueError, OSError) as exc:
        return refuse(where, exc)
    if args.json:
        from swarmloc.experiments.evaluate import json_default

        print(json.dumps(report, indent=2, default=json_default))
    else:
        start = report.get("start")
        if start is not None and not start["truth"]:  # how a recording without truth was started
            before = start["events_before"]
            print(f"start: {start['how']}" + (f" ({before} events before it left out)" if before else ""))
        if "yaw_calibration" in report:
            y = report["yaw_calibration"]
            terms = ", ".join(f"{k} = {v:.4g}" for k, v in y["motion"].items())
            print(f"yaw diffusion calibrated on the recording: x{y['scale']:.3g} (log std {y['log_std']:.2f}, "
                  f"{y['pairs']} snapshot pairs): {terms}")  # fmt: skip
        print(markdown_table(report))
        if args.out:
            print(f"results, figures and TUM trajectories in {args.out}/")
    return 0
