"""What a fixed-lag smoother's window knows later: the causal estimate against the lagged (smoothed) one.

    python benchmarks/fls_lagged.py ../shared/data/mrclam/MRCLAM_Dataset6                 # flsd, lag 2 s, all
    python benchmarks/fls_lagged.py ../shared/data/mrclam/MRCLAM_Dataset6 --duration 120 --estimator fls
    python benchmarks/fls_lagged.py ../shared/data/mrclam/MRCLAM_Dataset6 --lag 5 --no-landmarks

The nodes' belief (``belief_at(t)``, what every estimator is scored on) is causal: inputs stamped up to ``t``. A
window pose leaving the window has been re-estimated with at least ``lag`` seconds of later inputs: the smoothers'
delayed output (:attr:`swarmloc.estimators.fls.WindowSolver.lagged_log`, estimate and marginal covariance;
paired with the beliefs by :func:`swarmloc.evaluation.delayed.delayed_tracks`). This prints, at the same
instants (the window's poses that have ground truth), the team position RMSE [m] and ANEES per dof of the causal
belief and of the delayed output, and how many poses ``flsd`` filed as its causal belief because the window's
covariance bound was the larger (:attr:`~swarmloc.estimators.fls.WindowSolver.lagged_causal`; ``fls`` files none).
The delayed output answers ``lag`` seconds (or more) late.
"""

from __future__ import annotations

import argparse
import time

from swarmloc.estimators import make_team, node_options
from swarmloc.evaluation.delayed import delayed_tracks
from swarmloc.evaluation.metrics import evaluate
from swarmloc.events import Detection
from swarmloc.experiments.sources import load_source
from swarmloc.runner import run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", help="an MRCLAM_DatasetN folder")
    ap.add_argument("--duration", type=float, default=None, help="seconds from the start (default: all)")
    ap.add_argument("--estimator", default="flsd", choices=("fls", "flsd"))
    ap.add_argument("--lag", type=float, default=2.0, help="window length [s]")
    ap.add_argument("--no-landmarks", action="store_true", help="leave the landmark detections out")
    a = ap.parse_args()
    src = load_source(f"mrclam:{a.dataset}", duration=a.duration, landmarks=not a.no_landmarks)
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
    causal, delayed = delayed_tracks(nodes, res)
    n = sum(t.times.size for t in causal.tracks.values())
    print(f"{a.estimator}, lag {a.lag:g} s, {src.t_end - src.t_start:.0f} s, {n} instants, {wall:.0f} s wall")
    filed, causal_filed = (sum(len(getattr(node, k)) for node in nodes) for k in ("lagged_log", "lagged_causal"))
    print(f"poses filed: {filed}, as the causal belief (the window's bound the larger): {causal_filed}")
    for name, r in (("causal belief", causal), ("lagged (smoothed)", delayed)):
        team = evaluate(r)["team"]
        print(f"{name:18s} pos RMSE [m] {team['pos_rmse']:.4f}  ANEES/dof {team['anees']:.3f}")


if __name__ == "__main__":
    main()
