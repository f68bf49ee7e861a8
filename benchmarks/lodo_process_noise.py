"""Would a smaller process noise make the filters consistent on every MRCLAM dataset? The LODO filter score
(landmarks on: held-out landmark folds; ``--landmarks off``: every reading; the recording's own std) at process noise
scaled by ``--scales``, with the camera model chosen by :func:`swarmloc_studies.lodo.lodo`; on dataset 6 also RMSE
and ANEES against the truth.

    python benchmarks/lodo_process_noise.py --datasets 1,2,3,4,6,9 --scales 1,0.5,0.25,0.125
    python benchmarks/lodo_process_noise.py --datasets 9,6 --scales 0.125 --terms q_v0,q_v1,q_v2,q_lat0,q_lat1

``--terms``: the ``[motion]`` coefficients that are scaled (default: all of them).
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from _common import add_mrclam

from swarmloc.config import DEFAULTS
from swarmloc.datasets.mrclam import load_mrclam
from swarmloc_studies.lodo import DATASETS, detection_set, filter_scores, model_scores, own_std


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_mrclam(ap)
    ap.add_argument("--datasets", default="1,2,3,4,6,9", help="left-out datasets the filters run on")
    ap.add_argument("--scales", default="1,0.5,0.25,0.125", help="multipliers of the process noise")
    ap.add_argument("--terms", default=None, help="comma-separated [motion] keys to scale (default: all)")
    ap.add_argument("--estimators", default="rdl,diekf")
    ap.add_argument("--duration", type=float, default=200.0)
    ap.add_argument("--landmarks", choices=("on", "off"), default="on", help="the filters fuse the landmarks or not")
    a = ap.parse_args()
    t = time.perf_counter()
    sets = {k: detection_set(load_mrclam(a.mrclam / f"MRCLAM_Dataset{k}", require=("measurements",))) for k in DATASETS}
    ms = model_scores(sets)
    chosen = ms["chosen"]
    base = DEFAULTS.motion
    terms = a.terms.split(",") if a.terms else [f.name for f in dataclasses.fields(base)]
    ests = a.estimators.split(",")
    print(f"camera model: {chosen}; scaled: {', '.join(terms)}")
    print("| left out | scale | estimator | NIS ratio, own std | NIS ratio, model std | beyond gate | pos RMSE [m] "
          "| ANEES/dof | folds |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for k in (int(x) for x in a.datasets.split(",")):
        data = load_mrclam(a.mrclam / f"MRCLAM_Dataset{k}")
        m, fold = ms["models"][k][chosen], ms["folds"][k][chosen]
        ref = own_std(m, fold)
        for s in (float(x) for x in a.scales.split(",")):
            cfg = dataclasses.replace(
                DEFAULTS, motion=dataclasses.replace(base, **{n: getattr(base, n) * s for n in terms})
            )
            rows = filter_scores(data, m, ests, a.landmarks == "on", a.duration, config=cfg, reference_std=ref)
            for e in ests:
                r = rows[e]
                folds = r.get("anees_folds", float("nan"))  # landmarks off: no folds
                truth = f"{r['pos_rmse']:.3f} | {r['anees']:.2f} | {folds:.2f}" if "anees" in r else "- | - | -"
                print(f"| {k} | {s:g} | {e} | {r['nis_ratio_ref']:.2f} | {r['nis_ratio']:.2f} | "
                      f"{r['beyond_gate_ref']:.3f} | {truth} |", flush=True)  # fmt: skip
    print(f"wall {time.perf_counter() - t:.0f} s")


if __name__ == "__main__":
    main()
