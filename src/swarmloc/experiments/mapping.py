"""``swarmloc map``: the chapter's map-building experiment (Song, Tsai and Chiu Huang 2010, sec. 5, Figs 8-10).

Robots H1 and H2 (:func:`swarmloc.sim.lab.chapter_team`) drive through the points of Tables 3-4 in the area of
:func:`swarmloc.sim.walls.chapter_lab`, scanning with a :class:`~swarmloc.sim.walls.RangeFinder`. Each scan's lines
(:func:`swarmloc.mapping.extract_lines`) are carried into the world frame with the robot's recorded belief at the
scan's time (:func:`swarmloc.mapping.line_to_world`) and fused in one :class:`~swarmloc.mapping.LineMap`, in time
order. The beliefs come from an estimator run through the in-process runner on the simulation's events (as
``swarmloc evaluate`` runs a source): ``dr`` for dead reckoning, a cooperative one (``expfusion``, ``diekf``, ...)
for the team. Maps:

* ``H1 alone``, ``H2 alone``: one robot's scans, its dead-reckoning beliefs (the chapter's experiment 1, Fig. 8);
* ``team, dr``: both robots' scans, dead reckoning (no cooperative localization);
* ``team, <estimator>``: both robots' scans, cooperative localization (the chapter's Fig. 10);
* ``true poses``: both robots' scans at their true poses (what sensing and line extraction alone cost).

Each map is scored against the true walls with :func:`swarmloc.mapping.map_error`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.estimators import make_team, node_options
from swarmloc.experiments.output import save_figure
from swarmloc.experiments.progress import Tick, no_tick, steps
from swarmloc.lie import SE2
from swarmloc.mapping import LineMap, map_error, scan_observations
from swarmloc.runner import run
from swarmloc.runner.fanout import check_runs
from swarmloc.sim.lab import chapter_team
from swarmloc.sim.source import sim_source
from swarmloc.sim.walls import RangeFinder, Scans, Walls, chapter_lab, scan_team

__all__ = ["build_map", "map_experiment"]

Beliefs = dict[int, tuple[np.ndarray, np.ndarray]]
"""Robot id -> (means ``(S, 3)`` as ``(x, y, theta)``, exponential-coordinate covariances ``(S, 3, 3)``)."""


def build_map(scans: Scans, robots: tuple[int, ...], beliefs: Beliefs, order: int = 2, **map_kw: Any) -> LineMap:
    """Fuse the lines of ``robots``' scans, carried into the world with ``beliefs`` at the scan times, in time
    order (robots in id order at one time) into a new :class:`LineMap` (``map_kw`` to its constructor)."""
    lm = LineMap(**map_kw)
    col = {r: j for j, r in enumerate(scans.robot_ids)}
    for s in range(scans.times.size):
        for r in robots:
            mean, cov = beliefs[r][0][s], beliefs[r][1][s]
            for obs in scan_observations(scans.ranges[s, col[r]], scans.angles, scans.sigma, SE2.from_xytheta(mean),
                                         cov, r, float(scans.times[s]), order):  # fmt: skip
                lm.add(obs)
    return lm


def beliefs_of(estimator: str, sim: Any, times: np.ndarray) -> Beliefs:
    """Every robot's belief at ``times`` under ``estimator`` (in-process runner on the simulation's events)."""
    src = sim_source(sim, "sim:chapter")
    nodes = make_team(estimator, src.initial, **node_options(estimator, src.config, None, src.t_start))
    res = run(nodes, src.events, record_times=times, truth=src.truth, name=estimator)
    out = {}
    for r, tr in res.tracks.items():
        if tr.times.size != times.size or not np.allclose(tr.times, times):
            raise RuntimeError(f"{estimator}: robot {r}'s beliefs were not recorded at every scan time")
        out[r] = (tr.mean, tr.cov)
    return out


def one_seed(
    seed: int, estimators: tuple[str, ...], finder: RangeFinder, order: int, D: float, tick: Tick = no_tick
) -> dict[str, Any]:
    """The maps of one seed and their errors: ``{"errors": {name: metrics}, "maps": {name: LineMap}, ...}``;
    ``tick`` once per estimator run (dead reckoning first)."""
    sim = chapter_team(seed, D=D)
    walls = chapter_lab()
    scans = scan_team(sim, walls, finder, seed)
    both = scans.robot_ids
    truth = {r: (scans.poses[:, j], np.broadcast_to(1e-12 * np.eye(3), (scans.times.size, 3, 3)))
             for j, r in enumerate(both)}  # fmt: skip
    dr = beliefs_of("dr", sim, scans.times)
    tick(f"seed {seed}, dr")
    maps = {f"H{r} alone": build_map(scans, (r,), dr, order) for r in both}
    maps["team, dr"] = build_map(scans, both, dr, order)
    paths = {"truth": truth, "dr": dr}
    for est in estimators:
        paths[est] = beliefs_of(est, sim, scans.times)
        tick(f"seed {seed}, {est}")
        maps[f"team, {est}"] = build_map(scans, both, paths[est], order)
    maps["true poses"] = build_map(scans, both, truth, order)
    seen = scans.true_hits()
    errors = {name: map_error(lm.segments(), walls.segments, seen) for name, lm in maps.items()}
    return {"errors": errors, "maps": maps, "walls": walls, "paths": paths}


def map_experiment(
    seeds: int = 3,
    estimators: tuple[str, ...] = ("expfusion",),
    finder: RangeFinder | None = None,
    order: int = 2,
    D: float = 0.005,
    first_seed: int = 0,
    progress: bool = False,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Run :func:`one_seed` for ``seeds`` seeds; returns ``(report, first seed's result)``: the report has the
    errors per seed and their means per map. ``progress``: a bar on stderr over the estimator runs. Raises
    ValueError, before any run, for a count of seeds outside ``[1, MAX_RUNS]``, a first seed outside ``[0, 2^32 -
    seeds]``, an order other than 1 or 2, an unknown estimator or a bad ``D`` or ``finder``."""
    from swarmloc.estimators import check_known

    check_runs(seeds, "seeds")
    if isinstance(first_seed, bool) or not isinstance(first_seed, int) or not 0 <= first_seed <= 2**32 - seeds:
        raise ValueError(f"the first seed must be an integer in [0, 2^32 - seeds], got {first_seed!r}")
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order!r}")
    if not (isinstance(D, int | float) and 0 <= D < np.inf):
        raise ValueError(f"D (the wheel-speed diffusion) must be a finite number >= 0 [rad^2/s], got {D!r}")
    check_known(list(estimators))
    finder = RangeFinder() if finder is None else finder
    per_seed, first = [], None
    with steps(progress, seeds * (1 + len(estimators)), "map") as tick:
        for k in range(seeds):
            res = one_seed(first_seed + k, tuple(estimators), finder, order, D, tick)
            first = res if first is None else first
            per_seed.append(res["errors"])
    names = list(per_seed[0])
    keys = list(per_seed[0][names[0]])
    mean = {n: {k: float(np.nanmean([e[n][k] for e in per_seed])) for k in keys} for n in names}
    singles = [n for n in names if n.endswith("alone")]
    single = float(np.mean([mean[n]["endpoint_mean"] for n in singles]))
    ratio = {n: mean[n]["endpoint_mean"] / single for n in names if n.startswith("team")}
    report: dict[str, Any] = {
        "seeds": list(range(first_seed, first_seed + seeds)), "estimators": list(estimators), "order": order,
        "D": D, "finder": vars(finder), "per_seed": per_seed, "mean": mean, "team_over_single_endpoint_mean": ratio,
    }  # fmt: skip
    assert first is not None  # a seed at least (per_seed[0] above)
    return report, first


