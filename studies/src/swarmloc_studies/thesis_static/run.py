"""Computations of thesis Tables 5.1/5.2: :func:`run_tables` builds its result dictionary and hands it to
:mod:`swarmloc_studies.thesis_static.report`."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.experiments.thesis_demo.report import console, jsonable
from swarmloc.experiments.thesis_demo.spec import (
    CHI2_3_95,
    COMMANDS,
    NEIGHBOUR_OFFSETS,
    SIGMA_M,
    THESIS_DRIVE,
    Command,
    formation,
    pose_errors,
    prediction,
    relative_measurements,
    sample_end_poses,
)
from swarmloc.fusion import fuse_relative
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.motion import DiffDrive
from swarmloc_studies.thesis_static.report import tables_figures, write_tables
from swarmloc_studies.thesis_static.spec import THESIS_TABLES, deviation_510


def _summary(g_true: np.ndarray, post: GroupGaussian, prior_log_err: np.ndarray | None) -> dict[str, Any]:
    e = pose_errors(g_true, post.mean)
    dev = deviation_510(g_true, post.mean)
    nees = post.mahalanobis2(g_true, validate=False)
    mean_cov = post.cov.mean(axis=0)
    out = {
        "mean_deviation": float(dev.mean()),
        "median_deviation": float(np.median(dev)),
        "frobenius_mean_cov": float(np.linalg.norm(mean_cov)),
        "mean_trace_cov": float(np.trace(post.cov, axis1=-2, axis2=-1).mean()),
        "mean_log_error": float(e["log"].mean()),
        "mean_position_error_m": float(e["position"].mean()),
        "mean_heading_error_rad": float(e["heading"].mean()),
        "mean_nees": float(nees.mean()),
        "frac_nees_in_95": float(np.mean(nees <= CHI2_3_95)),
        "deviations": dev,
        "trace_cov": np.trace(post.cov, axis1=-2, axis2=-1),
        "log_errors": e["log"],
    }
    out["frac_better_than_prior"] = None if prior_log_err is None else float(np.mean(e["log"] < prior_log_err))
    return out


def table_trials(
    cmd: Command,
    drive: DiffDrive,
    Sm: np.ndarray,
    n_max: int,
    reps: int,
    rng: np.random.Generator,
    n_steps: int = 200,
    prior_substeps: int = 1,
) -> tuple[GroupGaussian, np.ndarray, Any]:
    """The trials behind Tables 5.1/5.2 for one motion: ``(prior, g_i, posteriors)``, with the batched prior of
    robot ``i``, its true end poses ``(reps, 3, 3)`` and ``posteriors(n, order)``: its fused posterior from the
    first ``n`` neighbours' measurements (one fresh truth and measurement set per repetition)."""
    mu_inc, Sigma = prediction(cmd, drive, prior_substeps)
    starts = formation(n_max)
    truth = sample_end_poses(cmd, drive, starts, reps, rng, n_steps)  # (reps, n_max + 1, 3, 3)
    meas = relative_measurements(truth, Sm, rng)  # (reps, n_max, 3, 3)
    means = starts @ mu_inc

    def batched(mean: np.ndarray, cov: np.ndarray) -> GroupGaussian:
        return GroupGaussian(SE2, np.broadcast_to(mean, (reps, 3, 3)), np.broadcast_to(cov, (reps, 3, 3)), False)

    beliefs = [batched(means[k], Sigma) for k in range(n_max + 1)]
    noise = np.broadcast_to(Sm, (reps, 3, 3))

    def posteriors(n: int, order: int) -> GroupGaussian:
        pairs = [(beliefs[k + 1], GroupGaussian(SE2, meas[:, k], noise, validate=False)) for k in range(n)]
        return fuse_relative(beliefs[0], pairs, order=order)

    return beliefs[0], truth[:, 0], posteriors


