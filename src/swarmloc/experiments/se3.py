"""3-D teams: run the SE(3) estimators on ``sim:3d`` / ``sim:3d_rot`` over seeds and tabulate RMSE and ANEES.

:func:`run_se3` runs one estimator on one :class:`~swarmloc.datasets.source.Source` of a 3-D team (beliefs recorded
at the simulator's truth instants, scored by :func:`swarmloc.evaluation.metrics.evaluate`: 3-D position RMSE,
rotation-angle RMSE, ANEES per dof over the 6 dof); :func:`se3_table` runs a grid of scenarios x estimators x
seeds (in a process pool) and :func:`se3_markdown` writes it as the README's table. ``write_tum_tracks`` writes
each robot's estimate and truth as TUM files with full quaternions (``evo_ape tum truth.tum estimate.tum``).
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.datasets.source import Source
from swarmloc.datasets.tum import write_tum3
from swarmloc.estimators import accepted_options, estimator_class, make_team
from swarmloc.evaluation.metrics import anees_bounds, evaluate
from swarmloc.events import Detection, Event, Odometry, Truth
from swarmloc.experiments.sources import load_source
from swarmloc.runner import RunResult, run

__all__ = ["run_se3", "se3_markdown", "se3_table", "with_truth", "write_tum_tracks"]


def run_se3(source: Source, estimator: str, **options: Any) -> RunResult:
    """One estimator on a 3-D team's source; ``options`` go to the nodes (``noise`` defaults to ``source.noise``)."""
    if source.noise is None:
        raise ValueError(f"run_se3: source {source.spec!r} is not a 3-D team (no twist noise)")
    base: dict[str, Any] = {"noise": source.noise, "t0": source.t_start}
    if source.landmarks and "landmarks" in accepted_options(estimator_class(estimator, source.initial)):
        base["landmarks"] = source.landmarks
    nodes = make_team(estimator, source.initial, **{**base, **options})
    return run(nodes, with_truth(source), name=estimator)


_PRIO = {Odometry: 0, Detection: 1, Truth: 2}


def with_truth(source: Source) -> list[Event]:
    """The source's events with its truth instants merged in stamp order (at one stamp: odometry, detections,
    truth; the other events keep their order). Appended after the other events instead, a truth instant reaches
    the runner when the nodes' history has moved past it and is not recorded (``record_too_old``): a 20-s run
    scored only its last 76 of 164 instants."""
    return sorted([*source.events, *(source.truth_events or [])], key=lambda e: (e.stamp, _PRIO[type(e)]))


def write_tum_tracks(result: RunResult, out: str | Path) -> list[Path]:
    """Each robot's recorded estimate and truth as ``<out>/<estimator>_robot<N>.tum`` and ``truth_robot<N>.tum``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for r, tr in sorted(result.tracks.items()):
        paths.append(write_tum3(out / f"{result.estimator}_robot{r}.tum", tr.times, tr.mean))
        paths.append(write_tum3(out / f"truth_robot{r}.tum", tr.times, tr.truth))
    return paths


def _job(args: tuple[str, str, int, int, float]) -> dict[str, Any]:
    spec, estimator, seed, robots, duration = args
    src = load_source(spec, robots=robots, duration=duration, seed=seed)
    res = run_se3(src, estimator)
    team = evaluate(res)["team"]
    return {"spec": spec, "estimator": estimator, "seed": seed, **team, "fused": res.stats["fused"],
            "accounted": res.accounted(), "wall_s": res.wall_time}  # fmt: skip


def se3_table(
    specs: tuple[str, ...] = ("sim:3d", "sim:3d_rot"),
    estimators: tuple[str, ...] = ("expfusion", "dekf", "ci", "diekf", "cekf", "dr"),
    seeds: int = 20,
    robots: int = 4,
    duration: float = 60.0,
    workers: int = 2,
) -> dict[str, Any]:
    """Every (scenario, estimator) over ``seeds`` seeds: mean over seeds of the team's position RMSE [m], rotation
    RMSE [rad] and ANEES/dof, with the per-seed rows."""
    jobs = [(s, e, k, robots, duration) for s in specs for e in estimators for k in range(seeds)]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        rows = list(pool.map(_job, jobs))
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
