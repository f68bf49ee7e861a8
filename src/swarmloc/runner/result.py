"""What a run produces: recorded beliefs per robot against truth, counters, and wall time."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from swarmloc.node.accounting import OUTCOMES
from swarmloc.text import ids, number

RUN_COUNTERS = ("detections", *OUTCOMES, "pending", "odometry", "messages")
"""The counters every driver's :class:`RunResult` holds in ``stats`` (zero when none was counted)."""


@dataclass
class RobotTrack:
    """Recorded beliefs of one robot: times ``(T,)`` [s], means ``(T, 3)`` as ``(x, y, theta)``,
    exponential-coordinate covariances ``(T, 3, 3)`` (right perturbation) and truth ``(T, 3)`` (NaN when unknown).
    SE(3) teams: means and truth ``(T, 7)`` as ``(x, y, z, qx, qy, qz, qw)``, covariances ``(T, 6, 6)``."""

    times: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    truth: np.ndarray

    def rows(self, idx: np.ndarray) -> RobotTrack:
        """The records ``idx`` (indices or a boolean mask) of the track."""
        return RobotTrack(self.times[idx], self.mean[idx], self.cov[idx], self.truth[idx])

    def with_truth(self) -> RobotTrack:
        """The records whose truth is known (finite): those that can be scored."""
        return self.rows(np.isfinite(self.truth).all(axis=1))


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


def summed(stats: Iterable[Mapping[str, int]]) -> dict[str, int]:
    """Counters of several runs summed key by key (as Python ints)."""
    out: dict[str, int] = {}
    for s in stats:
        for k, v in s.items():
            out[k] = out.get(k, 0) + int(v)
    return out
