"""Computations of thesis sec. 5.2.2 / Table 6.1: one simulation job through several estimators (timed by the nodes),
the process pool, the statistics over seeds, and :func:`run_dynamic`, which builds the result dictionary and hands it
to :mod:`swarmloc_studies.thesis_dynamic.report`."""

from __future__ import annotations

import os
import platform
import resource
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from swarmloc.estimators import make_team
from swarmloc.evaluation.metrics import evaluate, over_seeds
from swarmloc.events import Detection, Event, Kind
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.runner import RunResult, run
from swarmloc.runner.fanout import fan_out
from swarmloc.sim import thesis_ground_truth_neighbour, thesis_two_robot
from swarmloc_studies.thesis_dynamic.report import figures, progress_bar, pyplot, write_dynamic
from swarmloc_studies.thesis_dynamic.spec import (
    ABLATION_ESTIMATORS,
    ABLATION_NOISE,
    ABLATIONS,
    CURVE_EVERY,
    FULL,
    GT_ESTIMATORS,
    GT_NOISE,
    INIT_VAR,
    NOISE_LEVELS,
    QUICK,
    RUNS,
)

if TYPE_CHECKING:
    from distributed import Client


# ---------------------------------------------------------------------------------------------------------- jobs
def _filter_events(events: list[Event], every: int, oneway: bool, sensor_rate: float = 10.0) -> list[Event]:
    """Keep detections at every ``every``-th sensor instant; with ``oneway`` drop robot 2's detections."""
    if every == 1 and not oneway:
        return events
    out = []
    for e in events:
        if isinstance(e, Detection) and e.kind != Kind.ABSOLUTE:
            if oneway and e.observer != 1:
                continue
            if int(round(e.t * sensor_rate)) % every:
                continue
        out.append(e)
    return out


def _common_relative(res: RunResult) -> dict[str, float]:
    """RMS of the robots' common-mode position error ``(e1 + e2)/2`` and relative error ``e1 - e2``."""
    t1, t2 = res.tracks[1], res.tracks[2]
    n = min(t1.times.size, t2.times.size)
    e1 = t1.mean[:n, :2] - t1.truth[:n, :2]
    e2 = t2.mean[:n, :2] - t2.truth[:n, :2]
    rms = lambda e: float(np.sqrt(np.mean(np.sum(e * e, axis=1))))  # noqa: E731
    return {"common_rms": rms((e1 + e2) / 2), "relative_rms": rms(e1 - e2)}


def _claimed_pos_std(res: RunResult, robots: Sequence[int]) -> float:
    """``sqrt(mean trace Sigma_pos)``: the position RMSE the filter claims (equals the RMSE if consistent)."""
    tr = np.concatenate([np.trace(res.tracks[r].cov[:, :2, :2], axis1=1, axis2=2) for r in robots])
    return float(np.sqrt(np.mean(tr)))


