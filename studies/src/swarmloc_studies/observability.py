"""Observability of cooperative localization (lecture slide 20, thesis Fig. 5.22), as a scenario and a figure.

Without any absolute information, relative measurements between robots make their *relative* poses observable but
not the team's global pose (3 directions on SE(2)): the absolute error of every robot grows with time, like dead
reckoning's, while the error of the robots' relative positions stays bounded. One robot with absolute fixes makes
the whole team's pose observable and bounds everyone's absolute error.

:func:`observability_run` runs the centralized EKF (consistent without landmarks) on a simulated team
(:func:`swarmloc.sim.random_team`, a relative-pose sensor seeing every teammate at 2 Hz) with absolute fixes for
the robots in ``anchored`` (none by default), and returns per-record absolute and relative position errors over
time. The absolute error of robot ``i`` is ``|p_i - p_i^true|``; the relative error of a pair is the position
error of robot ``j``'s pose in robot ``i``'s frame, ``g_i^-1 g_j`` (invariant to a rigid motion of the whole
team), pooled over all pairs. :func:`observability_figure` plots both for the two cases.
"""

from __future__ import annotations

from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.estimators import make_team, node_options
from swarmloc.lie import SE2
from swarmloc.runner import run
from swarmloc.sim.source import sim_source

__all__ = ["observability_figure", "observability_run"]


def observability_run(
    robots: int = 4,
    duration: float = 120.0,
    seed: int = 0,
    anchored: tuple[int, ...] = (),
    estimator: str = "cekf",
    record_rate: float = 1.0,
) -> dict[str, np.ndarray]:
    """Times ``(T,)`` [s], absolute errors ``(T, robots)`` [m] and pooled relative errors ``(T, pairs)`` [m]."""
    from swarmloc.sim import AbsoluteSensor, RelativeSensor, random_team

    absolute = AbsoluteSensor(robots=tuple(anchored), rate=1.0, sigma_xy=0.05, sigma_theta=0.02) if anchored else None
    sensor = RelativeSensor(rate=2.0, max_range=50.0)
    sim = random_team(robots, duration, seed=seed, area=3.0, sensor=sensor, absolute=absolute)
    src = sim_source(sim, "sim:observability")
    times = np.arange(0.0, duration, 1.0 / record_rate)
    nodes = make_team(estimator, src.initial, **node_options(estimator, src.config, None))
    res = run(nodes, src.events, times, truth=src.truth)
    ids = sorted(res.tracks)
    est = np.stack([SE2.from_xytheta(res.tracks[r].mean) for r in ids], axis=1)
    tru = np.stack([SE2.from_xytheta(res.tracks[r].truth) for r in ids], axis=1)
    abs_err = np.linalg.norm(est[..., :2, 2] - tru[..., :2, 2], axis=-1)
    pairs = list(combinations(range(len(ids)), 2))
    inv = SE2.inverse
    rel = [
        np.linalg.norm((inv(est[:, i]) @ est[:, j])[:, :2, 2] - (inv(tru[:, i]) @ tru[:, j])[:, :2, 2], axis=-1)
        for i, j in pairs
    ]
    return {"times": res.tracks[ids[0]].times, "absolute": abs_err, "relative": np.stack(rel, axis=1)}


def observability_figure(out: str | Path, seeds: int = 5, **kw: Any) -> Path:
    """RMS over seeds of the absolute and relative errors against time, without and with one anchored robot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), sharey=True)
    for ax, anchored, title in ((axes[0], (), "no absolute information"), (axes[1], (0,), "robot 0 has fixes")):
        runs = [observability_run(seed=s, anchored=anchored, **kw) for s in range(seeds)]
        t = runs[0]["times"]
        for key, style in (("absolute", "-"), ("relative", "--")):
            rms = np.sqrt(np.mean([np.mean(r[key] ** 2, axis=1) for r in runs], axis=0))
            ax.plot(t, rms, style, label=f"{key} position error (RMS)")
        ax.set_title(title)
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("error [m]")
    axes[0].legend()
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