def markdown(report: dict[str, Any]) -> str:
    """The mean errors per map as a Markdown table."""
    lines = [
        f"# Map error, chapter experiment (H1, H2), {len(report['seeds'])} seeds {report['seeds']}",
        "",
        "| map | endpoint mean [m] | endpoint max [m] | Hausdorff [m] | wall length covered | seen | lines |",
        "|---|---|---|---|---|---|---|",
    ]
    for n, m in report["mean"].items():
        lines.append(f"| {n} | {m['endpoint_mean']:.3f} | {m['endpoint_max']:.3f} | {m['hausdorff']:.3f} | "
                     f"{m['covered']:.2f} | {m['seen_fraction']:.2f} | {m['lines']:.1f} |")  # fmt: skip
    lines += ["", "Team endpoint mean / single robots' (mean of H1 and H2 alone): "
              + ", ".join(f"{n}: {r:.2f}" for n, r in report["team_over_single_endpoint_mean"].items())]  # fmt: skip
    return "\n".join(lines) + "\n"


def figure(path: Path, res: dict[str, Any], coop: tuple[str, ...]) -> None:
    """Maps side by side like the chapter's Figs 8 and 10: H1 alone (dead reckoning), the team with dead
    reckoning, and the team with each cooperative estimator of ``coop``; true walls dotted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("H1 alone", ("dr",), (1,)), ("team, dr", ("dr",), (1, 2))]
    panels += [(f"team, {c}", (c,), (1, 2)) for c in coop]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.4 * len(panels), 6.2))
    walls: Walls = res["walls"]
    for ax, (name, (src,), robots) in zip(axes, panels, strict=True):
        for seg in walls.segments:
            ax.plot(seg[:, 0], seg[:, 1], ":", color="0.5", lw=1.2)
        res["maps"][name].plot(ax, color="k", lw=1.8)
        for r in robots:
            ax.plot(*res["paths"][src][r][0][:, :2].T, ".", ms=2, color=f"C{r}", label=f"H{r} estimated path")
        e = res["errors"][name]
        cm = f"endpoint mean {e['endpoint_mean'] * 100:.1f} cm, Hausdorff {e['hausdorff'] * 100:.1f} cm"
        ax.set_title(f"{name}\n{cm}", fontsize=9)
        ax.set_aspect("equal")
        ax.legend(fontsize=7, loc="lower right")
    save_figure(fig, path)
