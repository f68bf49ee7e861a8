"""Named event sources: what ``swarmloc node``, ``swarmloc team`` (and comparisons) read a team's data from.

A source spec is one of

* ``sim:random``: :func:`swarmloc.sim.random_team` (``robots``, ``duration``, ``seed``; area 3 m, relative-pose
  sensor at 5 Hz), process noise of the simulation, initial beliefs of ``config.initial``'s covariance drawn about
  the true start (:func:`swarmloc.sim.source.prior_starts`);
* ``sim:range_bearing``: the same team, measuring range and bearing instead of relative pose;
* ``sim:landmarks``: the ``sim:random`` team (the same events) plus 6 known landmarks and range-bearing detections
  of them (:func:`swarmloc.sim.landmarks.add_landmarks`: 2 Hz, up to 4 m, 0.05 m / 2 deg; ``Source.landmarks``);
* ``sim:corridor``: ``robots`` robots driving along the corridor of :func:`swarmloc.sim.walls.office_walls` at
  0.15 m/s, in two lanes, each with a range finder (:class:`swarmloc.sim.walls.RangeFinder` defaults: 61 beams over
  120 deg, 3 m, 1 cm, 2 Hz; ``Source.scans``) and the chapter's robot-to-robot camera; for the belief server's map;
* ``mrclam:PATH``: a UTIAS MRCLAM dataset folder (``duration`` truncates it; landmarks on unless told otherwise;
  detection covariances from the camera model that ``config.sensors.decorrelate`` names,
  :func:`swarmloc.experiments.mrclam.mrclam_stream`; the start :func:`swarmloc.experiments.mrclam.mrclam_start`:
  the truth, or without it the robots' landmark snapshots fused);
* ``sim:3d``: a 3-D team (:func:`swarmloc.sim.sim3d.simulate3d`, ``robots`` quadrotor-like robots on SE(3), body
  twist odometry at 10 Hz, relative poses ``"pose3"`` at 2 Hz within 12 m, 5 cm / 2 deg; initial beliefs drawn
  about the truth with 10 cm / 3 deg); ``sim:3d_rot``: the same with large rotational uncertainty (30 deg per
  axis at the start); ``sim:3d_rbe``: the ``sim:3d`` team (same trajectories, odometry and initial beliefs)
  measuring range, azimuth and elevation of teammates (``"rbe3"``, 5 cm / 1 deg) instead of relative poses;
  ``sim:3d_bearing``: the same with azimuth and elevation only (``"bearing3"``, 1 deg); ``sim:3d_landmarks``:
  the ``sim:3d`` team (the same events) plus 8 known 3-D landmarks detected by ``"rbe3"`` at 2 Hz within 8 m
  (``Source.landmarks`` ``id -> (x, y, z, 0, 0, 0)``). ``Source.noise`` is the team's
  :class:`~swarmloc.motion.twist3.TwistNoise`; :func:`swarmloc.estimators.make_team` picks the SE(3) estimators
  (``dr``, ``expfusion``, ``dekf``, ``ci``, ``diekf``, ``cekf``);
* ``events:PATH``: your own event file (:mod:`swarmloc.datasets.eventfile`), truth from ``truth_robot<N>.tum``
  beside it when present.

A :class:`Source` holds every robot's events; :meth:`Source.own_events` is what one robot's node may read (its
own odometry and its own detections). Ground truth stays with the evaluator (``Source.truth``): a node process
never calls it. Simulated sources are deterministic in ``seed``, so every process builds the same team.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TypedDict

from swarmloc.config import DEFAULTS, Config
from swarmloc.datasets.source import Source
from swarmloc.events import Kind, MeasurementKind
from swarmloc.sim.source import sim_source

__all__ = ["SIM_SCENARIOS", "Source", "load_source", "sim3d_source", "sim_source", "source_kind"]


class Sim3Variant(TypedDict, total=False):
    """The :class:`~swarmloc.sim.sim3d.Sim3Config` fields a ``sim:3d`` scenario sets (the others: defaults)."""

    detection: MeasurementKind
    landmarks: int


SIM3D_VARIANTS: dict[str, Sim3Variant] = {
    "3d": {},
    "3d_rot": {},
    "3d_rbe": {"detection": Kind.RBE3},
    "3d_bearing": {"detection": Kind.BEARING3},
    "3d_landmarks": {"landmarks": 8},
}
"""The ``sim:3d`` scenarios and their :class:`~swarmloc.sim.sim3d.Sim3Config` fields."""

SIM_SCENARIOS = ("random", "range_bearing", "landmarks", "corridor", *SIM3D_VARIANTS)
"""Every ``sim:`` scenario: the planar ones and :data:`SIM3D_VARIANTS`."""

_SCENARIO_KINDS = {"range_bearing": (Kind.RANGE_BEARING,)}
"""The detection kinds of a planar random team's scenario (relative poses when not listed)."""

LARGE_ROTATION = 30.0
"""[deg] Initial rotational standard deviation per axis of ``sim:3d_rot``."""


