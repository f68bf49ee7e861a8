"""What a fixed-lag smoother's window knows later: the causal estimate against the lagged (smoothed) one.

    python benchmarks/fls_lagged.py ../shared/data/mrclam/MRCLAM_Dataset6                 # flsd, lag 2 s, all
    python benchmarks/fls_lagged.py ../shared/data/mrclam/MRCLAM_Dataset6 --duration 120 --estimator fls

The nodes' belief (``belief_at(t)``, what every estimator is scored on) is causal: inputs stamped up to ``t``. A
window pose leaving the window has been re-estimated with at least ``lag`` seconds of later inputs: the smoothers'
delayed output (:attr:`swarmloc.estimators.fls.WindowSolver.lagged_log`, estimate and marginal covariance). This
prints, at the same instants (the window's poses that have ground truth), the team position RMSE [m] and ANEES
per dof of the causal belief and of the delayed output. The delayed output answers ``lag`` seconds (or more) late.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from swarmloc.estimators import make_team, node_options
from swarmloc.events import Detection
from swarmloc.experiments.sources import load_source
from swarmloc.kernels import cartesian as C
from swarmloc.lie import SE2
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
    causal, lagged = [], []  # per instant: (position error [m], NEES)
    for n in nodes:
        tr = res.tracks[n.robot]
        at = {float(t): k for k, t in enumerate(tr.times)}
        for ts, (x, P) in n.lagged_log.items():
            k = at.get(float(ts))
            if k is None or not np.isfinite(tr.truth[k]).all():
                continue
            truth = tr.truth[k]
            causal.append(_scores(tr.mean[k], tr.cov[k], truth))
            mean, cov = C.to_group(np.asarray(x), np.asarray(P))
            lagged.append(_scores(SE2.to_xytheta(mean), cov, truth))
    print(f"{a.estimator}, lag {a.lag:g} s, {src.t_end - src.t_start:.0f} s, {len(causal)} instants, {wall:.0f} s wall")
    for name, e in (("causal belief", causal), ("lagged (smoothed)", lagged)):
        e = np.asarray(e)
        print(f"{name:18s} pos RMSE [m] {np.sqrt(np.mean(e[:, 0] ** 2)):.4f}  ANEES/dof {np.mean(e[:, 1]) / 3:.3f}")


def _scores(mean: np.ndarray, cov: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Position error [m] and NEES (exponential coordinates, right perturbation) of one belief."""
    y = SE2.log(SE2.inverse(SE2.from_xytheta(mean)) @ SE2.from_xytheta(truth), validate=False)
    return float(np.hypot(*(mean[:2] - truth[:2]))), float(y @ np.linalg.solve(cov, y))


if __name__ == "__main__":
    main()
