"""What a fixed-lag smoother's window knows later: the causal estimate against the lagged (smoothed) one.

    python benchmarks/fls_lagged.py ../shared/data/mrclam/MRCLAM_Dataset6                 # flsd, lag 2 s, all
    python benchmarks/fls_lagged.py ../shared/data/mrclam/MRCLAM_Dataset6 --duration 120 --estimator fls

The nodes' belief (``belief_at(t)``, what every estimator is scored on) is causal: inputs stamped up to ``t``. A
window pose leaving the window has been re-estimated with ``lag`` seconds of later inputs; this files those
(:attr:`swarmloc.estimators.fls.WindowSolver.lagged_log`) and prints, at the same instants (the window's poses
that have ground truth), the team position RMSE [m] of the causal belief and of the lagged estimate. The lagged
figure is a diagnostic, not an output of the node: a node that answered it would answer ``lag`` seconds late.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from swarmloc.estimators import make_team, node_options
from swarmloc.events import Detection
from swarmloc.experiments.sources import load_source
from swarmloc.runner import run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", help="an MRCLAM_DatasetN folder")
    ap.add_argument("--duration", type=float, default=None, help="seconds from the start (default: all)")
    ap.add_argument("--estimator", default="flsd", choices=("fls", "flsd"))
    ap.add_argument("--lag", type=float, default=2.0, help="window length [s]")
    a = ap.parse_args()
    src = load_source(f"mrclam:{a.dataset}", duration=a.duration)
    opts = {**node_options(a.estimator, src.config, src.landmarks), "lag": a.lag}
    nodes = make_team(a.estimator, src.initial, **opts)
    for n in nodes:
        n.lagged_log = {}
    stamps = sorted(
        {float(d.stamp) for e in src.events for d in (e if isinstance(e, list) else [e]) if isinstance(d, Detection)}
    )
    t0 = time.perf_counter()
    res = run(nodes, src.events, stamps, truth=src.truth)
    wall = time.perf_counter() - t0
    causal, lagged = [], []
    for n in nodes:
        tr = res.tracks[n.robot]
        at = {float(t): k for k, t in enumerate(tr.times)}
        for ts, x in n.lagged_log.items():
            k = at.get(float(ts))
            if k is None or not np.isfinite(tr.truth[k]).all():
                continue
            causal.append(np.hypot(*(tr.mean[k][:2] - tr.truth[k][:2])))
            lagged.append(np.hypot(*(np.asarray(x)[:2] - tr.truth[k][:2])))
    rmse = lambda e: float(np.sqrt(np.mean(np.square(e))))  # noqa: E731
    print(f"{a.estimator}, lag {a.lag:g} s, {src.t_end - src.t_start:.0f} s, {len(causal)} instants, {wall:.0f} s wall")
    print(f"causal belief RMSE [m] {rmse(causal):.4f}; lagged (smoothed) RMSE [m] {rmse(lagged):.4f}")


if __name__ == "__main__":
    main()
