"""One robot = one process: a :class:`~swarmloc.node.base.Node` driven over a Zenoh session.

:class:`NetNode` is the network driver of the sans-I/O node. It reads the robot's own events from its source,
steps the node, and carries the messages the node returns: a query to a neighbour is a Zenoh ``get`` on the
neighbour's ``query`` key (the reply is the answer), a revised answer or a pairwise update is a ``put`` on the
receiver's ``inbox``. Everything received is authenticated (with ``auth``: signed by the member it names,
:mod:`swarmloc.net.auth`), decoded and validated (:func:`swarmloc.net.schema.decode`) on the node's one thread;
a bad message is dropped, counted with its reason, and logged; the node keeps running.

Parts, one job each, each an object the node holds that owns its state and meets the others through a few methods,
given what it needs when it is made: ``inbound`` (:mod:`~swarmloc.net.inbound`: the queue, decoding with its
bounds, queries, pushed messages, replies), ``lockstep`` (:mod:`~swarmloc.net.lockstep`: the teammates, and when to
read an input, answer a query, release an answer), ``outbound`` (:mod:`~swarmloc.net.outbound`: sending: link faults,
outbox, queries, timers; its envelopes, ``envelopes``), ``broadcaster`` (:mod:`~swarmloc.net.broadcast`: a team
estimator's broadcasts), ``wiring`` (:mod:`~swarmloc.net.wiring`: the Zenoh declarations), ``publishing`` and
``announcer`` (:mod:`~swarmloc.net.publishing`: beliefs, progress), ``inputs`` (:mod:`~swarmloc.net.inputs`: its
own events, recorded or live). Its settings: :class:`~swarmloc.net.settings.NetSettings`. This module holds stepping
the node, and the loop.

**Time and determinism.** Stamps are the source's (data) clock; wall time only paces. Lockstep: a node reads its
next input (stamp ``s``) once every live teammate it waits for (all; ``diekf`` in clusters on a recording: its
cluster and the robots it detects or is detected by, :func:`~swarmloc.net.lockstep.watched`) has announced
(:class:`~swarmloc.net.schema.Progress`) that it
has read its own source up to ``s - lag`` (the node with the lowest next stamp can always go on, so this never
deadlocks), with ``speed > 0`` not before ``(s - t_start) / speed`` wall seconds, and not more than half a horizon
past its own oldest detection group still waiting for answers. A detection group is read only once every teammate
has read its source up to the group's key and no ``rdl`` update keyed before it is expected. A query is answered
only once nothing keyed before it can still change the answer (:meth:`~swarmloc.net.lockstep.Lockstep.ready`).
Groups are thus applied across the team in key order, as :func:`swarmloc.runner.run` applies them, the first answer
is the final one, and the networked run equals the in-process run on the same events (tested to 1e-6; measured: equal).

**Missing answers.** A query that gets no valid reply within ``answer_timeout`` s is asked of the belief server
(with ``use_server``, a belief query only: the server holds no pair factors of an ``RdlStateQuery``; it gets
``answer_timeout`` s too), then of its robot again while the robot is alive and the
stamp within the horizon: ``answer_retries`` times, and more while less than ``lost_timeout`` s have passed since
the first ask (a Zenoh get drops a reply that comes after its timeout, so an answer held or stalled past
``answer_timeout`` would be lost); the detection group waits meanwhile, as lockstep holds it. Only when no ask is
left does the node get a "not found" answer (revision ``-2``) with the reason, so the detection ends ``unknown``
instead of waiting forever; a real answer that still arrives later (revision >= 0; the server's: -1) replaces it
and is replayed if it is within the horizon. (A "not found" given at the first timeout let the group go on without
the answer, which the answer to a later ask did not always undo: ``rdl`` on MRCLAM 6 once 0.084 m from the
in-process run in CI; ``benchmarks/short_waits.py``, docs/benchmarks.md.)
A neighbour's query held ``hold_timeout`` s without its state settling is answered as things stand, and revised if
they change. An ``rdl`` update expected for ``update_timeout`` s is given up. Pushed revisions and updates are
coalesced, the newest per exchange: those one batch of received messages makes
(:meth:`~swarmloc.net.inbound.Inbound.drain`), and with link faults all every ``coalesce`` s.

**Timeouts**, one name per wait, in seconds of wall time: :mod:`swarmloc.net.timeouts`.

**Beliefs.** At each record time ``t`` the node publishes its belief once its history has passed ``t``
(provisional) and again once it is final (the history is a horizon past ``t``, or the run ended); a final belief
that a later message still changes is published again with a higher revision. With ``ros_domain`` each belief is
also published as a ROS 2 ``geometry_msgs/msg/PoseWithCovarianceStamped`` under rmw_zenoh's key layout.

**The end.** When its source is exhausted the node announces ``Progress(t=inf)``; once every live member has and
the node has been idle (no reply outstanding, nothing queued) for ``quiet`` s, it expires what still waits,
publishes its final beliefs, announces ``done`` and its :class:`~swarmloc.net.schema.Report`, and keeps answering
until every live member it waits for is done and ``quiet`` s passed without traffic (at most ``linger`` s).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from swarmloc.events import Event
from swarmloc.messages import TeamUpdate
from swarmloc.net.auth import Auth
from swarmloc.net.broadcast import Broadcaster
from swarmloc.net.feed import LiveFeed
from swarmloc.net.hearing import hearing_of
from swarmloc.net.inbound import Inbound
from swarmloc.net.inputs import Inputs
from swarmloc.net.intake import Intake, vouch_for
from swarmloc.net.lockstep import Lockstep
from swarmloc.net.outbound import Envelopes, Outbound
from swarmloc.net.publishing import Announcer, Publishing, lagging
from swarmloc.net.schema import SERVER, Belief, Lines, Progress, Report
from swarmloc.net.settings import NetSettings
from swarmloc.net.teamlink import TeamLink
from swarmloc.net.wiring import Wiring
from swarmloc.node import Node

log = logging.getLogger(__name__)

WAIT_NOTE = 1.0
"""[s] A live node that has waited this long for its next input says what it waits for (a warning) ..."""
WAIT_NOTE_EVERY = 10.0
"""[s] ... and again every so often while it still waits."""


class NetNode:
    """Drive ``node`` (owning one robot) over ``session`` with ``events`` (that robot's own, in stamp order).

    Parameters
    ----------
    team, roster: the team's name and robot ids (messages from anybody else are dropped).
    record_times: times [s] at which the robot's belief is published.
    settings: how it runs (:class:`~swarmloc.net.settings.NetSettings`: pace, waits, end, server, faults, ROS);
        its fields may be given as keywords too (``lag=1.0``), replacing those of ``settings``.
    events: the robot's own events, or a :class:`~swarmloc.net.feed.LiveFeed` its inputs are pushed to as they happen
        (the run ends once the feed has ended and everything in it was read).
    on_belief, on_lines: called with each belief and each :class:`~swarmloc.net.schema.Lines` it publishes.
    on_settled: called with each record time's belief once it is settled (see the attribute).
    auth: this robot's key and the team's roster (:class:`~swarmloc.net.auth.Auth`): everything it sends is signed,
        everything it receives must be signed by the member it claims to come from (refusals counted
        ``auth_<category>``); None: an unauthenticated team (tests on one machine, a trusted network).
    scans: this robot's range scans (see the attribute).
    detected: ``(observer, target)`` of every robot detection of the team's run, when known in advance (a recording:
        :func:`~swarmloc.net.lockstep.detected_pairs`): with ``diekf`` in clusters, lockstep then waits only for the
        cluster and the robots this one detects or is detected by (:func:`~swarmloc.net.lockstep.watched`); None: for
        every teammate.
    """

    def __init__(
        self,
        node: Node,
        events: Sequence[Event] | LiveFeed,
        *,
        session: Any,
        team: str,
        roster: Iterable[int],
        record_times: Sequence[float] | np.ndarray = (),
        settings: NetSettings | None = None,
        on_belief: Callable[[Belief], None] | None = None,
        on_lines: Callable[[Lines], None] | None = None,
        on_settled: Callable[[float, Any], None] | None = None,
        auth: Auth | None = None,
        scans: Any = None,
        detected: Iterable[tuple[int, int]] | None = None,
        **kw: Any,
    ) -> None:
        if len(node.robots) != 1:
            raise ValueError("NetNode drives a node of one robot (a distributed estimator)")
        self.settings = settings = NetSettings.of(settings, kw)
        """How it runs (:class:`~swarmloc.net.settings.NetSettings`; a live feed's: ``speed`` 0)."""
        self.node = node
        self.robot = node.robots[0]
        link = TeamLink(session, team, roster, auth, settings.run_id).signing_as(self.robot, "NetNode")
        self.session, self.team, self.auth = link.session, link.team, link.auth
        self.scope, self.roster = link.scope, link.roster
        if self.robot not in self.roster:
            raise ValueError(f"robot {self.robot} is not in the roster {sorted(self.roster)}")
        faults = settings.faults
        self.faults = faults if faults is not None and faults.link else None
        self.link = self.faults.plan(self.robot) if self.faults else None
        wait_for = settings.wait_for
        self.wait_for = set(self.roster - {self.robot}) if wait_for is None else set(wait_for) - {self.robot}
        self.counts: Counter[str] = Counter()
        """Network counters: ``received``, ``rejected`` (with ``reasons``), ``sent``, ``lost``/``duplicated``/
        ``delayed`` (injected), ``no_reply``, ``server_answers``, ``beliefs_published``..."""
        self.reasons: Counter[str] = Counter()
        intake = Intake(self.roster | {SERVER}, signed=auth is not None, team_size=len(self.roster),
                        vouch=None if auth is None else vouch_for(auth))  # fmt: skip
        self._stop = threading.Event()
        self._last_status = 0.0
        self._wait_note = math.inf  # when to say next that the node waits for its live inputs (monotonic)
        self._waiting_since = 0.0  # since when it waits (monotonic)
        self.inputs = Inputs(events, node.t0, wake=lambda: self.inbound.wake())
        """Its own inputs, from a recording or a live feed (:class:`~.inputs.Inputs`)."""
        if self.inputs.feed is not None:
            self.settings = settings = replace(settings, speed=0.0)  # a live source is paced by its arrivals
        self.broadcasts = TeamUpdate in node.update_types
        """The node's estimator broadcasts its updates to the whole team (``diekf``: :mod:`.broadcast`)."""
        mates, self.watched, self.hearing = hearing_of(node, self.robot, self.broadcasts, detected)
        """The teammates whose progress it waits for, and subscribes to (:func:`~.lockstep.watched`; None: all); with
        re-forming clusters, whom it hears follows the schedule (:class:`~.hearing.Hearing`; None: it stays)."""
        self.envelopes = Envelopes(auth, team, self.robot)
        """What it sends, numbered in one sequence and sealed (:class:`~.outbound.Envelopes`)."""
        seal = self.envelopes.seal
        self.wiring = Wiring(session, self.scope, team, self.robot, intake.offer, seal, auth=auth, mates=mates,
                             watched=["*"] if self.watched is None else [str(r) for r in sorted(self.watched)],
                             delayed=lagging(node), lines=scans is not None,
                             ros_domain=settings.ros_domain)  # fmt: skip
        """Its Zenoh declarations, and publishing on its own keys (:class:`~.wiring.Wiring`)."""
        self.lockstep = Lockstep(node, self.robot, self.roster, settings, self.counts, next_key=self.inputs.next_key,
                                 step=self._step, others=lambda key: self.broadcaster.unsettled(key),
                                 watched=self.watched)  # fmt: skip
        """The teammates; when to read an input, answer a query, release an answer (:class:`~.lockstep.Lockstep`)."""
        self.outbound = Outbound(node, self.robot, self.roster, self.scope, settings, self.counts,
                                 wiring=self.wiring, seal=seal, intake=intake, lockstep=self.lockstep, step=self._step,
                                 broadcast=lambda m: self.broadcaster.queue(m), link=self.link,
                                 faults=self.faults)  # fmt: skip
        """Sending: link faults, the outbox, its queries, timers (:class:`~.outbound.Outbound`)."""
        self.broadcaster: Broadcaster = Broadcaster(
            node, self.robot, self.counts, active=self.broadcasts, wiring=self.wiring, seal=seal,
            outbound=self.outbound, lockstep=self.lockstep, step=self._step,
            reject=lambda reason, where: self.inbound.reject(reason, where), next_group=self.inputs.next_group,
            delay=self.faults.delay if self.faults else 0.0)  # fmt: skip
        """A team estimator's broadcasts (:class:`~.broadcast.Broadcaster`)."""
        if self.hearing is not None:
            self.hearing.attach(self.wiring, self.lockstep, self.broadcaster)
        self.inbound: Inbound = Inbound(
            self.robot, team, self.roster, auth, self.counts, self.reasons, intake=intake, stop=self._stop,
            lockstep=self.lockstep, outbound=self.outbound, broadcaster=self.broadcaster, step=self._step,
            flush=self._flush)  # fmt: skip
        """What it receives: its queue, decoded and handled (:class:`~.inbound.Inbound`)."""
        times = np.asarray(record_times, dtype=float)
        self.publishing = Publishing(node, self.robot, self.counts, self.wiring.put, times,
                                     unsettled=self.lockstep.unsettled, ros=self.wiring.put_ros, scans=scans,
                                     on_belief=on_belief, on_lines=on_lines, on_settled=on_settled)  # fmt: skip
        """Its beliefs, delayed output and scans' lines, published (:class:`~.publishing.Publishing`)."""
        self.announcer = Announcer(
            self.robot, settings.lag, self.wiring.put, self.inputs.next_key, lambda: self.lockstep.moved
        )
        """Its progress, announced (:class:`~.publishing.Announcer`)."""

    def _step(self, item: Any, query: Any = None) -> None:
        """Step the node with ``item`` (answering the Zenoh ``query`` with it if given) and send what it returns.
        A message stamped past the node's present moves it: the beliefs that become final are published first,
        before the history's pruning can drop what they are computed from (as before a source input)."""
        stamp, now = getattr(item, "stamp", None), self.node.present
        if isinstance(stamp, int | float) and now < stamp <= now + self.node.tolerance:  # past it: refused (future)
            self.publishing.due(upto=stamp)
        out = self.node.step(item)
        if self.hearing is not None:  # re-forming clusters: a boundary reached changes whom it hears
            self.hearing.follow()
        if out or query is not None:
            self.outbound.route(out, query, item)
        if not self.inbound.draining:  # within a drain, what the batch pushes goes out once at its end (Inbound.drain)
            self._flush()

    def _flush(self, force: bool = False) -> None:
        """Send what the node pushed: a team estimator's broadcasts (:meth:`~.broadcast.Broadcaster.flush`), then the
        outbox (:meth:`~.outbound.Outbound.flush`)."""
        if self.broadcasts:  # only a team estimator's node broadcasts (and announces heads)
            self.broadcaster.flush(force)
        self.outbound.flush(force)

    def stop(self) -> None:
        """Ask :meth:`run` to finish (from another thread or a signal handler)."""
        self._stop.set()
        self.inbound.wake()

    def run(self, max_wall: float | None = None) -> Report:
        """Run until the source is exhausted and the team settled (or :meth:`stop`, or ``max_wall`` s)."""
        t_wall0, t_cpu0 = time.perf_counter(), time.process_time()
        deadline = math.inf if max_wall is None else time.monotonic() + max_wall
        self.wiring.open()
        try:
            self.announcer.announce(self.inputs.items[0][0] if self.inputs.items else math.inf, force=True)
            self._wait_start(deadline)
            self._main(deadline)
            if not self._stop.is_set():
                self._finish(deadline)
        finally:
            report = self.report(time.perf_counter() - t_wall0, time.process_time() - t_cpu0)
            self.wiring.close(lambda: self._say_done(report))
        return report

    def _say_done(self, report: Report) -> None:
        """The node's last messages: its progress, done, and its ``report``."""
        self.wiring.put("progress", Progress(robot=self.robot, t=math.inf, done=True))
        key = self.wiring.key("report")
        self.session.put(key, self.envelopes.seal(report, key), congestion_control=self.wiring.block)

    def _wait_start(self, deadline: float) -> None:
        """Wait for the robots of ``wait_for`` (and, with ``use_server``, the belief server) to be alive: at most
        ``start_timeout`` s, and not past ``deadline``; saying for whom (a warning once 2 s passed, then every 5 s).
        The server is waited for because what is published before it subscribed (a scan's lines) never reaches it."""
        t0, wait, server = time.monotonic(), self.settings.start_timeout, self.settings.use_server
        end, note = min(t0 + wait, deadline), t0 + 2.0

        def missing() -> str:
            alive = self.lockstep.alive
            who = [f"robots {sorted(self.wait_for - alive)}"] if not self.wait_for <= alive else []
            return " and ".join(who + (["the belief server"] if server and not self.lockstep.server_up else []))

        if missing():
            log.info("robot %s: waiting up to %.0f s for %s to be alive", self.robot, wait, missing())
        while missing() and time.monotonic() < end and not self._stop.is_set():
            if time.monotonic() >= note:
                note += 5.0
                log.warning("robot %s: still waiting for %s to be alive (%.0f s left)", self.robot, missing(),
                            end - time.monotonic())  # fmt: skip
            self.inbound.drain(0.05)
            self.announcer.announce(self.announcer.last, force=True)
        if missing():
            log.warning("robot %s: starting without %s (not alive after %.1f s)", self.robot, missing(),
                        time.monotonic() - t0)  # fmt: skip

    def _main(self, deadline: float) -> None:
        inputs = self.inputs
        items, feed = inputs.items, inputs.feed
        t_start = items[0][0] if items else 0.0
        w0 = time.monotonic()
        while not self._stop.is_set():
            if feed is not None:
                self._pull()
            if inputs.i >= len(items) and (feed is None or feed.exhausted):
                break
            if time.monotonic() > deadline:
                log.warning("robot %s: wall-time limit reached at %d/%d inputs", self.robot, inputs.i, len(items))
                self._stop.set()
                break
            self.inbound.drain(0)
            self.lockstep.answer_ready()
            self.lockstep.release()
            self._flush()
            self.publishing.settled()
            self._status()
            wait = self.outbound.sends.run_timers()
            if inputs.i >= len(items):  # a live feed with nothing released yet: tell the team how far it is, wait
                self._say_waiting(inputs.i)
                self.announcer.announce(inputs.w)
                self.inbound.drain(min(wait, 0.02))
                continue
            self._wait_note = math.inf
            s, item = items[inputs.i]
            if self.settings.speed > 0:
                due = w0 + (s - t_start) / self.settings.speed - time.monotonic()
                if due > 0:
                    self.announcer.announce(self.announcer.last)  # every 0.2 s: a paced node is not silent
                    self.inbound.drain(min(due, wait, 0.05))
                    continue
            if not self.lockstep.may_feed(s) or (isinstance(item, list) and not self.lockstep.group_may_go(s)):
                self.lockstep.check_lost(s)
                self.announcer.announce(s, force=True)
                self.inbound.drain(min(wait, 0.02))
                continue
            if self.publishing.behind(s):
                self.publishing.due(upto=s)
            self._step(item)
            inputs.i += 1
            self.lockstep.answer_ready()
            i = inputs.i
            self.announcer.announce(items[i][0] if i < len(items) else inputs.w if feed is not None else math.inf)
            self.publishing.due()
        inputs.i = len(items)
        self.lockstep.answer_ready()
        self.announcer.announce(math.inf, force=True)

    def _say_waiting(self, taken: int) -> None:
        """While a live node has nothing to do, say (a warning: shown without ``--verbose``) what it waits for: its
        input keys and the teammates not alive; once :data:`WAIT_NOTE` s after it began to wait, then every
        :data:`WAIT_NOTE_EVERY` s."""
        now = time.monotonic()
        if self._wait_note == math.inf:
            self._wait_note, self._waiting_since = now + WAIT_NOTE, now
        if now < self._wait_note:
            return
        self._wait_note = now + WAIT_NOTE_EVERY
        missing = sorted(self.wait_for - self.lockstep.alive)
        assert self.inputs.feed is not None  # a live node's
        log.warning("robot %s: waiting %.0f s for its inputs on %s (%d taken so far; teammates alive %s%s)", self.robot,
                    now - self._waiting_since, self.inputs.feed.listens_on or "its live source", taken,
                    sorted(self.lockstep.alive),
                    f", not alive {missing}" if missing else "")  # fmt: skip

    def _pull(self) -> None:
        """Take what the live feed released (:meth:`~.inputs.Inputs.pull`); with ``record_rate``, add the record
        times up to the time its inputs are known to (:meth:`~.publishing.Publishing.record_until`)."""
        t0 = self.node.t0
        assert t0 is not None  # a live node is started before it runs (Inputs)
        known = self.inputs.pull(t0)
        if self.settings.record_rate is not None:
            self.publishing.record_until(known, t0, self.settings.record_rate)

    def _status(self) -> None:
        now = time.monotonic()
        if now - self._last_status > 2.0:
            self._last_status = now
            log.info("robot %s: %d/%d inputs, present %.2f, pending %d, deferred %d, expecting %d, outstanding %d; "
                     "node %s; net %s", self.robot, self.inputs.i, len(self.inputs.items), self.node.present,
                     self.node.pending,
                     len(self.lockstep.deferred), len(self.lockstep.expect), len(self.outbound.outstanding),
                     {k: v for k, v in self.node.stats().items() if v}, dict(self.counts))  # fmt: skip

    def _idle(self) -> bool:
        return not (self.outbound.busy() or self.lockstep.busy() or self.broadcaster.busy())

    def _finish(self, deadline: float) -> None:
        """Wait for the team to finish its sources (a teammate that goes silent is lost after ``lost_timeout`` s) and
        the traffic to settle (at most ``linger`` s once they have), then publish the final beliefs."""
        quiet_since, all_read_since = time.monotonic(), math.inf
        while not self._stop.is_set() and time.monotonic() < deadline:
            got = self.inbound.drain(0.02)
            self.lockstep.answer_ready()
            self.lockstep.release()
            self._flush()
            self._status()
            self.outbound.sends.run_timers()
            if time.monotonic() - self.announcer.last_wall > 0.2:
                self.announcer.announce(math.inf, force=True)
            if got or not self._idle():
                quiet_since = time.monotonic()
            all_read = self.lockstep.all_read()
            if not all_read:
                self.lockstep.check_lost(math.inf)
            now = time.monotonic()
            all_read_since = min(all_read_since, now) if all_read else math.inf
            if all_read and now - quiet_since >= self.settings.quiet:
                break
            if now - all_read_since > self.settings.linger:
                self.counts["never_settled"] += 1
                log.warning("robot %s: traffic still not settled %.0f s after the team read its sources; finishing",
                            self.robot, self.settings.linger)  # fmt: skip
                break
        self.outbound.route(self.node.expire())
        self._flush(force=True)
        self.publishing.due(end=True)
        self.publishing.settled(end=True)
        self.announcer.announce(math.inf, done=True, force=True)
        t_end = time.monotonic() + self.settings.linger
        quiet_since = time.monotonic()
        while not self._stop.is_set() and time.monotonic() < min(t_end, deadline):
            got = self.inbound.drain(0.02)
            self.outbound.sends.run_timers()
            self._flush()
            if got:
                self.outbound.route(self.node.expire())
                self.publishing.republish_changed()
                quiet_since = time.monotonic()
            if time.monotonic() - self.announcer.last_wall > 0.2:
                self.announcer.announce(math.inf, done=True, force=True)
            settled = self.lockstep.waited() <= self.lockstep.done and self._idle()
            if settled and time.monotonic() - quiet_since >= self.settings.quiet:
                break

    def report(self, wall: float = 0.0, cpu: float = 0.0) -> Report:
        self.inbound.intake.fold(self.counts, self.reasons)
        net = dict(self.counts, teammates_seen=len(self.lockstep.seen))
        if self.auth is not None:  # the per-pair sessions' counters (handshakes, renewals, twins)
            net.update(self.auth.session_counts())
        if self.inputs.feed is not None:  # a live source: what its inputs brought, and what was refused (by reason)
            net.update(self.inputs.feed.summary())
        if self.link is not None:
            net.update(injected_lost=self.link.lost, injected_dup=self.link.duplicated)
        return Report(
            robot=self.robot,
            stats={k: int(v) for k, v in self.node.stats().items()},
            reasons={k: int(v) for k, v in self.node.reasons.items()},
            net={k: int(v) for k, v in net.items()},
            net_reasons={k: int(v) for k, v in self.reasons.items()},
            wall_s=wall,
            cpu_s=cpu,
        )
