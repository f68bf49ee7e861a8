"""The 3-D study: the SE(3) estimators on ``sim:3d`` / ``sim:3d_rot`` over seeds, RMSE and ANEES tabulated.

:func:`se3_table` runs a grid of scenarios x estimators x seeds (in a process pool, each run by
:func:`swarmloc.experiments.se3.run_se3`: beliefs recorded at the simulator's truth instants, 3-D position RMSE,
rotation-angle RMSE, ANEES per dof over the 6 dof) and :func:`se3_markdown` writes it as the table of docs/se3.md;
:func:`se3_figures` plots one run per estimator.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from swarmloc.evaluation.metrics import anees_bounds, errors, evaluate
from swarmloc.experiments.se3 import run_se3
from swarmloc.experiments.sources import load_source
from swarmloc.runner import RunResult
from swarmloc.runner.fanout import fan_out

if TYPE_CHECKING:
    from distributed import Client

__all__ = ["se3_figures", "se3_markdown", "se3_table"]


def _job(args: tuple[str, tuple[str, ...], int, int, float]) -> list[dict[str, Any]]:
    """Every estimator on one (scenario, seed), in one process: the twist increments' matrix exponentials,
    memoized, are paid once per source instead of once per estimator."""
    spec, estimators, seed, robots, duration = args
    src = load_source(spec, robots=robots, duration=duration, seed=seed)
    rows = []
    for estimator in estimators:
        res = run_se3(src, estimator)
        team = evaluate(res)["team"]
        rows.append({"spec": spec, "estimator": estimator, "seed": seed, **team, "fused": res.stats["fused"],
                     "accounted": res.accounted(), "wall_s": res.wall_time})  # fmt: skip
    return rows


def se3_table(
    specs: tuple[str, ...] = ("sim:3d", "sim:3d_rot"),
    estimators: tuple[str, ...] = ("expfusion", "dekf", "ci", "diekf", "cekf", "dr"),
    seeds: int = 20,
    robots: int = 4,
    duration: float = 60.0,
    workers: int = 2,
    cluster: str | Client | None = None,
) -> dict[str, Any]:
    """Every (scenario, estimator) over ``seeds`` seeds: mean over seeds of the team's position RMSE [m], rotation
    RMSE [rad] and ANEES/dof, with the per-seed rows; in ``workers`` local processes or on a Dask ``cluster``
    (:func:`~swarmloc.runner.fanout.fan_out`)."""
    jobs = [(s, tuple(estimators), k, robots, duration) for s in specs for k in range(seeds)]
    done = dict(fan_out(_job, [(j,) for j in jobs], jobs=workers, cluster=cluster))
    rows = [r for i in range(len(jobs)) for r in done[i]]  # in job order, wherever each ran
    return _summary(specs, estimators, seeds, robots, duration, rows)


def _summary(
    specs: tuple[str, ...], estimators: tuple[str, ...], seeds: int, robots: int, duration: float, rows: list
) -> dict[str, Any]:
    """:func:`se3_table`'s result from its per-seed ``rows``."""
    summary: dict[str, Any] = {}
    for s in specs:
        for e in estimators:
            rs = [r for r in rows if r["spec"] == s and r["estimator"] == e]
            anees = np.array([r["anees"] for r in rs])
            summary[f"{s} {e}"] = {
                "spec": s,
                "estimator": e,
                "seeds": len(rs),
                "pos_rmse": float(np.mean([r["pos_rmse"] for r in rs])),
                "rot_rmse": float(np.mean([r["rot_rmse"] for r in rs])),
                "anees": float(anees.mean()),
                "anees_min": float(anees.min()),
                "anees_max": float(anees.max()),
                "in_band": float(np.mean((anees >= 0.5) & (anees <= 2.0))),
                "n_records": int(sum(r["n"] for r in rs)),
                "accounted": all(r["accounted"] for r in rs),
            }
    return {"robots": robots, "duration_s": duration, "seeds": seeds, "summary": summary, "rows": rows}