def _job(spec: dict[str, Any]) -> dict[str, Any]:
    """One simulation (experiment, noise, seed, event filter) run through several estimators."""
    if spec["scenario"] == "gt":
        sim = thesis_ground_truth_neighbour(noise_std=spec["noise"], seed=spec["seed"], duration=spec["duration"])
    else:
        sim = thesis_two_robot(noise_std=spec["noise"], seed=spec["seed"], duration=spec["duration"])
    events = _filter_events(sim.events, spec.get("every", 1), spec.get("oneway", False))
    out: dict[str, Any] = {"spec": spec, "runs": {}}
    for key in spec["estimators"]:
        es = RUNS[key]
        init = {
            r: GroupGaussian(SE2, m, INIT_VAR * np.eye(3), validate=False)
            for r, m in sim.initial_pose_matrices().items()
        }
        nodes = make_team(es.cls, init, noise=sim.unicycle_noise(), **dict(es.kwargs))
        for n in nodes:
            n.measure_time = True
        res = run(nodes, events)
        ev = evaluate(res)
        t = res.timing
        item: dict[str, Any] = {
            "team": ev["team"],
            "robots": {int(r): v for r, v in ev["robots"].items()},
            "wall": res.wall_time,
            "n_predict": int(t["predict_n"]),
            "n_update": int(t["fuse_n"]),
            "n_fused": int(res.stats["fused"]),
            "timing": {
                "predict_s": t["predict_s"],
                "predict_n": t["predict_n"],
                "update_s": t["fuse_s"],
                "update_n": t["fuse_n"],
            },  # fmt: skip
            "claimed_pos_std": _claimed_pos_std(res, sorted(res.tracks)),
            "claimed_pos_std_r1": _claimed_pos_std(res, [1]),
            **_common_relative(res),
        }
        if key == "cekf":
            central: Any = nodes[0]  # a CentralizedEKF: its joint belief
            _, P = central.joint_at(float(sim.times[-1]))
            s = np.sqrt(np.diag(P))
            item["final_corr"] = {n: float(P[i, i + 3] / (s[i] * s[i + 3])) for i, n in enumerate(("x", "y", "theta"))}
        if spec.get("keep"):
            item["result"] = RunResult(res.estimator, {1: res.tracks[1]}, res.wall_time, res.stats, res.n_events)
        out["runs"][key] = item
    return out


def _run_jobs(
    specs: list[dict[str, Any]],
    workers: int,
    progress: bool,
    weight: Callable[[dict[str, Any]], float],
    cluster: str | Client | None = None,
) -> list[dict[str, Any]]:
    """Run ``specs`` (largest first) where :func:`~swarmloc.runner.fanout.fan_out` runs them (``workers`` processes
    or a Dask ``cluster``), with a rich progress bar over estimator runs; the results in ``specs``' order."""
    order = sorted(range(len(specs)), key=lambda i: -weight(specs[i]))
    results: list[dict[str, Any] | None] = [None] * len(specs)
    total = sum(len(s["estimators"]) for s in specs)
    bar = None
    if progress:
        bar, task = progress_bar(total)
    try:
        for k, r in fan_out(_job, [(specs[i],) for i in order], jobs=workers, cluster=cluster):
            results[order[k]] = r
            if bar is not None:
                s = r["spec"]
                bar.update(task, advance=len(s["estimators"]), description=f"{s['label']} seed {s['seed']}")
    finally:
        if bar is not None:
            bar.stop()
    return [r for r in results if r is not None]


def _cpu_seconds() -> float:
    """CPU time of this process and its reaped children (the worker processes), user + system."""
    me, ch = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + ch.ru_utime + ch.ru_stime


# ---------------------------------------------------------------------------------------------------------- stats
def spread(values: Sequence[float]) -> dict[str, float]:
    """Mean, std (ddof=1; 0 for one value), min, max and n of ``values``."""
    a = np.asarray(values, dtype=float)
    return {
        "mean": float(a.mean()),
        "std": float(a.std(ddof=1)) if a.size > 1 else 0.0,
        "min": float(a.min()),
        "max": float(a.max()),
        "n": int(a.size),
    }


def _curve(results: list[RunResult], robot: int = 1) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    c = over_seeds(results, robot)
    inside = (c["anees"] >= c["anees_lo"]) & (c["anees"] <= c["anees_hi"])
    sl = slice(None, None, CURVE_EVERY)
    js: dict[str, Any] = {
        k: [round(float(x), 6) for x in v[sl]] for k, v in c.items() if k not in ("anees_lo", "anees_hi")
    }
    js["anees_bounds"] = [float(c["anees_lo"][0]), float(c["anees_hi"][0])]
    js["anees_frac_in_band"] = float(np.mean(inside))
    return c, js


