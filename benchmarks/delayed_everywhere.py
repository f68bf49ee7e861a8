"""Is ``flsd``'s delayed output out of the band without landmarks only because of where it is scored?

    python benchmarks/delayed_everywhere.py --datasets 1,4,6 --duration 200

The leave-one-out study scored the delayed output only at the instants it files (the window's poses: the
stamps of the team's detections), 9-27% of the held-out landmark readings without landmarks. Here it is carried
to every reading: the pose filed last at or before the reading, predicted to the reading's stamp through the
robot's odometry with the node's motion model (:func:`swarmloc.evaluation.delayed.carried_output`, as the node predicts
between detections; the study scores it so now). Landmarks off, the recording's own camera model (not held out),
from the truth-free start; the held-out score ``median(NIS) / 1.386`` of the causal belief on every reading, of the
delayed output carried to every reading, and of the causal belief on those same readings.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np
from _common import add_mrclam

from swarmloc.config import DEFAULTS
from swarmloc.datasets.mrclam import load_mrclam, mrclam_events
from swarmloc.estimators import make_team, node_options
from swarmloc.evaluation.delayed import carried_output
from swarmloc.evaluation.heldout import landmark_nis, nis_summary, reading_times, tracks_nis
from swarmloc.experiments.mrclam import camera_model, detection_set
from swarmloc.experiments.truthfree import fused_from_snapshots, landmark_readings
from swarmloc.runner import run
from swarmloc.sensors.decorrelate import decorrelate


def scores(n: int, root: Any, duration: float) -> dict[str, Any]:
    """The three scores on dataset ``n`` (module docstring)."""
    data = load_mrclam(root / f"MRCLAM_Dataset{n}")
    model = camera_model(data)
    std = (model.range.std, model.bearing.std)
    t0, initial = fused_from_snapshots(data, detection_set(data), DEFAULTS)[:2]
    t1 = min(data.t_end, t0 + duration)
    events = mrclam_events(data, landmarks=False, range_std=std[0], bearing_std=std[1])
    events = [e for e in decorrelate(events, model) if t0 <= e.stamp <= t1]
    readings = landmark_readings(data, t0, t1)
    config = DEFAULTS.with_filter(delayed_output=True)
    nodes = make_team("flsd", initial, **node_options("flsd", config, data.landmarks, t0))
    res = run(nodes, events, record_times=reading_times(readings), truth=None, name="flsd")
    out = {"causal": nis_summary(tracks_nis(res.tracks, readings, data.landmarks, std))}
    late = carried_output(nodes, events, np.unique([d.stamp for d in readings]), None, "flsd")
    delayed, same = [], []
    for node in nodes:
        mine = [d for d in readings if d.observer == node.robot]
        tr = late.tracks[node.robot]
        nis = landmark_nis(tr.times, tr.mean, tr.cov, mine, data.landmarks, std, 0.0)
        delayed.append(nis[np.isfinite(nis)])
        kept = [d for d, k in zip(mine, np.isfinite(nis), strict=True) if k]
        causal = res.tracks[node.robot]
        nis = landmark_nis(causal.times, causal.mean, causal.cov, kept, data.landmarks, std)
        same.append(nis[np.isfinite(nis)])
    out["delayed_everywhere"] = nis_summary(np.concatenate([np.empty(0), *delayed]))
    out["causal_same_readings"] = nis_summary(np.concatenate([np.empty(0), *same]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_mrclam(ap)
    ap.add_argument("--datasets", default="1,4,6")
    ap.add_argument("--duration", type=float, default=200.0)
    args = ap.parse_args()
    for n in (int(k) for k in args.datasets.split(",")):
        r = scores(n, args.mrclam, args.duration)
        print(json.dumps({"dataset": n, **{k: {"nis_ratio": round(v["nis_ratio"], 3), "readings": v["readings"]}
                                           for k, v in r.items()}}))  # fmt: skip


if __name__ == "__main__":
    main()
