"""Anonymous robot detections, misses and clutter (lecture slides 32-44, 64-69).

Two ways in, one convention: an anonymous detection is a robot :class:`~swarmloc.events.Detection` with
``target=None``; its true identity is kept in ``truth_target`` for scoring only (estimators never read it, it is
neither written to event files nor sent), :data:`CLUTTER_TRUTH` (-1) for a false detection.

:func:`anonymize` works on any event list (recorded or simulated):

* **anonymous**: each robot detection loses its ``target``; given the ``team``, a detection of a robot outside it is
  a false detection to the team (its ``truth_target`` :data:`CLUTTER_TRUTH`: refusing it is right);
* **misses**: each robot detection is kept with probability ``p_detect``;
* **clutter**: each scan (an observer's robot detections at one instant, before misses) gains ``Poisson(clutter)``
  false detections of the scan's kind, uniform in range ``[min_range, max_range]`` [m] and bearing within
  ``+-fov/2`` [rad] (a relative pose's heading uniform too), with the scan's noise covariance.

Landmark detections, absolute fixes, odometry and truth pass unchanged. Same seed, same result.

:func:`anonymize_sim` works on a simulation and knows its sensor, as Stegagno's laser robot detector (slides
41-44) sees: range-bearing detections only (``"pose"`` ones dropped, a relative pose needs the identity), limited
by an :class:`AnonymousSensor` (``max_range``, ``fov`` on top of the simulator's own), and clutter on *every* scan
(observer x sensor time, also scans that saw nothing) uniform over the sensed disc sector; within a scan the
detections are ordered by range then bearing, so the order reveals nothing. :func:`khepera_kidnap` is the slides'
Khepera III experiment built on it.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace

import numpy as np

from swarmloc.arrays import readonly
from swarmloc.events import Detection, Event, Kind, Odometry, Truth, sim_order
from swarmloc.lie import wrap_angle
from swarmloc.motion.diffdrive import DiffDrive
from swarmloc.sensors.models import MODELS
from swarmloc.sim.simulator import RelativeSensor, SimConfig, SimResult, WheelSchedule, simulate

__all__ = [
    "CLUTTER_TRUTH",
    "KHEPERA_DRIVE",
    "AnonymousSensor",
    "KheperaScenario",
    "anonymize",
    "anonymize_sim",
    "is_anonymous",
    "khepera_kidnap",
]

CLUTTER_TRUTH = -1
"""``truth_target`` of a false detection."""


def _z_clutter(rng: np.random.Generator, kind: str, n: int, lo: float, hi: float, fov: float) -> np.ndarray:
    rho = rng.uniform(lo, hi, n)
    beta = rng.uniform(-fov / 2, fov / 2, n)
    if MODELS[kind].targets == "point":  # which of (range, bearing) the kind measures
        return np.stack([rho, beta], axis=-1)[:, MODELS[kind].components]
    return np.stack([rho * np.cos(beta), rho * np.sin(beta), rng.uniform(-np.pi, np.pi, n)], axis=-1)  # pose


def anonymize(
    events: Sequence[Event],
    *,
    p_detect: float = 1.0,
    clutter: float = 0.0,
    max_range: float = 5.0,
    min_range: float = 0.3,
    fov: float = 2 * np.pi,
    hide_ids: bool = True,
    seed: int = 0,
    team: Collection[int] | None = None,
) -> list[Event]:
    """The events with robot detections made anonymous (``hide_ids``), missed and cluttered as the module says;
    ``team``: the robots the nodes know (None: every detected robot is one of them)."""
    if not 0.0 <= p_detect <= 1.0:
        raise ValueError(f"p_detect must be in [0, 1], got {p_detect}")
    if not (np.isfinite(clutter) and 0.0 <= clutter <= 100.0):
        raise ValueError(f"clutter must be a mean count per scan in [0, 100], got {clutter}")
    if not 0.0 <= min_range < max_range or not np.isfinite(max_range):
        raise ValueError(f"need 0 <= min_range < max_range (finite), got {min_range}, {max_range}")
    if not 0.0 < fov <= 2 * np.pi:
        raise ValueError(f"fov must be in (0, 2 pi], got {fov}")
    rng = np.random.default_rng(seed)
    out: list[Event] = []
    scan: tuple[int, float] | None = None
    for e in events:
        if not (isinstance(e, Detection) and e.target_is_robot and e.kind != Kind.ABSOLUTE and e.target is not None):
            out.append(e)
            continue
        if (e.observer, e.t) != scan:  # a new scan: its clutter first, drawn once
            scan = (e.observer, e.t)
            k = int(rng.poisson(clutter)) if clutter > 0 else 0
            for z in _z_clutter(rng, e.kind, k, min_range, max_range, fov):
                out.append(Detection(e.observer, e.t, e.kind, readonly(z), e.cov, None, True, CLUTTER_TRUTH))
        if p_detect < 1.0 and rng.random() >= p_detect:
            continue
        target = None if hide_ids else e.target
        truth = e.target if team is None or e.target in team else CLUTTER_TRUTH
        out.append(Detection(e.observer, e.t, e.kind, e.z, e.cov, target, True, truth))
    return out


@dataclass(frozen=True)
class AnonymousSensor:
    """Robot detector without identities: detection probability ``p_detect``, mean false positives per scan
    ``clutter_rate`` (Poisson), range limit ``max_range`` [m], field of view ``fov`` [rad] centred ahead."""

    p_detect: float = 1.0
    clutter_rate: float = 0.0
    max_range: float = np.inf
    fov: float = 2 * np.pi

    def __post_init__(self) -> None:
        if not 0.0 <= self.p_detect <= 1.0:
            raise ValueError(f"AnonymousSensor: p_detect must be in [0, 1], got {self.p_detect!r}")
        if not (np.isfinite(self.clutter_rate) and self.clutter_rate >= 0):
            raise ValueError(f"AnonymousSensor: clutter_rate must be a finite number >= 0, got {self.clutter_rate!r}")
        if not self.max_range > 0:
            raise ValueError(f"AnonymousSensor: max_range must be > 0, got {self.max_range!r}")
        if not 0 < self.fov <= 2 * np.pi:
            raise ValueError(f"AnonymousSensor: fov must be in (0, 2 pi], got {self.fov!r}")


def is_anonymous(e: Event) -> bool:
    """True for an anonymous robot detection (``target=None``, ``target_is_robot``, not an absolute fix)."""
    return isinstance(e, Detection) and e.kind != Kind.ABSOLUTE and e.target_is_robot and e.target is None


def _scan_times(cfg: SimConfig, sensor_rate: float, duration: float) -> np.ndarray:
    """The simulator's sensor times ``k / f`` (bit-identical to its detections' stamps) for its sensor's rate [Hz]."""
    n_sub = max(1, int(round((1.0 / cfg.odom_rate) / cfg.dt)))
    f = cfg.odom_rate * n_sub
    n_s = int(round(f / sensor_rate))
    N = int(round(duration * f))
    return np.arange(n_s, N + 1, n_s) / f


