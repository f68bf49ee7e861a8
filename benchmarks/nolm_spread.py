"""How far apart do an honest filter's scores land from one run to the next without landmarks? ``diekf`` with its
model *exactly* the simulator's (process noise, sensor noise, initial covariance), on independent MRCLAM-like
teams, scored as the leave-one-dataset-out study scores a recording: the held-out landmark NIS ratio
``median(NIS) / 1.386`` and ``ANIS/dof`` of readings the filter never fused, and beside them ANEES/dof against the
truth (mean NEES / 3 on a 4 Hz grid).

    python benchmarks/nolm_spread.py --seeds 60 --duration 200 --jobs 2 --out nolm_spread.json

The team (a stand-in for MRCLAM's five robots and their cameras, not a fit to it): 5 robots started in a 6 m square,
random piecewise-constant commands (0.05-0.3 m/s, |w| <= 0.5 rad/s, a new one every 2-5 s) and wheel-speed
diffusion ``D`` (yaw diffusion ``2 D r^2 / l^2`` rad^2/s: 1.1e-3 at the default ``D = 0.02``, MRCLAM's ``q_w0``);
robot detections by range and bearing in a 60 deg field of view up to 5 m at 5 Hz (0.1 m, 2 deg); 15 landmarks on a
jittered grid over [-3, 9]^2 read the same way (5 Hz, 60 deg, 5 m), never fused, only scored; initial beliefs of
std 0.1 m and 0.035 rad about the true start (the truth a sample of them). Without landmarks the team's common
position and heading are unobservable: every run is one draw of their drift, which is why the per-run scores spread.
Prints each score's quantiles over the seeds, the share of runs in [0.5, 2], and that share to the sixth power
(the chance that six independent recordings all land in the band).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.config import DEFAULTS, InitialConfig, MotionConfig
from swarmloc.estimators import make_team, node_options
from swarmloc.evaluation.heldout import BAND, nis_summary, reading_times, tracks_nis
from swarmloc.evaluation.metrics import DOF, errors
from swarmloc.events import Detection, Kind
from swarmloc.runner import run
from swarmloc.runner.fanout import fan_out
from swarmloc.sim.landmarks import LandmarkSensor, landmark_detections, landmark_streams, place_landmarks
from swarmloc.sim.scenarios import random_team
from swarmloc.sim.simulator import RelativeSensor
from swarmloc.sim.source import sim_source

FOV = math.radians(60.0)
SIGMA_RANGE, SIGMA_BEARING = 0.1, math.radians(2.0)
RATE = 5.0  # [Hz] robot and landmark readings: about the MRCLAM recordings' counts per robot and second


def one_seed(seed: int, duration: float, D: float, estimator: str) -> dict[str, Any]:
    """One team: the scores of ``estimator`` run without landmarks (module docstring)."""
    camera = RelativeSensor(rate=RATE, max_range=5.0, fov=FOV, kinds=(Kind.RANGE_BEARING,), sigma_range=SIGMA_RANGE,
                            sigma_bearing=SIGMA_BEARING)  # fmt: skip
    sim = random_team(5, duration, seed, area=6.0, D=D, sensor=camera)
    config = dataclasses.replace(DEFAULTS, motion=MotionConfig.from_noise(sim.unicycle_noise()),
                                 initial=InitialConfig(std_xy=0.1, std_theta=0.035))  # fmt: skip
    src = sim_source(sim, "nolm_spread", config)
    map_ss, noise_ss = landmark_streams(seed)
    landmarks = place_landmarks(15, (-3.0, 9.0, -3.0, 9.0), map_ss)
    sensor = LandmarkSensor(rate=RATE, max_range=5.0, fov=FOV, sigma_range=SIGMA_RANGE, sigma_bearing=SIGMA_BEARING)
    readings = landmark_detections(sim, landmarks, sensor, noise_ss)
    grid = src.record_times()
    at = reading_times(readings)
    times = np.union1d(grid, at)
    nodes = make_team(estimator, src.initial, **node_options(estimator, config, None, src.t_start))
    res = run(nodes, src.events, times, truth=src.truth, name=estimator)
    on_grid = np.isin(times, grid)
    nees = np.concatenate([errors(res.tracks[r])["nees"][on_grid] for r in src.robots])
    scores = nis_summary(tracks_nis(res.tracks, readings, landmarks, (SIGMA_RANGE, SIGMA_BEARING)))
    mutual = sum(1 for e in src.events if isinstance(e, Detection) and e.target_is_robot)
    return {"seed": seed, "anees": float(np.mean(nees) / DOF), **scores, "mutual": mutual,
            "fused": int(res.stats.get("fused", 0))}  # fmt: skip


def spread(values: np.ndarray) -> dict[str, float]:
    """Quantiles of per-run scores, the share in :data:`BAND` and that share to the sixth power."""
    inside = float(np.mean((values >= BAND[0]) & (values <= BAND[1])))
    q = np.quantile(values, [0.0, 0.05, 0.25, 0.5, 0.75, 0.95, 1.0])
    return {"min": q[0], "q05": q[1], "q25": q[2], "median": q[3], "q75": q[4], "q95": q[5], "max": q[6],
            "mean": float(values.mean()), "in_band": inside, "six_in_band": inside**6}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=60)
    ap.add_argument("--duration", type=float, default=200.0, help="seconds per run (the LODO study's 200 s)")
    ap.add_argument("--D", type=float, default=0.02, help="wheel-speed diffusion of the simulator [rad^2/s]")
    ap.add_argument("--estimator", default="diekf")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    t0 = time.perf_counter()
    tasks = [(s, a.duration, a.D, a.estimator) for s in range(a.seeds)]
    runs = sorted((r for _, r in fan_out(one_seed, tasks, jobs=a.jobs)), key=lambda r: r["seed"])
    report = {k: spread(np.array([r[k] for r in runs])) for k in ("nis_ratio", "anis", "anees")}
    print(f"{a.estimator}, {a.seeds} seeds x {a.duration:g} s, D = {a.D:g}, {time.perf_counter() - t0:.0f} s; "
          f"held-out readings per run {np.median([r['readings'] for r in runs]):.0f}, robot detections "
          f"{np.median([r['mutual'] for r in runs]):.0f} (medians)")  # fmt: skip
    print("| score | min | 5% | 25% | median | 75% | 95% | max | runs in [0.5, 2] | six in a row |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for k, s in report.items():
        print(f"| {k} | {s['min']:.2f} | {s['q05']:.2f} | {s['q25']:.2f} | {s['median']:.2f} | {s['q75']:.2f} | "
              f"{s['q95']:.2f} | {s['max']:.2f} | {s['in_band']:.2f} | {s['six_in_band']:.2f} |")  # fmt: skip
    if a.out is not None:
        a.out.write_text(json.dumps({"args": vars(a) | {"out": str(a.out)}, "report": report, "runs": runs}, indent=1))


if __name__ == "__main__":
    main()
