"""Trust in teammates: what a node checks their messages against, whom it suspects, and whom it quarantines.

A teammate (an insider: its own valid key) may lie. What the receiver knows to check it with is its own belief (and,
for ``diekf``, its replica of the team's cross-covariances); every check is the node's chi-square gate
(:class:`~swarmloc.node.update.Gate`, probability ``p``, threshold ``gamma_m`` of dimension ``m``). Without a gate
(``gate=None``) a node takes whatever its teammates send, as before (but for a ``diekf`` broadcast that would leave
its covariance not positive definite).

* **Answers** (a teammate's belief or state at the observer's detection) enter the detection's innovation, whose
  covariance the observer computes; the gate refuses a detection whose innovation does not fit (``gated``). A gated
  detection of a robot whose answer it used counts against that robot: ``suspect_<robot>`` (recounted when a replay
  re-applies the detection). That is evidence, not proof: the gate cannot tell a teammate's lie from the observer's
  own outlier or its own error (on MRCLAM dataset 6, honest pairs have up to 14 detections gated in a row, with
  normalized innovations up to 1.4e4), so answers never quarantine anyone.
* **Updates** must be corrections that a teammate with the same gate could have sent. ``rdl``/``irdl``: the update
  moves this robot from the state it answered, ``(x, P)``, by ``delta`` (Cartesian, or world-frame for ``irdl``);
  ``delta^T P^-1 delta <= gamma_3``. An honest joint update of a tracked (or independent) pair passes by
  construction: the correction of the joint state satisfies ``delta^T P^-1 delta <= NIS`` (the innovation
  covariance holds the state's), a marginal's Mahalanobis length is at most the joint's, and the observer's gate
  held ``NIS <= gamma_m <= gamma_3``. ``diekf``: a broadcast's own normalized innovation ``nu^T S nu`` (``nu =
  S^-1 r``) ``<= gamma_m``, which the sender's gate held; and the covariance it leaves this robot positive definite
  (else it is not applied: ``updates_unusable``). An update that fails is refused before it reaches the history,
  counted (``updates_refused``, ``messages_rejected`` with the reason) and against its sender (``suspect_<robot>``).
  ``flsd`` broadcasts its landmark updates linearized at its smoothed pose, where its gate does not bound their
  normalized innovation: only the covariance they leave is checked. One more exception: an ``rdl`` pair whose
  correlation is unknown (after a lost exchange) is fused by covariance
  intersection, whose honest correction may reach ``gamma / (1 - w)``; such an update may be refused, which leaves
  the pair untracked, as a lost update does.

**The bound on a lie that passes.** Per message, a lie accepted moves this robot by at most ``sqrt(gamma)`` standard
deviations of its own belief: ``delta^T P^-1 delta <= gamma`` (``rdl``/``irdl`` by the check itself; ``diekf``
because ``delta = Gamma S^-1 r`` with ``delta^T (Gamma S^-1 Gamma^T)^+ delta <= r^T S^-1 r`` and ``Gamma S^-1
Gamma^T < P``, the new covariance being positive definite; a cluster's covariance-intersection broadcast of scale
``w``: ``gamma / w``). A lying answer moves the observer by the same bound through the detection's gate (with an
``rdl`` pair fused by covariance intersection of weight ``w``: ``gamma / w``, ``w >= 0.02``). With ``p = 0.997``:
``gamma_3 = 14.2``, 3.8 standard deviations.

**Quarantine.** After ``quarantine`` (default 3) of a teammate's updates in a row were refused (none accepted
between), it is quarantined for the rest of the run: every later message from it is refused and counted
(``quarantined``, ``quarantined_<robot>``, ``messages_rejected``), a query from it is answered "not found", the
answers it was given are not revised, and this node no longer asks it anything (its detections of it end
``unknown``). Logged once per teammate: the first suspicion and the quarantine.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Mapping, Sequence

import numpy as np

from swarmloc.node.accounting import Accounting
from swarmloc.node.keys import Group
from swarmloc.node.update import Gate, Outcome

log = logging.getLogger("swarmloc.node")

__all__ = [
    "DEFAULT_QUARANTINE",
    "GATED",
    "SLACK",
    "Trust",
    "broadcast_nis",
    "check_quarantine",
    "correction_nis",
    "fits",
    "gated_answers",
]

DEFAULT_QUARANTINE = 3
"""A teammate's updates refused in a row after which it is quarantined."""
SLACK = 1e-6
"""Relative margin of an update's check over the gate's threshold: the receiver recomputes in another order what the
sender's gate compared, and the last bits may differ."""
GATED: Outcome = ("gated", "")
"""The outcome of a detection beyond the chi-square gate."""


