"""``swarmloc demo | reproduce | evaluate | simulate | config | compare``: the commands that run in one process."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

EST_DEFAULT = "dr,dekf,cekf,iekf,expfusion,ci,rdl,diekf"
"""Estimators ``evaluate`` and ``compare`` run by default: every kind, the recommended ``iekf`` (centralized) and
``diekf`` (distributed) included."""


def cmd_demo(args: argparse.Namespace) -> int:
    from swarmloc.experiments.thesis_static import run_demo

    t = time.perf_counter()
    run_demo(Path(args.out), seed=args.seed, progress=not args.quiet)
    print(f"demo written to {args.out}/ in {time.perf_counter() - t:.1f} s")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
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


def run_config(args: argparse.Namespace):  # noqa: ANN202
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


def cmd_evaluate(args: argparse.Namespace) -> int:
    from swarmloc.config import ConfigError
    from swarmloc.datasets.eventfile import EventFileError
    from swarmloc.datasets.mrclam import MRCLAMError
    from swarmloc.datasets.tum import TUMError
    from swarmloc.experiments.evaluate import markdown_table

    where = f"swarmloc evaluate {args.what}"
    names = [e.strip() for e in args.estimators.split(",") if e.strip()]
    try:
        config = _with_association(_with_gate(run_config(args), args.gate), args.association)
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
            print(f"{where}: {flag} needs an MRCLAM recording (evaluate mrclam)", file=sys.stderr)
            return 2
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
        if "yaw_calibration" in report:
            y = report["yaw_calibration"]
            terms = ", ".join(f"{k} = {v:.4g}" for k, v in y["motion"].items())
            print(f"yaw diffusion calibrated on the recording: x{y['scale']:.3g} (log std {y['log_std']:.2f}, "
                  f"{y['pairs']} snapshot pairs): {terms}")  # fmt: skip
        print(markdown_table(report))
        if args.out:
            print(f"results, figures and TUM trajectories in {args.out}/")
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
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


def cmd_config(args: argparse.Namespace) -> int:
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


def cmd_compare(args: argparse.Namespace) -> int:
    from swarmloc.experiments.compare import compare, compare_table, is_3d

    if args.estimators is None:  # the defaults; on a 3-D team, those with an SE(3) form
        from swarmloc.estimators import ESTIMATORS_SE3

        names = [e for e in EST_DEFAULT.split(",") if not is_3d(args.scenario) or e in ESTIMATORS_SE3]
    else:
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
