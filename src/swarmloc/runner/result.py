"""What a run produces: recorded beliefs per robot against truth, counters, and wall time."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from swarmloc.text import ids, number


@dataclass
class RobotTrack:
    """Recorded beliefs of one robot: times ``(T,)`` [s], means ``(T, 3)`` as ``(x, y, theta)``,
    exponential-coordinate covariances ``(T, 3, 3)`` (right perturbation) and truth ``(T, 3)`` (NaN when unknown).
    SE(3) teams: means and truth ``(T, 7)`` as ``(x, y, z, qx, qy, qz, qw)``, covariances ``(T, 6, 6)``."""

    times: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    truth: np.ndarray


@dataclass
class RunResult:
    """One estimator's run: ``tracks`` by robot id, ``wall_time`` [s] of the event loop, ``stats`` (the nodes'
    counters summed with the runner's), ``reasons`` (why inputs were rejected or unknown) and ``timing``
    (seconds in predictions and detection updates, summed over nodes)."""

    estimator: str
    tracks: dict[int, RobotTrack]
    wall_time: float
    stats: dict[str, int] = field(default_factory=dict)
    n_events: int = 0
    reasons: Counter[str] = field(default_factory=Counter)
    timing: dict[str, float] = field(default_factory=dict)

    def __repr__(self) -> str:
        """Estimator, robots, records, wall time and where the detections ended (never the arrays)."""
        s = self.stats
        records = sum(int(tr.times.size) for tr in self.tracks.values())
        ends = ""
        if "detections" in s:
            ends = (f", detections={s['detections']} (fused {s.get('fused', 0)}, gated {s.get('gated', 0)}, "
                    f"rejected {s.get('rejected', 0)}, unknown {s.get('unknown', 0)})")  # fmt: skip
        return (f"RunResult(estimator={self.estimator!r}, robots={ids(sorted(self.tracks))}, records={records}, "
                f"wall_time={number(self.wall_time)} s{ends})")  # fmt: skip

    def accounted(self) -> bool:
        """Every detection that came in ended fused, gated, rejected or unknown (none pending, none lost)."""
        s = self.stats
        return s["detections"] == s["fused"] + s["gated"] + s["rejected"] + s["unknown"] and s["pending"] == 0