def check_quarantine(quarantine: object) -> int | None:
    """``quarantine`` as the node takes it (an integer >= 1, or None: never); ValueError naming it otherwise."""
    if quarantine is None or (isinstance(quarantine, int) and not isinstance(quarantine, bool) and quarantine >= 1):
        return quarantine
    raise ValueError(f"'quarantine' must be an integer >= 1 (refused updates in a row) or None, got {quarantine!r}")


def fits(gate: Gate, nis: float, m: int) -> bool:
    """Whether a normalized innovation squared ``nis`` of dimension ``m`` passes ``gate`` with :data:`SLACK` (always
    without a gate; never when ``nis`` is NaN)."""
    return gate.p is None or nis <= gate.threshold(m) * (1.0 + SLACK)


def correction_nis(delta: np.ndarray, P: np.ndarray) -> float:
    """``delta^T P^-1 delta``: the squared length of a correction ``delta`` in the metric of the covariance ``P`` it
    corrects (inf when ``P`` is singular)."""
    try:
        return float(delta @ np.linalg.solve(P, delta))
    except np.linalg.LinAlgError:
        return math.inf


def broadcast_nis(Sinv: np.ndarray, nu: np.ndarray) -> float:
    """``nu^T S nu = r^T S^-1 r`` of a broadcast carrying ``S^-1`` and ``nu = S^-1 r`` (inf when ``S^-1`` is not
    positive definite: no honest innovation covariance has such an inverse)."""
    try:
        L = np.linalg.cholesky(Sinv)
    except np.linalg.LinAlgError:
        return math.inf
    y = np.linalg.solve(L, nu)
    return float(y @ y)


def gated_answers(g: Group, outcomes: Sequence[Outcome]) -> dict[int, int]:
    """``robot -> count`` of the detections of ``g`` gated (chi-square) with that robot's answer in their
    innovation."""
    out: Counter[int] = Counter()
    for d, o in zip(g.detections, outcomes, strict=True):
        if o == GATED and d.target_is_robot and d.target is not None:
            if any(k[0] == d.target and a is not None and a.found for k, a in g.answers.items()):
                out[d.target] += 1
    return dict(out)


class Trust:
    """One node's suspicions and quarantines (module docstring); ``name``: the node's, for log lines; ``quarantine``:
    refused updates in a row that quarantine a teammate (None: never)."""

    def __init__(self, name: str, quarantine: int | None, accounting: Accounting) -> None:
        self.name = name
        self.after = check_quarantine(quarantine)
        self.accounting = accounting
        self.quarantined: set[int] = set()
        """Teammates quarantined for the rest of the run."""
        self._row: dict[int, int] = {}
        self._told: set[tuple[int, str]] = set()

    def suspects(self) -> dict[int, int]:
        """``robot -> refusals counted against it`` (answers gated, updates refused), those above zero."""
        n = len("suspect_")
        return {int(k[n:]): v for k, v in self.accounting.counts.items() if k.startswith("suspect_") and v > 0}

    def refused(self, sender: int, why: str) -> bool:
        """A teammate's update refused by its check (``why``): counted, logged once per teammate; True when this
        refusal quarantines the sender."""
        counts = self.accounting.counts
        counts["updates_refused"] += 1
        counts[f"suspect_{sender}"] += 1
        self.accounting.message_rejected(why)
        self._tell(sender, "update", "%s: robot %s is suspect: %s", self.name, sender, why)
        row = self._row[sender] = self._row.get(sender, 0) + 1
        if self.after is None or row < self.after or sender in self.quarantined:
            return False
        self.quarantined.add(sender)
        self._tell(sender, "quarantine", "%s: robot %s quarantined for the rest of the run (%d updates in a row "
                   "refused): every later message from it is refused", self.name, sender, row)  # fmt: skip
        return True

    def accepted(self, sender: int) -> None:
        """A teammate's update passed its check: its run of refusals ends."""
        self._row.pop(sender, None)

    def shut_out(self, sender: int) -> bool:
        """True (counted) when ``sender`` is quarantined: its message is refused."""
        if sender not in self.quarantined:
            return False
        counts = self.accounting.counts
        counts["quarantined"] += 1
        counts[f"quarantined_{sender}"] += 1
        self.accounting.message_rejected(f"robot {sender} is quarantined")
        return True

    def recount(self, old: Mapping[int, int], new: Mapping[int, int]) -> None:
        """The gated answers of a re-applied group by teammate (:func:`gated_answers`): the old ones taken back,
        the new ones counted against their teammates."""
        counts = self.accounting.counts
        for r, k in old.items():
            counts[f"suspect_{r}"] -= k
        for r, k in new.items():
            counts[f"suspect_{r}"] += k
            self._tell(r, "answer", "%s: robot %s is suspect: a detection of it gated with its answer", self.name, r)

    def _tell(self, robot: int, what: str, *args: object) -> None:
        if (robot, what) not in self._told:
            self._told.add((robot, what))
            level = logging.INFO if what == "answer" else logging.WARNING
            log.log(level, *args)
