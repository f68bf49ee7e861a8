"""How a node takes its own robots' odometry and detections: checked against the input contract
(:mod:`~swarmloc.node.inputs`) and the clock (:mod:`~swarmloc.node.clock`), then filed in the history
(:mod:`~swarmloc.node.filing`); a detection group that needs teammates' answers waits in the exchange
(:mod:`~swarmloc.node.protocol`) until they are in. Inputs that disagree with the clock are held as a possible jump
of the robot's clock; once the jump is confirmed the history is reset and they are filed.
"""

from __future__ import annotations

import logging
import math
from typing import Any, Protocol

from swarmloc.events import Detection, Odometry
from swarmloc.messages import Message
from swarmloc.node.clock import FUTURE
from swarmloc.node.filing import Filing
from swarmloc.node.history import PRUNE_EVERY
from swarmloc.node.inputs import CONTIGUOUS, brief, command_value, odometry_problem, validate_detection
from swarmloc.node.keys import P_GROUP, P_ODOMETRY, Entry, Group, Key, detection_key
from swarmloc.node.protocol import Exchange, not_found, quarantine_reason

log = logging.getLogger("swarmloc.node")

__all__ = ["Intake", "IntakeHost"]


class IntakeHost(Protocol):
    """What the intake asks of its node (:class:`~swarmloc.node.base.Node`): to start it, and its hooks (the
    estimators override them)."""

    def start(self, t0: float) -> None: ...
    def _requests(self, g: Group) -> list[Message]: ...
    def _restamp(self, s: Any, t: float) -> Any: ...
    def _set_command(self, s: Any, robot: int, v: float, w: float) -> Any: ...


