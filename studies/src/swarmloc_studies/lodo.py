"""Leave-one-dataset-out (LODO) check of the MRCLAM camera model: does a model fitted on other recordings hold on
one it has never seen?

Only dataset 6 has ground truth here, so every dataset is scored without it, by two truth-free scores:

* **model score** (every dataset, 5 and 8 included): the held-out negative log-likelihood per residual of the
  left-out dataset's landmark-snapshot residual streams under the model's correlated error process, and the
  robust variance ratio ``median(u^2) / (0.4549 std^2)`` (1: the std fits)
  (:func:`swarmloc.sensors.decorrelate.heldout_score`). It chooses the model and its regularisation;
* **filter score** (datasets with odometry: 1, 2, 3, 4, 6, 9): each estimator runs on the left-out dataset with the
  model fitted on the others; at every landmark reading the observer's belief an instant before it (1 us) is pushed
  through the range-bearing model, and the *normalized innovation squared* ``NIS = r' (H P H' + R + L)^-1 r`` (``R``
  the reading's variance, ``L`` the landmark's map std) is compared with chi-square of 2 dof. Reported: the robust
  ratio ``median(NIS) / 1.386`` per dof (1: consistent; above: over-confident), the mean ``ANIS/dof = mean(NIS) / 2``
  (the truth-free twin of ANEES per dof: every scored reading, tails included), and the share of readings beyond the
  0.997 gate (heavy tails, barcode misreads). The two disagree where the errors are heavy-tailed: a covariance that
  covers a few large errors has a small median NIS. Only readings that never entered the belief are scored: with
  landmarks off, all of them; with landmarks on, the landmarks are split into folds and each fold's readings are
  scored against a run without that fold (earlier readings of the same landmark, whose errors correlate with this one,
  would otherwise be in the belief). ``R`` is taken twice: the model's std, and the left-out dataset's own std from
  its snapshot residuals (truth-free; the filter never uses it). With landmarks the belief's ``H P H'`` is of the
  order of ``R``, so a model std that is too large for the recording would make the NIS small whatever ``P`` is; the
  second ``R`` takes that out, so the score tests the belief's covariance. On dataset 6 position RMSE and ANEES per
  dof against the truth are given too.

Initial beliefs are truth-free on every dataset (dataset 6 included, so that its row is run as the others are):
each robot's landmark snapshots give its pose by the weighted fit of :mod:`swarmloc.sensors.decorrelate`
(covariance from the a-priori std 0.1 m, 0.035 rad), filtered as absolute pose fixes from its first one up to the
latest of the robots' first snapshots, where the run starts (the start of ``swarmloc evaluate`` without truth:
:func:`swarmloc.experiments.truthfree.fused_from_snapshots`; ``start=`` of :func:`filter_scores` takes another).
Runs cover ``duration`` s from there (part of each dataset, for compute).

**A smoother's delayed output** (``flsd``, ``fls``: a row ``<name>_delayed``) is scored on the same held-out
readings as the causal belief: at each reading's stamp, the pose filed last before it carried through the robot's
odometry (:func:`swarmloc.evaluation.delayed.carried_output`). Readings before its first filing, or in the run's
last lag, have none; the row ``causal`` of its columns scores the causal belief on the readings it does score.

**Yaw diffusion calibrated on the recording itself** (run ``on+yaw``): the motion model's yaw terms scaled by the
factor :func:`yaw_calibration` fits to the left-out recording's own snapshot heading increments
(:mod:`swarmloc.motion.calibrate`; truth-free, camera std of the held-out model). The fit never sees what scores
it: pairs with an end in the scored span are left out, and a run that holds a landmark fold out calibrates without
that fold's readings. The camera model stays held out; the robots' own motion is what is calibrated, as a user
would calibrate from a log of their robots before a run.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np

from swarmloc.config import DEFAULTS, Config, MotionConfig
from swarmloc.datasets.mrclam import MRCLAMData, load_mrclam, mrclam_events
from swarmloc.estimators import make_team, node_options
from swarmloc.evaluation.delayed import carried_output
from swarmloc.evaluation.heldout import (
    RECORD_LEAD,
    landmark_folds,
    landmark_nis,
    nis_summary,
    reading_times,
    tracks_nis,
)
from swarmloc.evaluation.metrics import evaluate
from swarmloc.experiments.mrclam import detection_set, yaw_calibration
from swarmloc.experiments.truthfree import HeldOutRun, fused_from_snapshots, heldout_runs, landmark_readings
from swarmloc.gaussian import GroupGaussian
from swarmloc.motion.calibrate import scale_yaw
from swarmloc.runner import RunResult, TruthFn, run
from swarmloc.runner.fanout import fan_out
from swarmloc.sensors.decorrelate import (
    PRIOR_BEARING_STD,
    PRIOR_RANGE_STD,
    CameraModel,
    DetectionSet,
    ErrorComponent,
    calibrate_pooled,
    decorrelate,
    heldout_residuals,
    heldout_score,
)

if TYPE_CHECKING:
    from distributed import Client

__all__ = [
    "CUTS",
    "DATASETS",
    "detection_set",
    "filter_scores",
    "lodo",
    "lodo_markdown",
    "own_std",
    "yaw_calibration",
]

StartFn: TypeAlias = Callable[[MRCLAMData, DetectionSet, Config], tuple[float, Mapping[int, GroupGaussian]]]
"""A truth-free start: ``(data, its detection set, config) -> (t0 [s], robot -> initial belief)``."""

DATASETS: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 8, 9)
CUTS: tuple[float, ...] = (2.5, 3.0, 4.0)
"""Candidate inlier cuts of the pooled variance components (the regularisation chosen by the held-out score)."""


def white_model(model: CameraModel) -> CameraModel:
    """``model``'s std with white errors (no correlation): the candidate that ignores time correlation."""
    return dataclasses.replace(
        model, range=ErrorComponent(model.range.std), bearing=ErrorComponent(model.bearing.std), source="white"
    )


