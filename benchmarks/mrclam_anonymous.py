"""MRCLAM with the robot barcodes hidden, ``anonymous`` policy with the scans binned in time, against the tagged run.

    python benchmarks/mrclam_anonymous.py                       # dataset 6, first 120 s, bins 0.5 and 1 s, cekf
    python benchmarks/mrclam_anonymous.py --bins 0.25,0.5 --duration 60

MRCLAM stamps each robot's camera detections on its own, so at almost every stamp only one robot has a scan and PMR
(which registers scans taken at one instant by several robots) has nothing to register. Here each bin's detections
are carried to the bin's end by their observer's odometry (:func:`swarmloc.association.tracker.binned_scans`) and
PMR + the bank run on those. Landmarks (their barcodes kept) are fused by the estimator in every run.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def score(src, events, estimator: str) -> tuple[float, float, dict]:
    """Team position RMSE [m], ANEES per dof and counters of ``estimator`` on ``events``."""
    from swarmloc.estimators import make_team, node_options
    from swarmloc.evaluation.metrics import errors
    from swarmloc.runner import run

    opts = node_options(estimator, src.config, src.landmarks, src.t_start)
    res = run(make_team(estimator, src.initial, **opts), events, src.record_times(), src.truth)
    se = nees = 0.0
    n = 0
    for tr in res.tracks.values():
        e = errors(tr)
        se += float(np.sum(e["pos"] ** 2))
        nees += float(np.sum(e["nees"]))
        n += e["pos"].size
    return float(np.sqrt(se / n)), nees / n / 3, dict(res.stats)


def main() -> None:
    from swarmloc.events import Detection
    from swarmloc.experiments.association import association_events
    from swarmloc.experiments.sources import load_source
    from swarmloc.lie import between_xyt, log_xyt

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--path", default="../shared/data/mrclam/MRCLAM_Dataset6")
    p.add_argument("--duration", type=float, default=120.0)
    p.add_argument("--bins", default="0.5,1", help="bin widths [s], comma-separated")
    p.add_argument("--estimator", default="cekf")
    p.add_argument("--fov", type=float, default=1.2, help="PMR's field of view [rad] (MRCLAM's bearings: +-0.59)")
    p.add_argument("--max-unmatched", type=int, default=2, help="PMR's unmatched points per side of a registration")
    p.add_argument("--max-range", type=float, default=7.0, help="PMR's sensor range [m] (MRCLAM's ranges: <= 6.6)")
    a = p.parse_args()
    src = load_source(f"mrclam:{a.path}", duration=a.duration)
    robots = sorted(src.initial)
    n_det = sum(1 for e in src.events if isinstance(e, Detection) and e.target_is_robot)
    print(f"# {a.estimator}, MRCLAM {a.path.rsplit('/', 1)[-1]}, first {a.duration:g} s, robots {robots}, "
          f"{n_det} robot detections, landmarks on")  # fmt: skip
    print("| run | hand-offs | outside 99.9% gate | hand-off position error, median [m] | team pos RMSE [m] | "
          "ANEES/dof | wall [s] |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    t0 = time.perf_counter()
    rmse, anees, _ = score(src, src.events, a.estimator)
    print(f"| tagged | - | - | - | {rmse:.3f} | {anees:.2f} | {time.perf_counter() - t0:.0f} |")
    for b in [None] + [float(x) for x in a.bins.split(",")]:
        t0 = time.perf_counter()
        bank = {
            "fov": a.fov,
            "max_range": a.max_range,
            "max_unmatched": a.max_unmatched,
            "lone": False,  # PMR and the banks alone (the policy passes lone detections on to the nodes' assignment)
            **({} if b is None else {"bin_width": b}),
        }
        events, notes = association_events(src.events, "anonymous", robots, src.config.motion.noise(), bank=bank)
        hand = [e for e in events if isinstance(e, Detection) and e.kind == "pose"]
        bad = 0
        perr = []
        for e in hand:
            ta, tb = src.truth(e.observer, np.array([e.t]))[0], src.truth(e.target, np.array([e.t]))[0]
            y = log_xyt(between_xyt(np.asarray(e.z), between_xyt(ta, tb)))
            bad += int(y @ np.linalg.solve(e.cov, y) > 16.266)
            rel = between_xyt(ta, tb)
            perr.append(float(np.hypot(*(np.asarray(e.z)[:2] - rel[:2]))))
        rmse, anees, _ = score(src, events, a.estimator)
        name = "anonymous, one stamp" if b is None else f"anonymous, {b:g} s bins"
        med = f"{np.median(perr):.2f}" if perr else "-"
        print(f"| {name} | {len(hand)} | {bad} | {med} | {rmse:.3f} | {anees:.2f} | {time.perf_counter() - t0:.0f} |",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
