"""Output of thesis sec. 5.2.2 / Table 6.1: the progress bar, the figures (error and ANEES vs time, trajectories,
ground-truth neighbour, double counting), ``dynamic.md`` (its text: :mod:`~swarmloc_studies.thesis_dynamic.markdown`)
and ``dynamic.json``. matplotlib and rich are imported only here, inside the functions that use them."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.experiments.output import save_figure
from swarmloc.runner import RunResult
from swarmloc_studies.thesis_dynamic.markdown import markdown
from swarmloc_studies.thesis_dynamic.spec import ABLATION_ESTIMATORS, ABLATION_NOISE, FIG_ERR, FIG_TRAJ, RUNS


# ---------------------------------------------------------------------------------------------------------- output
def progress_bar(total: int) -> tuple[Any, Any]:
    """A started rich progress bar over ``total`` estimator runs, and its task (for ``bar.update(task, ...)``)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from swarmloc.experiments.progress import stderr_console

    bar = Progress(
        TextColumn("[bold]thesis 5.2[/bold] {task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=stderr_console(),
    )
    task = bar.add_task("runs", total=total)
    bar.start()
    return bar, task


def pyplot() -> Any:
    """``matplotlib.pyplot`` with the non-interactive Agg backend, for :func:`figures`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write_dynamic(out_dir: Path, result: dict[str, Any]) -> str:
    """Write ``dynamic.md`` (tables and analysis) and ``dynamic.json`` (``result``) to ``out_dir``; return the text."""
    md = markdown(result)
    (out_dir / "dynamic.md").write_text(md)
    (out_dir / "dynamic.json").write_text(json.dumps(result, indent=1, allow_nan=True))
    return md


# ---------------------------------------------------------------------------------------------------------- figures
def _err_panel(ax: Any, cs: dict[str, dict[str, np.ndarray]]) -> None:
    """Robot 1's position error against time per estimator of ``cs`` (its curves): mean, 10-90% band, log scale."""
    for key, c in cs.items():
        es = RUNS[key]
        ax.plot(c["times"], c["pos_mean"], es.style, color=es.color, label=es.label, lw=1.3)
        ax.fill_between(c["times"], c["pos_p10"], c["pos_p90"], color=es.color, alpha=0.12, lw=0)
    ax.set_yscale("log")
    late = [c["pos_p10"][c["times"] >= 2.0] for c in cs.values()]
    floor = min((float(x.min()) for x in late if x.size), default=1e-3)
    ax.set_ylim(bottom=max(1e-4, 0.5 * floor))
    ax.set_xlabel("time [s]")
    ax.grid(alpha=0.3, which="both")


def _traj_panel(ax: Any, runs: dict[str, RunResult], last: float = 10.0) -> None:
    """Robot 1's true and estimated paths, with a zoom on the last ``last`` seconds (the errors are cm)."""
    tr = next(iter(runs.values())).tracks[1]
    arc = tr.truth[tr.times > 15.0, :2] if np.any(tr.times > 15.0) else tr.truth[:, :2]
    cx, cy = 0.5 * (arc.min(0) + arc.max(0))  # centre of the circle: empty space for the zoom
    w = 0.6 * float(np.min(arc.max(0) - arc.min(0)))
    ins = ax.inset_axes([cx - w / 2, cy - w / 2, w, w], transform=ax.transData)
    sel = tr.times >= tr.times[-1] - last
    ax.plot(tr.truth[:, 0], tr.truth[:, 1], color="tab:blue", lw=4, alpha=0.45, label="truth")
    ins.plot(tr.truth[sel, 0], tr.truth[sel, 1], color="tab:blue", lw=6, alpha=0.45)
    err = 0.0
    for key, res in runs.items():
        es = RUNS[key]
        m = res.tracks[1].mean
        ax.plot(m[:, 0], m[:, 1], es.style, color=es.color, lw=0.9, label=es.label)
        ins.plot(m[sel, 0], m[sel, 1], es.style, color=es.color, lw=1.2)
        err = max(err, float(np.max(np.linalg.norm(m[sel, :2] - tr.truth[sel, :2], axis=1))))
    c = tr.truth[-1, :2]
    h = max(0.05, 1.3 * err)
    ins.set_xlim(c[0] - h, c[0] + h)
    ins.set_ylim(c[1] - h, c[1] + h)
    ins.set_aspect("equal")
    ins.tick_params(labelsize=6)
    ins.set_title("zoom: end of the run", fontsize=7)
    ax.indicate_inset_zoom(ins, edgecolor="gray")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(alpha=0.3)


def figures(
    plt: Any,
    out_dir: Path,
    curves: dict[str, dict[str, dict[str, np.ndarray]]],
    traj: dict[str, dict[str, RunResult]],
    gt_curves: dict[str, dict[str, np.ndarray]],
    gt_traj: dict[str, RunResult],
    abl: dict[str, Any],
    seeds: int,
    gt_seeds: int,
) -> list[str]:
    """Draw the study's figures into ``out_dir`` (plotted with ``plt``, matplotlib's pyplot): error, trajectory and
    ANEES against time per noise level, the ground-truth neighbour, the double-counting study; their file names."""
    files = []
    noises = list(curves)

    def save(fig: Any, name: str) -> None:
        save_figure(fig, out_dir / name)
        files.append(name)

    # Figs 5.15 / 5.18 / 5.21
    fig, axes = plt.subplots(1, len(noises), figsize=(5 * len(noises), 4.2), sharey=True)
    for ax, nk in zip(np.atleast_1d(axes), noises, strict=True):
        _err_panel(ax, curves[nk])
        ax.set_title(f"noise std {nk} m (thesis Fig. {FIG_ERR.get(nk, '')})")
    np.atleast_1d(axes)[0].set_ylabel(f"robot 1 position error [m]\nmean, 10-90% band over {seeds} seeds")
    np.atleast_1d(axes)[0].legend(fontsize=7, loc="lower right")
    save(fig, "dynamic_error_vs_time.png")

    # Figs 5.14 / 5.17 / 5.20
    fig, axes = plt.subplots(1, len(noises), figsize=(5 * len(noises), 4.8))
    for ax, nk in zip(np.atleast_1d(axes), noises, strict=True):
        _traj_panel(ax, traj[nk])
        ax.set_title(f"robot 1, seed 0, noise {nk} (Fig. {FIG_TRAJ.get(nk, '')})")
    np.atleast_1d(axes)[0].legend(fontsize=7, loc="lower right")
    save(fig, "dynamic_trajectory.png")

    # ANEES vs time with the chi-square band
    fig, axes = plt.subplots(1, len(noises), figsize=(5 * len(noises), 4.2), sharey=True)
    for ax, nk in zip(np.atleast_1d(axes), noises, strict=True):
        for key, c in curves[nk].items():
            es = RUNS[key]
            ax.plot(c["times"], c["anees"], es.style, color=es.color, label=es.label, lw=1.1)
        c0 = next(iter(curves[nk].values()))
        ax.fill_between(c0["times"], c0["anees_lo"], c0["anees_hi"], color="gray", alpha=0.3, label="95% chi-square")
        ax.set_yscale("log")
        ax.set_ylim(bottom=0.1)
        ax.set_xlabel("time [s]")
        ax.set_title(f"robot 1 ANEES over {seeds} seeds, noise {nk}")
        ax.grid(alpha=0.3, which="both")
    np.atleast_1d(axes)[0].set_ylabel("ANEES per dof")
    np.atleast_1d(axes)[0].legend(fontsize=7, loc="upper left")
    save(fig, "dynamic_anees_vs_time.png")

    # Figs 5.22 / 5.23
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.8))
    _traj_panel(a1, gt_traj)
    a1.set_title("robot 1, seed 0, neighbour with absolute fixes (Fig. 5.22)")
    a1.legend(fontsize=7, loc="lower right")
    _err_panel(a2, gt_curves)
    a2.set_ylabel(f"robot 1 position error [m] (mean, 10-90% over {gt_seeds} seeds)")
    a2.set_title("robot 1 error, ground-truth neighbour (Fig. 5.23)")
    save(fig, "dynamic_gt_neighbour.png")

    # double-counting study
    fig, ax = plt.subplots(figsize=(9, 4.2))
    keys = list(abl)
    width = 0.8 / len(ABLATION_ESTIMATORS)
    for j, ek in enumerate(ABLATION_ESTIMATORS):
        es = RUNS[ek]
        vals = [abl[ak]["estimators"][ek]["robot1"]["anees"]["mean"] for ak in keys]
        ax.bar(np.arange(len(keys)) + (j - 1) * width, vals, width, color=es.color, label=es.label, alpha=0.8)
    ax.axhline(1.0, color="gray", ls="--", lw=1)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(keys)), keys, fontsize=8)
    ax.set_ylabel("robot 1 ANEES (mean over seeds)")
    ax.set_title(f"Why the distributed estimators are over-confident (noise {ABLATION_NOISE:g})")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, axis="y", which="both")
    save(fig, "dynamic_double_counting.png")
    return files