def model_scores(sets: dict[int, DetectionSet], cuts: Sequence[float] = CUTS) -> dict[str, Any]:
    """Per left-out dataset: the truth-free held-out score of every candidate model fitted on the other datasets
    (``pooled cut=c`` and its white twin), of the a-priori white model, and, for reference only, of the model
    fitted on the left-out dataset itself (``self``, not a held-out fit). ``chosen``: the LODO candidate with the
    lowest median held-out NLL over the folds (``mean_nll`` holds these medians)."""
    held = {}
    for k, ds in sets.items():  # weights of the left-out set's own fit: one neutral basis for every candidate
        own = calibrate_pooled([ds])
        held[k] = heldout_residuals(ds, own.range.std, own.bearing.std)
    folds: dict[int, dict[str, Any]] = {}
    models: dict[int, dict[str, CameraModel]] = {}
    for k in sets:
        train = [sets[j] for j in sets if j != k]
        cands: dict[str, CameraModel] = {
            "a priori white": CameraModel(
                ErrorComponent(PRIOR_RANGE_STD), ErrorComponent(PRIOR_BEARING_STD), source="a priori, white"
            )
        }
        for c in cuts:
            m = calibrate_pooled(train, cut=c)
            cands[f"pooled cut={c:g}"] = m
            cands[f"pooled cut={c:g}, white"] = white_model(m)
        cands["self (not held out)"] = calibrate_pooled([sets[k]])
        models[k] = cands
        folds[k] = {name: {**heldout_score(m, held[k]), **_consts(m)} for name, m in cands.items()}
    lodo_names = [n for n in next(iter(folds.values())) if n.startswith("pooled")]
    # the median over the folds: one recording whose map does not fit its readings must not choose alone (dataset 1
    # did, before the loader corrected its swapped barcodes)
    mean_nll = {n: float(np.median([folds[k][n]["nll"] for k in folds])) for n in lodo_names}
    chosen = min(mean_nll, key=mean_nll.__getitem__)
    return {"folds": folds, "mean_nll": mean_nll, "chosen": chosen, "models": models}


def _consts(m: CameraModel) -> dict[str, float]:
    return {
        "range_std": m.range.std, "range_phi": m.range.phi, "range_tau": m.range.tau,
        "bearing_std": m.bearing.std, "bearing_phi": m.bearing.phi, "bearing_tau": m.bearing.tau,
    }  # fmt: skip


