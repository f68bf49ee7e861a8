"""What a second noise model costs the compiled replays in one process, this checkout against a baseline revision.

    python benchmarks/noise_models.py --baseline REV                  # cekf, rdl, diekf, dekf
    python benchmarks/noise_models.py --baseline REV --estimators cekf

For each estimator, a fresh process of each checkout (baseline first) times ``run_engine(..., backend="numba")`` on
a simulated team (``sim:landmarks``, 4 robots, 4 s: numba compiles there), then on the first 60 s of MRCLAM dataset
6 (another noise model), then on the simulated team again. Where the noise model was compiled into the loops as
constants, the second source compiles them again; where it is an argument, it does not.
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

from _common import ROOT, add_mrclam

SNIPPET = """
import json, sys, time
from swarmloc.engine import run_engine
from swarmloc.experiments.sources import load_source
est, ds = sys.argv[1], sys.argv[2]
sim = load_source("sim:landmarks", robots=4, duration=4.0, seed=0)
rec = load_source(f"mrclam:{ds}", duration=60.0)
kw = {"adaptive": False} if est == "diekf" else {}
out = []
for src in (sim, rec, sim):
    t = time.perf_counter()
    run_engine(src, est, backend="numba", **kw)
    out.append(time.perf_counter() - t)
print(json.dumps(out))
"""


def measure(src: Path, est: str, ds: Path) -> list[float]:
    """Seconds of the three calls in one fresh process of the checkout whose ``src`` is given."""
    env = {**os.environ, "PYTHONPATH": str(src), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", SNIPPET, est, str(ds)], env=env, check=True, capture_output=True,
                         text=True)  # fmt: skip
    return list(json.loads(out.stdout.strip().splitlines()[-1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", required=True, help="git revision to compare with")
    ap.add_argument("--estimators", default="cekf,rdl,diekf,dekf", help="comma-separated (default cekf,rdl,diekf,dekf)")
    add_mrclam(ap, help="the folder of the MRCLAM_DatasetN folders")
    args = ap.parse_args()
    ds = args.mrclam / "MRCLAM_Dataset6"
    if not ds.is_dir():
        sys.exit(f"MRCLAM dataset 6 not found at {ds} (--mrclam or SWARMLOC_MRCLAM)")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.baseline, "src"], check=True,
                                 capture_output=True).stdout  # fmt: skip
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        for est in args.estimators.split(","):
            rows.append((est, measure(Path(tmp) / "src", est, ds), measure(ROOT / "src", est, ds)))
            print(f"{est} done", file=sys.stderr)
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}, "
          f"load average {os.getloadavg()[0]:.2f} (1 min); baseline {args.baseline}")  # fmt: skip
    print(f"{'estimator':<10} {'':>9} {'sim (compiles)':>15} {'MRCLAM 6, 60 s':>15} {'sim again':>10}")
    for est, base, cur in rows:
        for label, t in (("baseline", base), ("current", cur)):
            print(f"{est:<10} {label:>9} {t[0]:13.1f} s {t[1]:13.1f} s {t[2]:8.2f} s")


if __name__ == "__main__":
    main()
