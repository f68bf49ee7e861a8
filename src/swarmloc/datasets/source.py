"""A team's recorded or simulated data as one object: :class:`Source` (what every driver and evaluation reads).

Built by :func:`swarmloc.experiments.sources.load_source` from a spec (``sim:``, ``mrclam:``, ``events:``) or by
:func:`swarmloc.sim.source.sim_source` from a simulation.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarmloc.config import Config
from swarmloc.events import Detection, Event, Odometry, OwnEvent, Truth
from swarmloc.gaussian import GroupGaussian
from swarmloc.mapping.observe import ScanSeries

__all__ = ["Source", "TruthFn"]

TruthFn = Callable[[int, np.ndarray], np.ndarray]
"""``truth(robot, times) -> (len(times), 3)`` world poses ``(x, y, theta)``; raises ValueError outside its span."""


@dataclass
class Source:
    """A team's events (odometry and detections, sorted by stamp), initial beliefs, landmarks, span [s], truth
    (evaluator only) and the configuration its models come from; ``scans``: each robot's range scans when the
    source has a range finder (None otherwise)."""

    spec: str
    events: list[Event]
    initial: dict[int, GroupGaussian]
    landmarks: Mapping[int, Any] | None
    t_start: float
    t_end: float
    truth: TruthFn | None
    config: Config
    scans: Mapping[int, ScanSeries] | None = None
    noise: Any = None
    """The process noise the nodes take when it is not ``config.motion``'s (an SE(3) team's
    :class:`~swarmloc.motion.twist3.TwistNoise`), or None."""
    truth_events: list[Truth] | None = None
    """The simulation's ``Truth`` events (3-D teams), for recording at the simulator's truth instants; or None."""
    sensor: tuple[float | None, float | None] = (None, None)
    """The robot detector's reach: ``(range [m], field of view [rad], total width centred ahead)``; None where
    unknown. An association policy's nodes count the teammates within it that a scan missed
    (``association_missed``, :mod:`swarmloc.node.associate`)."""

    @property
    def robots(self) -> list[int]:
        return sorted(self.initial)

    def record_times(self) -> np.ndarray:
        """Times [s] at which beliefs are recorded: every ``1 / config.record.rate`` s over ``[t_start, t_end)``.
        Raises ValueError, before allocating, when they would be too many or none worth scoring
        (:meth:`~swarmloc.config.RecordConfig.count`)."""
        return self.config.record.times(self.t_start, self.t_end, len(self.initial), f" (source {self.spec})")

    def own_events(self, robot: int) -> list[OwnEvent]:
        """Robot ``robot``'s odometry and the detections it made, in stamp order."""
        return [
            e
            for e in self.events
            if (isinstance(e, Odometry) and e.robot == robot) or (isinstance(e, Detection) and e.observer == robot)
        ]
