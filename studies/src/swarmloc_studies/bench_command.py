"""``swarmloc-studies bench``'s command line: its options, the configuration they make and the run that prints the
report (the benchmarks themselves: :mod:`swarmloc_studies.bench`)."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace

from swarmloc.cli.options import real
from swarmloc.runner.fanout import check_runs
from swarmloc_studies.bench import FULL, MRCLAM_ENV, QUICK, REPLAY_ESTIMATORS, SECTIONS, BenchConfig, run_bench
from swarmloc_studies.bench_report import format_report


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``swarmloc-studies bench`` (and ``benchmarks/bench.py``)."""
    ap.add_argument("--quick", action="store_true", help="small sizes and 60 s of the replay (under a minute)")
    ap.add_argument("--json", action="store_true", help="print the results as JSON")
    ap.add_argument("--mrclam", default=None, help=f"MRCLAM_Dataset6 folder (or its parent; default ${MRCLAM_ENV})")
    ap.add_argument("--duration", type=real, default=None, help="replay: seconds of the dataset (default all)")
    ap.add_argument("--runs", type=int, default=None, help="fusion step: runs of each engine row, the median "
                    "reported with the minimum and maximum (default 10; --quick 3)")  # fmt: skip
    ap.add_argument("--rounds", type=int, default=None, help="replay: rounds, the best kept (default 1)")
    ap.add_argument("--estimators", default=None, help="replay: comma-separated names (default all six)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    ap.add_argument("--sections", default=SECTIONS, help="letters of the sections to run (default abcd; e: the "
                    "fusion step on jax's device, float64 and float32, against plain JAX)")  # fmt: skip
    ap.add_argument("--accelerator-sizes", default=None, help="section e: team sizes, comma-separated (default "
                    "10000,100000,1000000; --quick 1000,10000)")  # fmt: skip


def config_from_args(args: argparse.Namespace) -> BenchConfig:
    """The run's :class:`BenchConfig` from the options; ValueError naming a bad one (a count below 1 was taken as 1,
    a duration below 0 as given)."""
    cfg = QUICK if args.quick else FULL
    if args.duration is not None:
        if not args.duration > 0:
            raise ValueError(f"bench: --duration is seconds > 0, got {args.duration!r}")
        cfg = replace(cfg, replay_duration=args.duration)
    if args.rounds is not None:
        cfg = replace(cfg, replay_rounds=check_runs(args.rounds, "bench: --rounds"))
    if getattr(args, "runs", None) is not None:
        cfg = replace(cfg, runs=check_runs(args.runs, "bench: --runs"))
    if args.estimators:
        cfg = replace(cfg, estimators=tuple(e for e in args.estimators.split(",") if e))
    if getattr(args, "accelerator_sizes", None):
        cfg = replace(cfg, accelerator_sizes=_sizes(args.accelerator_sizes))
    return cfg


def _sizes(text: str) -> tuple[int, ...]:
    try:
        sizes = tuple(int(float(s)) for s in text.split(",") if s.strip())
    except ValueError:
        raise ValueError(f"bench: --accelerator-sizes must be comma-separated team sizes, not {text!r}") from None
    if not sizes or min(sizes) < 1 or max(sizes) > 100_000_000:
        raise ValueError(f"bench: --accelerator-sizes must be 1 to 100,000,000 robots each, not {text!r}")
    return sizes


def run_command(args: argparse.Namespace) -> int:
    """``swarmloc-studies bench``: run, then print the tables or the JSON."""
    try:
        cfg = config_from_args(args)
    except ValueError as exc:
        print(f"swarmloc-studies {exc}", file=sys.stderr)
        return 2
    unknown = [e for e in cfg.estimators if e not in REPLAY_ESTIMATORS]
    if unknown:
        print(
            f"swarmloc-studies bench: unknown estimator(s) {unknown}; choose from {list(REPLAY_ESTIMATORS)}",
            file=sys.stderr,
        )
        return 2
    sections = getattr(args, "sections", SECTIONS)
    if not sections or set(sections) - set("abcde"):
        print(f"swarmloc-studies bench: --sections takes letters of 'abcde', not {sections!r}", file=sys.stderr)
        return 2
    res = run_bench(cfg, args.mrclam, progress=not args.quiet, sections=sections)  # the bar goes to stderr
    print(json.dumps(res, indent=2, default=float) if args.json else format_report(res))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench", description="speed on this machine")
    add_arguments(ap)
    return run_command(ap.parse_args(argv))
