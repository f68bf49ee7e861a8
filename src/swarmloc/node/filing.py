"""How a node files its inputs: entries put into the history and applied, late ones replayed, the horizon kept.

The history (:mod:`~swarmloc.node.history`) holds the entries and the states after them; :class:`Filing` owns it
and applies an entry to the state before it: odometry sets its robot's command, a detection group is fused (its
outcomes re-counted on a replay, so nothing is counted twice), a neighbour's update applied. Every robot an entry
involves is first predicted to the entry's stamp with the command in force; past the end of that command's odometry
interval the robot is predicted as stopped (:mod:`~swarmloc.node.inputs`). The filter's steps are the node's hooks
(:class:`FilingHost`: the estimators override them); the answers a replay changes are revised by the node's exchange
(its ``_revise``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from typing import Any, Protocol

from swarmloc.messages import Message, RdlUpdate, TeamUpdate
from swarmloc.node.accounting import Accounting
from swarmloc.node.associate import AssociationView
from swarmloc.node.clock import Clock
from swarmloc.node.history import PRUNE_EVERY, History
from swarmloc.node.inputs import CONTIGUOUS, OdometryTimeline
from swarmloc.node.keys import Entry, Group, Key, Position
from swarmloc.node.trust import GATED, Trust, gated_answers
from swarmloc.node.update import Outcome

log = logging.getLogger("swarmloc.node")

__all__ = ["Filing", "FilingHost", "changed"]


class FilingHost(Protocol):
    """What the filing asks of its node (:class:`~swarmloc.node.base.Node`): the filter's steps (hooks the
    estimators override), the answers a replay changes revised, the pruning of the node's records, and the timing
    switch (``measure_time``, settable on a node or its class) with its ``timing`` counters."""

    measure_time: bool
    timing: dict[str, float]

    def _advance(self, s: Any, robot: int, t: float) -> Any: ...
    def _set_command(self, s: Any, robot: int, v: float, w: float) -> Any: ...
    def _advance_commands(self, s: Any, cmds: Sequence[tuple[float, int, float, float]]) -> Any: ...
    def _associate(self, s: Any, g: Group) -> AssociationView | None: ...
    def _fuse_group(self, s: Any, g: Group) -> tuple[Any, list[Outcome], list[Message]]: ...
    def _settle(self, g: Group) -> list[Message]: ...
    def _apply_update(self, s: Any, u: Message) -> tuple[Any, bool]: ...
    def _revise(self, after: Key) -> list[Message]: ...
    def _prune(self) -> None: ...


def changed(e: Entry, msgs: list[Message]) -> list[Message]:
    """Messages a (re-)applied entry produced that differ from what it sent last time; an update it no longer
    produces (e.g. now gated) is retracted with an empty one."""
    out = []
    new = {(m.receiver, m.sub): m for m in msgs}
    for k, old in list(e.sent.items()):
        if k not in new and isinstance(old, RdlUpdate | TeamUpdate) and not old.empty:
            e.sent[k] = old.retraction()
            out.append(e.sent[k])
    for k, m in new.items():
        if e.sent.get(k) != m:
            e.sent[k] = m
            out.append(m)
    return out


class Filing:
    """A node's history and how entries join it (module docstring). Its own state: the history, the odometry
    timeline (the command in force), the key of the entry being applied (``cursor``: the command in force is the one
    before it), the inputs filed since the last pruning, and the intervals past whose end a robot was counted as
    stopped. Its collaborators: the node (``host``), its clock (the present moves with accepted stamps), accounting
    and trust (outcomes re-counted); ``lazy``: the node's ``lazy_odometry``."""

    def __init__(self, host: FilingHost, lazy: bool, clock: Clock, accounting: Accounting, trust: Trust) -> None:
        self.host = host
        self.lazy = lazy
        self.clock = clock
        self.accounting = accounting
        self.trust = trust
        self.history = History(self.advance_run, lazy)
        self.timeline = OdometryTimeline()
        self.cursor: Key = (-math.inf, 0, 0, ())
        self.since_prune = 0
        self.stops: set[tuple[int, float]] = set()

    def set_lazy(self, lazy: bool) -> None:
        """Whether command entries appended in order are left to a later run (``lazy``), here and in the history."""
        self.lazy = lazy
        self.history.lazy = lazy

    def prune(self, cutoff: float) -> None:
        """Forget entries and odometry intervals stamped before ``cutoff``."""
        self.history.prune(cutoff)
        self.timeline.prune(cutoff)

    # ------------------------------------------------------------------------------------------------ prediction
    def timed_advance(self, s: Any, robot: int, t: float) -> Any:
        """The node's ``_advance``, timed with ``measure_time``."""
        host = self.host
        if not host.measure_time:
            return host._advance(s, robot, t)
        t_start = time.perf_counter()
        s2 = host._advance(s, robot, t)
        if s2 is not s:
            host.timing["predict_s"] += time.perf_counter() - t_start
            host.timing["predict_n"] += 1
        return s2

    def adv(self, s: Any, robot: int, t: float, after: Position | None = None) -> Any:
        """``s``, the state after the entries keyed before ``after`` (default: the entry being applied), with
        ``robot`` predicted to ``t``; past the end of the odometry interval in force the robot is stopped there."""
        iv = self.timeline.in_force(robot, self.cursor if after is None else after)
        if iv is not None and t > iv[1] + CONTIGUOUS:
            s = self.host._set_command(self.timed_advance(s, robot, iv[1]), robot, 0.0, 0.0)
            self.stopped(robot, iv[1])
        return self.timed_advance(s, robot, t)

    def stopped(self, robot: int, t1: float) -> None:
        """Count (once) that ``robot`` is predicted as stopped after its odometry interval ending at ``t1``."""
        if (robot, t1) not in self.stops:
            self.stops.add((robot, t1))
            self.accounting.counts["odometry_stops"] += 1
            log.info("%s: robot %s has no odometry from %.9g s: predicted as stopped", self.accounting.name, robot, t1)

    def advance_run(self, s: Any, run: Sequence[Entry]) -> Any:
        """The state after a run of command entries (the node's ``_advance_commands`` of :meth:`command_run`)."""
        return self.host._advance_commands(s, self.command_run(run))

    def command_run(self, run: Sequence[Entry]) -> list[tuple[float, int, float, float]]:
        """The commands of a run of command entries, with a stop ``(t1, robot, 0, 0)`` before every command whose
        robot's previous interval ended before it started (a gap in its odometry)."""
        out = []
        for e in run:
            t0 = e.key[0]
            robot = e.data[0]
            iv = self.timeline.in_force(robot, e.key)
            if iv is not None and t0 > iv[1] + CONTIGUOUS:
                out.append((iv[1], robot, 0.0, 0.0))
                self.stopped(robot, iv[1])
            out.append((t0, *e.data))
        return out

    # ------------------------------------------------------------------------------------------------ history
    def file(self, entries: list[Entry], accept: bool = True) -> list[Message]:
        """Put new entries into the history and apply them (replaying what follows a late one); with ``accept``
        their stamps move the node's present (not for a placeholder the node files itself)."""
        hist = self.history
        for e in entries if accept else ():
            self.clock.accept(e.key[0])
        if len(entries) == 1 and (not hist.keys or hist.keys[-1] < entries[0].key):  # in order: the common case
            entry = entries[0]
            hist.append(entry)
            out: list[Message] = []
            if not (self.lazy and entry.kind == "odometry"):
                entry.state, out, void = self.apply(hist.state_at(len(hist) - 2), entry)
                if void:
                    hist.remove(len(hist) - 1)
            out += self.host._revise(entry.key)  # (none when no answer is keyed after it: the common case)
        else:
            for e in entries:
                hist.insert(hist.position(e.key), e)
            out = self.replay(min(hist.position(e.key) for e in entries), late=True)
        self.since_prune += len(entries)
        if self.since_prune >= PRUNE_EVERY:
            self.since_prune = 0
            self.host._prune()
        return out

    def replay(self, pos: int, late: bool, changed_at: Key | None = None) -> list[Message]:
        """Re-apply the entries from ``pos`` on, re-count their outcomes, and revise the answers they change
        (those keyed after ``changed_at``, the first key whose state may differ: default the entry at ``pos``)."""
        if changed_at is None:
            changed_at = self.history.keys[pos]
        out, replayed = self.history.replay(pos, self.apply)
        if late:
            self.accounting.counts["late"] += 1
            self.accounting.counts["replayed"] += replayed
        return out + self.host._revise(changed_at)

    def commit_group(self, key: Key, g: Group) -> list[Message]:
        """Put a group whose answers are all in (or given up) into the history and apply it."""
        pos = self.history.find(key)
        if pos is not None:  # merge into the applied group
            old: Group = self.history.entries[pos].data
            for d in g.detections:
                old.add(d)
            old.answers.update({k: v for k, v in g.answers.items() if v is not None})
            return self.replay(pos, late=True)
        if key[0] < self.clock.present - self.clock.horizon:  # waited too long: beyond the horizon now
            for d in g.detections:
                self.accounting.detection_rejected(d.observer, d.t, "older than the history horizon")
            return []
        return self.file([Entry(key, "group", g)])

    def apply(self, s: Any, e: Entry) -> tuple[Any, list[Message], bool]:
        """Apply one history entry to the state before it: ``(state after, messages, entry now void)``."""
        self.cursor = e.key
        if e.kind == "odometry":
            robot, v, w = e.data
            return self.host._set_command(self.adv(s, robot, e.key[0]), robot, v, w), [], False
        if e.kind == "group":
            return self.apply_group(s, e)
        s, applies = self.host._apply_update(s, e.data)  # a neighbour's update
        return s, [], not applies

    def apply_group(self, s: Any, e: Entry) -> tuple[Any, list[Message], bool]:
        """Apply a detection group (the observer predicted to its stamp, its anonymous detections given identities
        by the node's association), re-counting its outcomes, association, suspects and ledger marks."""
        g: Group = e.data
        host = self.host
        s = self.adv(s, g.observer, g.t)
        view = host._associate(s, g)
        if host.measure_time:
            t_start, p_before = time.perf_counter(), host.timing["predict_s"]
            s, outcomes, msgs = host._fuse_group(s, g if view is None else view.group)
            host.timing["fuse_s"] += time.perf_counter() - t_start - (host.timing["predict_s"] - p_before)
            host.timing["fuse_n"] += 1
        else:
            s, outcomes, msgs = host._fuse_group(s, g if view is None else view.group)
        if view is not None:
            msgs = msgs + host._settle(view.group)
        if view is not None or e.assoc:
            outcomes, assoc = view.outcomes(outcomes) if view is not None else (outcomes, {})
            self.accounting.recount_counters(e.assoc, assoc)
            e.assoc = assoc
        self.accounting.recount(e.outcomes, outcomes)
        e.outcomes = outcomes
        if view is None and (e.suspects or GATED in outcomes):  # gated answers count against their teammates
            suspects = gated_answers(g, outcomes)
            self.trust.recount(e.suspects, suspects)
            e.suspects = suspects
        if self.accounting.ledger is not None:
            marks = [(g.observer, g.t, k, o[0]) for k, o in zip(g.keys, outcomes, strict=True)]
            self.accounting.remark(e.marks, marks)
            e.marks = marks
        return s, changed(e, msgs), False
