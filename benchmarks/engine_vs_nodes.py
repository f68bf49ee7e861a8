"""``diekf`` on whole MRCLAM recordings: the engine's compiled replay against the in-process nodes, per dataset, with
landmarks on and off: the largest difference of any recorded mean (position [m], heading wrapped [rad]) and
covariance entry, and whether the outcome counts and reasons are the same.

    python benchmarks/engine_vs_nodes.py --cluster 2                        # clusters of 2, datasets 1-4, 6, 9
    python benchmarks/engine_vs_nodes.py --cluster 0 --datasets 2,9         # the exact filter

Not a test: the nodes take 15-45 s per recording on a 2-core machine (the tests compare the two on the first 120 s
of MRCLAM 6, tests/test_engine_clusters.py and tests/test_engine_invariant.py).
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np
from _common import mrclam_root

from swarmloc.engine import run_engine
from swarmloc.estimators import make_team, node_options
from swarmloc.experiments.sources import load_source
from swarmloc.lie import wrap_angle
from swarmloc.runner import RunResult, run

COUNTS = ("detections", "fused", "gated", "rejected", "unknown")


def _reasons(res: RunResult) -> Counter:
    """The detections' reasons (nodes also count refused messages), zeros dropped."""
    return +Counter({k: v for k, v in res.reasons.items() if not k.startswith("message")})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=mrclam_root(), help="the folder of the MRCLAM_DatasetN folders")
    ap.add_argument("--datasets", default="1,2,3,4,6,9")
    ap.add_argument("--cluster", type=int, default=2, help="robots per cluster (0: the exact filter)")
    a = ap.parse_args()
    for ds in a.datasets.split(","):
        src = load_source(f"mrclam:{a.data / f'MRCLAM_Dataset{ds}'}")
        for lm in (True, False):
            opts = {
                **node_options("diekf", src.config, src.landmarks),
                "cluster": a.cluster,
                "use_landmarks": lm,
                "adaptive": False,
            }  # the engine's diekf keeps its noise fixed
            ref = run(make_team("diekf", src.initial, **opts), src.events, src.record_times(), truth=src.truth)
            eng = run_engine(src, "diekf", backend="numba", cluster=a.cluster, use_landmarks=lm, adaptive=False)
            dm = dc = cmax = 0.0
            for r, want in ref.tracks.items():
                got = eng.tracks[r]
                if not np.array_equal(got.times, want.times):
                    raise SystemExit(f"dataset {ds}, robot {r}: the engine and the nodes recorded different times")
                dm = max(dm, float(np.abs(got.mean[:, :2] - want.mean[:, :2]).max()),
                         float(np.abs(wrap_angle(got.mean[:, 2] - want.mean[:, 2])).max()))  # fmt: skip
                dc = max(dc, float(np.abs(got.cov - want.cov).max()))
                cmax = max(cmax, float(np.abs(want.cov).max()))
            same = [ref.stats[k] for k in COUNTS] == [eng.stats[k] for k in COUNTS] and _reasons(ref) == _reasons(eng)
            print(f"dataset {ds}, cluster {a.cluster}, landmarks {'on' if lm else 'off'}: means within {dm:.1e}, "
                  f"covariances within {dc:.1e} (largest entry {cmax:.3g}), counts and reasons the same: {same}, "
                  f"fused {eng.stats['fused']}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
