"""``swarmloc-studies reproduce thesis | tables``: chapter 5 and Table 6.1, or Tables 5.1/5.2 over many seeds."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from swarmloc.cli.options import add_sweep_args, seed


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``reproduce`` command: its options and help."""
    r = sub.add_parser("reproduce", help="reproduce a study: 'thesis' (chapter 5 and Table 6.1) or 'tables' "
                       "(Tables 5.1/5.2 over many seeds)")  # fmt: skip
    r.add_argument("what", help="thesis | tables")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--seeds", type=int, default=20, help="seeds per dynamic experiment, or pooled seeds (default 20)")
    r.add_argument("--reps", type=int, default=None,
                   help="repetitions for Tables 5.1/5.2 (60; with 'tables': per seed, 20000)")  # fmt: skip
    r.add_argument("--first-seed", type=seed, default=100, help="tables: first of the pooled seeds (default 100)")
    r.add_argument("--quick", action="store_true", help="few seeds and short runs (a smoke test)")
    add_sweep_args(r, jobs=None)
    r.add_argument("--quiet", action="store_true", help="no progress bars")
    r.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Reproduce ``thesis`` or ``tables`` into ``--out``; 0, or 2 on a bad target or argument."""
    from swarmloc.runner.fanout import ClusterUnavailable, check_runs, connected

    if args.what == "tables":
        from swarmloc_studies.thesis_static.pooled import pooled_tables

        try:
            reps = 20_000 if args.reps is None else args.reps
            res = pooled_tables(args.out, seeds=args.seeds, reps=reps, first_seed=args.first_seed,
                                cluster=args.cluster)  # fmt: skip
        except (ValueError, ClusterUnavailable) as exc:
            print(f"swarmloc-studies reproduce tables: {exc}", file=sys.stderr)
            return 2
        print((Path(args.out) / "pooled.md").read_text())
        print(f"written to {args.out}/pooled.md and pooled.json in {res['runtime_s']:.0f} s")
        return 0
    if args.what != "thesis":
        print(f"swarmloc-studies reproduce: unknown target {args.what!r} ('thesis' or 'tables')", file=sys.stderr)
        return 2
    from swarmloc_studies.thesis_dynamic import run_dynamic
    from swarmloc_studies.thesis_static import run_demo, run_tables

    try:
        check_runs(args.seeds, "--seeds")
        if args.reps is not None and args.reps < 1:
            raise ValueError(f"--reps must be >= 1, got {args.reps}")
    except ValueError as exc:
        print(f"swarmloc-studies reproduce thesis: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    progress = not args.quiet
    try:
        with connected(args.cluster) as cluster:  # an unreachable cluster is refused before anything runs
            report: dict[str, Any] = {
                "demo": run_demo(out / "demo", seed=0, progress=progress),
                "tables": run_tables(out / "tables", reps=5 if args.quick else args.reps or 60, progress=progress),
                "dynamic": run_dynamic(out / "dynamic", seeds=args.seeds, progress=progress, quick=args.quick,
                                       cluster=cluster),
            }  # fmt: skip
    except (ValueError, ClusterUnavailable) as exc:
        print(f"swarmloc-studies reproduce thesis: {exc}", file=sys.stderr)
        return 2
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