def filter_scores(
    data: MRCLAMData,
    model: CameraModel,
    estimators: Sequence[str],
    landmarks: bool,
    duration: float,
    config: Config = DEFAULTS,
    holdout: int = 3,
    reference_std: tuple[float, float] | None = None,
    calibrate_yaw: bool = False,
    start: StartFn | None = None,
) -> dict[str, dict[str, Any]]:
    """Run ``estimators`` on ``duration`` s of ``data`` with camera ``model`` (truth-free start) and return per
    estimator the landmark-reading NIS scores, and RMSE/ANEES when ``data`` has truth.

    Scored readings are ones that never entered the belief they are scored against. With landmarks off that is
    every reading. With ``landmarks`` and ``holdout`` = k > 1 each estimator runs k more times, each with one fold
    of the landmarks (:func:`landmark_folds`) left out of the filter, and each fold's readings are scored against
    its run (``anees_folds``: the folds' mean ANEES with truth). ``nis_ratio`` uses the model's std as the
    reading's noise; ``nis_ratio_ref`` uses ``reference_std`` (range [m], bearing [rad]; :func:`lodo` passes the
    left-out dataset's own snapshot-residual std, a truth-free estimate of how noisy its readings are, so that the
    score tests the belief's covariance rather than the model's std). ``nis_ratio_all``, landmarks on only: every
    reading against the run with every landmark, readings already in the belief (it under-states).

    ``calibrate_yaw`` (landmarks on): each run's yaw diffusion is scaled by :func:`yaw_calibration` from the
    recording's own snapshots outside the scored span, without the fold that run leaves out (``yaw_scale``: the
    scale of the run with every landmark, ``yaw_scale_folds``: the folds' runs').

    ``start``: the truth-free start, ``(data, ds, config) -> (t0, beliefs)`` (None: the first two of
    :func:`~swarmloc.experiments.truthfree.fused_from_snapshots`)."""
    ds = detection_set(data)
    t0, initial = fused_from_snapshots(data, ds, config)[:2] if start is None else start(data, ds, config)
    t1 = min(data.t_end, t0 + duration)
    events = mrclam_events(data, landmarks=landmarks, range_std=model.range.std, bearing_std=model.bearing.std)
    events = [e for e in decorrelate(events, model) if t0 <= e.stamp <= t1]
    readings = landmark_readings(data, t0, t1)
    record = reading_times(readings)
    truth = data.truth_at if data.has_truth else None
    std = (model.range.std, model.bearing.std)
    ref = std if reference_std is None else reference_std
    folds = landmark_folds(data.landmarks, holdout) if landmarks and holdout > 1 else []
    configs: dict[frozenset[int], Config] = {frozenset(): config} | {f: config for f in folds}
    if calibrate_yaw and landmarks:
        noise = config.motion.noise()
        scales = {f: yaw_calibration(data, ds, model, noise, f, (t0, t1)).scale for f in configs}
        configs = {f: dataclasses.replace(config, motion=MotionConfig.from_noise(scale_yaw(noise, s)))
                   for f, s in scales.items()}  # fmt: skip
    out: dict[str, dict[str, Any]] = {}
    for name in estimators:
        own = configs
        if name in SMOOTHER_NAMES:  # the delayed output too (filing it changes no causal belief)
            own = {f: c.with_filter(delayed_output=True) for f, c in configs.items()}
        nodes = make_team(name, initial, **node_options(name, own[frozenset()], data.landmarks, t0))
        wall = time.perf_counter()
        res = run(nodes, events, record_times=record, truth=truth, name=name)
        wall = time.perf_counter() - wall
        row: dict[str, Any] = {"wall_s": wall, "fused": int(res.stats.get("fused", 0))}
        scored = [HeldOutRun(res, readings, nodes)]  # landmarks off: every reading, this run
        if folds:
            row.update(nis_summary(tracks_nis(res.tracks, readings, data.landmarks, std), "_all"))
            scored = heldout_runs(name, initial, events, readings, data.landmarks, t0, {f: own[f] for f in folds},
                                  truth)  # fmt: skip
        out[name] = row | _scores(res, scored, bool(folds), data, truth, std, ref)
        if name in SMOOTHER_NAMES:
            # carried to every reading's stamp through the robot's odometry (the truth scored there too)
            at = np.unique([d.t for d in readings])
            whole = carried_output(nodes, events, at, truth, name)
            late = [HeldOutRun(carried_output(h.nodes, events, at, truth, name) if folds else whole, h.readings,
                               h.nodes) for h in scored]  # fmt: skip
            out[f"{name}_delayed"] = _scores(whole, late, bool(folds), data, truth, std, ref, 0.0)
            # the causal belief on the very readings the delayed output scores: the two rows' readings differ
            same = [HeldOutRun(h.run, scored_at(d.run, h.readings, data.landmarks, std), h.nodes)
                    for h, d in zip(scored, late, strict=True)]  # fmt: skip
            for suffix, s in (("_causal", std), ("_causal_ref", ref)):
                nis = [tracks_nis(h.run.tracks, h.readings, data.landmarks, s) for h in same]
                out[f"{name}_delayed"].update(nis_summary(np.concatenate([np.empty(0), *nis]), suffix))
        if calibrate_yaw and landmarks:
            out[name]["yaw_scale"] = scales[frozenset()]
            out[name]["yaw_scale_folds"] = [scales[f] for f in folds]
    out["_span"] = {"t0": t0 - data.t_start, "duration_s": t1 - t0}
    out["_reference_std"] = {"range": ref[0], "bearing": ref[1]}
    return out