def _summarize(items: list[dict[str, Any]]) -> dict[str, Any]:
    """Spread over seeds of one estimator in one experiment."""
    team = {k: spread([it["team"][k] for it in items]) for k in ("pos_rmse", "heading_rmse", "anees", "frac_in_95")}
    team["claimed_pos_std"] = spread([it["claimed_pos_std"] for it in items])
    robots = {
        str(r): {k: spread([it["robots"][r][k] for it in items]) for k in ("pos_rmse", "heading_rmse", "anees")}
        for r in sorted(items[0]["robots"])
    }
    robots["1"]["claimed_pos_std"] = spread([it["claimed_pos_std_r1"] for it in items])
    t = {k: sum(it["timing"][k] for it in items) for k in ("predict_s", "predict_n", "update_s", "update_n")}
    calls = sum(it["n_predict"] + it["n_update"] for it in items)
    timing = {
        "us_per_call_wall": 1e6 * sum(it["wall"] for it in items) / max(calls, 1),
        "us_per_predict": 1e6 * t["predict_s"] / max(t["predict_n"], 1),
        "us_per_update": 1e6 * t["update_s"] / max(t["update_n"], 1),
        "predict_calls": int(t["predict_n"]),
        "update_calls": int(t["update_n"]),
        "wall_s_per_run": spread([it["wall"] for it in items]),
    }
    return {
        "team": team,
        "robots": robots,
        "common_rms": spread([it["common_rms"] for it in items]),
        "relative_rms": spread([it["relative_rms"] for it in items]),
        "per_seed": {
            "pos_rmse": [it["team"]["pos_rmse"] for it in items],
            "heading_rmse": [it["team"]["heading_rmse"] for it in items],
            "anees": [it["team"]["anees"] for it in items],
        },
        "timing": timing,
        "detections_fused_per_run": float(np.mean([it["n_fused"] for it in items])),
    }


def _paired(a: Sequence[float], b: Sequence[float]) -> dict[str, float]:
    """Paired comparison over seeds of ``a`` vs ``b`` (e.g. RMSE of two estimators on the same simulations)."""
    x, y = np.asarray(a, float), np.asarray(b, float)
    d = x - y
    return {
        "a_lower_in_seeds": int(np.sum(x < y)),
        "n": int(x.size),
        "mean_diff": float(d.mean()),
        "std_diff": float(d.std(ddof=1)) if d.size > 1 else 0.0,
        "mean_rel_diff": float(np.mean(d / y)),
    }


# ---------------------------------------------------------------------------------------------------------- main
def _specs(seeds: int, gt_seeds: int, ab_seeds: int, dur: float, gt_dur: float) -> list[dict[str, Any]]:
    """The jobs of :func:`run_dynamic`: the two-robot runs at every noise level (every estimator, trajectories
    kept), the ground-truth-neighbour runs, and the double-counting ablations but ``mutual_10hz`` (identical to the
    main runs at :data:`ABLATION_NOISE`: taken from there)."""
    specs: list[dict[str, Any]] = []
    for noise in NOISE_LEVELS:
        for s in range(seeds):
            specs.append(
                {
                    "label": f"two robots, noise {noise:g}",
                    "exp": "two_robot",
                    "scenario": "two",
                    "noise": noise,
                    "seed": s,
                    "duration": dur,
                    "estimators": tuple(RUNS),
                    "keep": True,
                }
            )
    specs += [{"label": "ground-truth neighbour", "exp": "gt", "scenario": "gt", "noise": GT_NOISE, "seed": s,
               "duration": gt_dur, "estimators": GT_ESTIMATORS, "keep": True} for s in range(gt_seeds)]  # fmt: skip
    for ak, (_, every, oneway) in ABLATIONS.items():
        if ak == "mutual_10hz":
            continue
        for s in range(ab_seeds):
            specs.append(
                {
                    "label": f"double counting: {ak}",
                    "exp": "ablation",
                    "ablation": ak,
                    "scenario": "two",
                    "noise": ABLATION_NOISE,
                    "seed": s,
                    "duration": dur,
                    "estimators": ABLATION_ESTIMATORS,
                    "every": every,
                    "oneway": oneway,
                }
            )
    return specs


