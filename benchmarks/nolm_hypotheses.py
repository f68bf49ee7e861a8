"""Four suspected causes of ``diekf``'s out-of-band truth-free scores without landmarks, each measured
without ground truth on the MRCLAM recordings:

* ``gap``: the odometry's sample interval. A command held over the interval to the next sample is wrong, when the
  command changes, for the unknown part of the interval: with the switch instant uniform in it, a yaw variance
  ``(dw dt)^2 / 12``. Printed per robot over the first 300 s: that variance summed, against the model's yaw
  diffusion over the same span (``[motion]`` defaults).
* ``robots``: which robots each recording has odometry (and so a belief) for, and how many detections of the
  others there are (a robot without odometry is not estimated: its readings and the detections of it are left out).
* ``scale``: per robot, the heading change of consecutive landmark snapshots (1 to 8 s apart) minus the odometry's
  yaw integral, regressed on that integral and the interval: ``r = (a_w - 1) yaw + b_w dt`` (residuals beyond 0.5
  rad left out), over the whole recording; and the residuals' tail: ``z = r / sqrt(fits' variance + model's yaw
  diffusion)``, ``median(z^2) / 0.455`` (1 for the model's Gaussian), ``mean(z^2)`` and ``P(|z| > 3)``.
* ``lag``: the odometry's stamps shifted by ``tau`` against the camera's: the robust variance ``median(r^2) / 0.455``
  of the turning pairs' residuals (commanded turn 0.3 rad or more) for each ``tau``; ``--filter`` also runs
  :func:`nolm_diagnosis.diagnose` (the score of ``swarmloc evaluate mrclam DIR --duration 300 --estimators diekf
  --landmarks off``) with the odometry shifted by each ``tau`` and with its yaw rates scaled by ``--yaw-scale``.

    python benchmarks/nolm_hypotheses.py --datasets 1,2,3,4,6,9 [--filter 9,3,2,4] [--yaw-scale 0.92]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

import numpy as np
from _common import add_mrclam

from swarmloc.config import DEFAULTS
from swarmloc.datasets.mrclam import ROBOT_SUBJECTS, load_mrclam
from swarmloc.experiments.mrclam import detection_set
from swarmloc.motion import UnicycleNoise
from swarmloc.motion.calibrate import heading_increments, held_integral
from swarmloc.sensors.decorrelate import PRIOR_BEARING_STD, PRIOR_RANGE_STD, snapshot_poses

MED1 = 0.454936  # chi-square median, 1 dof
TAUS = (-1.0, -0.5, -0.25, -0.12, 0.0, 0.12, 0.25, 0.5, 1.0)
NOISE = UnicycleNoise(**{f.name: getattr(DEFAULTS.motion, f.name) for f in dataclasses.fields(UnicycleNoise)})


def gap(data: Any, span: float = 300.0) -> list[str]:
    """Hold-gap yaw variance against the model's yaw diffusion, per robot, over the first ``span`` s."""
    m, rows = DEFAULTS.motion, []
    for r, o in sorted(data.odometry.items()):
        o = o[(o[:, 0] >= data.t_start) & (o[:, 0] <= data.t_start + span)]
        dt, v, w, dw = np.diff(o[:, 0]), o[:-1, 1], o[:-1, 2], np.diff(o[:, 2])
        q = ((m.q_w0 + m.q_w1 * abs(w) + m.q_w2 * w**2 + m.q_wv * abs(v)) * dt).sum()
        hold = ((dw * dt) ** 2 / 12).sum()
        rows.append(f"r{r}: dt {np.median(dt):.3f} s, {int((abs(dw) > 1e-6).sum())} changes, hold {hold:.4f} "
                    f"rad^2 / model {q:.3f} rad^2 = {hold / q:.3f}")  # fmt: skip
    return rows


