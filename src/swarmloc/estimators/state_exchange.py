"""The asking side of the pairwise state exchange that ``rdl``, ``irdl`` and ``diekf`` share: an observer asks the
robot it detected for its filter state at the detection's stamp (:class:`~swarmloc.messages.RdlStateQuery`, one per
detection, keyed by the detection's key), and with an association policy asks every teammate about each anonymous
detection, keyed as the detection would be were it of that teammate (:func:`anonymous_sub`), so that the true
target's exchange is the tagged run's. What the answers are used for (a pairwise update, a broadcast) is the
estimator's; this part only forms the queries and reads the answers back.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from swarmloc.events import Detection
from swarmloc.gaussian import GroupGaussian
from swarmloc.messages import Message, RdlState, RdlStateQuery
from swarmloc.node import Group
from swarmloc.node.associate import is_anonymous
from swarmloc.node.keys import SubKey, detection_key

__all__ = ["StateQueries", "anonymous_sub"]

BeliefOf = Callable[[float, np.ndarray, np.ndarray, int], GroupGaussian]
"""``(stamp [s], x, P, robot) -> belief``: a teammate's belief from the state it answered with (the estimator's
convention)."""


def anonymous_sub(d: Detection, robot: int) -> tuple[float, ...]:
    """The sub-key of the exchange with ``robot`` for the anonymous detection ``d``: ``d``'s key were it of
    ``robot`` (so that, given ``robot``, the detection is fused under the key a tagged run uses)."""
    return detection_key(replace(d, target=robot))


class StateQueries:
    """The queries of one observer (``robot``) and the answers it reads back: :meth:`requests` (what a group asks),
    :meth:`candidates` (teammates' beliefs for association), :meth:`unused` (answers no detection used)."""

    def __init__(self, robot: int) -> None:
        self.robot = robot

    def requests(
        self, g: Group, needs_answer: Callable[[Group, Detection], bool], mates: Sequence[int]
    ) -> list[Message]:
        """One ``RdlStateQuery`` per detection for which ``needs_answer(g, d)`` (sub-key: the detection's key) and
        one per anonymous detection and teammate in ``mates`` (sub-key: :func:`anonymous_sub`)."""
        out = {
            (d.target, k): RdlStateQuery(sender=self.robot, receiver=d.target, stamp=g.t, sub=k)
            for d, k in zip(g.detections, g.keys, strict=True)
            if d.target is not None and needs_answer(g, d)
        }
        for d in g.detections if mates else ():
            if is_anonymous(d):
                for r in mates:
                    k = anonymous_sub(d, r)
                    out.setdefault((r, k), RdlStateQuery(sender=self.robot, receiver=r, stamp=g.t, sub=k))
        return list(out.values())

    @staticmethod
    def candidates(g: Group, mates: Sequence[int], belief: BeliefOf) -> dict[int, GroupGaussian]:
        """Each teammate's belief at the stamp from its answer to the group's first anonymous detection's query
        (the state before that key: the same as a ``BeliefQuery``'s unless the observer's own updates of this scan
        keyed before it reached the teammate)."""
        anon = [d for d in g.detections if is_anonymous(d)]
        out = {}
        for r in mates:
            for d in anon:
                a: Any = g.answers.get((r, anonymous_sub(d, r)))
                if a is not None and a.found:
                    x, P, _ = a.arrays()
                    out[r] = belief(float(a.stamp), x, P, r)
                    break
        return out

    @staticmethod
    def unused(g: Group) -> list[tuple[int, SubKey, RdlState]]:
        """``(teammate, sub-key, answer)`` of every ``RdlStateQuery`` answer of ``g`` (identities given) that no
        detection used: the teammates asked about an anonymous detection that was given another robot, or none."""
        used = {(d.target, k) for d, k in zip(g.detections, g.keys, strict=True) if d.target is not None}
        return [(r, k, a) for (r, k), a in g.answers.items() if (r, k) not in used and isinstance(a, RdlState)]
