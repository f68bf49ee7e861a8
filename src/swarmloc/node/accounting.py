"""A node's accounting: every input ends counted, and the counters always add up.

Detections end in exactly one of ``fused``, ``gated`` (innovation beyond the chi-square gate), ``rejected``
(with a reason) or ``unknown`` (target not known or not answering); until then they are ``pending`` (waiting for
an answer, or held while the node decides whether its robot's clock jumped). A replay takes an entry's old
outcomes back before counting the new ones, so nothing is counted twice. Odometry is ``odometry_used`` or
``odometry_rejected`` (or pending while held). Messages in are counted, and ``messages_rejected`` with a reason.
Teammates' updates refused by their check, messages of quarantined teammates, and the refusals counted against each
teammate (``updates_refused``, ``quarantined``, ``suspect_<robot>``): :mod:`~swarmloc.node.trust`.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterable, Mapping

from swarmloc.node.associate import ASSOCIATION_KEYS
from swarmloc.node.keys import Mark
from swarmloc.node.update import Outcome

log = logging.getLogger("swarmloc.node")

__all__ = ["MAX_REASONS", "OTHER_REASONS", "OUTCOMES", "STAT_KEYS", "Accounting", "reason_key"]

MAX_REASONS = 256
"""The most distinct reasons a counter of reasons keeps: a reason may quote the numbers of what it refuses (a
stamp), so that a stream of refused messages would otherwise grow it without bound; past it a new reason is counted
under :data:`OTHER_REASONS`."""
MAX_REASON_CHARS = 300
"""A reason is counted under its first this many characters."""
OTHER_REASONS = "(other reasons: more than 256 distinct)"


def reason_key(reasons: Mapping[str, int], reason: str) -> str:
    """The key to count ``reason`` under in ``reasons``: itself (its first :data:`MAX_REASON_CHARS` characters) while
    fewer than :data:`MAX_REASONS` distinct ones are counted, else :data:`OTHER_REASONS`."""
    reason = reason[:MAX_REASON_CHARS]
    return reason if reason in reasons or len(reasons) < MAX_REASONS else OTHER_REASONS


OUTCOMES = ("fused", "gated", "rejected", "unknown")
STAT_KEYS = (
    "detections", *OUTCOMES, "pending", "odometry", "odometry_used", "odometry_rejected", "odometry_pending",
    "odometry_stops", "late", "replayed", "future", "clock_resets", "clock_jumps", "messages",
    "messages_rejected", "answers_sent", "not_yet_sent", "revisions_sent", "updates_refused", "updates_unusable",
    "quarantined", *ASSOCIATION_KEYS,
)  # fmt: skip
"""Keys of :meth:`Accounting.stats` (every one present, zeros included)."""


class Accounting:
    """Counters, reasons and the optional per-measurement ledger of one node (``name`` for log lines)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.counts: Counter[str] = Counter()
        """Counters (see :meth:`stats`)."""
        self.reasons: Counter[str] = Counter()
        """Why inputs were rejected or unknown: ``"<outcome>: <reason>"`` -> count."""
        self.ledger: Counter[Mark] | None = None
        """Set to a Counter to track the outcome of every applied detection by measurement id: ``(observer, t,
        detection key, outcome) -> count`` (replays take the old outcome back). A correct node has, for every
        measurement, exactly one outcome counted once: nothing fused twice."""

    def outcome(self, o: Outcome, sign: int = 1) -> None:
        self.counts[o[0]] += sign
        if o[1]:
            self.reasons[f"{o[0]}: {o[1]}"] += sign

    def recount(self, old: Iterable[Outcome], new: Iterable[Outcome]) -> None:
        """An entry re-applied: its old outcomes taken back, its new ones counted."""
        for o in old:
            self.outcome(o, -1)
        for o in new:
            self.outcome(o)

    def recount_counters(self, old: Mapping[str, int], new: Mapping[str, int]) -> None:
        """Counters of a re-applied entry (e.g. its association's): the old ones taken back, the new ones counted."""
        for k, v in old.items():
            self.counts[k] -= v
        for k, v in new.items():
            self.counts[k] += v

    def remark(self, old: Iterable[Mark], new: Iterable[Mark]) -> None:
        """The ledger's marks of a re-applied group: the old ones taken back, the new ones counted."""
        if self.ledger is not None:
            for m in old:
                self.ledger[m] -= 1
            for m in new:
                self.ledger[m] += 1

    def detection_rejected(self, observer: object, t: object, reason: str, outcome: str = "rejected") -> None:
        self.outcome((outcome, reason))
        log.debug("%s: detection by %s at t=%s %s: %s", self.name, observer, t, outcome, reason)

    def odometry_rejected(self, reason: str) -> None:
        self.counts["odometry_rejected"] += 1
        self.reasons[f"odometry rejected: {reason}"] += 1
        log.debug("%s: odometry rejected: %s", self.name, reason)

    def message_rejected(self, reason: str) -> None:
        """A neighbour's message refused (its reason counted: :func:`reason_key`, a message's numbers in it)."""
        self.counts["messages_rejected"] += 1
        self.reasons[reason_key(self.reasons, f"message rejected: {reason}")] += 1
        log.debug("%s: message rejected: %s", self.name, reason)

    def stats(self, pending: int, odometry_pending: int) -> dict[str, int]:
        """A copy of the counters, every key of :data:`STAT_KEYS` present, with the detections and odometry
        still ``pending``: ``detections == fused + gated + rejected + unknown + pending`` and ``odometry ==
        odometry_used + odometry_rejected + odometry_pending`` at all times."""
        out = dict.fromkeys(STAT_KEYS, 0)
        out.update(self.counts)
        out["pending"] = pending
        out["odometry_pending"] = odometry_pending
        return out
