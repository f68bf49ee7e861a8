"""The asking side of the pairwise state exchange that ``rdl``, ``irdl`` and ``diekf`` share: an observer asks the
robot it detected for its filter state at the detection's stamp (:class:`~swarmloc.messages.RdlStateQuery`, one per
detection, keyed by the detection's key), and with an association policy asks every teammate about each anonymous
detection, keyed as the detection would be were it of that teammate (:func:`anonymous_sub`), so that the true
target's exchange is the tagged run's. What the answers are used for (a pairwise update, a broadcast) is the
estimator's; this part only forms the queries and reads the answers back.

The identities are chosen from each teammate's belief **before the scan**: a
:class:`~swarmloc.messages.BeliefQuery` (sub-key ``()``, answered from the state before every key of the scan), not
from the ``RdlStateQuery`` answers. Those are keyed per teammate, so a teammate with a higher id answers from a state
that holds the observer's own update of this scan (``diekf``'s broadcast moves every robot; ``rdl``'s moves the
target of another detection of the scan): a choice made from them depends on itself. On MRCLAM dataset 6 with
``joint`` association, ``diekf`` chose a robot, its broadcast changed the other answers, the choice became "none",
the retraction changed them back, and the exchange never settled (at 604 s of the recording: one answer revised
10,000 times and counting). Cost: ``n - 1`` more queries and answers per scan with anonymous detections.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

from swarmloc.events import Detection
from swarmloc.messages import BeliefQuery, Message, RdlState, RdlStateQuery
from swarmloc.node import Group
from swarmloc.node.associate import is_anonymous
from swarmloc.node.keys import SubKey, detection_key

__all__ = ["StateQueries", "anonymous_sub"]


def anonymous_sub(d: Detection, robot: int) -> tuple[float, ...]:
    """The sub-key of the exchange with ``robot`` for the anonymous detection ``d``: ``d``'s key were it of
    ``robot`` (so that, given ``robot``, the detection is fused under the key a tagged run uses)."""
    return detection_key(replace(d, target=robot))


class StateQueries:
    """The queries of one observer (``robot``) and the answers it reads back: :meth:`requests` (what a group asks),
    :meth:`unused` (answers no detection used); the node reads the candidates from the ``BeliefQuery`` answers."""

    def __init__(self, robot: int) -> None:
        self.robot = robot

    def requests(
        self, g: Group, needs_answer: Callable[[Group, Detection], bool], mates: Sequence[int]
    ) -> list[Message]:
        """One ``RdlStateQuery`` per detection for which ``needs_answer(g, d)`` (sub-key: the detection's key); with
        an anonymous detection, one per anonymous detection and teammate in ``mates`` (sub-key:
        :func:`anonymous_sub`) and one ``BeliefQuery`` per teammate (sub-key ``()``: the candidates)."""
        out: dict[tuple[int, SubKey], Message] = {
            (d.target, k): RdlStateQuery(sender=self.robot, receiver=d.target, stamp=g.t, sub=k)
            for d, k in zip(g.detections, g.keys, strict=True)
            if d.target is not None and needs_answer(g, d)
        }
        anon = [d for d in g.detections if is_anonymous(d)] if mates else []
        for d in anon:
            for r in mates:
                k = anonymous_sub(d, r)
                out.setdefault((r, k), RdlStateQuery(sender=self.robot, receiver=r, stamp=g.t, sub=k))
        if anon:
            for r in mates:
                out.setdefault((r, ()), BeliefQuery(sender=self.robot, receiver=r, stamp=g.t))
        return list(out.values())

    @staticmethod
    def unused(g: Group) -> list[tuple[int, SubKey, RdlState]]:
        """``(teammate, sub-key, answer)`` of every ``RdlStateQuery`` answer of ``g`` (identities given) that no
        detection used: the teammates asked about an anonymous detection that was given another robot, or none."""
        used = {(d.target, k) for d, k in zip(g.detections, g.keys, strict=True) if d.target is not None}
        return [(r, k, a) for (r, k), a in g.answers.items() if (r, k) not in used and isinstance(a, RdlState)]
