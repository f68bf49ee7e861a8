"""Command line: ``swarmloc demo | reproduce thesis | evaluate mrclam``.

Every command writes its results (Markdown, JSON, PNG) to an output folder and prints a short summary; errors in
the input (a missing dataset file, a malformed line, an unknown estimator) are reported in one line with exit
status 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from swarmloc import __version__


def _demo(args: argparse.Namespace) -> int:
    from swarmloc.experiments.thesis_static import run_demo

    t = time.perf_counter()
    run_demo(Path(args.out), seed=args.seed, progress=not args.quiet)
    print(f"demo written to {args.out}/ in {time.perf_counter() - t:.1f} s")
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    if args.what != "thesis":
        print(f"swarmloc reproduce: unknown target {args.what!r} (only 'thesis')", file=sys.stderr)
        return 2
    from swarmloc.experiments.thesis_dynamic import run_dynamic
    from swarmloc.experiments.thesis_static import run_demo, run_tables

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    progress = not args.quiet
    report = {
        "demo": run_demo(out / "demo", seed=0, progress=progress),
        "tables": run_tables(out / "tables", reps=5 if args.quick else args.reps, progress=progress),
        "dynamic": run_dynamic(out / "dynamic", seeds=args.seeds, progress=progress, quick=args.quick),
    }
    report["wall_time_s"] = time.perf_counter() - t
    (out / "thesis.json").write_text(json.dumps(report, indent=2, default=_jsonable))
    parts = ["# Reproducing the thesis (swarmloc)", ""]
    for sub, name in (("demo", "demo.md"), ("tables", "tables.md"), ("dynamic", "dynamic.md")):
        f = out / sub / name
        if f.exists():
            parts += [f.read_text(), ""]
    parts.append(f"Total wall time: {report['wall_time_s']:.0f} s")
    (out / "thesis.md").write_text("\n".join(parts))
    print(f"thesis reproduction written to {out}/thesis.md and thesis.json in {report['wall_time_s']:.0f} s")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    if args.what != "mrclam":
        print(f"swarmloc evaluate: unknown data set kind {args.what!r} (only 'mrclam')", file=sys.stderr)
        return 2
    from swarmloc.datasets.mrclam import MRCLAMError
    from swarmloc.experiments.mrclam import evaluate_mrclam, markdown_table

    names = [e.strip() for e in args.estimators.split(",") if e.strip()]
    try:
        report = evaluate_mrclam(
            args.path,
            estimators=names,
            landmarks=args.landmarks == "on",
            duration=args.duration,
            out_dir=args.out,
            gate=None if args.gate <= 0 else args.gate,
            progress=not (args.quiet or args.json),
        )
    except MRCLAMError as exc:
        print(f"swarmloc evaluate mrclam: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"swarmloc evaluate mrclam: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(report, indent=2, default=_jsonable))
    else:
        print(markdown_table(report))
        if args.out:
            print(f"results, figures and TUM trajectories in {args.out}/")
    return 0


def _jsonable(o: object) -> object:
    import numpy as np

    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    return str(o)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="swarmloc", description="Multi-robot cooperative localization on SE(2)/SE(3).")
    p.add_argument("--version", action="version", version=f"swarmloc {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("demo", help="thesis sec. 5.1: a team of 4, prior vs fused posterior, figures")
    d.add_argument("--out", default="swarmloc-demo", help="output folder (default: swarmloc-demo)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=_demo)

    r = sub.add_parser("reproduce", help="reproduce a study: 'thesis' (chapter 5 and Table 6.1)")
    r.add_argument("what", help="thesis")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--seeds", type=int, default=20, help="seeds per dynamic experiment (default 20)")
    r.add_argument("--reps", type=int, default=60, help="repetitions for Tables 5.1/5.2 (default 60)")
    r.add_argument("--quick", action="store_true", help="few seeds and short runs (a smoke test)")
    r.add_argument("--quiet", action="store_true", help="no progress bars")
    r.set_defaults(func=_reproduce)

    e = sub.add_parser("evaluate", help="evaluate estimators on real data: 'mrclam PATH'")
    e.add_argument("what", help="mrclam")
    e.add_argument("path", help="an MRCLAM_DatasetN folder")
    e.add_argument("--estimators", default="dr,dekf,cekf,expfusion,ci,rdl", help="comma-separated names")
    e.add_argument("--landmarks", choices=["on", "off"], default="on", help="use landmark measurements")
    e.add_argument("--duration", type=float, default=None, help="seconds from the start (default: all)")
    e.add_argument("--gate", type=float, default=0.997, help="chi-square gate probability; 0 disables")
    e.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    e.add_argument("--out", default=None, help="output folder for JSON, Markdown, figures, TUM files")
    e.add_argument("--quiet", action="store_true", help="no progress bar")
    e.set_defaults(func=_evaluate)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())