def se3_markdown(table: dict[str, Any]) -> str:
    """The table of :func:`se3_table` in Markdown."""
    lines = [
        "| scenario | estimator | pos RMSE [m] | rot RMSE [deg] | ANEES/dof (mean over seeds) | min - max "
        "| seeds in [0.5, 2] |",
        "|---|---|---|---|---|---|---|",
    ]
    for v in table["summary"].values():
        lines.append(
            f"| {v['spec']} | {v['estimator']} | {v['pos_rmse']:.3f} | {np.degrees(v['rot_rmse']):.2f} | "
            f"{v['anees']:.2f} | {v['anees_min']:.2f} - {v['anees_max']:.2f} | {v['in_band']:.0%} |"
        )
    n = next(iter(table["summary"].values()))["n_records"] // max(1, table["seeds"])
    lo, hi = anees_bounds(n, 6)
    lines.append("")
    lines.append(f"95% band of one run's ANEES/dof if its {n} records were independent: [{lo:.2f}, {hi:.2f}].")
    return "\n".join(lines)


def se3_figures(out: str | Path, results: dict[str, RunResult], t_start: float = 0.0) -> list[Path]:
    """Figures of one 3-D run per estimator (PNG in ``out``): ``trajectories3d.png``, every robot's truth and
    estimates from above (x-y) and from the side (x-z); ``error_nees3d.png``, the team's mean position error [m],
    rotation error [deg] and NEES per dof (6 dof) over time, with the 95% band of the team's per-time NEES."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    first = next(iter(results.values()))
    robots = sorted(r for r, tr in first.tracks.items() if tr.times.size)
    if not robots:
        raise ValueError("se3_figures: nothing was recorded (no track with a record)")
    fig, (top, side) = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, (i, j, name) in zip((top, side), ((0, 1, "y"), (0, 2, "z")), strict=True):
        for k, r in enumerate(robots):
            tru = first.tracks[r].truth
            ax.plot(tru[:, i], tru[:, j], "k-", lw=2, label="truth" if k == 0 else None)
            for c, (est, res) in enumerate(results.items()):
                tr = res.tracks.get(r)
                if tr is not None and tr.times.size:
                    ax.plot(tr.mean[:, i], tr.mean[:, j], lw=0.8, color=f"C{c}", label=est if k == 0 else None)
        ax.set_xlabel("x [m]")
        ax.set_ylabel(f"{name} [m]")
        ax.set_title("from above (x-y)" if name == "y" else "from the side (x-z)")
        ax.set_aspect("equal", adjustable="datalim")
    top.legend(fontsize=7)
    fig.tight_layout()
    paths = [out / "trajectories3d.png"]
    fig.savefig(paths[0], dpi=110)
    plt.close(fig)

    fig, (a1, a2, a3) = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for est, res in results.items():
        tracks = [res.tracks[r] for r in robots if r in res.tracks and res.tracks[r].times.size]
        if not tracks:
            continue
        n = min(tr.times.size for tr in tracks)
        errs = [errors(tr) for tr in tracks]
        t = tracks[0].times[:n] - t_start
        a1.plot(t, np.mean([e["pos"][:n] for e in errs], axis=0), lw=0.8, label=est)
        a2.plot(t, np.degrees(np.mean([e["heading"][:n] for e in errs], axis=0)), lw=0.8, label=est)
        a3.semilogy(t, np.mean([e["nees"][:n] / 6 for e in errs], axis=0), lw=0.8, label=est)
    lo, hi = anees_bounds(len(robots), 6)
    a3.axhspan(lo, hi, color="0.85", label="95% band (team, per time)")
    a1.set_ylabel("team mean position error [m]")
    a2.set_ylabel("team mean rotation error [deg]")
    a3.set_ylabel("team NEES per dof")
    a3.set_ylim(1e-2, 1e3)
    a3.set_xlabel("time since start [s]")
    a1.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    paths.append(out / "error_nees3d.png")
    fig.savefig(paths[1], dpi=110)
    plt.close(fig)
    return paths
