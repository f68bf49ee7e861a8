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
each robot's first landmark snapshot gives its pose by the weighted fit of
:mod:`swarmloc.sensors.decorrelate` (covariance from the a-priori std 0.1 m, 0.035 rad), dead-reckoned (``dr``)
to the latest of the robots' first snapshots, where the run starts. Runs cover ``duration`` s from there (part of
each dataset, for compute).

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
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from swarmloc.config import DEFAULTS, Config, MotionConfig
from swarmloc.datasets.mrclam import MRCLAMData, load_mrclam, mrclam_events
from swarmloc.estimators import make_team, node_options
from swarmloc.evaluation.metrics import evaluate
from swarmloc.events import Detection, Odometry
from swarmloc.experiments.mrclam import detection_set, yaw_calibration
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, wrap_angle
from swarmloc.motion.calibrate import scale_yaw
from swarmloc.runner import run
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
    snapshot_poses,
)

if TYPE_CHECKING:
    from distributed import Client

__all__ = [
    "CUTS",
    "DATASETS",
    "detection_set",
    "filter_scores",
    "landmark_folds",
    "landmark_nis",
    "lodo",
    "lodo_markdown",
    "nis_summary",
    "own_std",
    "yaw_calibration",
]

DATASETS: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 8, 9)
CUTS: tuple[float, ...] = (2.5, 3.0, 4.0)
"""Candidate inlier cuts of the pooled variance components (the regularisation chosen by the held-out score)."""
GATE_2DOF = 11.618  # chi-square 0.997 quantile, 2 dof
MEDIAN_CHI2_2 = 1.386294  # 2 ln 2
RECORD_LEAD = 1e-6  # [s] beliefs are recorded this long before each landmark reading


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


def initial_from_snapshots(
    data: MRCLAMData, ds: DetectionSet, config: Config = DEFAULTS
) -> tuple[float, dict[int, GroupGaussian]]:
    """Truth-free initial beliefs: each robot's first landmark snapshot pose (fit covariance at the a-priori std),
    dead-reckoned to ``t0``, the latest first snapshot; returns ``(t0, beliefs)``. Raises ValueError when a robot
    of ``data`` never sees two landmarks at once."""
    poses = snapshot_poses(ds, PRIOR_RANGE_STD, PRIOR_BEARING_STD)
    first: dict[int, tuple[float, np.ndarray, np.ndarray]] = {}
    for r in data.robots:
        sel = np.flatnonzero((poses["observer"] == r) & (poses["t"] >= data.t_start))
        if sel.size == 0:
            raise ValueError(f"{data.name}: robot {r} never reads two landmarks at once; no truth-free start")
        i = int(sel[0])
        first[r] = (float(poses["t"][i]), poses["pose"][i], poses["cov"][i])
    t0 = max(v[0] for v in first.values())
    events = mrclam_events(data, landmarks=False, robot_measurements=False)
    out: dict[int, GroupGaussian] = {}
    for r, (ts, pose, cov) in first.items():
        # the fit's covariance is of (x, y, theta); at a small angle it is that of the left perturbation: rotate
        # it into the body frame for the right-perturbation convention of the nodes
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        belief = GroupGaussian(SE2, SE2.from_xytheta(pose), rot @ cov @ rot.T + 1e-8 * np.eye(3), validate=False)
        if t0 - ts <= 0:
            out[r] = belief
            continue
        mine = [e for e in events if isinstance(e, Odometry) and e.robot == r and ts <= e.stamp <= t0]  # all odometry
        res = run(make_team("dr", {r: belief}, **node_options("dr", config, None, ts)), mine, record_times=[t0])
        tr = res.tracks[r]
        out[r] = GroupGaussian(SE2, SE2.from_xytheta(tr.mean[-1]), tr.cov[-1], validate=False)
    return t0, out


def landmark_nis(track_times: np.ndarray, mean: np.ndarray, cov: np.ndarray, dets: Sequence[Detection],
                 landmarks: Mapping[int, Sequence[float]], std: tuple[float, float]) -> np.ndarray:  # fmt: skip
    """Predictive NIS (2 dof) of landmark readings ``dets`` of one observer against its beliefs recorded
    :data:`RECORD_LEAD` s before each (``mean`` ``(T, 3)``, right-perturbation ``cov`` ``(T, 3, 3)``), with the
    reading's error std ``std`` = (range [m], bearing [rad]) and each landmark's map std."""
    if not dets:
        return np.empty(0)
    t = np.array([d.t for d in dets])
    idx = np.clip(np.searchsorted(track_times, t - RECORD_LEAD - 1e-9), 0, len(track_times) - 1)
    ok = np.abs(track_times[idx] - (t - RECORD_LEAD)) < 1e-7
    x, P = mean[idx], cov[idx]
    ids = [d.target for d in dets if d.target is not None]
    if len(ids) < len(dets):
        raise ValueError("landmark_nis: a reading without its landmark's id (target)")
    lm = np.array([landmarks[k][:4] for k in ids], dtype=float)
    z = np.array([d.z for d in dets])
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    dx, dy = lm[:, 0] - x[:, 0], lm[:, 1] - x[:, 1]
    q = np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)  # landmark in the body frame
    rng = np.maximum(np.hypot(q[:, 0], q[:, 1]), 1e-6)
    r = np.stack([z[:, 0] - rng, wrap_angle(z[:, 1] - np.arctan2(q[:, 1], q[:, 0]))], axis=-1)
    jq = np.stack([q / rng[:, None], np.stack([-q[:, 1], q[:, 0]], -1) / (rng**2)[:, None]], axis=1)  # d(rb)/dq
    dq = np.zeros((len(dets), 2, 3))  # dq / d(right perturbation): -I for the translation, (q_y, -q_x) for theta
    dq[:, 0, 0] = dq[:, 1, 1] = -1.0
    dq[:, 0, 2], dq[:, 1, 2] = q[:, 1], -q[:, 0]
    H = jq @ dq
    rot_t = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], axis=1)  # d q / d landmark
    jl = jq @ rot_t
    L = jl @ (np.eye(2)[None] * np.square(lm[:, 2:4])[:, :, None]) @ np.swapaxes(jl, 1, 2)
    S = H @ P @ np.swapaxes(H, 1, 2) + np.diag([std[0] ** 2, std[1] ** 2])[None] + L
    nis = np.einsum("ni,ni->n", r, np.linalg.solve(S, r[..., None])[..., 0])
    return np.where(ok, nis, np.nan)


