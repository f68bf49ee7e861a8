"""The recommended estimator's verdict per MRCLAM dataset, landmarks on and off, for configurations given:
what ``swarmloc evaluate mrclam DIR --duration 300 --estimators diekf --landmarks on|off [--config X.toml]`` prints.

    python benchmarks/nolm_table.py --datasets 1,2,3,4,9,6 --configs default,odocal.toml [--whole 6]

Each cell: the truth-free score (held-out landmark NIS ratio) or, with truth, RMSE [m] / ANEES/dof; ``--whole``:
datasets also run whole (no ``--duration``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from _common import add_mrclam

from swarmloc.config import DEFAULTS, load_config
from swarmloc.experiments.mrclam import evaluate_mrclam


def cell(path: Path, landmarks: bool, duration: float | None, config_path: str) -> str:
    config = DEFAULTS if config_path == "default" else load_config(config_path)
    rep = evaluate_mrclam(path, ["diekf"], landmarks=landmarks, duration=duration, config=config)
    rec = rep["recommended"]
    if rec["basis"] == "truth":
        return f"{rec['pos_rmse']:.3f} / {rec['value']:.2f}"
    return f"{rec['value']:.2f}" if rec["value"] is not None else str(rec.get("why"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_mrclam(ap)
    ap.add_argument("--datasets", default="1,2,3,4,9,6")
    ap.add_argument("--configs", default="default", help="comma-separated: default or TOML files")
    ap.add_argument("--landmarks", default="on,off")
    ap.add_argument("--whole", default="", help="datasets also run whole")
    ap.add_argument("--out", type=Path, default=Path("nolm_table.json"))
    a = ap.parse_args()
    configs = a.configs.split(",")
    rows = [(int(k), 300.0) for k in a.datasets.split(",")] + [(int(k), None) for k in a.whole.split(",") if k]
    out = {}
    print("| dataset | landmarks | " + " | ".join(configs) + " |")
    for k, duration in rows:
        for lm in a.landmarks.split(","):
            cells = [cell(a.mrclam / f"MRCLAM_Dataset{k}", lm == "on", duration, c) for c in configs]
            out[f"{k}/{'300' if duration else 'whole'}/{lm}"] = cells
            print(f"| {k}{'' if duration else ', whole'} | {lm} | " + " | ".join(cells) + " |", flush=True)
    a.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
