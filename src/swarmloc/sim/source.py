"""A simulation as a :class:`~swarmloc.datasets.source.Source`: :func:`sim_source`."""

from __future__ import annotations

import dataclasses

import numpy as np

from swarmloc.config import DEFAULTS, Config, MotionConfig
from swarmloc.datasets.source import Source
from swarmloc.datasets.tum import interpolate
from swarmloc.events import Detection, Event, Odometry
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.sim.simulator import SimResult

__all__ = ["prior_starts", "sim_source"]


def prior_starts(sim: SimResult, cov: np.ndarray) -> dict[int, np.ndarray]:
    """Initial-belief means ``robot -> g0 exp(-y)`` (SE(2) matrices), ``y ~ N(0, cov)`` (exponential coordinates
    [m, m, rad]) about each true start ``g0``, so the truth is a sample of the prior ``(mean, cov)``; drawn from the
    fourth child of ``SeedSequence(sim.seed)``, in robot order (the same draws for the same simulation)."""
    rng = np.random.default_rng(np.random.SeedSequence(sim.seed).spawn(4)[3])
    L0 = np.linalg.cholesky(cov)
    return {r: SE2.from_xytheta(p) @ SE2.exp(-(L0 @ rng.standard_normal(3))) for r, p in sim.initial_poses.items()}


def sim_source(sim: SimResult, spec: str, config: Config | None = None) -> Source:
    """A :class:`Source` of a simulation: its odometry and detections, initial beliefs of ``config.initial``'s
    covariance whose means are drawn about the true starts by :func:`prior_starts` (so the truth is a sample of
    the prior, as in :mod:`swarmloc.sim.sim3d`), and truth interpolated on its grid. ``config`` defaults to
    :data:`DEFAULTS` with the simulation's own process noise; ``sensor``: its robot sensor's range and field of
    view."""
    if config is None:
        config = dataclasses.replace(DEFAULTS, motion=MotionConfig.from_noise(sim.unicycle_noise()))
    cov = config.initial.cov()
    initial = {r: GroupGaussian(SE2, g, cov) for r, g in prior_starts(sim, cov).items()}
    events: list[Event] = [e for e in sim.events if isinstance(e, Odometry | Detection)]  # the truth left out
    col = {r: j for j, r in enumerate(sim.robot_ids)}

    def truth(robot: int, times: np.ndarray) -> np.ndarray:
        if robot not in col:
            raise ValueError(f"no ground truth for robot {robot}")
        return interpolate(sim.times, sim.truth[:, col[robot]], times)

    sen = sim.config.sensor
    reach = (None, None) if sen is None else (float(sen.max_range), float(sen.fov))
    return Source(spec, events, initial, None, float(sim.times[0]), float(sim.times[-1]), truth, config,
                  sensor=reach)  # fmt: skip
