"""The thesis' second-order estimator against the first-order EKF on 3-D teams: ``sim:3d`` and
``sim:3d_rot`` (large rotational uncertainty), ``expfusion``, ``dekf``, ``ci``, ``diekf``, ``cekf`` and ``dr`` over 20
seeds.

    PYTHONPATH=src python benchmarks/se3.py --seeds 20 --out se3   # writes se3.md and se3.json
    PYTHONPATH=src python benchmarks/se3.py --seeds 0 --figures docs/se3   # seed 0's figures and TUM files only
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from swarmloc.experiments.evaluate import json_default
from swarmloc.experiments.se3 import run_se3, write_tum_tracks
from swarmloc.experiments.sources import load_source
from swarmloc_studies.se3 import se3_figures, se3_markdown, se3_table


def _figures(a: argparse.Namespace) -> None:
    for spec in a.specs.split(","):
        src = load_source(spec, robots=a.robots, duration=a.duration, seed=0)
        results = {e: run_se3(src, e) for e in a.estimators.split(",")}
        folder = a.figures / spec.replace(":", "_")
        for p in se3_figures(folder, results, src.t_start or 0.0):
            print(p)
        for res in results.values():
            write_tum_tracks(res, folder / "tum")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--robots", type=int, default=4)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--estimators", default="expfusion,dekf,ci,diekf,cekf,dr")
    ap.add_argument("--specs", default="sim:3d,sim:3d_rot", help="comma-separated 3-D sources (e.g. sim:3d_rbe)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cluster", default=None, help="a Dask scheduler's address (tcp://HOST:8786) instead of --workers")
    ap.add_argument("--out", type=Path, default=Path("se3"))
    ap.add_argument("--figures", type=Path, default=None,
                    help="also draw seed 0 of each source (top/side views, error and NEES over time) and write its "
                    "TUM files into this folder, then stop if --seeds is 0")  # fmt: skip
    a = ap.parse_args()
    if a.figures is not None:
        _figures(a)
        if a.seeds == 0:
            return
    table = se3_table(specs=tuple(a.specs.split(",")), estimators=tuple(a.estimators.split(",")), seeds=a.seeds,
                      robots=a.robots, duration=a.duration, workers=a.workers, cluster=a.cluster)  # fmt: skip
    md = se3_markdown(table)
    a.out.with_suffix(".md").write_text(md + "\n")
    a.out.with_suffix(".json").write_text(json.dumps(table, default=json_default, indent=1))
    print(md)


if __name__ == "__main__":
    main()
