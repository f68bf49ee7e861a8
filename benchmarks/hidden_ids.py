"""Every MRCLAM recording with the robots' barcodes hidden: each association policy against the tagged run.

    python benchmarks/hidden_ids.py                                   # datasets 1,2,3,4,6,9, whole, diekf
    python benchmarks/hidden_ids.py --datasets 6,9 --duration 200 --policies joint --estimator cekf

Landmarks on (their barcodes kept). For each recording and policy: the robot detections given an identity, those
refused (ambiguous or clutter), the association accuracy as ``swarmloc evaluate`` reports it (the hidden barcodes
are known and scored, never read by a choice), and how far the run's trajectory is from the tagged run's (root mean
square of the position difference over every robot and record instant [m]): the run's RMSE against any truth
differs from the tagged run's by at most that much (triangle inequality), so it bounds what hiding the ids costs
where there is no ground truth. Where there is (dataset 6), the RMSE and ANEES/dof too. Every run starts as
``swarmloc evaluate mrclam`` does (without truth, the truth-free start, the same for every policy).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from _common import add_mrclam

from swarmloc.config import DEFAULTS
from swarmloc.datasets.mrclam import load_mrclam
from swarmloc.experiments.evaluate import evaluate_stream, handoffs
from swarmloc.experiments.mrclam import detector_reach, mrclam_start, mrclam_stream
from swarmloc.runner import RunResult


def trajectory_gap(a: RunResult, b: RunResult) -> float:
    """Root mean square of the position difference [m] between two runs' tracks over every robot and instant."""
    se, n = 0.0, 0
    for r, ta in a.tracks.items():
        tb = b.tracks[r]
        if not np.array_equal(ta.times, tb.times):
            raise ValueError(f"robot {r}: the two runs recorded different instants")
        d = ta.mean[:, :2] - tb.mean[:, :2]
        se += float(np.sum(d**2))
        n += len(d)
    return float(np.sqrt(se / max(n, 1)))


def one_dataset(path: Path, estimator: str, policies: list[str], duration: float | None) -> dict[str, Any]:
    data = load_mrclam(path)
    events, _ = mrclam_stream(data, DEFAULTS, duration, True)
    t_end = data.t_end if duration is None else min(data.t_end, data.t_start + duration)
    start = mrclam_start(data, DEFAULTS, t_end)
    run_events = start.after(events)
    out: dict[str, Any] = {"dataset": data.name, "truth": data.has_truth, "span_s": t_end - start.t0, "runs": {}}
    tagged: RunResult | None = None
    for policy in ["tags", *policies]:
        t = time.perf_counter()
        report, results = evaluate_stream(
            run_events, start.beliefs, t_start=start.t0, t_end=t_end,
            truth=data.truth_at if data.has_truth else None, landmarks=data.landmarks, estimators=[estimator],
            config=DEFAULTS.with_filter(association=policy), sensor=detector_reach(data),
        )  # fmt: skip
        res, ev = results[estimator], report["estimators"][estimator]
        s = res.stats
        row: dict[str, Any] = {
            "wall_s": time.perf_counter() - t,
            "detections": s["detections"], "fused": s["fused"], "gated": s["gated"], "rejected": s["rejected"],
            "team": ev.get("team"),
        }  # fmt: skip
        if policy == "tags":
            tagged = res
        else:
            assert tagged is not None  # noqa: S101  (tags run first)
            given = handoffs(res, {})  # the detections given an identity, scored by their outcomes' reasons
            row.update(
                given_right=given["assigned_right"], given_wrong=given["assigned_wrong"],
                associated=s["association_associated"], right=s["association_right"], wrong=s["association_wrong"],
                ambiguous=s["association_ambiguous"], clutter=s["association_clutter"],
                accuracy=ev["association_accuracy"], gap_m=trajectory_gap(res, tagged),
                handoffs=ev.get("handoffs"),
            )  # fmt: skip
        out["runs"][policy] = row
        print(f"{data.name} {policy}: {json.dumps({k: v for k, v in row.items() if k != 'handoffs'})}", flush=True)
    return out


def table(rows: list[dict[str, Any]], policies: list[str]) -> str:
    """Markdown: per recording, the tagged run's RMSE / ANEES (with truth) and per policy the detections given an
    identity (in brackets those given the right robot), those refused (right where the detected robot is not in the
    team), the accuracy and the gap to the tagged run."""
    head = "| recording | span [s] | robot detections | tags: RMSE [m] / ANEES | " + " | ".join(
        f"{p}: given (right) / refused | {p}: accuracy | {p}: gap to tags [m] (RMSE / ANEES)" for p in policies
    )
    lines = [head + " |", "|" + "---|" * (4 + 3 * len(policies))]
    for o in rows:
        tg = o["runs"]["tags"]["team"]
        first = o["runs"][policies[0]]
        robot = first["right"] + first["wrong"]  # every robot detection is scored once
        cells = [o["dataset"], f"{o['span_s']:.0f}", str(robot),
                 "-" if tg is None else f"{tg['pos_rmse']:.3f} / {tg['anees']:.2f}"]  # fmt: skip
        for p in policies:
            r = o["runs"][p]
            refused = r["ambiguous"] + r["clutter"]
            cells += [f"{r['associated']} ({r['given_right']}) / {refused}", f"{r['accuracy']:.3f}"]
            team = r["team"]
            extra = "" if team is None else f" ({team['pos_rmse']:.3f} / {team['anees']:.2f})"
            cells.append(f"{r['gap_m']:.3f}{extra}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_mrclam(ap)
    ap.add_argument("--datasets", default="1,2,3,4,6,9")
    ap.add_argument("--estimator", default="diekf")
    ap.add_argument("--policies", default="joint,anonymous")
    ap.add_argument("--duration", type=float, default=None, help="seconds of each recording (default: all)")
    ap.add_argument("--out", type=Path, default=None, help="JSON of every run")
    a = ap.parse_args()
    policies = a.policies.split(",")
    rows = [one_dataset(a.mrclam / f"MRCLAM_Dataset{k}", a.estimator, policies, a.duration)
            for k in a.datasets.split(",")]  # fmt: skip
    print(table(rows, policies))
    if a.out is not None:
        a.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