def _nis_of(res: Any, readings: Sequence[Detection], data: MRCLAMData, std: tuple[float, float]) -> np.ndarray:
    """The finite predictive NIS of ``readings`` against the beliefs of run ``res`` (every observer)."""
    nis = np.concatenate([np.empty(0)] + [
        landmark_nis(tr.times, tr.mean, tr.cov, [d for d in readings if d.observer == rb], data.landmarks, std)
        for rb, tr in res.tracks.items()
    ])  # fmt: skip
    return nis[np.isfinite(nis)]


def nis_summary(nis: np.ndarray, suffix: str = "") -> dict[str, Any]:
    """The scores of 2-dof NIS values (keys end in ``suffix``): ``nis_ratio`` median / 1.386, ``anis`` mean / 2,
    ``beyond_gate`` the share above the 0.997 quantile, ``readings`` the count (NaN scores for none)."""
    return {
        f"nis_ratio{suffix}": float(np.median(nis) / MEDIAN_CHI2_2) if nis.size else float("nan"),
        f"anis{suffix}": float(np.mean(nis) / 2.0) if nis.size else float("nan"),
        f"beyond_gate{suffix}": float(np.mean(nis > GATE_2DOF)) if nis.size else float("nan"),
        f"readings{suffix}": int(nis.size),
    }


def landmark_folds(ids: Iterable[int], k: int) -> list[frozenset[int]]:
    """``k`` folds of the landmark ids (every ``k``-th of the sorted ids, so that each fold spreads over the map)."""
    order = sorted(ids)
    return [frozenset(order[f::k]) for f in range(k)]


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
    scale of the run with every landmark, ``yaw_scale_folds``: the folds' runs')."""
    ds = detection_set(data)
    t0, initial = initial_from_snapshots(data, ds, config)
    t1 = min(data.t_end, t0 + duration)
    events = mrclam_events(data, landmarks=landmarks, range_std=model.range.std, bearing_std=model.bearing.std)
    events = [e for e in decorrelate(events, model) if t0 <= e.stamp <= t1]
    lm_events = mrclam_events(data, landmarks=True, robot_measurements=False)
    readings = [e for e in lm_events if isinstance(e, Detection) and not e.target_is_robot and t0 < e.t <= t1]
    record = np.unique(np.array([d.t for d in readings]) - RECORD_LEAD)
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
        nodes = make_team(name, initial, **node_options(name, configs[frozenset()], data.landmarks, t0))
        wall = time.perf_counter()
        res = run(nodes, events, record_times=record, truth=truth, name=name)
        wall = time.perf_counter() - wall
        row: dict[str, Any] = {"wall_s": wall, "fused": int(res.stats.get("fused", 0))}
        if truth is not None:
            team = evaluate(res)["team"]
            row.update(pos_rmse=team["pos_rmse"], heading_rmse=team["heading_rmse"], anees=team["anees"])
        scored: list[tuple[Any, list[Detection]]] = []
        if not folds:  # landmarks off (or no folds: every reading against the run with every landmark)
            scored = [(res, readings)]
        else:
            row.update(nis_summary(_nis_of(res, readings, data, std), "_all"))
            anees = []
            for fold in folds:
                lm_out = [e for e in events if not (isinstance(e, Detection) and not e.target_is_robot
                                                    and e.target in fold)]  # fmt: skip
                mine = [d for d in readings if d.target in fold]
                nodes = make_team(name, initial, **node_options(name, configs[fold], data.landmarks, t0))
                rec = np.unique(np.array([d.t for d in mine]) - RECORD_LEAD) if mine else record[:1]
                res_f = run(nodes, lm_out, record_times=rec, truth=truth, name=name)
                scored.append((res_f, mine))
                if truth is not None:
                    anees.append(evaluate(res_f)["team"]["anees"])
            if anees:
                row["anees_folds"] = float(np.mean(anees))
        if scored:
            row.update(nis_summary(np.concatenate([_nis_of(r, d, data, std) for r, d in scored])))
            row.update(nis_summary(np.concatenate([_nis_of(r, d, data, ref) for r, d in scored]), "_ref"))
        if calibrate_yaw and landmarks:
            row["yaw_scale"] = scales[frozenset()]
            row["yaw_scale_folds"] = [scales[f] for f in folds]
        out[name] = row
    out["_span"] = {"t0": t0 - data.t_start, "duration_s": t1 - t0}
    out["_reference_std"] = {"range": ref[0], "bearing": ref[1]}
    return out


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
        "| NIS ratio, every reading in | yaw scale |"
    )
    lines.append("|---" * 13 + "|")
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
            lines.append(f"| {k} | {lm} | {est} | {acc} | {folds} | {r['nis_ratio_ref']:.2f} | "
                         f"{r['anis_ref']:.2f} | {r['nis_ratio']:.2f} | {r['beyond_gate_ref']:.3f} | {r['readings']} "
                         f"| {every} | {yaw} |")  # fmt: skip
    return "\n".join(lines) + "\n"
