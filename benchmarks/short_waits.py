"""Networked = in-process when the waits are short? A team of node processes on MRCLAM data with the given waits,
against the in-process run of the same events: detections left ``unknown``, queries asked again, revisions sent and
pushes coalesced, and the largest difference of any recorded belief (mean or covariance entry; a heading unwrapped).

    python benchmarks/short_waits.py --answer-timeout 0.02 --hold-timeout 1 --update-timeout 0.01 --answer-retries 0
    python benchmarks/short_waits.py --answer-timeout 0.02 --hold-timeout 1 --update-timeout 0.01   # retries: 2
    python benchmarks/short_waits.py --answer-timeout 0.02 --hold-timeout 0.05 --update-timeout 0.02
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from _common import mrclam_root

from swarmloc.estimators import make_team, node_options
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.net.timeouts import ANSWER_RETRIES
from swarmloc.runner import run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", type=Path, default=mrclam_root() / "MRCLAM_Dataset6")
    ap.add_argument("--estimator", default="rdl")
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--answer-timeout", type=float, required=True)
    ap.add_argument("--hold-timeout", type=float, required=True)
    ap.add_argument("--update-timeout", type=float, required=True)
    ap.add_argument("--answer-retries", type=int, default=ANSWER_RETRIES)
    a = ap.parse_args()
    spec = f"mrclam:{a.dataset}"
    src = load_source(spec, duration=a.duration)
    t = time.perf_counter()
    tr = run_team(src=src, source=spec, duration=a.duration, estimator=a.estimator, team=f"waits{os.getpid()}",
                  max_wall=600, answer_timeout=a.answer_timeout, hold_timeout=a.hold_timeout,
                  update_timeout=a.update_timeout, answer_retries=a.answer_retries)  # fmt: skip
    wall = time.perf_counter() - t
    res = team_result(tr, src, a.estimator)
    nodes = make_team(a.estimator, src.initial, **node_options(a.estimator, src.config, src.landmarks))
    ref = run(nodes, src.events, src.record_times(), truth=src.truth)
    diff = 0.0
    for r, want in ref.tracks.items():
        got = res.tracks[r]
        if got.times.shape != want.times.shape or not np.array_equal(got.times, want.times):
            raise SystemExit(f"robot {r}: {got.times.size} records networked, {want.times.size} in-process")
        diff = max(diff, float(np.abs(got.mean - want.mean).max()), float(np.abs(got.cov - want.cov).max()))
    s = res.stats
    print(f"{a.estimator}, {a.duration:g} s, waits answer {a.answer_timeout:g} / hold {a.hold_timeout:g} / update "
          f"{a.update_timeout:g} s, answer_retries {a.answer_retries}: unknown {s.get('unknown', 0)} (in-process "
          f"{ref.stats.get('unknown', 0)}), no_reply {s.get('net_no_reply', 0)}, asked_again "
          f"{s.get('net_asked_again', 0)}, revisions {s.get('revisions_sent', 0)}, pushes coalesced "
          f"{s.get('net_coalesced', 0)}, largest difference {diff:.3g}, {wall:.0f} s wall")  # fmt: skip


if __name__ == "__main__":
    main()
