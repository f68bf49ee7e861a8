"""The fusion step on an accelerator: section e of ``swarmloc-studies bench``, the engine's JAX backends (float64 and
float32) against the same step in plain JAX on device-resident arrays, and numba, all measured in one run.

    OPENBLAS_NUM_THREADS=1 python benchmarks/gpu_fusion.py                     # 1e4, 1e5, 1e6 robots
    python benchmarks/gpu_fusion.py --sizes 1000 --repeats 2                  # a quick check (a CPU is fine)
    python benchmarks/gpu_fusion.py --json-out e.json                         # the results as JSON too

The same as ``swarmloc-studies bench --sections e --accelerator-sizes ...``; what each column is:
:mod:`swarmloc_studies.accelerator`. The device is jax's default one (``jax.devices()[0]``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "src"), str(ROOT / "studies" / "src")]  # this checkout: swarmloc and its studies

from swarmloc_studies.accelerator import accelerator_rates, format_accelerator  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="10000,100000,1000000", help="robots, comma-separated")
    ap.add_argument("--neighbours", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json-out", default=None, help="also write the results to this JSON file")
    args = ap.parse_args()
    res: dict = {}
    for n in (int(float(s)) for s in args.sizes.split(",")):  # one size at a time: each row printed when measured
        part = accelerator_rates([n], args.neighbours, args.repeats, tick=lambda s: print(s, file=sys.stderr))
        res = {**part, "rows": res.get("rows", []) + part.get("rows", [])}
        print("\n".join(format_accelerator(part)), flush=True)
        if args.json_out:
            Path(args.json_out).write_text(json.dumps(res, indent=2, default=float))
    print("\n".join(["", "all sizes:", *format_accelerator(res)]), flush=True)


if __name__ == "__main__":
    main()
