"""Named event sources: what ``swarmloc node``, ``swarmloc team`` (and comparisons) read a team's data from.

A source spec is one of

* ``sim:random``: :func:`swarmloc.sim.random_team` (``robots``, ``duration``, ``seed``; area 3 m, relative-pose
  sensor at 5 Hz), process noise of the simulation, initial beliefs at the true start with ``config.initial``;
* ``sim:range_bearing``: the same team, measuring range and bearing instead of relative pose;
* ``sim:landmarks``: the ``sim:random`` team (the same events) plus 6 known landmarks and range-bearing detections
  of them (:func:`swarmloc.sim.landmarks.add_landmarks`: 2 Hz, up to 4 m, 0.05 m / 2 deg; ``Source.landmarks``);
* ``mrclam:PATH``: a UTIAS MRCLAM dataset folder (``duration`` truncates it; landmarks on unless told otherwise;
  detection covariances from the camera model that ``config.sensors.decorrelate`` names,
  :func:`swarmloc.experiments.mrclam.mrclam_stream`);
* ``events:PATH``: your own event file (:mod:`swarmloc.datasets.eventfile`), truth from ``truth_robot<N>.tum``
  beside it when present.

A :class:`Source` holds every robot's events; :meth:`Source.own_events` is what one robot's node may read (its
own odometry and its own detections). Ground truth stays with the evaluator (``Source.truth``): a node process
never calls it. Simulated sources are deterministic in ``seed``, so every process builds the same team.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.config import DEFAULTS, Config, MotionConfig
from swarmloc.events import Detection, Event, Odometry
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.runner import TruthFn
from swarmloc.sim.simulator import SimResult

__all__ = ["SIM_SCENARIOS", "Source", "load_source", "sim_source"]

SIM_SCENARIOS = ("random", "range_bearing", "landmarks")


@dataclass
class Source:
    """A team's events (odometry and detections, sorted by stamp), initial beliefs, landmarks, span [s], truth
    (evaluator only) and the configuration its models come from."""

    spec: str
    events: list[Event]
    initial: dict[int, GroupGaussian]
    landmarks: Mapping[int, Any] | None
    t_start: float
    t_end: float
    truth: TruthFn | None
    config: Config

    @property
    def robots(self) -> list[int]:
        return sorted(self.initial)

    def record_times(self) -> np.ndarray:
        """Times [s] at which beliefs are recorded: every ``1 / config.record.rate`` s over ``[t_start, t_end)``."""
        return np.arange(self.t_start, self.t_end, 1.0 / self.config.record.rate)

    def own_events(self, robot: int) -> list[Event]:
        """Robot ``robot``'s odometry and the detections it made, in stamp order."""
        return [
            e
            for e in self.events
            if (isinstance(e, Odometry) and e.robot == robot) or (isinstance(e, Detection) and e.observer == robot)
        ]


def sim_source(sim: SimResult, spec: str, config: Config | None = None) -> Source:
    """A :class:`Source` of a simulation: its odometry and detections, initial beliefs at the true start with
    ``config.initial``'s std, and truth interpolated on its grid. ``config`` defaults to :data:`DEFAULTS` with the
    simulation's own process noise."""
    from swarmloc.datasets.tum import interpolate

    if config is None:
        config = dataclasses.replace(DEFAULTS, motion=MotionConfig.from_noise(sim.unicycle_noise()))
    cov = config.initial.cov()
    initial = {r: GroupGaussian(SE2, SE2.from_xytheta(p), cov) for r, p in sim.initial_poses.items()}
    events = [e for e in sim.events if isinstance(e, Odometry | Detection)]
    col = {r: j for j, r in enumerate(sim.robot_ids)}

    def truth(robot: int, times: np.ndarray) -> np.ndarray:
        if robot not in col:
            raise ValueError(f"no ground truth for robot {robot}")
        return interpolate(sim.times, sim.truth[:, col[robot]], times)

    return Source(spec, events, initial, None, float(sim.times[0]), float(sim.times[-1]), truth, config)


def _sim(scenario: str, robots: int, duration: float, seed: int, config: Config | None) -> Source:
    from swarmloc.sim import RelativeSensor, random_team

    kinds = ("range_bearing",) if scenario == "range_bearing" else ("pose",)
    sim = random_team(robots, duration, seed=seed, area=3.0, sensor=RelativeSensor(rate=5.0, kinds=kinds))
    if scenario != "landmarks":
        return sim_source(sim, f"sim:{scenario}", config)
    from swarmloc.sim.landmarks import add_landmarks

    sim, landmarks = add_landmarks(sim, seed=seed)
    return dataclasses.replace(sim_source(sim, "sim:landmarks", config), landmarks=landmarks)


def load_source(
    spec: str,
    *,
    robots: int = 3,
    duration: float | None = None,
    seed: int = 0,
    config: Config | None = None,
    landmarks: bool = True,
) -> Source:
    """The :class:`Source` named by ``spec`` (see the module docstring). ``robots`` and ``seed`` apply to
    simulations (``duration`` default 30 s there; for datasets, ``None`` keeps the whole span). Raises ValueError
    naming the problem (unknown kind or scenario, missing path, malformed file)."""
    kind, _, arg = spec.partition(":")
    if kind == "sim":
        scenario = arg or "random"
        if scenario not in SIM_SCENARIOS:
            raise ValueError(f"unknown simulated scenario {scenario!r}; choose from {list(SIM_SCENARIOS)}")
        if not (isinstance(robots, int) and robots >= 1):
            raise ValueError(f"robots must be a positive integer, got {robots!r}")
        return _sim(scenario, robots, 30.0 if duration is None else float(duration), seed, config)
    if kind == "mrclam":
        from swarmloc.datasets.mrclam import load_mrclam
        from swarmloc.experiments.mrclam import initial_beliefs, mrclam_stream

        config = DEFAULTS if config is None else config
        data = load_mrclam(Path(arg))
        events, _ = mrclam_stream(data, config, duration, landmarks)  # camera model: config.sensors.decorrelate
        t_end = data.t_end if duration is None else min(data.t_end, data.t_start + duration)
        truth = data.truth_at if data.has_truth else None
        return Source(spec, events, initial_beliefs(data, config), data.landmarks, data.t_start, t_end, truth, config)
    if kind == "events":
        from swarmloc.experiments.own_robots import load_event_source

        config = DEFAULTS if config is None else config
        return Source(spec, *load_event_source(Path(arg), config), config)
    raise ValueError(f"unknown source {spec!r}: use sim:SCENARIO, mrclam:PATH or events:PATH")