def _select(jobs: list[dict[str, Any]], exp: str, **kw: Any) -> list[dict[str, Any]]:
    """The jobs of experiment ``exp`` whose spec has the values ``kw``, by seed."""
    js = [j for j in jobs if j["spec"]["exp"] == exp and all(j["spec"].get(k) == v for k, v in kw.items())]
    return sorted(js, key=lambda j: j["spec"]["seed"])


def _summary_and_curve(items: list[dict[str, Any]]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """One estimator's runs over seeds: :func:`_summarize` with robot 1's error against time added, and that
    curve's arrays for the figures."""
    summ = _summarize(items)
    c, cj = _curve([it["result"] for it in items])
    summ["robot1_error_vs_time"] = cj
    return summ, c


def _orderings(ps: dict[str, dict[str, list[float]]]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Paired comparisons over seeds of the per-seed values ``ps`` (estimator -> metric -> values): the thesis'
    ordering (expfusion < dekf < dr), and the second-order fusion against the first-order one."""
    ordering = {
        "expfusion_vs_dekf_rmse": _paired(ps["expfusion"]["pos_rmse"], ps["dekf"]["pos_rmse"]),
        "expfusion_vs_dr_rmse": _paired(ps["expfusion"]["pos_rmse"], ps["dr"]["pos_rmse"]),
        "dekf_vs_dr_rmse": _paired(ps["dekf"]["pos_rmse"], ps["dr"]["pos_rmse"]),
        "cekf_vs_expfusion_rmse": _paired(ps["cekf"]["pos_rmse"], ps["expfusion"]["pos_rmse"]),
        "cekf_vs_dr_rmse": _paired(ps["cekf"]["pos_rmse"], ps["dr"]["pos_rmse"]),
        "thesis_order_holds_in_seeds": int(
            np.sum(
                (np.array(ps["expfusion"]["pos_rmse"]) < np.array(ps["dekf"]["pos_rmse"]))
                & (np.array(ps["dekf"]["pos_rmse"]) < np.array(ps["dr"]["pos_rmse"]))
            )
        ),
    }
    order12 = {
        "rmse_order2_vs_order1": _paired(ps["expfusion"]["pos_rmse"], ps["expfusion1"]["pos_rmse"]),
        "heading_rmse_order2_vs_order1": _paired(ps["expfusion"]["heading_rmse"], ps["expfusion1"]["heading_rmse"]),
        "anees_order2_vs_order1": _paired(ps["expfusion"]["anees"], ps["expfusion1"]["anees"]),
    }
    return ordering, order12


def _two_robot(jobs: list[dict[str, Any]]) -> tuple[dict[str, Any], ...]:
    """The two-robot runs by noise level (its ``f"{noise:g}"``): every estimator's summary, the curves and the
    first seed's trajectories for the figures, and :func:`_orderings`'s two comparisons."""
    curves: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    traj: dict[str, dict[str, RunResult]] = {}
    two_robot: dict[str, Any] = {}
    ordering: dict[str, Any] = {}
    order12: dict[str, Any] = {}
    for noise in NOISE_LEVELS:
        nk = f"{noise:g}"
        js = _select(jobs, "two_robot", noise=noise)
        two_robot[nk] = {}
        curves[nk] = {}
        for key in RUNS:
            items = [j["runs"][key] for j in js]
            two_robot[nk][key], curves[nk][key] = _summary_and_curve(items)
            if key == "cekf":
                two_robot[nk][key]["final_corr_r1_r2"] = {
                    n: spread([it["final_corr"][n] for it in items]) for n in ("x", "y", "theta")
                }
        traj[nk] = {key: js[0]["runs"][key]["result"] for key in RUNS}
        ordering[nk], order12[nk] = _orderings({k: two_robot[nk][k]["per_seed"] for k in RUNS})
    return two_robot, curves, traj, ordering, order12


def _double_counting(jobs: list[dict[str, Any]], ab_seeds: int) -> dict[str, Any]:
    """Each ablation of :data:`ABLATIONS`: its settings and, per estimator, both robots' RMSE and ANEES over seeds
    and the detections fused per run."""
    abl: dict[str, Any] = {}
    for ak, (desc, every, oneway) in ABLATIONS.items():
        if ak == "mutual_10hz":
            js = _select(jobs, "two_robot", noise=ABLATION_NOISE)[:ab_seeds]
        else:
            js = _select(jobs, "ablation", ablation=ak)
        abl[ak] = {"description": desc, "every": every, "oneway": oneway, "seeds": len(js), "estimators": {}}
        for key in ABLATION_ESTIMATORS:
            items = [j["runs"][key] for j in js]
            abl[ak]["estimators"][key] = {
                f"robot{r}": {k: spread([it["robots"][r][k] for it in items]) for k in ("pos_rmse", "anees")}
                for r in (1, 2)
            } | {"detections_fused_per_run": float(np.mean([it["n_fused"] for it in items]))}
    return abl


def _table61(jobs: list[dict[str, Any]], two_robot: dict[str, Any], gt: dict[str, Any]) -> list[dict[str, Any]]:
    """Table 6.1's rows: every estimator's errors, its costs (timing pooled over all two-robot runs) and traits."""
    table61 = []
    for key, es in RUNS.items():
        items = [j["runs"][key] for j in _select(jobs, "two_robot")]
        tp = sum(it["timing"]["predict_s"] for it in items) / max(sum(it["timing"]["predict_n"] for it in items), 1)
        tu = sum(it["timing"]["update_s"] for it in items) / max(sum(it["timing"]["update_n"] for it in items), 1)
        table61.append(
            {
                "key": key,
                "method": es.label,
                "implemented": True,
                "pos_rmse": {f"{n:g}": two_robot[f"{n:g}"][key]["team"]["pos_rmse"]["mean"] for n in NOISE_LEVELS},
                "anees": {f"{n:g}": two_robot[f"{n:g}"][key]["team"]["anees"]["mean"] for n in NOISE_LEVELS},
                "gt_neighbour_robot1_pos_rmse": gt[key]["robots"]["1"]["pos_rmse"]["mean"] if key in gt else None,
                "gt_neighbour_robot1_anees": gt[key]["robots"]["1"]["anees"]["mean"] if key in gt else None,
                "us_per_predict": 1e6 * tp,
                "us_per_update": None if key == "dr" else 1e6 * tu,
                "multiple_detections_at_once": es.multiple_detections,
                "distributed": "yes" if es.cls.distributed else "no",
                "note": es.note,
            }
        )
    return table61


def _meta(seeds: int, quick: bool, dur: float, gt_dur: float, gt_seeds: int, ab_seeds: int, workers: int) -> dict:
    """The ``meta`` of :func:`run_dynamic`'s result: its settings, the model's, units, the machine."""
    sim0 = thesis_two_robot(noise_std=NOISE_LEVELS[0], seed=0, duration=dur)
    sens = sim0.config.sensor
    assert sens is not None  # noqa: S101  (thesis_two_robot's robots detect each other)
    return {
        "seeds": seeds,
        "quick": quick,
        "noise_levels": list(NOISE_LEVELS),
        "duration_s": dur,
        "gt_neighbour": {"duration_s": gt_dur, "seeds": gt_seeds, "noise": GT_NOISE},
        "double_counting": {"seeds": ab_seeds, "noise": ABLATION_NOISE},
        "initial_cov": f"{INIT_VAR:g} * I (exponential coordinates): known initial poses, as in the thesis",
        "wheel_diffusion_D": sim0.config.drive.D,
        "sensor": {
            "rate_hz": sens.rate,
            "max_range_m": sens.max_range,
            "sigma_theta": "2 * noise std [rad] (assumption of swarmloc.sim.thesis_two_robot)",
        },
        "units": "metres, radians, seconds; ANEES per degree of freedom (3)",
        "spread": "mean/std(ddof=1)/min/max over seeds of per-run (time-averaged) values",
        "curves": f"robot 1, over seeds at each record time, stored every {CURVE_EVERY}th record (1 s)",
        "workers": workers,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__},
        "estimators": {
            k: {"label": e.label, "distributed": bool(e.cls.distributed), "note": e.note} for k, e in RUNS.items()
        },
    }


def run_dynamic(
    out_dir: Path,
    seeds: int = 20,
    progress: bool = True,
    quick: bool = False,
    *,
    workers: int | None = None,
    cluster: str | Client | None = None,
) -> dict:
    """Reproduce thesis sec. 5.2.2 (Figs 5.14-5.23) and Table 6.1 with measured numbers; write into ``out_dir``.

    ``seeds``: simulations per noise level (seeds ``0..seeds-1``; the ground-truth-neighbour run uses
    ``min(seeds, 5)``, the double-counting study ``min(seeds, 8)``). ``quick``: 3 seeds and shorter runs
    (30 s / 60 s), for tests. ``workers``: processes (default ``min(2, cpu count)``; 1 runs in-process);
    ``cluster``: a Dask scheduler's address or client instead (:func:`~swarmloc.runner.fanout.fan_out`).

    Writes ``dynamic.json``, ``dynamic.md`` and ``dynamic_*.png``; returns the JSON content plus ``"markdown"``
    (the text of ``dynamic.md``).
    """
    plt = pyplot()

    t_start = time.perf_counter()
    cpu0 = _cpu_seconds()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cfg = dict(FULL)
    if quick:
        cfg.update(QUICK)
        seeds = min(seeds, QUICK["seeds"])
    if seeds < 1:
        raise ValueError(f"run_dynamic: seeds must be >= 1, got {seeds}")
    if workers is None:
        workers = max(1, min(2, os.cpu_count() or 1))
    gt_seeds = min(seeds, cfg["gt_seeds"])
    ab_seeds = min(seeds, cfg["ablation_seeds"])
    dur, gt_dur = cfg["duration"], cfg["gt_duration"]
    specs = _specs(seeds, gt_seeds, ab_seeds, dur, gt_dur)
    jobs = _run_jobs(specs, workers, progress, lambda s: s["duration"] * len(s["estimators"]), cluster)
    t_runs = time.perf_counter() - t_start

    two_robot, curves, traj, ordering, order12 = _two_robot(jobs)
    gt_jobs = _select(jobs, "gt")
    gt: dict[str, Any] = {}
    gt_curves: dict[str, dict[str, np.ndarray]] = {}
    for key in GT_ESTIMATORS:
        gt[key], gt_curves[key] = _summary_and_curve([j["runs"][key] for j in gt_jobs])
    gt_traj = {key: gt_jobs[0]["runs"][key]["result"] for key in GT_ESTIMATORS}
    abl = _double_counting(jobs, ab_seeds)
    result: dict[str, Any] = {
        "meta": _meta(seeds, quick, dur, gt_dur, gt_seeds, ab_seeds, workers),
        "two_robot": two_robot,
        "thesis_ordering": ordering,
        "order2_vs_order1": order12,
        "ground_truth_neighbour": gt,
        "double_counting": abl,
        "table_6_1": _table61(jobs, two_robot, gt),
    }
    files = figures(plt, out_dir, curves, traj, gt_curves, gt_traj, abl, seeds, gt_seeds)
    runtime = time.perf_counter() - t_start
    result["meta"]["runtime_s"] = {"runs": t_runs, "total": runtime, "cpu": _cpu_seconds() - cpu0}
    result["files"] = ["dynamic.json", "dynamic.md", *files]
    md = write_dynamic(out_dir, result)
    return result | {"markdown": md}