class Intake:
    """How a :class:`~swarmloc.node.base.Node` takes its own robots' inputs (module docstring). It keeps no state of
    its own: its collaborators are the node (``host``), its robots, its filing (history, odometry timeline, and the
    node's clock, accounting and trust it was made with) and its exchange (groups waiting for answers, answers
    given)."""

    def __init__(self, host: IntakeHost, robots: tuple[int, ...], filing: Filing, exchange: Exchange) -> None:
        self.host = host
        self.robots = robots
        self.filing = filing
        self.exchange = exchange
        self.history, self.timeline = filing.history, filing.timeline
        self.clock, self.accounting, self.trust = filing.clock, filing.accounting, filing.trust
        self.counts = filing.accounting.counts

    # ------------------------------------------------------------------------------------------------ clock
    def ensure_started(self, t: float) -> None:
        if self.clock.t0 is None:
            self.host.start(t)

    def admit(self, t: float, item: Any) -> list[Message] | None:
        """Check an input of the node's own robots stamped ``t`` against the clock. None: file it (inputs held
        before are then refused: the clock did not jump). Otherwise it is held as a possible clock jump and the
        messages to send are returned (those of the held inputs, filed after a confirmed jump)."""
        verdict = self.clock.side(t)
        if verdict is None:
            if self.clock.held:
                self.refuse_held(self.clock.release())
            return None
        side = verdict[0]
        self.refuse_held(self.clock.hold(t, side, item))
        if self.clock.jumped():
            return self.clock_jump(side)
        return []

    def refuse_held(self, held: list[tuple[float, str, Any]]) -> None:
        """Count inputs held as a possible clock jump, which it was not, as refused with their reason."""
        for t, side, item in held:
            why = self.clock.future(t) if side == FUTURE else self.clock.too_old(t)
            why = why or f"stamp {t} did not agree with the node's clock when it came"
            if side == FUTURE:
                self.counts["future"] += 1 if isinstance(item, Odometry) else len(item)
            if isinstance(item, Odometry):
                self.accounting.odometry_rejected(why)
            else:
                for d in item:
                    self.accounting.detection_rejected(d.observer, d.t, why)

    def clock_jump(self, side: str) -> list[Message]:
        """The robot's clock jumped (the held inputs agree): keep the belief at the present, re-stamped at the
        earliest held stamp; forget the history, the answers given, the groups waiting (``unknown``); then file
        the held inputs."""
        held = self.clock.release()
        t_new = min(t for t, _, _ in held)
        old = self.clock.present
        s = self.history.last_state()
        for r in self.robots:
            s = self.filing.adv(s, r, old, (math.inf,))
        pending = self.exchange.pending
        for key in sorted(pending):
            g = pending.pop(key)
            for d in g.detections:
                self.accounting.detection_rejected(d.observer, d.t, "the robot's clock jumped", "unknown")
        self.history.reset(self.host._restamp(s, t_new), (t_new, -1, -1, ()))
        self.timeline.clear()
        self.exchange.served.clear()
        self.clock.restart(t_new)
        self.counts["clock_jumps" if side == FUTURE else "clock_resets"] += 1
        log.warning("%s: robot clock jumped %s from %.9g s to %.9g s: history reset, belief kept", self.accounting.name,
                    "forward" if side == FUTURE else "back", old, t_new)  # fmt: skip
        out: list[Message] = []
        for t, _, item in sorted(held, key=lambda h: h[0]):
            if isinstance(item, Odometry):
                out += self.take_odometry(item)
            else:
                out += self.take_detections(int(item[0].observer), t, item)
        return out

    # ------------------------------------------------------------------------------------------------ odometry
    def odometry_fast(self, e: Odometry) -> bool:
        """Consume ``e`` if it takes the common path: valid, in order (after every entry), contiguous with its
        robot's last interval, inside the clock, nothing to revise and no pruning due; False (nothing changed)
        otherwise, for the node's ``step`` to handle it. The in-process runner calls it before ``step``."""
        t0, t1, v, w = e.t0, e.t1, e.v, e.w
        clock = self.clock
        filing = self.filing
        if not (type(t0) is type(t1) is type(v) is type(w) is float) or filing.since_prune >= PRUNE_EVERY - 1:
            return False
        robot = e.robot
        start = clock.t0
        if start is None or robot not in self.robots or not (start <= t0 <= t1) or clock.held:
            return False
        present = clock.present
        if not (present - clock.horizon <= t0 <= present + clock.tolerance and t1 <= max(present, t0) + clock.tolerance
                and math.isfinite(v) and math.isfinite(w)):  # fmt: skip
            return False
        last = self.timeline.last(robot)
        if last is not None and not (last[0] < t0 and abs(t0 - last[1]) <= CONTIGUOUS):
            return False
        key: Key = (t0, P_ODOMETRY, robot, ())
        hist = self.history
        latest = self.exchange.served.latest_key()
        if (hist.keys and not hist.keys[-1] < key) or (latest is not None and latest > key):
            return False
        counts = self.counts
        counts["odometry"] += 1
        counts["odometry_used"] += 1
        self.timeline.add(robot, t0, t1)
        entry = Entry(key, "odometry", (robot, v, w))
        if not filing.lazy:
            filing.cursor = key
            entry.state = self.host._set_command(filing.adv(hist.last_state(), robot, t0), robot, v, w)
        hist.append(entry)
        if t0 > present:
            clock.present = t0
        filing.since_prune += 1
        return True

    def on_odometry(self, e: Odometry) -> list[Message]:
        if self.odometry_fast(e):
            return []
        self.counts["odometry"] += 1
        if e.robot not in self.robots:
            self.accounting.odometry_rejected(f"robot {brief(e.robot)} is not a robot of this node")
            return []
        why = odometry_problem(e)
        if why:
            self.accounting.odometry_rejected(why)
            return []
        self.ensure_started(float(e.t0))
        return self.take_odometry(e)

    def take_odometry(self, e: Odometry) -> list[Message]:
        """File a well-formed odometry record of this node's robot (counted in): clock, duplicates, overlaps,
        then the command and the stops its gaps need."""
        held = self.admit(float(e.t0), e)
        if held is not None:
            return held
        t0, t1 = float(e.t0), float(e.t1)
        if t1 > max(self.clock.present, t0) + self.clock.tolerance:
            self.counts["future"] += 1
            self.accounting.odometry_rejected(f"interval ends at {t1:.9g} s, {self.clock.future(t1)}")
            return []
        key: Key = (t0, P_ODOMETRY, e.robot, ())
        pos = self.history.find(key)
        if pos is not None:
            _, v, w = self.history.entries[pos].data
            why = "duplicate" if (v, w) == (e.v, e.w) else "a different command at the same t0"
            self.accounting.odometry_rejected(why)
            return []
        overlap = self.timeline.overlap(e.robot, t0, t1)
        if overlap:
            self.accounting.odometry_rejected(overlap)
            return []
        self.counts["odometry_used"] += 1
        self.timeline.add(e.robot, t0, t1)
        return self.filing.file([Entry(key, "odometry", (e.robot, command_value(e.v), command_value(e.w)))])

    # ------------------------------------------------------------------------------------------------ detections
    def on_detections(self, dets: list[Detection]) -> list[Message]:
        groups: dict[tuple[int, float], list[Detection]] = {}
        for d in dets:
            self.counts["detections"] += 1
            why = validate_detection(d)
            if why is None and d.observer not in self.robots:
                why = f"observer {brief(d.observer)} is not a robot of this node"
            if why is not None:
                self.accounting.detection_rejected(d.observer, d.t, why)
                continue
            groups.setdefault((int(d.observer), float(d.t)), []).append(d)
        out: list[Message] = []
        for (obs, t), ds in groups.items():
            self.ensure_started(t)
            out += self.take_detections(obs, t, ds)
        return out

    def take_detections(self, observer: int, t: float, ds: list[Detection]) -> list[Message]:
        """File well-formed detections of one observer at one instant (counted in): clock, then the group."""
        held = self.admit(t, ds)
        if held is not None:
            return held
        return self.add_detections(observer, t, ds)

    def add_detections(self, observer: int, t: float, ds: list[Detection]) -> list[Message]:
        key: Key = (t, P_GROUP, observer, ())
        pending_groups = self.exchange.pending
        pending = pending_groups.get(key)
        g = pending if pending is not None else Group(observer, t)
        pos = self.history.find(key)
        applied: Group | None = self.history.entries[pos].data if pos is not None else None
        added = []
        for d in ds:
            if (applied is not None and detection_key(d) in applied.keys) or not g.add(d):
                self.accounting.detection_rejected(d.observer, d.t, "duplicate detection")
            else:
                added.append(d)
        if not added:
            return []
        if applied is not None:  # the answers already received serve the new detections too
            g.answers = {**applied.answers, **g.answers}
        queries = [q for q in self.host._requests(g) if (q.receiver, q.sub) not in g.answers]
        shut = self.trust.quarantined  # nothing is asked of a quarantined teammate: answered here, not found
        for q in queries:
            g.answers[(q.receiver, q.sub)] = not_found(q, quarantine_reason(q.receiver)) if q.receiver in shut else None
        queries = [q for q in queries if q.receiver not in shut]
        if queries or (pending is not None and g.waiting()):
            pending_groups[key] = g
            return queries
        pending_groups.pop(key, None)
        return self.filing.commit_group(key, g)
