"""MRCLAM replay speed per estimator, this checkout against a baseline git revision, in one run.

    python benchmarks/replay.py                       # dataset 6, full 756 s, landmarks on, against 9bda81e, 3 rounds
    python benchmarks/replay.py --duration 120 --rounds 5 --baseline HEAD~3
    python benchmarks/replay.py --datasets 6,9 --estimators dekf,cekf,rdl,diekf,ci,expfusion --baseline aa78436
    python benchmarks/replay.py --datasets 6,9 --estimators dekf,cekf,rdl --engine --baseline 107b7fd

The baseline's ``src/`` is exported with ``git archive`` into a temporary folder; every round runs the baseline and
this checkout in fresh subprocesses, one after the other, each calling its own
``swarmloc.experiments.mrclam.evaluate_mrclam`` (event loop + recording, as ``swarmloc evaluate mrclam`` reports
``wall``; with ``--engine``, the engine's compiled replays, each timed whole after an untimed warm-up in which
numba compiles: ``swarmloc evaluate mrclam --engine``). The best wall time over the rounds is kept per estimator,
and the ratio baseline / current is printed (above 1: this checkout is faster). The default baseline ``9bda81e`` is
the last commit before estimators became nodes.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

from _common import mrclam_root

ROOT = Path(__file__).resolve().parents[1]
DATA = mrclam_root()
ESTIMATORS = ("dr", "dekf", "cekf", "expfusion", "ci", "rdl")

SNIPPET = """
import json, sys
from swarmloc.experiments.mrclam import evaluate_mrclam
duration = None if sys.argv[2] == "all" else float(sys.argv[2])
rep = evaluate_mrclam(sys.argv[1], estimators=sys.argv[3].split(","), duration=duration, landmarks=sys.argv[4] == "on",
                     **({"engine": True} if sys.argv[5] == "engine" else {}))
print(json.dumps({k: [v["wall_time_s"], rep["duration_s"]] for k, v in rep["estimators"].items()}))
"""


def measure(src: Path, ds: Path, duration: str, estimators: list[str], landmarks: str, engine: bool = False
            ) -> dict[str, list[float]]:  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(src), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    out = subprocess.run(
        [sys.executable, "-c", SNIPPET, str(ds), duration, ",".join(estimators), landmarks,
         "engine" if engine else "nodes"],
        env=env, check=True, capture_output=True, text=True,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", default="9bda81e", help="git revision to compare with (default 9bda81e)")
    ap.add_argument("--duration", default="all", help="seconds of the dataset, or 'all' (default)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds; the best time per estimator is kept")
    ap.add_argument("--estimators", default=",".join(ESTIMATORS))
    ap.add_argument("--landmarks", choices=["on", "off"], default="on")
    ap.add_argument("--engine", action="store_true", help="the engine's compiled replays (dekf, cekf, rdl)")
    ap.add_argument("--datasets", default="6", help="MRCLAM dataset numbers, comma-separated (default 6)")
    args = ap.parse_args()
    for number in args.datasets.split(","):
        ds = DATA / f"MRCLAM_Dataset{number}"
        if not ds.is_dir():
            sys.exit(f"MRCLAM dataset {number} not found at {ds} (set SWARMLOC_MRCLAM)")
        compare(args, ds, number)


def compare(args: argparse.Namespace, ds: Path, number: str) -> None:
    """Baseline and current, alternately in fresh processes, ``args.rounds`` times; print the best of each."""
    names = [e for e in args.estimators.split(",") if e]
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.baseline, "src"], check=True,
                                 capture_output=True).stdout  # fmt: skip
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        base_src, cur_src = Path(tmp) / "src", ROOT / "src"
        best: dict[str, dict[str, float]] = {"baseline": {}, "current": {}}
        span = 0.0
        for r in range(args.rounds):
            for label, src in (("baseline", base_src), ("current", cur_src)):
                res = measure(src, ds, args.duration, names, args.landmarks, args.engine)
                for k, (wall, dur) in res.items():
                    span = dur
                    best[label][k] = min(best[label].get(k, float("inf")), wall)
            print(f"dataset {number}: round {r + 1}/{args.rounds} done", file=sys.stderr)
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}, "
          f"load average {os.getloadavg()[0]:.2f} (1 min)")  # fmt: skip
    print(f"MRCLAM dataset {number}, {span:.0f} s, landmarks {args.landmarks}; best of {args.rounds} rounds; "
          f"baseline {args.baseline}{'; engine (compiled replays)' if args.engine else ''}")  # fmt: skip
    print(f"{'estimator':<10} {'baseline':>16} {'current':>16} {'current / baseline speed':>26}")
    for k in names:
        b, c = best["baseline"][k], best["current"][k]
        print(f"{k:<10} {span / b:9.0f}x real {span / c:9.0f}x real {b / c:25.2f}x")


if __name__ == "__main__":
    main()
