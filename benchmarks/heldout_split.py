"""Why the truth-free score with landmarks reads under-confident on some MRCLAM recordings: the held-out landmark
innovations of ``swarmloc evaluate mrclam``'s score split into range and bearing, the belief's share of their
covariance into heading and position, the bulk against the tail, and the tail by robot and time.

    python benchmarks/heldout_split.py --datasets 9,1 [--duration 300] [--calibrate-yaw] [--config X.toml]

Each dataset: the runs of ``swarmloc evaluate mrclam DIR --duration 300 --estimators diekf``'s score (landmarks on,
three landmark folds held out in turn, from the truth-free start, the evaluation's camera model and configuration;
``--calibrate-yaw`` as the command's). Printed: the score (``median(NIS) / 1.386``, as the command prints it); per
component, the median of ``r^2 / S`` over the chi-square median of 1 dof (1: consistent; ``S`` the component's
variance, belief and reading) and the means of ``r^2``, of the belief's share ``H P H'`` (its heading variance's
part, and the rest: position and the cross terms) and of the reading's variance; the bearing's tail (``|r|`` beyond
``--tail`` rad): its share of the readings and of the sum of ``r^2``, and the bulk's mean ``r^2`` against its mean
``S``; the heading std's quartiles; per robot, its readings, those in the tail and the spans [s after the start of
the scored span] they fall in.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
from _common import add_mrclam

from swarmloc.config import DEFAULTS, load_config
from swarmloc.datasets.mrclam import load_mrclam
from swarmloc.evaluation.heldout import MEDIAN_CHI2_2, landmark_innovations
from swarmloc.experiments.evaluate import RECOMMENDED
from swarmloc.experiments.mrclam import detection_set, mrclam_start, mrclam_stream, yaw_calibrated
from swarmloc.experiments.truthfree import truth_free_score

MEDIAN_CHI2_1 = 0.454936


def innovations(k: int, root: Path, config: Any, duration: float, yaw: bool) -> dict[str, Any]:
    """Every held-out landmark reading's innovation terms on dataset ``k`` (module docstring), as arrays."""
    data = load_mrclam(root / f"MRCLAM_Dataset{k}")
    events, camera = mrclam_stream(data, config, duration, landmarks=True)
    if yaw:
        config = yaw_calibrated(data, camera, config)[0]
    t_end = min(data.t_end, data.t_start + duration)
    start = mrclam_start(data, config, t_end)
    first = (start.t0, start.beliefs) if not start.truth and start.t0 > data.t_start else None
    std = (camera.range.std, camera.bearing.std)
    score = truth_free_score(data, detection_set(data), events, RECOMMENDED, config, std, True, t_end, start=first,
                             keep_runs=True)  # fmt: skip
    t0 = data.t_start + score["t0_s"]
    rows: dict[str, list[np.ndarray]] = {}
    for held in score["runs"]:
        for robot, tr in held.run.tracks.items():
            mine = [d for d in held.readings if d.observer == robot]
            if not mine:
                continue
            li = landmark_innovations(tr.times, tr.mean, tr.cov, mine, data.landmarks, std)
            nis = li.nis()
            ok = li.ok & np.isfinite(nis)
            P = li.P[ok]
            heading = np.zeros_like(P)
            heading[:, 2, 2] = P[:, 2, 2]
            H = li.H[ok]
            got = {"nis": nis[ok], "r": li.r[ok], "belief": li.belief[ok], "noise": li.noise[ok],
                   "heading": H @ heading @ np.swapaxes(H, 1, 2), "heading_std": np.sqrt(P[:, 2, 2]),
                   "robot": np.full(ok.sum(), robot), "t": np.array([d.t for d in mine])[ok] - t0}  # fmt: skip
            for key, v in got.items():
                rows.setdefault(key, []).append(v)
    return {key: np.concatenate(v) for key, v in rows.items()}


def spans(t: np.ndarray, gap: float = 5.0) -> list[tuple[int, int]]:
    """The runs of sorted times ``t`` [s] with no gap over ``gap`` s, as rounded ``(first, last)``."""
    if not t.size:
        return []
    cut = np.flatnonzero(np.diff(t) > gap)
    ends = zip(np.r_[0, cut + 1], np.r_[cut, t.size - 1], strict=True)
    return [(round(float(t[a])), round(float(t[b]))) for a, b in ends]


def report(k: int, x: dict[str, Any], tail: float) -> None:
    """Print dataset ``k``'s split (module docstring)."""
    print(f"dataset {k}: score {np.median(x['nis']) / MEDIAN_CHI2_2:.2f} over {x['nis'].size} held-out readings")
    for c, name in ((0, "range"), (1, "bearing")):
        r2, sp, sn, sh = x["r"][:, c] ** 2, x["belief"][:, c, c], x["noise"][:, c, c], x["heading"][:, c, c]
        print(f"  {name}: median r^2/S {np.median(r2 / (sp + sn)) / MEDIAN_CHI2_1:.2f}; means: r^2 {r2.mean():.3g}, "
              f"belief {sp.mean():.3g} (heading {sh.mean():.3g}, position {(sp - sh).mean():.3g}), reading "
              f"{sn.mean():.3g}")  # fmt: skip
    rb = np.abs(x["r"][:, 1])
    S = x["belief"][:, 1, 1] + x["noise"][:, 1, 1]
    big = rb > tail
    print(f"  bearing |r| > {tail} rad: {big.mean():.1%} of the readings, {(rb[big] ** 2).sum() / (rb**2).sum():.1%} "
          f"of the sum of r^2; the rest: mean r^2 {np.mean(rb[~big] ** 2):.3g} against mean S {S[~big].mean():.3g}; "
          f"|r| quantiles 50/90/95/99%: {np.round(np.quantile(rb, [0.5, 0.9, 0.95, 0.99]), 3).tolist()}")  # fmt: skip
    print(f"  heading std [rad] quartiles: {np.round(np.quantile(x['heading_std'], [0.25, 0.5, 0.75]), 3).tolist()}")
    for robot in np.unique(x["robot"]):
        m = x["robot"] == robot
        order = np.argsort(x["t"][m])
        tb = x["t"][m][order][rb[m][order] > tail]
        print(f"  robot {int(robot)}: {m.sum()} readings, {tb.size} beyond {tail} rad, in {spans(tb)[:8]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_mrclam(ap)
    ap.add_argument("--datasets", default="9")
    ap.add_argument("--duration", type=float, default=300.0, help="[s] from the recording's start, as evaluate's")
    ap.add_argument("--config", type=Path, default=None)
    ap.add_argument("--calibrate-yaw", action="store_true", help="as swarmloc evaluate's (on the whole recording)")
    ap.add_argument("--tail", type=float, default=0.3, help="[rad] a bearing innovation beyond it is in the tail")
    a = ap.parse_args()
    config = DEFAULTS if a.config is None else load_config(a.config)
    for k in (int(s) for s in a.datasets.split(",")):
        report(k, innovations(k, a.mrclam, config, a.duration, a.calibrate_yaw), a.tail)


if __name__ == "__main__":
    main()