def sim3d_source(robots: int, duration: float, seed: int, large_rotation: bool = False, scenario: str = "3d") -> Source:
    """``sim:3d`` (``large_rotation``: ``sim:3d_rot``; ``scenario`` one of :data:`SIM3D_VARIANTS`) as a
    :class:`Source` (see the module docstring)."""
    import numpy as np

    from swarmloc.events import Event, Truth
    from swarmloc.sim.sim3d import Sim3Config, simulate3d

    large_rotation = large_rotation or scenario == "3d_rot"
    cfg = Sim3Config(robots=robots, duration=duration, **SIM3D_VARIANTS[scenario])
    if large_rotation:
        cfg = dataclasses.replace(cfg, init_rot=float(np.deg2rad(LARGE_ROTATION)))
    sim = simulate3d(cfg, seed)
    events: list[Event] = [e for e in sim.events if not isinstance(e, Truth)]
    truths = [e for e in sim.events if isinstance(e, Truth)]
    spec = "sim:3d_rot" if large_rotation else f"sim:{scenario}"
    # beliefs recorded where the simulator has truth (its truth instants, on the odometry grid): a networked team
    # records at the configuration's rate and is scored there
    config = dataclasses.replace(DEFAULTS, record=dataclasses.replace(DEFAULTS.record, rate=cfg.truth_rate))
    return Source(spec, events, sim.initial, sim.landmarks or None, float(sim.times[0]), float(sim.times[-1]),
                  sim.truth, config, noise=sim.noise, truth_events=truths)  # fmt: skip


def _corridor(robots: int, duration: float, seed: int, config: Config | None) -> Source:
    """``robots`` robots (ids 0 ..) in a column along the office corridor (``y`` 2.75 and 3.25 m alternately),
    each driving ``+x`` at about 0.15 m/s for ``duration`` s (to ``x <= 9.6`` m), scanning the walls."""
    import numpy as np

    from swarmloc.mapping import ScanSeries
    from swarmloc.motion.diffdrive import DiffDrive
    from swarmloc.sim.lab import axis_schedule
    from swarmloc.sim.simulator import RelativeSensor, SimConfig, simulate
    from swarmloc.sim.walls import RangeFinder, office_walls, scan_team

    drive = DiffDrive(D=0.005)
    starts, schedules = {}, {}
    for r in range(robots):
        x0, y = 0.4 + 0.5 * (robots - 1 - r), (2.75, 3.25)[r % 2]
        x1 = min(9.6, x0 + 0.15 * duration)
        starts[r], schedules[r], _ = axis_schedule(((x0, y), (x1, y)), drive, (), 0.15)
    sensor = RelativeSensor(rate=2.0, max_range=3.0, fov=float(np.deg2rad(120)), sigma_xy=0.03,
                            sigma_theta=float(np.deg2rad(2.0)))  # fmt: skip
    sim = simulate(starts, schedules, SimConfig(duration=duration, drive=drive, odom_rate=10.0, sensor=sensor), seed)
    scans = scan_team(sim, office_walls(), RangeFinder(), seed)
    series = {r: ScanSeries(scans.times, scans.ranges[:, j], scans.angles, scans.sigma)
              for j, r in enumerate(scans.robot_ids)}  # fmt: skip
    return dataclasses.replace(sim_source(sim, "sim:corridor", config), scans=series)


def _sim(scenario: str, robots: int, duration: float, seed: int, config: Config | None) -> Source:
    from swarmloc.sim import RelativeSensor, random_team

    if scenario == "corridor":
        return _corridor(robots, duration, seed, config)
    if scenario in SIM3D_VARIANTS:
        return sim3d_source(robots, duration, seed, scenario=scenario)
    kinds = _SCENARIO_KINDS.get(scenario, (Kind.POSE,))
    sim = random_team(robots, duration, seed=seed, area=3.0, sensor=RelativeSensor(rate=5.0, kinds=kinds))
    if scenario != "landmarks":
        return sim_source(sim, f"sim:{scenario}", config)
    from swarmloc.sim.landmarks import add_landmarks

    sim, landmarks = add_landmarks(sim, seed=seed)
    return dataclasses.replace(sim_source(sim, "sim:landmarks", config), landmarks=landmarks)


def source_kind(spec: str) -> tuple[str, str]:
    """``(kind, the rest)`` of a source spec (``sim``'s rest: its scenario, ``random`` when not named); ValueError
    for an unknown kind or simulated scenario."""
    kind, _, arg = spec.partition(":")
    if kind == "sim" and (arg or "random") not in SIM_SCENARIOS:
        raise ValueError(f"unknown simulated scenario {arg!r}; choose from {list(SIM_SCENARIOS)}")
    if kind not in ("sim", "mrclam", "events"):
        raise ValueError(f"unknown source {spec!r}: use sim:SCENARIO, mrclam:PATH or events:PATH")
    return kind, (arg or "random") if kind == "sim" else arg


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
    kind, arg = source_kind(spec)
    if kind == "sim":
        if not (isinstance(robots, int) and robots >= 1):
            raise ValueError(f"robots must be a positive integer, got {robots!r}")
        return _sim(arg, robots, 30.0 if duration is None else float(duration), seed, config)
    config = DEFAULTS if config is None else config
    if kind == "mrclam":
        from swarmloc.datasets.mrclam import load_mrclam
        from swarmloc.experiments.mrclam import detector_reach, mrclam_start, mrclam_stream

        data = load_mrclam(Path(arg))
        events, _ = mrclam_stream(data, config, duration, landmarks)  # camera model: config.sensors.decorrelate
        t_end = data.t_end if duration is None else min(data.t_end, data.t_start + duration)
        truth = data.truth_at if data.has_truth else None
        start = mrclam_start(data, config, t_end)  # without truth: from the landmark snapshots, where it can
        return Source(spec, start.after(events), start.beliefs, data.landmarks, start.t0, t_end, truth, config,
                      sensor=detector_reach(data))  # fmt: skip
    from swarmloc.experiments.own_robots import load_event_source  # kind "events"

    return Source(spec, *load_event_source(Path(arg), config), config)