def anonymize_sim(sim: SimResult, sensor: AnonymousSensor, seed: int | None = 0) -> SimResult:
    """The simulation with anonymous range-bearing robot detections as ``sensor`` sees them (module docstring);
    same seed, same events."""
    sen = sim.config.sensor
    if sen is None or Kind.RANGE_BEARING not in sen.kinds:
        raise ValueError("anonymize_sim: the simulation needs a RelativeSensor with kinds including 'range_bearing'")
    rng = np.random.default_rng(seed)
    reach = min(sensor.max_range, sen.max_range)
    half_fov = min(sensor.fov, sen.fov) / 2
    cov = readonly(sen.range_bearing_cov())
    scans: dict[tuple[float, int], list[Detection]] = {}
    rest: list[Event] = []
    for e in sim.events:
        if isinstance(e, Detection) and e.target_is_robot and e.kind in (Kind.POSE, Kind.RANGE_BEARING):
            if e.kind == Kind.RANGE_BEARING and e.z[0] <= sensor.max_range and abs(e.z[1]) <= sensor.fov / 2:
                if rng.random() < sensor.p_detect:
                    d = replace(e, target=None, truth_target=e.target)
                    scans.setdefault((e.t, e.observer), []).append(d)
        else:
            rest.append(e)
    if sensor.clutter_rate > 0:
        for t in _scan_times(sim.config, sen.rate, float(sim.times[-1])):
            for r in sim.robot_ids:
                k = rng.poisson(sensor.clutter_rate)
                if k:
                    rr = reach * np.sqrt(rng.random(k))
                    bb = rng.uniform(-half_fov, half_fov, k)
                    for z in np.column_stack([rr, wrap_angle(bb)]):
                        d = Detection(r, float(t), Kind.RANGE_BEARING, readonly(z), cov, truth_target=CLUTTER_TRUTH)
                        scans.setdefault((float(t), r), []).append(d)
    dets = [d for key in scans for d in sorted(scans[key], key=lambda d: (float(d.z[0]), float(d.z[1])))]
    events = rest + dets
    events.sort(key=lambda e: (*sim_order(e), getattr(e, "observer", getattr(e, "robot", 0))))
    return SimResult(events, sim.initial_poses, sim.robot_ids, sim.times, sim.truth, sim.config, sim.seed)


# ------------------------------------------------------------------------------------------------ Khepera III
KHEPERA_DRIVE = DiffDrive(r=0.0205, l=0.0884, D=0.002)
"""Khepera III: wheel radius 20.5 mm, axle 88.4 mm (K-Team's data sheet; the slides give the 130 mm body). The
wheel diffusion ``D`` [rad^2/s] is not in the slides: with it the heading drifts ~0.17 rad (1 sigma) in 120 s."""


