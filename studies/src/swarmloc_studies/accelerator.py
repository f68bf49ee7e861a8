"""Section e of ``swarmloc-studies bench`` (``--sections e``): the fusion step on jax's default device (a GPU where jax
sees one), in float64 and float32, against the same step in plain JAX measured in the same run.

For each team size ``n`` (robots; ``neighbours`` relative-pose detections each, no gate) it measures
robot-updates per second (one robot-update: a prediction and its ``neighbours`` updates) of:

* ``engine jax`` / ``engine jax32``: :func:`swarmloc.engine.fusion_step` with ``backend="jax"`` (float64) or
  ``"jax32"`` (float32 on the device, states float64): the engine's Gauss-Seidel levels, screening and outcomes, a
  stamp in one device call (:mod:`swarmloc.engine.jax_stamp`) on the team's states kept on the device between
  stamps (:mod:`swarmloc.engine.resident`), the detections and commands uploaded and the stamp's outcome counts
  downloaded once per step: what a user of the engine gets;
* ``plain jax f64`` / ``plain jax f32``: the same arithmetic as one ``jax.jit`` function on arrays kept on the
  device (:func:`swarmloc.engine.swarm.device_step`: no scheduling, Jacobi order within a detection position):
  the device's ceiling for this step;
* ``engine numba``: the CPU backend of the same run, for the ratio.

Each rate is ``n`` over the median of ``repeats`` steps after an untimed first step (compilation).
"""

from __future__ import annotations

import importlib.util
import os
import platform
from collections.abc import Callable, Sequence
from typing import Any

SIZES = (10_000, 100_000, 1_000_000)
"""Team sizes of section e by default [robots]."""

COLUMNS = (
    ("engine_jax", "engine jax f64"),
    ("engine_jax32", "engine jax f32"),
    ("plain_float64", "plain jax f64"),
    ("plain_float32", "plain jax f32"),
    ("engine_numba", "engine numba"),
)
"""Keys of a row of section e and their column headings."""


def _no_tick(label: str) -> None:
    return None


def accelerator_rates(
    sizes: Sequence[int] = SIZES, neighbours: int = 3, repeats: int = 5, tick: Callable[[str], None] = _no_tick
) -> dict[str, Any]:
    """Section e: per size, robot-updates/s of every column of :data:`COLUMNS` and the ratios ``engine jax / plain
    jax f64`` and ``engine jax32 / plain jax f32``; ``device`` and ``jax`` (versions) of the run. Without jax, a
    ``skipped`` reason."""
    if importlib.util.find_spec("jax") is None:
        return {"skipped": "jax is not installed (pip install 'swarmloc[jax]')"}
    import jax

    from swarmloc.engine import fusion_step
    from swarmloc.engine.swarm import device_step

    numba = importlib.util.find_spec("numba") is not None
    out: dict[str, Any] = {"jax": jax.__version__, "device": str(jax.devices()[0]), "neighbours": neighbours,
                           "repeats": repeats, "cpu_count": os.cpu_count(), "platform": platform.platform(),
                           "rows": []}  # fmt: skip
    for n in sizes:
        row: dict[str, Any] = {"n": n}
        for backend in ("jax", "jax32") + (("numba",) if numba else ()):
            r = fusion_step(n, backend=backend, neighbours=neighbours, repeats=repeats)
            row[f"engine_{backend}"] = r["robot_updates_per_s"]
            tick(f"accelerator: engine {backend}, {n:,} robots")
        for dtype in ("float64", "float32"):
            r = device_step(n, dtype=dtype, neighbours=neighbours, repeats=repeats)
            row[f"plain_{dtype}"] = r["robot_updates_per_s"]
            row[f"compile_{dtype}_s"] = r["compile_s"]
            tick(f"accelerator: plain jax {dtype}, {n:,} robots")
        row["engine_over_plain_f64"] = row["engine_jax"] / row["plain_float64"]
        row["engine_over_plain_f32"] = row["engine_jax32"] / row["plain_float32"]
        out["rows"].append(row)
    return out


def format_accelerator(e: dict[str, Any]) -> list[str]:
    """Section e as lines of text."""
    out = ["e. accelerator: the fusion step on jax's default device (robot-updates/s)"]
    if "skipped" in e:
        return [*out, f"  skipped: {e['skipped']}"]
    out.append(f"  device {e['device']}, jax {e['jax']}, {e['neighbours']} neighbours, median of {e['repeats']}")
    keys = [k for k, _ in COLUMNS if any(k in r for r in e["rows"])]
    heads = dict(COLUMNS)
    out.append(f"  {'robots':>9}" + "".join(f"{heads[k]:>16}" for k in keys) + f"{'engine/plain f64':>18}"
               + f"{'engine/plain f32':>18}")  # fmt: skip
    for r in e["rows"]:
        cells = "".join(f"{r[k]:>16.3g}" if k in r else f"{'-':>16}" for k in keys)
        out.append(f"  {r['n']:>9,}{cells}{r['engine_over_plain_f64']:>18.3f}{r['engine_over_plain_f32']:>18.3f}")
    return out