def scored_at(delayed: RunResult, readings: Sequence[Any], landmarks: Mapping[int, Sequence[float]],
              std: tuple[float, float]) -> list[Any]:  # fmt: skip
    """The ``readings`` that the delayed output ``delayed`` scores: those with a belief of their observer at their
    stamp (and a finite NIS against it)."""
    keep = []
    for rb, tr in delayed.tracks.items():
        mine = [d for d in readings if d.observer == rb]
        ok = np.isfinite(landmark_nis(tr.times, tr.mean, tr.cov, mine, landmarks, std, 0.0))
        keep += [d for d, k in zip(mine, ok, strict=True) if k]
    return keep


SMOOTHER_NAMES = ("fls", "flsd")
"""The estimators :func:`filter_scores` also scores by their delayed output (a row ``<name>_delayed``)."""


def _scores(
    res: RunResult, scored: Sequence[HeldOutRun], folds: bool, data: MRCLAMData, truth: TruthFn | None,
    std: tuple[float, float], ref: tuple[float, float], lead: float = RECORD_LEAD,
) -> dict[str, Any]:  # fmt: skip
    """A row of :func:`filter_scores`: against the truth (the run ``res`` with every landmark; with ``folds``,
    ``anees_folds`` of the folds' runs ``scored``), and the held-out NIS of ``scored`` with the model's std ``std``
    and the reference ``ref``, beliefs ``lead`` s before each reading (0: the delayed output's, at the readings'
    stamps)."""
    row: dict[str, Any] = {}
    if truth is not None:
        team = evaluate(res)["team"]
        row.update(pos_rmse=team["pos_rmse"], heading_rmse=team["heading_rmse"], anees=team["anees"])
        if folds:
            row["anees_folds"] = float(np.mean([evaluate(h.run)["team"]["anees"] for h in scored]))
    for suffix, s in (("", std), ("_ref", ref)):
        nis = [tracks_nis(h.run.tracks, h.readings, data.landmarks, s, lead) for h in scored]
        row.update(nis_summary(np.concatenate([np.empty(0), *nis]), suffix))
    return row


def own_std(model: CameraModel, fold: dict[str, Any]) -> tuple[float, float]:
    """The left-out recording's own (range [m], bearing [rad]) std: ``model``'s std times the square root of the
    robust variance ratios of its held-out score ``fold`` (:func:`model_scores`)."""
    return model.range.std * math.sqrt(fold["ratio_range"]), model.bearing.std * math.sqrt(fold["ratio_bearing"])


def _run_key(landmarks: bool, calibrate_yaw: bool) -> str:
    return f"{'on' if landmarks else 'off'}{'+yaw' if calibrate_yaw else ''}"


@functools.lru_cache(maxsize=1)
def _recording(root: Path, k: int) -> MRCLAMData:
    """Dataset ``k`` under ``root``, loaded once for its consecutive runs in one process (as before the runs were
    jobs: the variants of a dataset share one recording, which the filters only read)."""
    return load_mrclam(root / f"MRCLAM_Dataset{k}")


def _filter_job(
    root: Path,
    k: int,
    model: CameraModel,
    ref: tuple[float, float],
    estimators: tuple[str, ...],
    landmarks: bool,
    calibrate_yaw: bool,
    duration: float,
    holdout: int,
) -> dict[str, Any]:
    """One filter run of :func:`lodo`: dataset ``k`` (the robots with odometry) with landmarks on or off."""
    data = _recording(root, k)
    return filter_scores(data, model, estimators, landmarks, duration, holdout=holdout, reference_std=ref,
                         calibrate_yaw=calibrate_yaw)  # fmt: skip