def run_tables(
    out_dir: Path,
    reps: int = 60,
    max_measurements: int = 6,
    seed: int = 0,
    progress: bool = True,
    *,
    n_steps: int = 200,
    figures: bool = True,
    noise_scale: float = 1.0,
    prior_substeps: int = 1,
) -> dict:
    """Tables 5.1/5.2 and figures 5.8/5.9: accuracy of robot ``i``'s posterior vs the number of measurements.

    For each motion and each repetition a fresh truth (one SDE end pose per robot, all paths sampled at once) and
    fresh measurement noise are drawn; within a repetition ``n = 1..max_measurements`` uses the first ``n``
    neighbours of :data:`NEIGHBOUR_OFFSETS` (nested, so the rows are paired). Per ``n`` and fusion order (2, 1):
    mean and median deviation (5.10), Frobenius norm of the average posterior covariance, mean trace, mean
    ``|log(g_true^-1 mu)|``, position and heading error, mean NEES and the fraction of runs with NEES inside the
    95% chi-square(3) bound, and the fraction of runs where the posterior beats the prior. Row ``n = 0`` is the
    prior. Writes ``tables.json``, ``tables.md`` and (``figures``) ``tables_{straight,circular}.png``.
    ``noise_scale`` and ``prior_substeps`` as in :func:`run_demo`. Returns the dictionary written to
    ``tables.json`` (plain Python types).
    """
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    con = console(progress)
    if reps < 1 or not 1 <= max_measurements <= len(NEIGHBOUR_OFFSETS):
        raise ValueError(f"run_tables: need reps >= 1 and 1 <= max_measurements <= {len(NEIGHBOUR_OFFSETS)}")
    drive = DiffDrive(THESIS_DRIVE.r, THESIS_DRIVE.l, THESIS_DRIVE.D * noise_scale)
    Sm = SIGMA_M * noise_scale
    N = max_measurements
    motions: dict[str, Any] = {}
    for cmd, ss in zip(COMMANDS, np.random.SeedSequence(seed).spawn(len(COMMANDS)), strict=True):
        prior, g_i, posteriors = table_trials(cmd, drive, Sm, N, reps, np.random.default_rng(ss), n_steps,
                                              prior_substeps)  # fmt: skip
        prior_row = _summary(g_i, prior, None)
        rows: dict[int, list[dict[str, Any]]] = {}
        for order in (2, 1):
            rows[order] = [
                {"n": n, **_summary(g_i, posteriors(n, order), prior_row["log_errors"])} for n in range(1, N + 1)
            ]
        motions[cmd.name] = {
            "command": {"w1": cmd.w1, "w2": cmd.w2, "T": cmd.T},
            "prior": prior_row,
            "order2": rows[2],
            "order1": rows[1],
            "thesis": THESIS_TABLES[cmd.name],
            "norm_x_true_mean": float(np.linalg.norm(SE2.to_xytheta(g_i), axis=-1).mean()),
        }
        con.print(f"[tables] {cmd.name}: {reps} repetitions x {N} measurement counts x 2 orders")

    result: dict[str, Any] = {
        "experiment": "thesis sec. 5.1, Tables 5.1 (straight) and 5.2 (circular), figures 5.8/5.9",
        "settings": {
            "reps": reps,
            "max_measurements": N,
            "seed": seed,
            "n_steps": n_steps,
            "noise_scale": noise_scale,
            "prior_substeps": prior_substeps,
            "D": drive.D,
            "sigma_m": Sm,
            "neighbour_offsets_m": list(NEIGHBOUR_OFFSETS[:N]),
            "deviation": "eq. 5.10 with x = (x, y, theta) in the world frame (robot i starts at the origin), "
            "heading difference wrapped",
            "design": "nested: within a repetition the same truth and measurements, neighbours 1..n",
        },
        "motions": motions,
        "files": [str(out_dir / "tables.json"), str(out_dir / "tables.md")],
    }
    if figures:
        result["files"] += tables_figures(out_dir, motions, reps)
    result["runtime_s"] = time.perf_counter() - t0
    write_tables(out_dir, result, con)
    return jsonable(result)
