"""``swarmloc compare``: every estimator on identical events, one table.

For a simulated scenario (``sim:random``, ``sim:range_bearing``; :mod:`swarmloc.experiments.sources`) each of
``runs`` seeds gives one team and its events, and every estimator runs on exactly those events; for a dataset
(``mrclam:PATH``, ``events:PATH``) the one recording is run once per estimator. Jobs (estimator x seed) run in
``jobs`` worker processes.

Columns, pooled over all robots' records of all runs:

* position and heading RMSE [m, rad];
* ANEES per degree of freedom and its two-sided 95% band for that many *independent* NEES values (records of one
  run are correlated in time, so the band is a yardstick, not a test), and the share of records whose NEES lies
  inside its own 95% interval;
* time per update: seconds in detection-group updates per group and in predictions per prediction (the node's
  ``measure_time`` counters), in microseconds;
* messages per robot per second of data (queries, answers, pairwise updates; 0 for the centralized EKF);
* detections fused / gated / rejected / unknown, summed.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from swarmloc.evaluation.metrics import DOF, anees_bounds, errors, pooled, summarize
from swarmloc.experiments.association import association_accuracy
from swarmloc.experiments.evaluate import association_text
from swarmloc.experiments.output import write_summary
from swarmloc.experiments.progress import steps
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, SE3
from swarmloc.runner.fanout import check_runs, cluster_address, fan_out
from swarmloc.runner.result import summed

if TYPE_CHECKING:
    from distributed import Client

_ONE = GroupGaussian(SE2, SE2.identity(), 0.01 * np.eye(3))
"""A belief to build a throwaway team with (the up-front check of the estimators' options)."""
_ONE3 = GroupGaussian(SE3, SE3.identity(), 0.01 * np.eye(6))
"""The same on SE(3): which estimators have a 3-D form."""


def is_3d(scenario: str) -> bool:
    """Whether ``scenario`` is a simulated 3-D team (``sim:3d``, ``sim:3d_rot``, ...: SE(3) beliefs)."""
    from swarmloc.experiments.sources import SIM3D_VARIANTS

    kind, _, name = scenario.partition(":")
    return kind == "sim" and name in SIM3D_VARIANTS


__all__ = ["compare", "compare_table", "is_3d"]


def _job(
    spec: str, estimator: str, seed: int, robots: int, duration: float | None, assoc: tuple = ("tags", 0.0, 1.0)
) -> dict[str, Any]:
    """One estimator on one source: pooled error arrays and counters (runs in a worker process). ``assoc``:
    ``(policy, clutter per scan, detection probability)`` (:mod:`swarmloc.experiments.association`)."""
    from swarmloc.estimators import make_team, node_options
    from swarmloc.experiments.association import association_events
    from swarmloc.experiments.sources import load_source
    from swarmloc.runner import run

    src = load_source(spec, robots=robots, duration=duration, seed=seed)
    policy, clutter, p_detect = assoc
    if src.noise is not None:  # a 3-D team: its SE(3) nodes, recorded at its truth instants (experiments.se3)
        from swarmloc.experiments.se3 import se3_team, with_truth

        nodes, events, record = se3_team(src, estimator), with_truth(src), None
    else:
        config = src.config.with_filter(association=policy)
        events, _ = association_events(src.events, policy, sorted(src.initial), config.motion.noise(),
                                       clutter=clutter, p_detect=p_detect, seed=seed)  # fmt: skip
        nodes = make_team(estimator, src.initial, **node_options(estimator, config, src.landmarks, src.t_start,
                                                                 src.sensor))  # fmt: skip
        record = src.record_times()
    for n in nodes:
        n.measure_time = True
    t = time.perf_counter()
    res = run(nodes, events, record, truth=src.truth if record is not None else None, name=estimator)
    wall = time.perf_counter() - t
    scored = [tr.with_truth() for tr in res.tracks.values()]
    return {
        "estimator": estimator,
        "seed": seed,
        **pooled(errors(tr) for tr in scored if tr.times.size),
        "stats": res.stats,
        "timing": res.timing,
        "wall_s": wall,
        "data_s": float(src.t_end - src.t_start),
        "robots": len(src.robots),
        "dof": 6 if src.noise is not None else DOF,
    }


def _refuse_what_cannot_run(
    scenario: str, estimators: Sequence[str], association: str, clutter: float, p_detect: float
) -> None:
    """Raise ValueError, before anything runs, for a scenario, policy or estimator :func:`compare` cannot run: an
    unknown scenario, a 3-D team with untagged detections or an estimator without 3-D support, an estimator that
    cannot run the association policy."""
    from swarmloc.config import DEFAULTS
    from swarmloc.estimators import estimator_class, make_team, node_options
    from swarmloc.experiments.association import association_policy
    from swarmloc.experiments.sources import source_kind

    policy = association_policy(association)
    source_kind(scenario)  # an unknown source kind or scenario, before any worker starts
    cfg = DEFAULTS.with_filter(association=policy)
    if is_3d(scenario):
        if association != "tags" or clutter or p_detect != 1.0:
            raise ValueError(f"{scenario}: a 3-D team's detections are tagged (association tags, no clutter, "
                             "p_detect 1)")  # fmt: skip
        for e in estimators:
            estimator_class(e, {0: _ONE3})
    for e in estimators:
        make_team(e, {0: _ONE, 1: _ONE}, **node_options(e, cfg, None, 0.0))


def _estimator_summary(rs: list[dict[str, Any]], dof: int) -> dict[str, Any]:
    """One estimator's row of :func:`compare`'s summary from its runs ``rs`` (:func:`_job`'s results): errors,
    NEES statistics for ``dof`` degrees of freedom, costs, counters."""
    n = sum(int(r["nees"].size) for r in rs)
    m = summarize(pooled(rs), dof)  # {"n": 0} when nothing was scored: those entries NaN
    st = summed(r["stats"] for r in rs)
    tm = {k: sum(r["timing"][k] for r in rs) for k in ("predict_s", "predict_n", "fuse_s", "fuse_n")}
    robot_s = sum(r["robots"] * r["data_s"] for r in rs)
    return {
        "records": n,
        "pos_rmse": m.get("pos_rmse", math.nan),
        "heading_rmse": m.get("heading_rmse", math.nan),
        "anees": m.get("anees", math.nan),
        "anees_band_95": anees_bounds(max(n, 1), dof),
        "frac_in_95": m.get("frac_in_95", math.nan),
        "anees_per_run": [float(np.mean(r["nees"]) / dof) for r in rs if r["nees"].size],
        "update_us": 1e6 * tm["fuse_s"] / tm["fuse_n"] if tm["fuse_n"] else 0.0,
        "predict_us": 1e6 * tm["predict_s"] / tm["predict_n"] if tm["predict_n"] else 0.0,
        "messages_per_robot_s": st.get("messages", 0) / robot_s if robot_s else 0.0,
        "detections": {k: st.get(k, 0) for k in ("detections", "fused", "gated", "rejected", "unknown")},
        "association": {k[12:]: st.get(k, 0) for k in st if k.startswith("association_")},
        "association_accuracy": association_accuracy(st),
        "x_real_time": sum(r["data_s"] for r in rs) / sum(r["wall_s"] for r in rs),
    }


def compare(
    scenario: str,
    estimators: Sequence[str],
    runs: int = 1,
    robots: int = 4,
    duration: float | None = None,
    out_dir: str | os.PathLike[str] | None = None,
    jobs: int = 2,
    progress: bool = False,
    association: str = "tags",
    clutter: float = 0.0,
    p_detect: float = 1.0,
    cluster: str | Client | None = None,
) -> dict[str, Any]:
    """Run ``estimators`` on ``scenario`` (``runs`` seeds for a simulation) and return the summary per estimator;
    with ``out_dir`` also write ``compare.md`` and ``compare.json``. ``association`` (with ``clutter`` false
    detections per scan and detection probability ``p_detect``): how robot detections get their identity
    (:mod:`swarmloc.experiments.association`; every policy but ``tags`` hides the ids). The runs go to ``jobs``
    worker processes, or to a Dask ``cluster`` (an address or a client: :func:`~swarmloc.runner.fanout.fan_out`)."""
    from swarmloc.estimators import check_known

    check_known(estimators)
    check_runs(runs)
    _refuse_what_cannot_run(scenario, estimators, association, clutter, p_detect)
    sim = scenario.startswith("sim:")
    seeds = list(range(runs)) if sim else [0]
    assoc = (association, float(clutter), float(p_detect))
    tasks = [(scenario, e, s, robots, duration, assoc) for e in estimators for s in seeds]
    done: dict[int, dict[str, Any]] = {}
    t0 = time.perf_counter()
    with steps(progress, len(tasks), f"compare {scenario}") as tick:
        for i, r in fan_out(_job, tasks, jobs=jobs, cluster=cluster):
            done[i] = r
            tick(f"{r['estimator']} seed {r['seed']}")
    results = [done[i] for i in range(len(tasks))]  # in task order, wherever and whenever each job ran
    summary: dict[str, Any] = {
        "scenario": scenario,
        "runs": len(seeds),
        "robots": results[0]["robots"] if results else 0,
        "duration_s": results[0]["data_s"] if results else 0.0,
        "wall_s": time.perf_counter() - t0,
        "cluster": cluster_address(cluster),
        "association": association,
        "clutter_per_scan": float(clutter),
        "p_detect": float(p_detect),
        "estimators": {},
    }
    dof = results[0]["dof"] if results else DOF  # 6 for a 3-D team: NEES of the 6 exponential coordinates
    summary["dof"] = dof
    for e in estimators:
        summary["estimators"][e] = _estimator_summary([r for r in results if r["estimator"] == e], dof)
    if out_dir is not None:
        write_summary(out_dir, "compare", summary, compare_table(summary))
    return summary


def compare_table(summary: dict[str, Any]) -> str:
    """The summary as Markdown."""
    s = summary
    lines = [
        f"# {s['scenario']}: {s['runs']} run(s), {s['robots']} robots, {s['duration_s']:.0f} s each"
        + ("" if s.get("association", "tags") == "tags" and not s.get("clutter_per_scan") and s.get("p_detect", 1) == 1
           else f"; association {s['association']}, clutter {s['clutter_per_scan']:g}/scan, "
                f"p_detect {s['p_detect']:g}"),
        "",
        f"| estimator | pos RMSE [m] | {'rotation' if s.get('dof') == 6 else 'heading'} RMSE [rad] | "
        "ANEES/dof (95% band if independent) | in 95% band | "
        "update [us] | predict [us] | messages / robot / s | fused / gated / rejected / unknown | "
        "association accuracy |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for name, e in s["estimators"].items():
        d = e["detections"]
        lo, hi = e["anees_band_95"]
        a = association_text({f"association_{k}": v for k, v in e.get("association", {}).items()})
        lines.append(
            f"| {name} | {e['pos_rmse']:.3f} | {e['heading_rmse']:.3f} | {e['anees']:.2f} ({lo:.2f}-{hi:.2f}) | "
            f"{e['frac_in_95']:.2f} | {e['update_us']:.0f} | {e['predict_us']:.0f} | {e['messages_per_robot_s']:.1f} "
            f"| {d['fused']} / {d['gated']} / {d['rejected']} / {d['unknown']} | {a} |"
        )
    return "\n".join(lines) + "\n"
