"""The vocabulary of a node's history: keys, entries and detection groups.

Every input is filed in the history under a **key** ``(t, priority, robot, sub)``:

* a command (odometry) of ``robot`` starting at ``t0``: ``(t0, P_ODOMETRY, robot, ())``;
* the detections one observer made at one instant form one group: ``(t, P_GROUP, observer, ())``;
* a neighbour's update keyed by its detection: ``(t, P_GROUP, neighbour, sub)``.

Keys order the history: at one stamp, detection groups come before commands (a command starting at ``t`` moves
the robot only after ``t``), and among groups the lower robot id first.
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import Any, cast

import numpy as np

from swarmloc.events import Detection
from swarmloc.messages import Answer, Message
from swarmloc.sensors.models3 import ALL_MODELS

__all__ = ["P_GROUP", "P_ODOMETRY", "Entry", "Group", "Key", "Mark", "Position", "SubKey", "detection_key"]

SubKey = tuple[float, ...]
"""A detection's place in its group (:func:`detection_key`); ``()`` for a whole group or an odometry interval."""

Key = tuple[float, int, int, SubKey]
"""History key ``(stamp [s], priority, robot id, sub-key)``."""

Position = Key | tuple[float]
"""A place in the history: a :data:`Key`, or ``(t,)``: before every entry stamped ``t`` (``(inf,)``: after all)."""

Mark = tuple[int, float, SubKey, str]
"""A ledger mark: ``(observer, stamp [s], detection key, outcome)`` (:class:`~swarmloc.node.accounting.Accounting`)."""

P_GROUP = 1
P_ODOMETRY = 2


def detection_key(d: Detection) -> SubKey:
    """Canonical order of the detections in a group (and the sub-key of per-detection exchanges)."""
    target = -1.0 if d.target is None else float(d.target)
    order = float(ALL_MODELS[d.kind].order)
    return (order, 0.0 if d.target_is_robot else 1.0, target, *np.asarray(d.z, float).tolist())


class Group:
    """The detections one observer made at one instant, in canonical order, and the neighbours' answers."""

    __slots__ = ("observer", "t", "detections", "keys", "answers")

    def __init__(self, observer: int, t: float) -> None:
        self.observer = observer
        self.t = t
        self.detections: list[Detection] = []
        self.keys: list[SubKey] = []
        self.answers: dict[tuple[int, SubKey], Answer | None] = {}

    @property
    def key(self) -> Key:
        return (self.t, P_GROUP, self.observer, ())

    def add(self, d: Detection) -> bool:
        """Insert ``d`` in canonical order; False when an identical detection is already there."""
        k = detection_key(d)
        i = bisect_left(self.keys, k)
        if i < len(self.keys) and self.keys[i] == k:
            return False
        self.keys.insert(i, k)
        self.detections.insert(i, d)
        return True

    def waiting(self) -> bool:
        """True while an answer it asked for has not come."""
        return any(v is None for v in self.answers.values())


_NOTHING_SENT: Mapping[Any, Any] = MappingProxyType({})  # only group entries send messages


class Entry:
    """One history entry: its key, what it is (``kind``: ``"odometry"``, ``"group"`` or ``"update"``, a
    neighbour's), its data, and the filter state after it (None: not computed yet, a command of a node
    whose filter predicts runs of commands at once; the history computes it when it is needed)."""

    __slots__ = ("key", "kind", "data", "state", "outcomes", "sent", "marks", "assoc", "suspects")

    def __init__(self, key: Key, kind: str, data: Any) -> None:
        self.key = key
        self.kind = kind
        self.data = data
        self.state: Any = None
        self.outcomes: Sequence[tuple[str, str]] = ()  # replaced, never appended to
        # a group's own dict; every other entry shares the read-only empty mapping (a write to it would raise)
        self.sent: dict[tuple[int, SubKey], Message] = (
            {} if kind == "group" else cast("dict[tuple[int, SubKey], Message]", _NOTHING_SENT)
        )
        self.marks: Sequence[Mark] = ()  # replaced, never appended to
        self.assoc: Mapping[str, int] = _NOTHING_SENT  # association counters of a group (swarmloc.node.associate)
        self.suspects: Mapping[int, int] = _NOTHING_SENT  # a group's gated answers by teammate (swarmloc.node.trust)
