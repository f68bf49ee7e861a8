"""swarmloc benchmarks: `python benchmarks/run.py` (about a minute).

Each line prints a time and a ratio against a baseline measured in the same run, so numbers from different
machines compare by their ratios. Results for this repository's machine are in docs/benchmarks.md.
"""

from __future__ import annotations

import os
import platform
import time

import numpy as np
from _common import mrclam_root

from swarmloc import SE2, SE3
from swarmloc.gaussian import convolution_F, convolution_F_reference, convolve_moments


def best(fn, repeat: int = 5, number: int = 1) -> float:
    """Best-of-``repeat`` seconds per call."""
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(number):
            fn()
        out.append((time.perf_counter() - t) / number)
    return min(out)


def line(name: str, t: float, base_name: str, base: float) -> None:
    print(f"{name:<48s} {t * 1e6:12.2f} us   {base / t:8.1f}x faster than {base_name}")


def bench_group(G, n: int, rng: np.random.Generator) -> None:
    x = rng.standard_normal((n, G.dim))
    g = G.exp(x, validate=False)
    loop = best(lambda: [G.exp(xi, validate=False) for xi in x[:2000]], repeat=3) / 2000
    batched = best(lambda: G.exp(x, validate=False), repeat=3) / n
    line(f"{G.name} exp, batched over {n} (per element)", batched, "a Python loop", loop)
    loop = best(lambda: [G.log(gi, validate=False) for gi in g[:2000]], repeat=3) / 2000
    batched = best(lambda: G.log(g, validate=False), repeat=3) / n
    line(f"{G.name} log, batched over {n} (per element)", batched, "a Python loop", loop)
    A = np.cov(rng.standard_normal((G.dim, 50)))
    B = np.cov(rng.standard_normal((G.dim, 50)))
    ref = best(lambda: convolution_F_reference(G, A, B), number=200)
    fast = best(lambda: convolution_F(G, A, B), number=2000)
    line(f"{G.name} second-order term F(A, B), one pair", fast, "term-by-term einsum", ref)
    As = np.broadcast_to(A, (10_000, G.dim, G.dim))
    Bs = np.broadcast_to(B, (10_000, G.dim, G.dim))
    mus = G.exp(rng.standard_normal((10_000, G.dim)), validate=False)
    single = best(lambda: [convolve_moments(G, mus[i], A, mus[i], B) for i in range(500)], repeat=3) / 500
    batched = best(lambda: convolve_moments(G, mus, As, mus, Bs), repeat=3) / 10_000
    line(f"{G.name} convolution of 10000 beliefs (per belief)", batched, "one at a time", single)


def main() -> None:
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}")  # fmt: skip
    rng = np.random.default_rng(0)
    for G, n in ((SE2, 100_000), (SE3, 20_000)):
        bench_group(G, n, rng)

    data = mrclam_root()
    ds6 = data / "MRCLAM_Dataset6"
    if ds6.is_dir():
        from swarmloc.experiments.mrclam import evaluate_mrclam

        rep = evaluate_mrclam(ds6, duration=120)
        base = rep["estimators"]["dr"]["wall_time_s"]
        for name, ev in rep["estimators"].items():
            print(f"MRCLAM dataset 6, 120 s, landmarks on: {name:<10s} {ev['x_real_time']:6.0f}x real time   "
                  f"{base / ev['wall_time_s']:5.2f}x the speed of dead reckoning")  # fmt: skip
    else:
        print(f"MRCLAM data not found at {data}: replay benchmark skipped")


if __name__ == "__main__":
    main()
