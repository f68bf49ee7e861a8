"""``swarmloc team``'s evaluation side: a live team on a source named by its spec, scored like ``swarmloc evaluate``.

:func:`run_team` loads the source (unless given) and runs the team (:func:`swarmloc.net.team.launch_team`: node
processes on 127.0.0.1); :func:`team_result` turns what the team published into a
:class:`~swarmloc.runner.RunResult`; :func:`write_team_report` scores it against the source's truth and writes
the report. The network package below knows nothing of sources by spec, metrics or reports.
"""

from __future__ import annotations

import os
from collections import Counter
from typing import Any

from swarmloc.datasets.source import Source
from swarmloc.evaluation.metrics import anees_bounds, evaluate
from swarmloc.experiments.evaluate import delayed_row, report_head, run_row, write_report
from swarmloc.experiments.sources import load_source
from swarmloc.net.entry import network_class
from swarmloc.net.team import TeamRun, launch_team
from swarmloc.runner.result import RUN_COUNTERS, RobotTrack, RunResult

__all__ = ["TeamRun", "delayed_team_result", "run_team", "team_result", "with_truth", "write_team_report"]


def run_team(
    *,
    src: Source | None = None,
    source: str = "sim:random",
    robots: int = 3,
    duration: float | None = None,
    seed: int = 0,
    estimator: str = "expfusion",
    **launch: Any,
) -> TeamRun:
    """Run a live team on ``src``, or on the source ``source`` names (``robots``, ``duration``, ``seed``: as
    :func:`~swarmloc.experiments.sources.load_source`); ``launch``: :func:`~swarmloc.net.team.launch_team`'s other
    options (faults, speed, timeouts, ``max_wall``...). The node processes load the same source from its spec."""
    if src is None:
        network_class(estimator)  # refuse an estimator a team cannot run before loading anything
        src = load_source(source, robots=robots, duration=duration, seed=seed)
    return launch_team(src=src, source=source, robots=robots, duration=duration, seed=seed, estimator=estimator,
                       **launch)  # fmt: skip


def team_result(run: TeamRun, src: Source, estimator: str) -> RunResult:
    """The collected run as a :class:`~swarmloc.runner.RunResult` (node counters summed over the reports; network
    counters under ``net_*``, e.g. ``net_auth_key_mismatch``; the collector's own under ``collector_*``, its reasons
    as ``collector: <reason>``)."""
    stats: Counter[str] = Counter()
    reasons: Counter[str] = Counter()
    for rep in run.reports.values():
        stats.update(rep.stats)
        reasons.update(rep.reasons)
        stats.update({f"net_{k}": v for k, v in rep.net.items()})
        reasons.update({f"network: {k}": v for k, v in rep.net_reasons.items()})
    for k in RUN_COUNTERS:
        stats.setdefault(k, 0)
    reasons.update({f"collector: {k}": v for k, v in run.reasons.items()})
    stats["recorded"] = len(run.beliefs)
    stats["recorded_provisional_only"] = sum(not b.final for b in run.beliefs.values())
    stats["reports"] = len(run.reports)
    stats.update(run.counts)
    tracks, missing = with_truth(run.tracks(src.truth), src.truth is not None)
    if missing:
        stats["truth_missing"] += missing
    return RunResult(estimator, tracks, run.wall_s, dict(stats), len(src.events), reasons, {})


def with_truth(tracks: dict[int, RobotTrack], truth: bool) -> tuple[dict[int, RobotTrack], int]:
    """With ``truth``, each track's rows where the truth is known (as the in-process runner records them: a source
    whose odometry runs past its ground truth has record times without it), and how many rows were left out."""
    if not truth:
        return tracks, 0
    out = {r: tr.with_truth() for r, tr in tracks.items()}
    return out, sum(tr.times.size - out[r].times.size for r, tr in tracks.items())


def delayed_team_result(run: TeamRun, src: Source, estimator: str) -> RunResult | None:
    """A smoother team's delayed output as a :class:`~swarmloc.runner.RunResult` named ``"<estimator>_delayed"``
    (as :func:`swarmloc.evaluation.delayed.delayed_output` names the in-process one; with truth, the stamps
    without it left out, as there); None when the team published none."""
    if not run.delayed:
        return None
    tracks, _ = with_truth(run.tracks(src.truth, delayed=True), src.truth is not None)
    return RunResult(f"{estimator}_delayed", tracks, run.wall_s)


def ended_notes(run: TeamRun, robots: list[int]) -> tuple[list[str], list[int]]:
    """What the totals leave out: a sentence per process that ended with a non-zero exit code (named, with the
    code) and per robot without a report; and the robots whose detections are (partly) missing from the totals."""
    notes, missing = [], []
    for e in run.ended:
        what = f"{e['process']} (pid {e['pid']}) {e['how']}, exit code {e['exit_code']}"
        what += f" (it said: {e['said']})" if e.get("said") else ""
        if e["process"] == "server":
            notes.append(f"{what}.")
            continue
        r = int(e["process"].removeprefix("robot"))
        if e["how"].endswith(", restarted"):  # a kill fault's robot, restarted (killonly: "not restarted")
            missing.append(r)
            notes.append(f"{what}: the detections it handled before are missing from the totals.")
        elif r in run.reports:
            notes.append(f"{what}; its report is in the totals.")
        else:
            missing.append(r)
            notes.append(f"{what}: its detections are missing from the totals.")
    for r in robots:
        if r not in run.reports and r not in missing:
            missing.append(r)
            notes.append(f"robot{r} sent no report: its detections are missing from the totals.")
    return notes, sorted(set(missing))


def write_team_report(run: TeamRun, src: Source, estimator: str, out_dir: str | os.PathLike[str], extra: dict) -> dict:
    """Score the run against the source's truth and write ``team.json``/``team.md``, TUM files and figures (the
    layout of ``swarmloc evaluate``)."""
    res = team_result(run, src, estimator)
    truth = src.truth is not None
    notes, missing = ended_notes(run, src.robots)
    ev: dict[str, Any] = {"estimator": estimator, "robots": {}, "team": None}
    try:
        ev = evaluate(res) if truth else ev
    except Exception as exc:  # noqa: BLE001 - the report is written whatever the scoring meets; it says what
        notes.append(f"scoring failed: {type(exc).__name__}: {exc}")
    if res.stats.get("truth_missing"):
        notes.append(f"{res.stats['truth_missing']} record times have no ground truth (past its end): not scored")
    duration = float(src.t_end - src.t_start)
    run_row(ev, res, duration)
    ev.update(accounted=ev["accounted"] and not missing, detections_missing_of=missing)
    n_rec = sum(tr.times.size for tr in res.tracks.values())
    report = {
        "title": f"live team over Zenoh: {src.spec}, {estimator}",
        **report_head(src.robots, duration, len(src.events), src.config, truth),
        "estimators": {estimator: ev},
        "anees_bounds_if_independent": anees_bounds(max(n_rec, 1)),
        "run_id": run.run_id,
        "processes_ended": run.ended,
        "notes": notes,
        **extra,
    }
    results = {estimator: res}
    late = delayed_team_result(run, src, estimator)
    if late is not None:  # a smoother's delayed output: its own row, the team's counts and speed
        results[late.estimator] = late
        report["estimators"][late.estimator] = delayed_row(late, ev, truth, src.config.filter.smoother_lag)
    write_report(out_dir, "team", report, results, src.t_start)
    return report