def lodo(
    root: str | Path,
    estimators: Sequence[str] = ("dekf", "ci", "rdl", "diekf", "iekf"),
    duration: float = 300.0,
    datasets: Sequence[int] = DATASETS,
    cuts: Sequence[float] = CUTS,
    filter_datasets: Sequence[int] | None = None,
    progress: bool = False,
    holdout: int = 3,
    calibrate_yaw: bool = True,
    workers: int = 1,
    cluster: str | Client | None = None,
) -> dict[str, Any]:
    """The whole LODO check (module docstring): model scores on every dataset of ``datasets`` found under
    ``root``, the chosen candidate, and filter scores with landmarks on and off on the ones with odometry
    (``holdout``: the landmark folds of :func:`filter_scores`); with ``calibrate_yaw`` also landmarks on with the
    yaw diffusion calibrated from the recording's own snapshots (run keys ``k/on``, ``k/on+yaw``, ``k/off``). The
    filter runs go to ``workers`` local processes or a Dask ``cluster`` (:func:`~swarmloc.runner.fanout.fan_out`;
    every worker needs the data under ``root``)."""
    root = Path(root)
    datas = {k: load_mrclam(root / f"MRCLAM_Dataset{k}", require=("measurements",)) for k in datasets}
    sets = {k: detection_set(d) for k, d in datas.items()}
    ms = model_scores(sets, cuts)
    chosen = ms["chosen"]
    jobs: list[tuple[Any, ...]] = []
    for k, d in datas.items():
        if (filter_datasets is not None and k not in filter_datasets) or not d.odometry:
            continue
        m, fold = ms["models"][k][chosen], ms["folds"][k][chosen]
        variants = [(True, False), (True, True), (False, False)] if calibrate_yaw else [(True, False), (False, False)]
        jobs += [(root, k, m, own_std(m, fold), tuple(estimators), lm, cal, duration, holdout) for lm, cal in variants]
    done: dict[int, dict[str, Any]] = {}
    for i, r in fan_out(_filter_job, jobs, jobs=workers, cluster=cluster):
        done[i] = r
        if progress:
            print(f"dataset {jobs[i][1]}, {_run_key(*jobs[i][5:7]).split('/')[0]}: done", flush=True)
    runs = {f"{jobs[i][1]}/{_run_key(*jobs[i][5:7])}": done[i] for i in range(len(jobs))}  # in job order
    return {"model": {k: v for k, v in ms.items() if k != "models"}, "filters": runs, "duration_s": duration,
            "models": {k: ms["models"][k][chosen].to_dict() for k in ms["models"]}, "holdout": holdout}  # fmt: skip


def lodo_markdown(rep: dict[str, Any]) -> str:
    """Two Markdown tables: held-out model scores per dataset and candidate, and filter scores per run."""
    folds = rep["model"]["folds"]
    names = list(next(iter(folds.values())))
    lines = ["| left out | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for k, f in folds.items():
        cells = [f"{f[n]['nll']:.3f} ({f[n]['ratio_range']:.2f}, {f[n]['ratio_bearing']:.2f})" for n in names]
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    mean = rep["model"]["mean_nll"]
    lines.append("| median NLL | " + " | ".join(f"{mean[n]:.3f}" if n in mean else "-" for n in names) + " |")
    lines += ["", f"chosen: {rep['model']['chosen']}", ""]
    lines.append(
        "| left out | landmarks | estimator | pos RMSE [m] | ANEES/dof | ANEES/dof, folds "
        "| NIS ratio, own std | ANIS/dof, own std | NIS ratio, model std | beyond gate | readings "
        "| NIS ratio, every reading in | yaw scale | causal on these readings: NIS ratio, own std (readings) |"
    )
    lines.append("|---" * 14 + "|")
    for key, rows in rep["filters"].items():
        k, lm = key.split("/")
        for est, r in rows.items():
            if est.startswith("_"):
                continue
            acc = (f"{r['pos_rmse']:.3f} | {r['anees']:.2f}") if "anees" in r else "- | -"
            folds = f"{r['anees_folds']:.2f}" if "anees_folds" in r else "-"
            every = f"{r['nis_ratio_all']:.2f}" if "nis_ratio_all" in r else "-"
            yaw = (
                "-"
                if "yaw_scale" not in r
                else (f"{r['yaw_scale']:.3f} (" + ", ".join(f"{x:.3f}" for x in r["yaw_scale_folds"]) + ")")
            )
            same = (
                f"{r['nis_ratio_causal_ref']:.2f} ({r['readings_causal_ref']})" if "readings_causal_ref" in r else "-"
            )
            lines.append(f"| {k} | {lm} | {est} | {acc} | {folds} | {r['nis_ratio_ref']:.2f} | "
                         f"{r['anis_ref']:.2f} | {r['nis_ratio']:.2f} | {r['beyond_gate_ref']:.3f} | {r['readings']} "
                         f"| {every} | {yaw} | {same} |")  # fmt: skip
    return "\n".join(lines) + "\n"
