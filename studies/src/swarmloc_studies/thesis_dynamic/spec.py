"""Set-up of thesis sec. 5.2.2 / Table 6.1: noise levels, initial covariance, run lengths and seed counts, the
estimator runs (:data:`RUNS`: class, options, plot style, Table 6.1 notes) and the double-counting conditions."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from swarmloc.estimators import CentralizedEKF, DeadReckoning, DistributedEKF, ExpFusion, MonteCarloLocalization
from swarmloc.node import Node

NOISE_LEVELS = (0.01, 0.05, 0.1)
"""Relative-pose measurement noise std [m] of the thesis' three runs (Figs 5.15, 5.18, 5.21)."""

INIT_VAR = 1e-6
"""Initial covariance ``INIT_VAR * I`` (exponential coordinates): the initial poses are known, as in the thesis."""

GT_NOISE = 0.05
ABLATION_NOISE = 0.05
FULL: dict[str, Any] = {"duration": 90.0, "gt_duration": 500.0, "gt_seeds": 5, "ablation_seeds": 8}
QUICK: dict[str, Any] = {"duration": 30.0, "gt_duration": 60.0, "gt_seeds": 3, "ablation_seeds": 3, "seeds": 3}

FIG_ERR = {"0.01": "5.15", "0.05": "5.18", "0.1": "5.21"}
"""Thesis figure of the error against time at each noise level (its ``f"{noise:g}"``)."""
FIG_TRAJ = {"0.01": "5.14", "0.05": "5.17", "0.1": "5.20"}
"""Thesis figure of the trajectories at each noise level."""

CURVE_EVERY = 10
"""Error-vs-time curves are stored in the JSON every ``CURVE_EVERY``-th record (1 s); figures use all records."""


@dataclass(frozen=True)
class EstimatorSpec:
    key: str
    label: str
    cls: type[Node]
    kwargs: tuple[tuple[str, Any], ...]
    color: str
    style: str
    multiple_detections: str
    note: str


RUNS: dict[str, EstimatorSpec] = {
    s.key: s
    for s in (
        EstimatorSpec(
            "dr", "Dead reckoning", DeadReckoning, (), "magenta", "-", "n/a", "ignores detections (prediction only)"
        ),
        EstimatorSpec(
            "dekf",
            "Distributed EKF",
            DistributedEKF,
            (),
            "black",
            "-",
            "no",
            "one detection at a time; neighbour covariance added to the innovation covariance",
        ),
        EstimatorSpec(
            "expfusion",
            "Thesis estimator (ExpFusion, 2nd order)",
            ExpFusion,
            (),
            "red",
            "-",
            "yes",
            "all detections of one instant fused in one closed-form step",
        ),
        EstimatorSpec(
            "expfusion1",
            "ExpFusion, 1st order (ablation)",
            ExpFusion,
            (("order", 1),),
            "darkorange",
            "--",
            "yes",
            "as the thesis estimator, first-order convolution and fusion",
        ),
        EstimatorSpec(
            "cekf",
            "Centralized EKF (reference)",
            CentralizedEKF,
            (),
            "green",
            "-",
            "no",
            "one joint filter; detections processed one at a time (exact for a joint Kalman update)",
        ),
        EstimatorSpec(
            "mcl",
            "Multi-robot MCL (Fox et al. 2000, thesis sec. 2.2)",
            MonteCarloLocalization,
            (("particles", 500),),
            "royalblue",
            "-",
            "no (thesis Table 2.1)",
            "500 particles per robot; the neighbour's answer is a Gaussian fitted to its particles",
        ),
    )
}

ABLATION_ESTIMATORS = ("expfusion", "dekf", "cekf")
GT_ESTIMATORS = ("dr", "dekf", "expfusion", "cekf")
"""The 500 s ground-truth-neighbour runs leave out the first-order ablation (compared in the main runs) for time."""
ABLATIONS: dict[str, tuple[str, int, bool]] = {
    # key: (description, keep every k-th detection instant, only robot 1 fuses)
    "mutual_10hz": ("both robots fuse, every detection (10 Hz), as in the thesis", 1, False),
    "mutual_1hz": ("both robots fuse, every 10th detection instant (1 Hz)", 10, False),
    "mutual_0.1hz": ("both robots fuse, every 100th detection instant (0.1 Hz)", 100, False),
    "oneway_10hz": ("only robot 1 fuses (robot 2 = dead reckoning), 10 Hz", 1, True),
    "oneway_1hz": ("only robot 1 fuses (robot 2 = dead reckoning), 1 Hz", 10, True),
}