@dataclass
class KheperaScenario:
    """:func:`khepera_kidnap`'s output: the anonymous simulation, the kidnapped robot, the kidnap time [s] and its
    pose just after (world frame), and the sensor the detections went through."""

    sim: SimResult
    kidnapped: int
    kidnap_time: float
    kidnap_pose: tuple[float, float, float]
    sensor: AnonymousSensor


KHEPERA_START = {1: (0.6, 0.45, 0.0), 2: (1.45, 1.05, 2.0), 3: (2.3, 0.5, -1.2), 4: (3.0, 0.8, 3.0)}
"""Initial poses ``(x, y, theta)`` in a 3.5 m x 1.5 m arena (the plot of slide 66)."""

KHEPERA_CIRCLES = {1: (0.05, 0.30), 2: (0.04, -0.25), 3: (0.05, 0.40), 4: (0.03, -0.35)}
"""Each robot's forward speed [m/s] and turning radius [m] (negative: clockwise): circles that stay in the arena."""


def khepera_kidnap(
    seed: int = 0,
    duration: float = 120.0,
    kidnap_time: float = 60.0,
    kidnapped: int = 4,
    kidnap_pose: tuple[float, float, float] = (1.9, 0.5, 1.5),
    sensor: AnonymousSensor | None = None,
    rate: float = 5.0,
) -> KheperaScenario:
    """The slides' experiment (64-69), simulated: 4 Khepera III robots, a laser robot detector of 240 deg, range
    limited to 2 m, range error 10 mm (taken as one standard deviation; bearing std 1 deg, an assumption), at
    ``rate`` [Hz], odometry at 10 Hz. Robot ``kidnapped`` is lifted just after ``kidnap_time`` [s] and put down at
    ``kidnap_pose``; its odometry does not notice. Detections are anonymous (``sensor``: by default no misses, no
    clutter, the 2 m / 240 deg limits). ``Truth`` at the kidnap time is the pose after the kidnap; the ``truth``
    array holds the pose before it at that grid time."""
    if not 0 < kidnap_time < duration:
        raise ValueError(f"khepera_kidnap: kidnap_time must be inside (0, {duration:g}) s, got {kidnap_time!r}")
    if kidnapped not in KHEPERA_START:
        raise ValueError(f"khepera_kidnap: kidnapped must be one of {sorted(KHEPERA_START)}, got {kidnapped!r}")
    sensor = sensor or AnonymousSensor(max_range=2.0, fov=np.deg2rad(240.0))
    rel = RelativeSensor(
        rate=rate, max_range=2.0, fov=float(np.deg2rad(240.0)), kinds=(Kind.RANGE_BEARING,),
        sigma_range=0.01, sigma_bearing=float(np.deg2rad(1.0)),
    )  # fmt: skip
    cmds = {
        r: WheelSchedule.from_unicycle([0.0], [v], [v / rad], KHEPERA_DRIVE) for r, (v, rad) in KHEPERA_CIRCLES.items()
    }
    s1, s2 = (int(x) for x in np.random.SeedSequence(seed).generate_state(2))
    cfg1 = SimConfig(duration=kidnap_time, drive=KHEPERA_DRIVE, odom_rate=10.0, sensor=rel)
    a = simulate(KHEPERA_START, cmds, cfg1, seed=s1)
    start2 = {r: tuple(a.truth[-1, c]) for c, r in enumerate(a.robot_ids)}
    start2[kidnapped] = kidnap_pose
    b = simulate(start2, cmds, replace(cfg1, duration=duration - kidnap_time), seed=s2)
    n_sub = max(1, int(round(0.1 / cfg1.dt)))
    f = 10.0 * n_sub
    K1 = int(round(kidnap_time * f))

    def shift(t: float) -> float:
        return (int(round(t * f)) + K1) / f

    events: list[Event] = [
        e for e in a.events if not (isinstance(e, Truth) and e.robot == kidnapped and e.t == a.times[-1])
    ]
    for e in b.events:
        if isinstance(e, Odometry):
            events.append(replace(e, t0=shift(e.t0), t1=shift(e.t1)))
        elif isinstance(e, Truth):
            if e.t > 0 or e.robot == kidnapped:
                events.append(replace(e, t=shift(e.t)))
        else:
            events.append(replace(e, t=shift(e.t)))
    times = np.concatenate([a.times, [shift(t) for t in b.times[1:]]])
    truth = np.concatenate([a.truth, b.truth[1:]])
    events.sort(key=sim_order)
    full = SimResult(events, a.initial_poses, a.robot_ids, times, truth, replace(cfg1, duration=duration), a.seed)
    return KheperaScenario(anonymize_sim(full, sensor, seed=seed), kidnapped, float(kidnap_time), kidnap_pose, sensor)
