"""Evaluate estimators on one stream of events: run each, score against truth, write a report.

Used by ``swarmloc evaluate mrclam`` (:mod:`swarmloc.experiments.mrclam`) and ``swarmloc evaluate events``
(your own robots, :mod:`swarmloc.datasets.eventfile`). Every estimator runs on the same events through the
in-process runner; beliefs are recorded on a regular grid and scored with :mod:`swarmloc.evaluation.metrics`
(position and heading RMSE, NEES/ANEES per degree of freedom). The report is a dict (and, with ``out_dir``,
``<name>.json``, ``<name>.md``, figures and TUM trajectories that ``evo`` reads).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.config import DEFAULTS, Config
from swarmloc.datasets.source import Source
from swarmloc.datasets.tum import write_tum, write_tum3
from swarmloc.estimators import check_known, make_team, node_options
from swarmloc.estimators.fls import FixedLagSmoother
from swarmloc.estimators.fls_team import TeamFixedLagSmoother
from swarmloc.evaluation.delayed import delayed_output
from swarmloc.evaluation.heldout import BAND, band_verdict
from swarmloc.evaluation.metrics import anees_bounds, errors, evaluate
from swarmloc.events import Event
from swarmloc.experiments.association import association_accuracy, association_events, handoff_accuracy
from swarmloc.experiments.output import save_figure, write_summary
from swarmloc.experiments.progress import progress_bar
from swarmloc.gaussian import GroupGaussian
from swarmloc.runner import RunResult, TruthFn, run

ALL = ("dr", "dekf", "cekf", "expfusion", "ci", "rdl")

RECOMMENDED = "diekf"
"""The distributed estimator ``swarmloc evaluate`` recommends, the same on every recording (the report's
``recommended`` entry, :func:`recommended`): the distributed invariant EKF (exact). On MRCLAM dataset 6 (756 s,
against the truth) it scores what the centralized invariant EKF does, 0.128 m / ANEES per dof 1.43 with landmarks
and 0.579 m / 0.98 without, where the other distributed filters are over-confident without landmarks (dekf,
expfusion, rdl: ANEES per dof 27-32) or under-confident (ci: 0.44). Truth-free, in the leave-one-dataset-out
study (camera model fitted on the other recordings, 200 s), its held-out landmark score is in [0.5, 2] on five of
the six recordings with odometry with the ``[motion]`` defaults and on all six with the yaw diffusion calibrated on
each; by this command's own score (camera fitted on the recording, 300 s) dataset 9 with landmarks reads 0.20,
under-confident (docs/mrclam.md says why)."""

SMOOTHERS = (FixedLagSmoother, TeamFixedLagSmoother)
"""The nodes that may file a delayed output (``lagged_log`` set: option ``delayed``)."""


def evaluate_stream(
    events: Sequence[Event],
    initial: Mapping[int, GroupGaussian],
    *,
    t_start: float,
    t_end: float,
    truth: TruthFn | None,
    landmarks: Mapping[int, Any] | None = None,
    estimators: Sequence[str] = ALL,
    config: Config = DEFAULTS,
    progress: bool = False,
    span_origin: str = "",
    sensor: tuple[float | None, float | None] = (None, None),
    engine: bool = False,
) -> tuple[dict, dict[str, RunResult]]:
    """Run ``estimators`` on ``events`` and score them; returns ``(report, results)``.

    Beliefs are recorded every ``1 / config.record.rate`` s over ``[t_start, t_end)``; ValueError, before anything
    runs, when those are too many or none is worth scoring (:meth:`~swarmloc.config.RecordConfig.count`; its
    message names the span, and ``span_origin`` where it comes from). Without ``truth`` the report has wall times,
    counters and trajectories but no accuracy (``"truth": false``). ``sensor``: the robot detector's ``(range [m],
    field of view [rad])`` where known, for the nodes' ``association_missed`` count
    (:func:`~swarmloc.estimators.node_options`). ``engine``: run them through the engine's compiled replays
    (:data:`ENGINE_DRIVEN`, :func:`engine_run`) instead of the in-process nodes: the same results, each row's wall
    time the whole call after an untimed warm-up (``compile_s``).
    """
    check_known(estimators)
    record_times = config.record.times(t_start, t_end, len(initial), span_origin)
    policy = config.filter.association
    if engine:
        _check_engine(estimators, policy)
    for name in estimators:  # a policy an estimator cannot run is refused before anything runs
        make_team(name, initial, **node_options(name, config, landmarks, t_start, sensor))
    notes: dict[str, Any] = {}
    if policy != "tags":
        events, notes = association_events(events, policy, sorted(initial), config.motion.noise())
    if policy == "anonymous" and truth is not None:
        notes["bank_handoffs_right_wrong"] = handoff_accuracy(events, truth)
    duration = float(t_end - t_start)
    report: dict[str, Any] = {
        **report_head(sorted(initial), duration, len(events), config, truth is not None),
        "association": policy,
        "sensor": {"range_m": sensor[0], "fov_rad": sensor[1]},
        **({"association_notes": notes} if notes else {}),
        "estimators": {},
    }
    results: dict[str, RunResult] = {}
    with progress_bar(progress) as start:
        for name in estimators:
            nodes = make_team(name, initial, **node_options(name, config, landmarks, t_start, sensor))
            cb = start(name) if start is not None else None
            if engine:
                src = Source(f"stream:{name}", list(events), dict(initial), landmarks, t_start, t_end, truth, config)
                res, compile_s = engine_run(src, name, record_times)
            else:
                res = run(nodes, events, record_times=record_times, truth=truth, progress=cb, name=name)
            results[name] = res
            ev = evaluate(res) if truth is not None else {"estimator": name, "robots": {}, "team": None}
            if engine:
                ev.update(driver="engine (numba, compiled replay)", compile_s=compile_s)
            run_row(ev, res, duration)
            if policy == "anonymous":
                ev["handoffs"] = handoffs(res, notes)
            report["estimators"][name] = ev
            first = nodes[0]
            if not engine and isinstance(first, SMOOTHERS) and first.lagged_log is not None:
                # a smoother's delayed output, its own row
                late = delayed_output(nodes, truth, name, res.wall_time)
                results[late.estimator] = late
                report["estimators"][late.estimator] = delayed_row(late, ev, truth is not None, first.lag)
    n_rec = sum(tr.times.size for tr in next(iter(results.values())).tracks.values()) if results else 0
    report["anees_bounds_if_independent"] = anees_bounds(max(n_rec, 1))
    report["recommended"] = recommended(report)
    return report, results


def report_head(robots: list[int], duration: float, n_events: int, config: Config, truth: bool) -> dict[str, Any]:
    """A report's first entries: its ``robots``, ``duration_s`` [s], ``n_events``, ``config`` and whether it has
    ``truth``."""
    return {"robots": robots, "duration_s": duration, "n_events": n_events, "config": config.to_dict(), "truth": truth}


def run_row(ev: dict[str, Any], res: RunResult, duration: float) -> None:
    """Complete ``ev``, the scores of ``res`` (:func:`~swarmloc.evaluation.metrics.evaluate`), as a report's row:
    the run's wall time [s] and speed on ``duration`` s of data, its counters, association accuracy, reasons,
    timing and accounting; robot ids as text (JSON keys)."""
    ev.update(wall_time_s=res.wall_time, x_real_time=duration / res.wall_time if res.wall_time > 0 else math.inf,
              stats=res.stats, association_accuracy=association_accuracy(res.stats), reasons=dict(res.reasons),
              timing=res.timing, accounted=res.accounted())  # fmt: skip
    ev["robots"] = {str(k): v for k, v in ev["robots"].items()}


def recommended(report: Mapping[str, Any], score: Mapping[str, Any] | str = "no ground truth") -> dict[str, Any]:
    """The report's ``recommended`` entry: :data:`RECOMMENDED` (``ran``: among the report's estimators; nothing more
    if not), its team position RMSE [m] (None without truth), and its consistency ``verdict``
    (:func:`~swarmloc.evaluation.heldout.band_verdict` of ``value`` against ``band``): ANEES per dof against the
    truth (``basis`` ``"truth"``); without truth the held-out landmark NIS ratio of ``score``
    (:func:`~swarmloc.experiments.truthfree.truth_free_score`, kept as ``score``; ``basis`` ``"held-out landmark
    readings"``); or, ``score`` a text, no verdict (None) and that text as ``why``."""
    entry: dict[str, Any] = {"estimator": RECOMMENDED, "ran": RECOMMENDED in report["estimators"], "band": list(BAND),
                             "pos_rmse": None, "basis": None, "value": None, "verdict": None}  # fmt: skip
    team = report["estimators"][RECOMMENDED]["team"] if entry["ran"] else None
    if not entry["ran"]:
        entry["why"] = "not among the estimators run"
    elif team and "anees" in team:
        entry.update(pos_rmse=team["pos_rmse"], basis="truth", value=team["anees"], verdict=band_verdict(team["anees"]))
    elif team is not None:
        entry["why"] = "nothing recorded to score against the truth"
    elif isinstance(score, str):
        entry["why"] = score
    else:
        value = score["nis_ratio"]
        entry.update(basis="held-out landmark readings", value=value, verdict=band_verdict(value), score=dict(score))
    return entry


def recommended_lines(report: Mapping[str, Any]) -> list[str]:
    """The report's ``recommended`` entry (:func:`recommended`) as a line of text after a blank one; none without."""
    rec = report.get("recommended")
    if rec is None:
        return []
    head = f"Recommended: `{rec['estimator']}` (distributed)"
    if not rec["ran"]:
        return ["", f"{head}: not among the estimators run (add it to them for its accuracy and consistency here)."]
    lo, hi = rec["band"]
    value = rec["value"]
    if rec["verdict"] is None:
        verdict = f"no consistency verdict: {rec['why']}"
    else:
        side = " (over-confident)" if value > hi else " (under-confident)" if value < lo else ""
        verdict = f"{rec['verdict']} [{lo:g}, {hi:g}]{side}"
        if rec["basis"] == "truth":
            verdict = f"ANEES/dof {value:.2f} against the ground truth: {verdict}"
        else:
            sc = rec["score"]
            how = f"{sc['folds']} landmark folds held out in turn" if sc["folds"] else "landmarks not fused"
            verdict = (
                f"no ground truth; held-out landmark NIS ratio {value:.2f} (median NIS / 1.386 over {sc['readings']} "
                f"readings never fused, {how}, {sc['duration_s']:.0f} s from a truth-free start "
                f"{sc['t0_s']:.0f} s in): {verdict}"
            )
    rmse = "" if rec["pos_rmse"] is None else f" team pos RMSE {rec['pos_rmse']:.3f} m,"
    return ["", f"{head}:{rmse} {verdict}."]


ENGINE_DRIVEN = ("dekf", "cekf", "iekf", "rdl", "diekf")
"""Estimators :func:`evaluate_stream` can run through the engine's compiled replays (numba; ``swarmloc evaluate
... --engine``)."""


def _check_engine(estimators: Sequence[str], policy: str) -> None:
    """Refuse, before anything runs, what the engine's compiled replays do not run."""
    import importlib.util

    other = [e for e in estimators if e not in ENGINE_DRIVEN]
    if other:
        raise ValueError(f"the engine's compiled replays run {list(ENGINE_DRIVEN)}, not {other}")
    if policy != "tags":
        raise ValueError(f"the engine fuses tagged detections only, not association {policy!r}: run the nodes")
    if importlib.util.find_spec("numba") is None:
        raise ValueError("the engine's compiled replays need numba: pip install 'swarmloc[numba]'")


def engine_run(src: Source, name: str, record_times: np.ndarray) -> tuple[RunResult, float]:
    """``name`` on ``src`` through :func:`swarmloc.engine.run_engine` (numba): the result, its ``wall_time`` the
    whole call [s], and the seconds of an untimed warm-up on the first second of the events (numba compiles its
    kernels there, once per process and noise model)."""
    import dataclasses
    import time

    from swarmloc.engine import run_engine

    t = time.perf_counter()
    first = [e for e in src.events if e.stamp < src.t_start + 1.0]
    run_engine(dataclasses.replace(src, events=first), name, backend="numba", record_times=record_times[:1])
    compile_s = time.perf_counter() - t
    t = time.perf_counter()
    res = run_engine(src, name, backend="numba", record_times=record_times)
    return dataclasses.replace(res, estimator=name, wall_time=time.perf_counter() - t), compile_s


def delayed_row(late: RunResult, causal: dict, scored: bool, lag: float) -> dict:
    """The report's row of a delayed output: its accuracy at its own stamps, the causal run's counts and speed."""
    ev = evaluate(late) if scored else {"estimator": late.estimator, "robots": {}, "team": None}
    ev.update({k: v for k, v in causal.items() if k not in ("estimator", "robots", "team")})
    ev["robots"] = {str(k): v for k, v in ev["robots"].items()}
    ev["delayed_s"] = lag
    ev["instants"] = int(sum(tr.times.size for tr in late.tracks.values()))
    return ev


def write_report(
    out_dir: str | os.PathLike[str], stem: str, report: dict, results: dict[str, RunResult], t_start: float
) -> None:
    """``<stem>.json``, ``<stem>.md``, ``tum/<estimator>_robot<N>.tum`` (+ ground truth) and, with truth, figures.
    Whatever the results hold, the report is written: a row that is not finite is left out of its TUM file (the
    format has no NaN) and counted in ``tum_rows_left_out`` with a note; figures that cannot be drawn are a note."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tum = out / "tum"
    tum.mkdir(exist_ok=True)
    first = next(iter(results.values()), None)
    left: dict[str, int] = {}

    def _tum(path: Path, times: np.ndarray, poses: np.ndarray) -> None:
        ok = np.isfinite(times) & np.isfinite(poses).reshape(times.size, -1).all(axis=1)
        if not ok.all():
            left[f"tum/{path.name}"] = int((~ok).sum())
        (write_tum3 if poses.shape[-1] == 7 else write_tum)(path, times[ok], poses[ok])  # SE(3): full quaternions

    if first is not None and report["truth"]:
        for r, tr in first.tracks.items():
            _tum(tum / f"groundtruth_robot{r}.tum", tr.times, tr.truth)
    for name, res in results.items():
        for r, tr in res.tracks.items():
            _tum(tum / f"{name}_robot{r}.tum", tr.times, tr.mean)
    notes = report.setdefault("notes", [])
    if left:
        report["tum_rows_left_out"] = left
        notes += [f"{f}: {n} rows not finite, left out of the file (TUM has no NaN)" for f, n in left.items()]
    try:
        report["figures"] = figures(out, results, t_start) if results and report["truth"] else []
    except Exception as exc:  # noqa: BLE001 - the report is written whatever the figures meet; it says why
        report["figures"] = []
        notes.append(f"figures not drawn: {type(exc).__name__}: {exc}")
    write_summary(out, stem, report, markdown_table(report), default=json_default)


def json_default(o: object) -> object:
    """``json.dumps(default=...)`` for reports: arrays to lists, numpy scalars to numbers, anything else to text."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)


def figures(out: Path, results: dict[str, RunResult], t_start: float) -> list[str]:
    """Trajectories per robot, and team position error and NEES over time per estimator (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files: list[str] = []
    robots = sorted(next(iter(results.values())).tracks)
    if not robots:  # nothing recorded (e.g. a team whose nodes all failed): the report says so, no figure to draw
        return files
    fig, axes = plt.subplots(1, len(robots), figsize=(4 * len(robots), 4), squeeze=False)
    for ax, r in zip(axes[0], robots, strict=True):
        first = next(iter(results.values())).tracks.get(r)
        if first is not None:
            ax.plot(first.truth[:, 0], first.truth[:, 1], "k-", lw=2, label="truth")
        for name, res in results.items():
            tr = res.tracks.get(r)
            if tr is not None:
                ax.plot(tr.mean[:, 0], tr.mean[:, 1], lw=0.8, label=name)
        ax.set_title(f"robot {r}")
        ax.set_aspect("equal")
    axes[0][0].legend(fontsize=7)
    save_figure(fig, out / "trajectories.png")
    files.append("trajectories.png")

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for name, res in results.items():
        tracks = [tr for tr in res.tracks.values() if tr.times.size]
        n = min((tr.times.size for tr in tracks), default=0)
        if not n or any(not np.array_equal(tr.times[:n], tracks[0].times[:n]) for tr in tracks):
            continue  # a team mean over time needs common stamps (a delayed output has each robot's own)
        errs = [errors(tr) for tr in tracks]
        t = tracks[0].times[:n] - t_start
        a1.plot(t, np.mean([e["pos"][:n] for e in errs], axis=0), lw=0.8, label=name)
        a2.semilogy(t, np.mean([e["nees"][:n] / 3 for e in errs], axis=0), lw=0.8, label=name)
    lo, hi = anees_bounds(len(robots))
    a2.axhspan(lo, hi, color="0.85", label="95% band (team, per time)")
    a1.set_ylabel("team mean position error [m]")
    a2.set_ylim(1e-2, 1e3)  # the first record is the exact initial pose (NEES ~ 0)
    a2.set_ylabel("team NEES per dof")
    a2.set_xlabel("time since start [s]")
    a1.legend(fontsize=7, ncol=3)
    save_figure(fig, out / "error_nees_over_time.png")
    files.append("error_nees_over_time.png")
    return files


def speed_text(x: float | None) -> str:
    """An ``x real time`` figure with the decimals it needs: ``1234``, ``56.7``, ``3.45``, ``0.012``; ``-`` for
    none (nothing ran or an infinite speed)."""
    if x is None or not np.isfinite(x):
        return "-"
    if x >= 100:
        return f"{x:.0f}"
    return f"{x:.1f}" if x >= 10 else f"{x:.3g}"


def handoffs(res: RunResult, notes: Mapping[str, Any]) -> dict[str, Any]:
    """The ``anonymous`` policy's hand-offs in one run: ``bank`` (relative poses from the particle-filter banks) with
    ``bank_right`` (:func:`~swarmloc.experiments.association.handoff_accuracy`, None without truth), ``assigned``
    (detections without a mutual counterpart that the node's gated assignment gave an identity) with
    ``assigned_right`` / ``assigned_wrong`` (those the filter fused or gated, scored by the hidden true id), the
    refusals ``ambiguous`` and ``clutter``, and ``correct``: right / scored over both kinds (None: none scored)."""
    s, why = res.stats, res.reasons
    bank = sum(int(c.get("emitted", 0)) for c in notes.get("bank", {}).values())
    rw = notes.get("bank_handoffs_right_wrong")
    right = sum(int(n) for k, n in why.items() if k.endswith(": association right"))
    wrong = sum(int(n) for k, n in why.items() if k.endswith(": association wrong"))
    scored = right + wrong + (sum(rw) if rw else 0)
    return {
        "bank": bank,
        "bank_right": None if rw is None else int(rw[0]),
        "assigned": int(s.get("association_associated", 0)),
        "assigned_right": right,
        "assigned_wrong": wrong,
        "ambiguous": int(s.get("association_ambiguous", 0)),
        "clutter": int(s.get("association_clutter", 0)),
        "correct": (right + (int(rw[0]) if rw else 0)) / scored if scored else None,
    }


def handoff_lines(report: dict) -> list[str]:
    """The hand-offs table of an ``anonymous`` report (:func:`handoffs`); empty for the other policies."""
    rows = [(name, ev["handoffs"]) for name, ev in report["estimators"].items() if "handoffs" in ev]
    if not rows:
        return []
    lines = ["", "Hand-offs (anonymous):", "",
             "| estimator | relative poses from the banks (right) | detections assigned (right / wrong) | ambiguous | "
             "clutter | correct |", "|---|---|---|---|---|---|"]  # fmt: skip
    for name, h in rows:
        bank_right = "-" if h["bank_right"] is None else str(h["bank_right"])
        correct = "-" if h["correct"] is None else f"{h['correct']:.3f}"
        lines.append(f"| {name} | {h['bank']} ({bank_right}) | {h['assigned']} ({h['assigned_right']} / "
                     f"{h['assigned_wrong']}) | {h['ambiguous']} | {h['clutter']} | {correct} |")  # fmt: skip
    return lines


def association_text(stats: Mapping[str, int]) -> str:
    """The association accuracy of a run's counters as ``share (right/scored)`` (``-``: nothing scored)."""
    right, wrong = int(stats.get("association_right", 0)), int(stats.get("association_wrong", 0))
    a = association_accuracy(stats)
    return "-" if a is None else f"{a:.3f} ({right}/{right + wrong})"


def _rotation_word(report: dict) -> str:
    """``rotation`` for SE(3) rows (the error is a 3-D rotation angle), ``heading`` for SE(2)."""
    teams = [ev.get("team") or {} for ev in report["estimators"].values()]
    return "rotation" if any("rot_rmse" in t or t.get("dof") == 6 for t in teams) else "heading"


def markdown_table(report: dict) -> str:
    """The report as Markdown: per estimator its accuracy, consistency, accounting and speed (team: every robot's
    records pooled), then one row per estimator and robot. SE(3) rows say ``rotation RMSE`` (the 3-D rotation
    angle), SE(2) rows ``heading RMSE``."""
    title = report.get("title", "evaluation")
    rot = _rotation_word(report)
    lines = [
        f"# {title}: {report['duration_s']:.0f} s, robots {report['robots']}"
        + ("" if report.get("truth", True) else " (no ground truth: replay only)"),
        "",
        f"| estimator | team pos RMSE [m] | {rot} RMSE [rad] | ANEES (per dof) | in 95% NEES band | detections "
        "fused / gated / rejected / unknown | association accuracy | wall [s] | x real time |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    if report.get("association", "tags") != "tags":
        lines[0] += f", association {report['association']} (robot ids hidden)"
    per_robot: list[str] = []
    for name, ev in report["estimators"].items():
        s = ev["stats"]
        acc = f"{s['detections']}: {s['fused']} / {s['gated']} / {s['rejected']} / {s['unknown']}"
        tail = f"{acc} | {association_text(s)} | {ev['wall_time_s']:.1f} | {speed_text(ev['x_real_time'])} |"
        t = ev["team"]
        if t is None or "pos_rmse" not in t:  # no ground truth, or nothing recorded to score
            lines.append(f"| {name} | - | - | - | - | {tail}")
            continue
        lines.append(f"| {name} | {_scores(t)} | {tail}")
        for r, rs in sorted(ev.get("robots", {}).items(), key=lambda kv: int(kv[0])):
            if "pos_rmse" in rs:
                per_robot.append(f"| {name} | {r} | {_scores(rs)} | {rs['n']} |")
    if per_robot:
        lines += ["", "Per robot:", "",
                  f"| estimator | robot | pos RMSE [m] | {rot} RMSE [rad] | ANEES (per dof) | in 95% NEES band | "
                  "records |", "|---|---|---|---|---|---|---|", *per_robot]  # fmt: skip
    lines += handoff_lines(report)
    lines += recommended_lines(report)
    notes = report.get("notes") or []
    if notes:
        lines += ["", *(f"* {n}" for n in notes)]
    return "\n".join(lines) + "\n"


def _scores(t: Mapping[str, Any]) -> str:
    """``pos RMSE | rotation RMSE | ANEES | in band`` cells of a team or robot summary."""
    return f"{t['pos_rmse']:.3f} | {t['heading_rmse']:.3f} | {t['anees']:.2f} | {t['frac_in_95']:.2f}"
