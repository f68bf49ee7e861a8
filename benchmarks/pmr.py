"""PMR multiple registration: time against the number of robots, in ratios to a baseline of the same run.

    python benchmarks/pmr.py                       # n = 4, 6, ..., 20; best of 3; baseline n = 4
    python benchmarks/pmr.py --max-n 12 --repeats 5 --out pmr.json

One robot (ego) registers the anonymous observations of a team of ``n`` robots (all see all, point noise
``--sigma`` m), :func:`swarmloc.association.multiple_registration`, in three regimes:

* ``generic``: a random configuration (robots at least 0.3 m apart in a square of side ``0.6 sqrt(n)`` m), no belief:
  one solution;
* ``symmetric+belief``: a regular ``n``-gon (the worst case, ``(n - 1)!`` solutions without a belief) with a good
  belief of every neighbour (Gaussian gate, 5 cm / 0.05 rad): one solution -- slide 60's "square cost once the system
  reaches ambiguity with a good belief";
* ``symmetric``: the regular ``n``-gon without a belief, only up to ``--max-factorial`` robots: ``(n - 1)!``
  solutions (slide 60's factorial growth).

Printed per ``n``: solutions, binary registrations (``n (n - 1) / 2``), partial solutions expanded, milliseconds (best
of ``--repeats``), and the ratios of the time and of the number of registrations to the baseline ``n``.

    python benchmarks/pmr.py --khepera             # the slides' experiment, simulated (seed 0)
    python benchmarks/pmr.py --khepera --p-detect 0.9 --clutter 0.2   # with misses and false positives

runs PMR and the particle-filter bank for robot 1 over the simulated Khepera III kidnapping
(:func:`swarmloc.sim.khepera_kidnap`, :func:`swarmloc.association.track_anonymous`) and prints, per neighbour, the
median and 90th percentile of the position error and the median heading error over the run, when robot 4's
estimate is back within 0.1 m after its kidnapping, and the wall time per scan.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time

import numpy as np

from swarmloc.association import multiple_registration
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, between_xyt


def spread(rng: np.random.Generator, n: int, min_sep: float = 0.3) -> np.ndarray:
    half = 0.3 * np.sqrt(n)
    while True:
        P = rng.uniform(-half, half, (n, 2))
        d = np.hypot(*(P[:, None] - P[None]).transpose(2, 0, 1)) + 9 * np.eye(n)
        if d.min() >= min_sep:
            return P


def polygon(n: int) -> np.ndarray:
    a = 0.3 + 2 * np.pi * np.arange(n) / n
    r = max(1.0, 0.3 * n / (2 * np.sin(np.pi / n)))  # neighbours at least 0.3 m apart
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def observe(poses: np.ndarray, rng: np.random.Generator, sigma: float) -> dict[int, np.ndarray]:
    out = {}
    for i in range(len(poses)):
        rel = np.delete(between_xyt(poses[i], poses)[:, :2], i, 0)
        out[i] = rng.permutation(rel + sigma * rng.standard_normal(rel.shape))
    return out


def case(regime: str, n: int, sigma: float, seed: int) -> tuple[dict, dict | None]:
    rng = np.random.default_rng(seed)
    P = spread(rng, n) if regime == "generic" else polygon(n)
    poses = np.column_stack([P, rng.uniform(-np.pi, np.pi, n)])
    beliefs = None
    if regime == "symmetric+belief":
        C = np.diag([0.05**2, 0.05**2, 0.05**2])
        beliefs = {j: GroupGaussian(SE2, SE2.from_xytheta(between_xyt(poses[0], poses[j])), C)
                   for j in range(1, n)}  # fmt: skip
    return observe(poses, rng, sigma), beliefs


def measure(regime: str, n: int, sigma: float, repeats: int, seed: int) -> dict:
    obs, beliefs = case(regime, n, sigma, seed)
    best, res = math.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = multiple_registration(obs, 0, sigma, beliefs=beliefs)
        best = min(best, time.perf_counter() - t0)
    return {"regime": regime, "n": n, "solutions": len(res.solutions), "registrations": res.registrations,
            "branches": res.branches, "ms": 1e3 * best}  # fmt: skip


def khepera(seed: int, n_particles: int, p_detect: float, clutter: float) -> None:
    from swarmloc.association import track_anonymous
    from swarmloc.motion import UnicycleNoise
    from swarmloc.sim import AnonymousSensor, khepera_kidnap

    fov = float(np.deg2rad(240.0))
    sc = khepera_kidnap(seed=seed, sensor=AnonymousSensor(p_detect, clutter, max_range=2.0, fov=fov))
    noisy = p_detect < 1 or clutter > 0
    sim = sc.sim
    t0 = time.perf_counter()
    track = track_anonymous(
        sim.events, 1, sim.robot_ids, UnicycleNoise.from_diff_drive(sim.config.drive), 0.035, max_range=2.0,
        fov=fov, sigma_range=0.01, max_unmatched=int(noisy), n_particles=n_particles, rng=seed,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    col = {r: c for c, r in enumerate(sim.robot_ids)}
    k = np.searchsorted(sim.times, np.array(track.times) - 1e-9)
    print(f"Khepera III kidnapping (seed {seed}, {n_particles} particles per filter, kidnap of robot "
          f"{sc.kidnapped} at {sc.kidnap_time:g} s, detection probability {p_detect:g}, {clutter:g} false positives "
          f"per scan, max_unmatched {int(noisy)}): {track.counts}")  # fmt: skip
    print(f"{'robot':>5} {'pos median [m]':>15} {'pos p90 [m]':>12} {'heading median [rad]':>21}")
    for j in sim.robot_ids[1:]:
        truth = between_xyt(sim.truth[k, col[1]], sim.truth[k, col[j]])
        t, pos, ang = track.errors(j, truth)
        print(f"{j:>5} {np.nanmedian(pos):>15.3f} {np.nanpercentile(pos, 90):>12.3f} {np.nanmedian(ang):>21.3f}")
        if j == sc.kidnapped:
            back = t[(t > sc.kidnap_time) & (pos < 0.1)]
            print(f"      robot {j} back within 0.1 m at t = {back[0]:.1f} s" if back.size else "      never back")
    print(f"{1e3 * wall / len(track.times):.1f} ms per scan ({len(track.times)} scans, {wall:.1f} s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--min-n", type=int, default=4, help="baseline and smallest team")
    ap.add_argument("--max-n", type=int, default=20)
    ap.add_argument("--step", type=int, default=2)
    ap.add_argument("--max-factorial", type=int, default=7, help="largest n for the symmetric regime without belief")
    ap.add_argument("--sigma", type=float, default=0.01, help="point noise std [m]")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="write the rows as JSON")
    ap.add_argument("--khepera", action="store_true", help="run the simulated Khepera III experiment instead")
    ap.add_argument("--particles", type=int, default=300, help="particles per filter (--khepera)")
    ap.add_argument("--p-detect", type=float, default=1.0, help="detection probability (--khepera)")
    ap.add_argument("--clutter", type=float, default=0.0, help="false positives per scan (--khepera)")
    a = ap.parse_args()
    if a.khepera:
        khepera(a.seed, a.particles, a.p_detect, a.clutter)
        return
    print(f"# {platform.machine()}, {os.cpu_count()} cores, {platform.python_implementation()} "
          f"{platform.python_version()}, numpy {np.__version__}; sigma {a.sigma} m, best of {a.repeats}")  # fmt: skip
    rows = []
    for regime in ("generic", "symmetric+belief", "symmetric"):
        top = a.max_n if regime != "symmetric" else min(a.max_n, a.max_factorial)
        ns = list(range(a.min_n, top + 1, a.step if regime != "symmetric" else 1))
        print(f"\n{regime}\n{'n':>3} {'solutions':>9} {'regs':>5} {'branches':>8} {'ms':>9} {'t/t0':>7} {'regs/r0':>7}")
        base = None
        for n in ns:
            r = measure(regime, n, a.sigma, a.repeats, a.seed + n)
            base = base or r
            r["time_ratio"] = r["ms"] / base["ms"]
            r["registration_ratio"] = r["registrations"] / base["registrations"]
            rows.append(r)
            print(f"{n:>3} {r['solutions']:>9} {r['registrations']:>5} {r['branches']:>8} {r['ms']:>9.2f} "
                  f"{r['time_ratio']:>7.2f} {r['registration_ratio']:>7.2f}")  # fmt: skip
    if a.out:
        with open(a.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