def scale(data: Any, snaps: dict[str, np.ndarray]) -> list[str]:
    """Per robot ``a_w, b_w`` from the snapshot heading increments, and the normalized residuals' tail."""
    inc = heading_increments(data.odometry, snaps, NOISE)
    rows = []
    for r, o in sorted(data.odometry.items()):
        ts = snaps["t"][snaps["observer"] == r]
        yaw = np.interp(ts, o[:, 0], held_integral(o[:, 0], o[:, 2]))
        dt = np.diff(ts)
        ok = (dt >= 1.0) & (dt <= 8.0) & (ts[:-1] >= o[0, 0]) & (ts[1:] <= o[-1, 0])
        res = inc["res"][inc["robot"] == r]
        keep = np.abs(res) < 0.5
        a = np.column_stack([np.diff(yaw)[ok], dt[ok]])[keep]
        c = np.linalg.lstsq(a, res[keep], rcond=None)[0]
        rows.append(f"r{r}: a_w {1 + c[0]:.3f} b_w {c[1]:+.4f} rad/s ({int(keep.sum())} pairs)")
    z = inc["res"] / np.sqrt(inc["fit"] + inc["model"])
    rows.append(f"tail: {z.size} pairs, median(z^2)/0.455 {np.median(z**2) / MED1:.2f}, mean(z^2) "
                f"{np.mean(z**2):.2f}, P(|z|>3) {np.mean(np.abs(z) > 3):.2%}")  # fmt: skip
    return rows


def shifted(data: Any, tau: float, yaw_scale: float = 1.0) -> Any:
    """``data`` with every odometry stamp shifted by ``tau`` [s] and its yaw rates scaled by ``yaw_scale``."""
    odo = {r: np.column_stack([o[:, 0] + tau, o[:, 1], o[:, 2] * yaw_scale]) for r, o in data.odometry.items()}
    return dataclasses.replace(data, odometry=odo)


def lag(data: Any, snaps: dict[str, np.ndarray]) -> str:
    """Robust residual variance of the turning pairs for each odometry shift in :data:`TAUS`."""
    out = []
    for tau in TAUS:
        inc = heading_increments(shifted(data, tau).odometry, snaps, NOISE)
        sel = (np.abs(inc["res"]) < 0.5) & (inc["turn"] > 0.3)
        out.append(f"{tau:+.2f}: {np.median(inc['res'][sel] ** 2) / MED1:.4f}")
    return ", ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_mrclam(ap)
    ap.add_argument("--datasets", default="1,2,3,4,6,9")
    ap.add_argument("--filter", default="", help="datasets to score with shifted odometry (diekf, landmarks off)")
    ap.add_argument("--taus", default="0,0.12,0.25")
    ap.add_argument("--yaw-scale", type=float, default=0.0, help="also score with the yaw rates scaled by this")
    a = ap.parse_args()
    for k in (int(x) for x in a.datasets.split(",")):
        data = load_mrclam(a.mrclam / f"MRCLAM_Dataset{k}")
        snaps = snapshot_poses(detection_set(data), PRIOR_RANGE_STD, PRIOR_BEARING_STD)
        print(f"dataset {k}")
        print("  gap:", *gap(data), sep="\n    ")
        others = {
            r: {s: int((m[:, 1] == s).sum()) for s in ROBOT_SUBJECTS if s not in data.odometry}
            for r, m in data.measurements.items()
        }
        print(f"  robots with odometry {sorted(data.odometry)}; detections of the others: {others}")
        print("  scale:", *scale(data, snaps), sep="\n    ")
        print("  lag (turning pairs, robust residual variance [rad^2] by odometry shift [s]):", lag(data, snaps))
    if not a.filter:
        return
    sys.path.insert(0, str(Path(__file__).parent))
    import nolm_diagnosis as nd

    loader = nd.load_mrclam
    runs = [(float(t), 1.0) for t in a.taus.split(",")] + ([(0.0, a.yaw_scale)] if a.yaw_scale else [])
    for tau, ys in runs:
        nd.load_mrclam = lambda p, *x, tau=tau, ys=ys, **kw: shifted(loader(p, *x, **kw), tau, ys)
        for k in (int(x) for x in a.filter.split(",")):
            r = nd.diagnose(k, a.mrclam, DEFAULTS, 300.0)
            per = {q: round(v["nis_ratio"], 2) for q, v in r["robots"].items()}
            print(f"tau {tau:+.2f} s, yaw scale {ys}: dataset {k} score {r['score']:.2f}, per robot {per}", flush=True)


if __name__ == "__main__":
    main()
