"""The settings of a :class:`~swarmloc.net.process.NetNode`, one typed, frozen object: its pace, its waits (the
timeouts of :mod:`swarmloc.net.timeouts`, all seconds of wall time), how it ends, what it asks and publishes.

Each setting is a field with its default and, below it, a docstring with its unit in brackets (the convention of
:mod:`swarmloc.declared`). The values are checked on construction (a :func:`dataclasses.replace` too): a wrong one
raises ``ValueError`` naming it. What the node runs on (its estimator node, inputs, session, team, roster, record
times, keys, scans, callbacks) is not a setting: :class:`~swarmloc.net.process.NetNode` takes it beside them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from swarmloc.net import timeouts as T
from swarmloc.net.faults import Faults

MAX_ROS_DOMAIN = 232
"""Largest ROS 2 domain id (DDS's: its ports would overflow above it)."""

WAITS = ("answer_timeout", "hold_timeout", "update_timeout", "start_timeout", "lost_timeout", "quiet", "linger")
"""The settings that are waits: seconds >= 0."""


@dataclass(frozen=True)
class NetSettings:
    """How a :class:`~swarmloc.net.process.NetNode` runs (see the module docstring)."""

    run_id: str | None = None
    """This run's id, in every key expression with the team's name (:func:`~swarmloc.net.transport.team_scope`;
    None: the name alone): two teams of one name with different run ids never hear each other."""
    speed: float = 0.0
    """[x real time] 0: as fast as lockstep allows; X > 0: X times real time (a live feed: 0, paced by arrivals)."""
    lag: float = 0.5
    """[s] lockstep slack (well below the node's horizon)."""
    answer_timeout: float = T.ANSWER_TIMEOUT
    """[s] wall time the node waits for the reply to one of its queries (neighbour, then server)."""
    hold_timeout: float = T.HOLD_TIMEOUT
    """[s] wall time it holds a neighbour's query for its state to settle before answering as it stands."""
    update_timeout: float = T.UPDATE_TIMEOUT
    """[s] wall time it waits for an observer's ``rdl`` update after giving its state."""
    answer_retries: int = T.ANSWER_RETRIES
    """How many more times it asks a query that went unanswered (while its robot is alive), more while within
    ``lost_timeout`` s of the first ask (0 to 100)."""
    use_server: bool = False
    """Ask the belief server a belief query a neighbour does not answer (and wait for it at the start); an
    ``RdlStateQuery`` is never asked of it (the server holds no pair factors)."""
    faults: Faults | None = None
    """Link faults on the messages this node sends (:mod:`swarmloc.net.faults`)."""
    wait_for: frozenset[int] | None = None
    """Robots to wait for (alive) before starting (None: the whole roster but this robot)."""
    start_timeout: float = T.START_TIMEOUT
    """[s] wall time it waits at the start for the robots of ``wait_for`` to be alive."""
    lost_timeout: float = T.LOST_TIMEOUT
    """[s] wall time it waits for a live teammate that is silent (no announcement) before declaring it lost and
    going on without it; one that announces but does not advance: ``STALL_TIMEOUTS`` times as long."""
    quiet: float = 0.3
    """[s] wall time without traffic that counts as settled at the end."""
    linger: float = 10.0
    """[s] wall time at most it keeps answering after it is done, while teammates are not."""
    ros_domain: int | None = None
    """Publish beliefs as ROS 2 messages too (rmw_zenoh layout, this domain id; None: not)."""
    record_rate: float | None = None
    """[Hz] with a live feed: record times every ``1 / record_rate`` s from the node's start, added as the inputs
    come (None: the record times given alone)."""

    def __post_init__(self) -> None:
        bad = {k: getattr(self, k) for k in WAITS if not float(getattr(self, k)) >= 0.0}
        if bad:
            raise ValueError(f"NetNode: timeouts are seconds >= 0, got {bad}")
        for k in ("speed", "lag"):  # a negative lag held every node back for good; a negative speed read as 0
            if not 0.0 <= float(getattr(self, k)) < math.inf:
                raise ValueError(f"NetNode: {k} is a finite number >= 0, got {getattr(self, k)!r}")
        for k in (*WAITS, "speed", "lag"):
            object.__setattr__(self, k, float(getattr(self, k)))
        object.__setattr__(self, "answer_retries", T.check_retries(self.answer_retries))
        d = self.ros_domain
        if d is not None and (isinstance(d, bool) or not isinstance(d, int) or not 0 <= d <= MAX_ROS_DOMAIN):
            raise ValueError(f"NetNode: ros_domain is a ROS 2 domain id in 0..{MAX_ROS_DOMAIN}, got {d!r}")
        if self.wait_for is not None:
            object.__setattr__(self, "wait_for", frozenset(int(r) for r in self.wait_for))
        if self.record_rate is not None:
            rate = float(self.record_rate)
            if not (math.isfinite(rate) and rate > 0):
                raise ValueError(f"NetNode: record_rate must be > 0 Hz, got {self.record_rate!r}")
            object.__setattr__(self, "record_rate", rate)

    @classmethod
    def of(cls, settings: NetSettings | None, kw: dict[str, Any]) -> NetSettings:
        """``settings`` (default: the defaults) with the keyword settings ``kw`` replacing its fields; TypeError
        naming a keyword that is no setting."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(kw) - names)
        if unknown:
            raise TypeError(f"NetNode: no such setting {unknown} (the settings: {sorted(names)})")
        base = cls() if settings is None else settings
        return cls(**{**{n: getattr(base, n) for n in names}, **kw}) if kw else base
