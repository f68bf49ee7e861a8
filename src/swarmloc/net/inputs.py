"""A :class:`~swarmloc.net.process.NetNode`'s own inputs: its robot's events, read in stamp order, from a recording or
from a :class:`~swarmloc.net.feed.LiveFeed` as it releases them.

Inputs are ``(stamp, item)``: an odometry interval (its start) or the detections of one instant (one list: a
detection group). Their keys, ``(stamp, priority)`` (a group 1, odometry 2), order them as the in-process runner
does, and are what the node announces and its lockstep compares (:mod:`swarmloc.net.lockstep`).
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Callable, Sequence
from typing import Any

from swarmloc.events import Detection, Event, Odometry
from swarmloc.net.feed import LiveFeed


def groups(events: Sequence[Event]) -> list[tuple[float, Any]]:
    """``(stamp, item)`` in order; consecutive detections at one instant form one list."""
    out: list[tuple[float, Any]] = []
    for e in events:
        if isinstance(e, Detection) and out and isinstance(out[-1][1], list) and out[-1][1][0].t == e.t:
            out[-1][1].append(e)
        elif isinstance(e, Detection):
            out.append((float(e.t), [e]))
        elif isinstance(e, Odometry):
            out.append((float(e.t0), e))
    return out


class Inputs:
    """Part of :class:`~swarmloc.net.process.NetNode` (``node.inputs``): the robot's own ``events``, or a live feed
    whose inputs are taken as it releases them (:meth:`pull`; ``t0``: [s] the node's start, the feed's first
    watermark, required with a feed; ``wake``: called when the feed has new inputs, from its thread)."""

    def __init__(self, events: Sequence[Event] | LiveFeed, t0: float | None, wake: Callable[[], None]) -> None:
        self.feed = events if isinstance(events, LiveFeed) else None
        """A live source (:mod:`swarmloc.net.feed`): ``items`` grows as it releases inputs; None: a recording."""
        self.items = groups(events) if not isinstance(events, LiveFeed) else []
        """The inputs, ``(stamp, item)`` (:func:`groups`)."""
        self.i = 0
        """The index of the next input to read in ``items``."""
        self.w = -math.inf
        """The feed's watermark at the last take: every input not yet taken is at or after it."""
        self._hi = -math.inf  # the latest time an input taken is known at (odometry: its end)
        self._group_at = [k for k, (_, item) in enumerate(self.items) if isinstance(item, list)]  # detection groups
        if self.feed is not None:
            if t0 is None:
                raise ValueError("NetNode: with a live feed, start the node first (node.start(t0))")
            self.w = float(t0)
            self.feed.on_push = wake

    @property
    def live(self) -> bool:
        """A live feed that has not ended: inputs may still come."""
        return self.feed is not None and not self.feed.exhausted

    def next_key(self) -> tuple[float, int]:
        """``(stamp, priority)`` of the node's next input (a detection group 1, odometry 2; ``(inf, 3)``: none left).
        With a live feed and nothing read yet, a lower bound of it: ``(watermark, 1)``."""
        if self.i >= len(self.items):
            if self.live:
                return (self.w, 1)
            return (math.inf, 3)
        s, item = self.items[self.i]
        return (s, 2 if isinstance(item, Odometry) else 1)

    def next_group(self) -> float:
        """The stamp of the node's next detection group (inf: none); with a live feed, at most its watermark (its
        groups to come are at or after it)."""
        k = bisect_left(self._group_at, self.i)
        t = self.items[self._group_at[k]][0] if k < len(self._group_at) else math.inf
        return min(t, self.w) if self.live else t

    def pull(self, t0: float) -> float:
        """Take what the live feed released: append it to ``items`` (grouped). Returns the time [s] up to which the
        robot's inputs are known: the latest input, or the watermark (time went on), but not more than the feed's
        ``max_ahead`` past the input (or past ``t0``, the node's start, before any input)."""
        assert self.feed is not None  # a live node's
        new, w = self.feed.take()
        self.w = max(self.w, w)
        if new:
            base, more = len(self.items), groups(new)
            self.items.extend(more)
            self._group_at.extend(base + k for k, (_, item) in enumerate(more) if isinstance(item, list))
            for e in new:
                self._hi = max(self._hi, float(e.t))
        w = self.w if math.isfinite(self.w) else -math.inf  # inf: the stream ended
        return max(self._hi, min(w, max(self._hi, t0) + self.feed.max_ahead))
