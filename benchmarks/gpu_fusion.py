"""The fusion step on an accelerator: swarmloc's JAX backend against the same step in plain JAX, one run.

    python benchmarks/gpu_fusion.py                          # 1e4, 1e5, 1e6 robots on jax's default device
    python benchmarks/gpu_fusion.py --sizes 1000 --repeats 2 # a quick check (CPU is fine)

For each size ``n`` (robots, 3 relative-pose detections each, no gate) it prints robot-updates per second of:

* ``engine jax f64``: :func:`swarmloc.engine.fusion_step` with ``backend="jax"`` (float64; the engine's
  Gauss-Seidel levels, one padded kernel call per level and detection position, states copied between host and
  device at every call: what a user of the engine gets);
* ``plain jax f64`` / ``plain jax f32``: the same arithmetic (:mod:`swarmloc.engine.soa`: one prediction and 3
  pose updates per robot, every robot at once, Jacobi order, no scheduling) as one ``jax.jit`` function on
  arrays kept on the device: the device's ceiling for this step, in double and single precision;
* ``engine numba``: the CPU backend, for the ratio.

The device is printed from ``jax.devices()``. Set ``OPENBLAS_NUM_THREADS=1`` for the CPU figures.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from swarmloc.engine import fusion_step, soa  # noqa: E402
from swarmloc.engine.backends import _cols, _full, _up  # noqa: E402
from swarmloc.engine.swarm import SWARM_NOISE, Swarm, neighbour_pairs  # noqa: E402


def plain_jax(n: int, neighbours: int, repeats: int, dtype: str) -> float:
    """Robot-updates per second of the step as one jitted function on device-resident arrays (median)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    sw = Swarm(n, seed=0)
    obs, tgt = neighbour_pairs(sw.pose[:, :2], neighbours, math.inf)
    det = sw.sense(neighbours, math.inf, np.diag([0.05**2, 0.05**2, np.deg2rad(1.0) ** 2]), (obs, tgt))
    v, w = sw.commands(0.1)
    dt = np.full(n, 0.1)
    x = sw.pose.copy()
    P = np.broadcast_to(1e-4 * np.eye(3), (n, 3, 3)).copy()
    z = det.z.reshape(n, neighbours, 3)
    R = np.ascontiguousarray(det.R).reshape(n, neighbours, 3, 3)
    t = tgt.reshape(n, neighbours)

    def step(x, P, v, w, dt, z, R, t):
        # the states as one (n, 9) array behind a barrier at each stage: gathering from per-entry arrays that XLA
        # may fuse, it recomputes the producers of a gathered value per element, stage after stage (measured on the
        # CPU: 1e3 robot-updates/s at any size with 3 neighbours; 16 ms -> 0.9 s from 2 to 3 neighbours at 1000)
        xs, ps = soa.predict(jnp, _cols(x), _up(P), v, w, dt, SWARM_NOISE)
        S = jnp.stack(xs + ps, -1)
        for j in range(neighbours):
            S = jax.lax.optimization_barrier(S)
            G = S[t[:, j]]
            xs, ps = tuple(S[:, i] for i in range(3)), tuple(S[:, i] for i in range(3, 9))
            xk, pk = tuple(G[:, i] for i in range(3)), tuple(G[:, i] for i in range(3, 9))
            xs, ps, _, _ = soa.pose_update(jnp, xs, ps, xk, pk, _cols(z[:, j]), _up(R[:, j]))
            S = jnp.stack(xs + ps, -1)
        return jnp.stack(xs, -1), _full(jnp, ps)

    f = jax.jit(step)
    cast = np.float32 if dtype == "f32" else np.float64
    args = [jax.device_put(a.astype(cast)) for a in (x, P, v, w, dt, z, R)] + [jax.device_put(t)]
    jax.block_until_ready(f(*args))  # compile
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*args))
        times.append(time.perf_counter() - t0)
    return n / float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="10000,100000,1000000", help="robots, comma-separated")
    ap.add_argument("--neighbours", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    import jax

    print(f"machine: {platform.platform()}, {os.cpu_count()} cores; jax {jax.__version__}, device {jax.devices()}")
    print(f"{'robots':>9} {'engine jax f64':>16} {'plain jax f64':>15} {'plain jax f32':>15} {'engine numba':>14}")
    for n in (int(s) for s in args.sizes.split(",")):
        fusion_step(n, backend="jax", neighbours=args.neighbours, repeats=1)  # compiles every bucket it meets
        eng = fusion_step(n, backend="jax", neighbours=args.neighbours, repeats=args.repeats)["robot_updates_per_s"]
        p64 = plain_jax(n, args.neighbours, args.repeats, "f64")
        p32 = plain_jax(n, args.neighbours, args.repeats, "f32")
        nb = fusion_step(n, backend="numba", neighbours=args.neighbours, repeats=args.repeats)["robot_updates_per_s"]
        print(f"{n:9d} {eng:16.3g} {p64:15.3g} {p32:15.3g} {nb:14.3g}  (robot-updates/s)", flush=True)


if __name__ == "__main__":
    main()
