"""Leave-one-dataset-out check of the MRCLAM camera model: held-out truth-free scores of the candidate
models on every dataset, and filter consistency on every dataset with odometry (:mod:`swarmloc_studies.lodo`):
landmarks on, on with the yaw diffusion calibrated on the recording (``on+yaw``; ``--no-yaw`` leaves it out), off.

    python benchmarks/lodo.py --mrclam ../shared/data/mrclam --duration 200 --out lodo   # writes lodo.md, lodo.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from _common import add_mrclam

from swarmloc.experiments.evaluate import json_default
from swarmloc_studies.lodo import lodo, lodo_markdown


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_mrclam(ap)
    ap.add_argument("--estimators", default="dekf,ci,rdl,diekf,flsd", help="flsd: its delayed output too")
    ap.add_argument("--duration", type=float, default=200.0, help="seconds of each left-out dataset the filters run")
    ap.add_argument("--datasets", default="1,2,3,4,5,6,8,9", help="datasets to fit and score on")
    ap.add_argument("--filter-datasets", default=None, help="datasets the filters run on (default: all with odometry)")
    ap.add_argument("--holdout", type=int, default=3, help="landmark folds held out in turn (landmarks on; 0: none)")
    ap.add_argument("--no-yaw", action="store_true", help="leave out the runs with the yaw diffusion calibrated")
    ap.add_argument("--out", type=Path, default=Path("lodo"))
    ap.add_argument("--jobs", type=int, default=2, help="worker processes for the filter runs (default 2)")
    ap.add_argument("--cluster", default=None, help="a Dask scheduler's address (tcp://HOST:8786) instead of --jobs")
    a = ap.parse_args()
    t = time.perf_counter()
    fd = None if a.filter_datasets is None else [int(x) for x in a.filter_datasets.split(",")]
    rep = lodo(a.mrclam, a.estimators.split(","), a.duration, [int(x) for x in a.datasets.split(",")],
               filter_datasets=fd, progress=True, holdout=a.holdout, calibrate_yaw=not a.no_yaw, workers=a.jobs,
               cluster=a.cluster)  # fmt: skip
    rep["wall_s"] = time.perf_counter() - t
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "lodo.json").write_text(json.dumps(rep, indent=2, default=json_default))
    md = lodo_markdown(rep)
    (a.out / "lodo.md").write_text(md)
    print(md)
    print(f"wall {rep['wall_s']:.0f} s")


if __name__ == "__main__":
    main()
