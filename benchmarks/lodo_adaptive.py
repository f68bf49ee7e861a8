"""``diekf`` with and without ``[filter] diekf_adaptive`` on every MRCLAM dataset with odometry, the camera model held
out (the leave-one-out study's filter scores, :func:`swarmloc_studies.lodo.filter_scores`), landmarks on and off.

    python benchmarks/lodo_adaptive.py --mrclam ../shared/data/mrclam --duration 200 --datasets 6,9,3,1,2,4
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from _common import add_mrclam

from swarmloc.config import DEFAULTS
from swarmloc.datasets.mrclam import load_mrclam
from swarmloc_studies.lodo import DATASETS, detection_set, filter_scores, model_scores, own_std

KEYS = ("pos_rmse", "anees", "anees_folds", "nis_ratio_ref", "anis_ref", "beyond_gate_ref")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_mrclam(ap)
    ap.add_argument("--duration", type=float, default=200.0)
    ap.add_argument("--datasets", default="6,9,3,1,2,4", help="datasets the filters run on")
    ap.add_argument("--out", type=Path, default=Path("lodo_adaptive.json"))
    a = ap.parse_args()
    datas = {k: load_mrclam(a.mrclam / f"MRCLAM_Dataset{k}", require=("measurements",)) for k in DATASETS}
    ms = model_scores({k: detection_set(d) for k, d in datas.items()})
    chosen = ms["chosen"]
    adaptive = dataclasses.replace(DEFAULTS, filter=dataclasses.replace(DEFAULTS.filter, diekf_adaptive=True))
    out = {}
    for k in (int(x) for x in a.datasets.split(",")):
        model = ms["models"][k][chosen]
        ref = own_std(model, ms["folds"][k][chosen])
        for landmarks in (True, False):
            for name, cfg in (("default", DEFAULTS), ("adaptive", adaptive)):
                r = filter_scores(datas[k], model, ["diekf"], landmarks, a.duration, config=cfg, holdout=3,
                                  reference_std=ref)["diekf"]  # fmt: skip
                key = f"{k}/{'on' if landmarks else 'off'}/{name}"
                out[key] = r
                print(key, {x: round(r[x], 3) for x in KEYS if x in r}, flush=True)
    a.out.write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
