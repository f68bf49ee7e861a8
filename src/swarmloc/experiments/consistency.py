"""``swarmloc consistency``: Monte Carlo NEES of every estimator on a simulated team, without and with landmarks.

For each of ``seeds`` seeds, :func:`swarmloc.sim.random_team` gives a team of ``robots`` robots (area 3 m,
``duration`` s, relative-pose sensor at 5 Hz: the ``sim:random`` source of :mod:`swarmloc.experiments.sources`);
with landmarks on, the same team and events plus 6 known landmarks and range-bearing detections of them
(``sim:landmarks``, :mod:`swarmloc.sim.landmarks`). Every estimator runs on exactly those events. The initial beliefs
are *sampled*: covariance ``config.initial``, mean ``g exp(-y)`` with ``y ~ N(0, P0)`` drawn from its own stream of
the seed (a belief centred on the truth would make the early NEES ~0, not chi-square). Beliefs are recorded on the
common grid ``t_k`` every ``1 / config.record.rate`` s (4 Hz by default).

With ``NEES[s, i, k]`` of robot ``i`` in seed ``s`` at ``t_k`` (3 dof on SE(2), :mod:`swarmloc.evaluation.metrics`),
per estimator and landmark setting:

* position and heading RMSE [m, rad] over all seeds, robots and times (and per time, ``pos_rmse_t``);
* ``anees``: time-averaged ANEES per dof, the mean of ``NEES / 3`` over seeds, robots and times;
* ``anees_t``: the team ANEES over time, ``a(t_k) = mean over s, i of NEES[s, i, k] / 3``;
* ``in_band``: the share of record times at which ``a(t_k)`` lies inside its two-sided 95% band (below), and
  ``in_band_independent`` the same for the band of independent robots.

**The band.** Robots of one team are correlated: without landmarks all of them share the unobservable drift of
the team's frame (relative measurements cannot correct it), so their errors, and NEES, are nearly fully correlated;
with landmarks less so, but neighbours still share information. Only the seeds are independent. So the band takes
``S = seeds`` independent units per time, each the team's mean NEES ``m_s(t) = mean_i NEES[s, i, k]``: if the
robots' errors were identical, ``m_s ~ chi2(3)``, and no correlation can give the mean of ``n`` chi2(3) values a
larger variance than that. Hence the *conservative* (team-as-one-robot) band

    ``[chi2.ppf(0.025, 3 S) / (3 S), chi2.ppf(0.975, 3 S) / (3 S)]``,

as if each team contributed one robot's worth of independent information; the *independent-robots* band
``chi2.ppf(., 3 S n) / (3 S n)`` (every robot its own unit) is reported for reference: narrower, and right only for
uncorrelated robots. The conservative band is also the yardstick for the time-averaged ``anees`` (an average of
correlated chi2(3) values has at most the variance of one). No joint team NEES is computed: the runner records
per-robot marginals only.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from swarmloc.evaluation.metrics import DOF, anees_bounds, errors
from swarmloc.experiments.output import save_figure, write_summary
from swarmloc.experiments.progress import steps
from swarmloc.runner.fanout import check_runs, cluster_address, fan_out
from swarmloc.runner.result import summed

if TYPE_CHECKING:
    from distributed import Client

__all__ = [
    "EXCLUDED_BY_DEFAULT",
    "INITIAL_STREAM",
    "bands",
    "consistency",
    "consistency_table",
    "default_estimators",
    "sampled_initial",
]

EXCLUDED_BY_DEFAULT = ("mcl", "dr")
"""Registered estimators left out of the default list (particles: slow; dead reckoning: no fusion)."""

INITIAL_STREAM = 0x494E4954
"""Second entropy word of the initial-belief stream ``SeedSequence([seed, INITIAL_STREAM])``."""

SETTINGS = {False: "off", True: "on"}


def default_estimators() -> list[str]:
    """Every registered estimator (:data:`swarmloc.estimators.ESTIMATORS`) except :data:`EXCLUDED_BY_DEFAULT`."""
    from swarmloc.estimators import ESTIMATORS

    return [e for e in ESTIMATORS if e not in EXCLUDED_BY_DEFAULT]


def bands(seeds: int, robots: int, p: float = 0.95) -> dict[str, tuple[float, float]]:
    """Two-sided ``p`` bands of the team ANEES per dof at one time (see the module docstring): ``"team"`` (``seeds``
    independent units of 3 dof) and ``"independent"`` (``seeds * robots`` units)."""
    return {"team": anees_bounds(seeds, DOF, p), "independent": anees_bounds(seeds * robots, DOF, p)}


def sampled_initial(src: Any, seed: int) -> dict[int, Any]:
    """``src.initial`` with each mean moved to ``g exp(-y)``, ``y ~ N(0, cov)`` (so that the truth ``g`` is
    ``mean exp(y)``: right perturbation), robots in id order, from ``SeedSequence([seed, INITIAL_STREAM])``."""
    from swarmloc.gaussian import GroupGaussian
    from swarmloc.lie import SE2

    rng = np.random.default_rng(np.random.SeedSequence([int(seed), INITIAL_STREAM]))
    out = {}
    for r in sorted(src.initial):
        b = src.initial[r]
        y = np.linalg.cholesky(b.cov) @ rng.standard_normal(b.cov.shape[-1])
        out[r] = GroupGaussian(SE2, b.mean @ SE2.exp(-y), b.cov)
    return out


def _job(
    estimator: str, seed: int, robots: int, duration: float, landmarks: bool, sample_initial: bool
) -> dict[str, Any]:
    """One estimator on one seed: per-robot error arrays ``(n, K)`` on the record grid (runs in a worker)."""
    from swarmloc.estimators import make_team, node_options
    from swarmloc.experiments.sources import load_source
    from swarmloc.runner import run

    spec = "sim:landmarks" if landmarks else "sim:random"
    src = load_source(spec, robots=robots, duration=duration, seed=seed)
    initial = sampled_initial(src, seed) if sample_initial else src.initial
    nodes = make_team(estimator, initial, **node_options(estimator, src.config, src.landmarks, src.t_start))
    times = src.record_times()
    t = time.perf_counter()
    res = run(nodes, src.events, times, truth=src.truth, name=estimator)
    wall = time.perf_counter() - t
    errs = [errors(res.tracks[r]) for r in src.robots]
    return {
        "key": (landmarks, estimator, seed),
        "times": times,
        "pos": np.stack([e["pos"] for e in errs]),
        "heading": np.stack([e["heading"] for e in errs]),
        "nees": np.stack([e["nees"] for e in errs]),
        "stats": res.stats,
        "wall_s": wall,
    }


def _summarize(rs: list[dict[str, Any]], band: dict[str, tuple[float, float]]) -> dict[str, Any]:
    """Statistics of one estimator and landmark setting from its per-seed results (in seed order)."""
    nees = np.stack([r["nees"] for r in rs])  # (S, n, K)
    pos = np.stack([r["pos"] for r in rs])
    head = np.stack([r["heading"] for r in rs])
    a_t = nees.mean(axis=(0, 1)) / DOF
    lo, hi = band["team"]
    ilo, ihi = band["independent"]
    st = summed(r["stats"] for r in rs)
    return {
        "pos_rmse": float(np.sqrt(np.mean(pos**2))),
        "heading_rmse": float(np.sqrt(np.mean(head**2))),
        "anees": float(nees.mean() / DOF),
        "in_band": float(np.mean((a_t >= lo) & (a_t <= hi))),
        "in_band_independent": float(np.mean((a_t >= ilo) & (a_t <= ihi))),
        "anees_per_seed": (nees.mean(axis=(1, 2)) / DOF).tolist(),
        "anees_t": a_t.tolist(),
        "pos_rmse_t": np.sqrt(np.mean(pos**2, axis=(0, 1))).tolist(),
        "detections": {k: st.get(k, 0) for k in ("detections", "fused", "gated", "rejected", "unknown")},
        "run_wall_s": float(sum(r["wall_s"] for r in rs)),
    }


def consistency(
    estimators: Sequence[str] | None = None,
    seeds: int = 50,
    robots: int = 5,
    duration: float = 60.0,
    landmarks: Sequence[bool] = (False, True),
    jobs: int = 2,
    out: str | os.PathLike[str] | None = None,
    *,
    sample_initial: bool = True,
    progress: bool = False,
    cluster: str | Client | None = None,
) -> dict[str, Any]:
    """Run ``estimators`` (default :func:`default_estimators`) on ``seeds`` simulated teams of ``robots`` over
    ``duration`` s, for each landmark setting in ``landmarks``, in ``jobs`` worker processes or on a Dask ``cluster``
    (an address or a client: :func:`~swarmloc.runner.fanout.fan_out`); returns the summary
    (see the module docstring; ``summary["settings"]["off" | "on"][estimator]``). With ``out`` also writes
    ``consistency.json``, ``consistency.md`` and ``consistency.png`` (team ANEES over time with both bands) there.
    Raises ValueError for unknown estimators or bad sizes."""
    from swarmloc.estimators import check_known

    estimators = default_estimators() if estimators is None else list(estimators)
    check_known(estimators)
    if not estimators:
        raise ValueError("no estimators given")
    check_runs(seeds, "seeds")
    if not (isinstance(robots, int) and robots >= 1):
        raise ValueError(f"robots must be a positive integer, got {robots!r}")
    if not duration > 0:
        raise ValueError(f"duration must be positive, got {duration!r}")
    settings = list(dict.fromkeys(bool(x) for x in landmarks))
    if not settings:
        raise ValueError("landmarks: give at least one of off (False) and on (True)")
    t0 = time.perf_counter()
    tasks = [(e, s, robots, float(duration), lm, sample_initial) for lm in settings for e in estimators
             for s in range(seeds)]  # fmt: skip
    results: dict[tuple, dict[str, Any]] = {}  # _job's results by key, wherever fan_out ran them
    with steps(progress, len(tasks), "consistency") as tick:
        for _, r in fan_out(_job, tasks, jobs=jobs, cluster=cluster):
            results[r["key"]] = r
            tick("")
    band = bands(seeds, robots)
    summary: dict[str, Any] = {
        "seeds": seeds,
        "robots": robots,
        "duration_s": float(duration),
        "sample_initial": sample_initial,
        "jobs": jobs,
        "cluster": cluster_address(cluster),
        "wall_s": time.perf_counter() - t0,
        "band": {
            "p": 0.95,
            "team": band["team"],
            "independent": band["independent"],
            "note": (
                f"per time, {seeds} independent units (seeds), each the team's mean NEES: conservative band "
                f"chi2(3*{seeds})/(3*{seeds}) as if a team gave one robot's worth of information (its robots are "
                f"correlated: without landmarks they share the unobservable drift); the independent-robots band "
                f"chi2(3*{seeds}*{robots})/(3*{seeds}*{robots}) is for reference"
            ),
        },
        "times": results[tasks[0][4], tasks[0][0], 0]["times"].tolist(),
        "settings": {},
    }
    for lm in settings:
        summary["settings"][SETTINGS[lm]] = {
            e: _summarize([results[lm, e, s] for s in range(seeds)], band) for e in estimators
        }
    if out is not None:
        d = Path(out)
        d.mkdir(parents=True, exist_ok=True)
        summary["figure"] = "consistency.png"
        figure(summary, d / "consistency.png")
        write_summary(d, "consistency", summary, consistency_table(summary))
    return summary


def consistency_table(summary: dict[str, Any]) -> str:
    """The summary as Markdown: one row per landmark setting and estimator, and the band's definition."""
    s = summary
    lo, hi = s["band"]["team"]
    ilo, ihi = s["band"]["independent"]
    lines = [
        f"# Consistency: {s['seeds']} seeds, {s['robots']} robots, {s['duration_s']:.0f} s each "
        f"(wall {s['wall_s']:.0f} s)",
        "",
        f"95% band of the team ANEES per dof at one time: {lo:.3f}-{hi:.3f} (conservative: {s['seeds']} seeds as "
        f"the independent units, a team counts as one robot); {ilo:.3f}-{ihi:.3f} if the robots were independent.",
        "",
        "| landmarks | estimator | pos RMSE [m] | heading RMSE [rad] | ANEES/dof (time avg) | time in band "
        "| time in independent band | fused / gated / rejected |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for setting, ests in s["settings"].items():
        for name, e in ests.items():
            d = e["detections"]
            lines.append(
                f"| {setting} | {name} | {e['pos_rmse']:.3f} | {e['heading_rmse']:.4f} | {e['anees']:.2f} | "
                f"{e['in_band']:.2f} | {e['in_band_independent']:.2f} | {d['fused']} / {d['gated']} / {d['rejected']} |"
            )
    return "\n".join(lines) + "\n"


def figure(summary: dict[str, Any], path: str | os.PathLike[str]) -> None:
    """Team ANEES per dof over time per estimator, one panel per landmark setting, both 95% bands (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    settings = summary["settings"]
    t = np.asarray(summary["times"])
    lo, hi = summary["band"]["team"]
    ilo, ihi = summary["band"]["independent"]
    fig, axes = plt.subplots(1, len(settings), figsize=(6.5 * len(settings), 4.5), squeeze=False, sharey=True)
    for ax, (setting, ests) in zip(axes[0], settings.items(), strict=True):
        ax.axhspan(lo, hi, color="0.85", label=f"95% band, team as one unit ({lo:.2f}-{hi:.2f})")
        ax.axhline(ilo, color="0.4", ls="--", lw=0.8, label=f"95% band, independent robots ({ilo:.2f}-{ihi:.2f})")
        ax.axhline(ihi, color="0.4", ls="--", lw=0.8)
        for name, e in ests.items():
            ax.semilogy(t, e["anees_t"], lw=1.0, label=f"{name} (avg {e['anees']:.2f})")
        ax.set_title(f"landmarks {setting}: {summary['seeds']} seeds x {summary['robots']} robots")
        ax.set_xlabel("time [s]")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel("team ANEES per dof a(t)")
    save_figure(fig, path)
