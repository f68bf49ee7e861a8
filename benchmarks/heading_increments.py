"""Does the motion model's yaw diffusion match how far the robots' headings drift from their odometry, per MRCLAM
dataset, without ground truth? (Issue 21: dataset 9 with landmarks is under-confident.)

For every pair of consecutive landmark snapshots of one robot 1 to 4 s apart (the robot's pose fitted from two or
more landmarks read at one instant, :func:`swarmloc.sensors.decorrelate.snapshot_poses`, at the pooled camera std),
the heading change of the fits minus the odometry's integrated yaw rate (as loaded: dataset 9's turn commands
clipped) is a residual whose variance is the heading diffusion over the interval plus the two fits' heading
variances. Printed per dataset, for intervals driven straight (under 0.05 rad of commanded turn) and turning (0.3
rad or more): the robust residual variance ``median(r^2) / 0.455`` (residuals beyond 0.5 rad left out: missed or
unexecuted turns), the fits' heading variance (median of the two summed) and the model's yaw diffusion over the
interval (``[motion]`` defaults, median).

    python benchmarks/heading_increments.py --datasets 1,2,4,6,9
    python benchmarks/heading_increments.py --datasets 1,2,3,4,6,9 --lodo-yaw 9,6,4   # + filter scores, ~5 min

``--lodo-yaw``: the yaw terms ``q_w0, q_w2, q_wv`` fitted by maximum likelihood to each dataset's residuals (a free
scale on the fits' variance per dataset; residuals beyond 0.5 rad left out), and for each dataset named, the
filters (rdl, diekf) scored as in :mod:`swarmloc_studies.lodo` with the median of the *other* datasets' fits.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
from _common import add_mrclam
from scipy.optimize import minimize

from swarmloc.config import DEFAULTS
from swarmloc.datasets.mrclam import load_mrclam
from swarmloc.motion import UnicycleNoise
from swarmloc.motion.calibrate import heading_increments
from swarmloc.sensors.decorrelate import snapshot_poses
from swarmloc_studies.lodo import DATASETS, detection_set, filter_scores, model_scores, own_std

CHI2_1_MEDIAN = 0.4549


def increments(data, range_std: float, bearing_std: float) -> dict[str, np.ndarray]:
    """Per consecutive snapshot pair of one robot 1-4 s apart (:func:`swarmloc.motion.calibrate.heading_increments`
    under the ``[motion]`` defaults): heading residual [rad], the fits' summed heading variance [rad^2], the model's
    yaw diffusion [rad^2], the commanded turn [rad] and ``phi`` = (duration [s], integral of w^2 [rad^2/s],
    distance [m]) over the interval (the same function under unit noises of one term each)."""
    sp = snapshot_poses(detection_set(data), range_std, bearing_std)
    inc = heading_increments(data.odometry, sp, DEFAULTS.motion.noise(), max_gap=4.0)
    units = (UnicycleNoise(q_v0=0.0, q_w0=1.0), UnicycleNoise(q_v0=0.0, q_w0=0.0, q_w2=1.0),
             UnicycleNoise(q_v0=0.0, q_w0=0.0, q_wv=1.0))  # fmt: skip
    phi = [heading_increments(data.odometry, sp, u, max_gap=4.0)["model"] for u in units]
    return {**inc, "phi": np.stack(phi, axis=-1)}


def fit_yaw(inc: dict[str, np.ndarray]) -> np.ndarray:
    """``(scale of the fits' variance, q_w0, q_w2, q_wv)`` maximizing the Gaussian likelihood of the residuals
    within 0.5 rad, variance ``scale * fits' variance + q_w0 T + q_w2 int w^2 + q_wv int |v|``."""
    ok = np.abs(inc["res"]) < 0.5
    r, f, phi = inc["res"][ok], inc["fit"][ok], inc["phi"][ok]

    def nll(p: np.ndarray) -> float:
        var = np.exp(p[0]) * f + phi @ np.exp(p[1:])
        return 0.5 * float(np.sum(np.log(var) + r * r / var))

    starts = ([0.0, np.log(1e-3), np.log(0.05), np.log(0.02)], [-1.0, -9.0, -5.0, -6.0])
    opts = {"maxiter": 4000, "xatol": 1e-4, "fatol": 1e-6}
    best = min((minimize(nll, x0, method="Nelder-Mead", options=opts) for x0 in starts), key=lambda o: o.fun)
    return np.exp(best.x)


def lodo_yaw(root: Path, fitted: list[int], scored: list[int]) -> None:
    """Print the per-dataset yaw fits, then the filter scores of each dataset of ``scored`` with the median of the
    other fitted datasets' yaw terms."""
    fits = {k: fit_yaw(increments(load_mrclam(root / f"MRCLAM_Dataset{k}"), 0.158, 0.0046)) for k in fitted}
    for k, p in fits.items():
        print(f"dataset {k}: fits' variance x{p[0]:.2f}, q_w0 {p[1]:.2e}, q_w2 {p[2]:.3f}, q_wv {p[3]:.2e}")
    sets = {k: detection_set(load_mrclam(root / f"MRCLAM_Dataset{k}", require=("measurements",))) for k in DATASETS}
    ms = model_scores(sets)
    for k in scored:
        q = np.median([fits[j][1:] for j in fits if j != k], axis=0)
        motion = dataclasses.replace(DEFAULTS.motion, q_w0=float(q[0]), q_w2=float(q[1]), q_wv=float(q[2]))
        data = load_mrclam(root / f"MRCLAM_Dataset{k}")
        m, fold = ms["models"][k][ms["chosen"]], ms["folds"][k][ms["chosen"]]
        cfg = dataclasses.replace(DEFAULTS, motion=motion)
        rows = filter_scores(data, m, ["rdl", "diekf"], True, 200.0, config=cfg, reference_std=own_std(m, fold))
        for e in ("rdl", "diekf"):
            r = rows[e]
            truth = f", RMSE {r['pos_rmse']:.3f} m, ANEES/dof {r['anees']:.2f}" if "anees" in r else ""
            print(f"left out {k}, yaw terms ({q[0]:.1e}, {q[1]:.3f}, {q[2]:.1e}), {e}: score {r['nis_ratio_ref']:.2f}, "
                  f"beyond gate {r['beyond_gate_ref']:.3f}{truth}", flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_mrclam(ap)
    ap.add_argument("--datasets", default="1,2,4,6,9")
    ap.add_argument("--range-std", type=float, default=0.158, help="[m] the snapshot fits' range std")
    ap.add_argument("--bearing-std", type=float, default=0.0046, help="[rad] the snapshot fits' bearing std")
    ap.add_argument("--lodo-yaw", default=None, help="datasets to score with yaw terms fitted on the others")
    a = ap.parse_args()
    print("| dataset | intervals | n | residual var (robust) [rad^2] | fits' var [rad^2] | model diffusion [rad^2] "
          "| beyond 0.5 rad |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for k in (int(x) for x in a.datasets.split(",")):
        inc = increments(load_mrclam(a.mrclam / f"MRCLAM_Dataset{k}"), a.range_std, a.bearing_std)
        for name, s in (("straight", inc["turn"] < 0.05), ("turning", inc["turn"] >= 0.3)):
            keep = s & (np.abs(inc["res"]) < 0.5)
            print(f"| {k} | {name} | {keep.sum()} | {np.median(inc['res'][keep] ** 2) / CHI2_1_MEDIAN:.4f} | "
                  f"{np.median(inc['fit'][keep]):.4f} | {np.median(inc['model'][keep]):.4f} | "
                  f"{np.mean(np.abs(inc['res'][s]) >= 0.5):.3f} |", flush=True)  # fmt: skip
    if a.lodo_yaw:
        lodo_yaw(a.mrclam, [int(x) for x in a.datasets.split(",")], [int(x) for x in a.lodo_yaw.split(",")])


if __name__ == "__main__":
    main()
