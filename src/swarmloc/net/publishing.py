"""What a :class:`~swarmloc.net.process.NetNode` publishes: its progress and its beliefs.

**Progress.** The key of the node's next input (:class:`~swarmloc.net.schema.Progress`), which its teammates'
lockstep waits on (:mod:`swarmloc.net.lockstep`).

**Beliefs.** At each record time ``t`` the node publishes its belief once its history has passed ``t``
(provisional) and again once it is final (the history is a horizon past ``t``, or the run ended); a final belief
that a later message still changes is published again with a higher revision. With ``ros_domain`` each belief is
also published as a ROS 2 ``geometry_msgs/msg/PoseWithCovarianceStamped`` under rmw_zenoh's key layout.

**Delayed output.** A smoother node with its delayed output on (``fls`` / ``flsd`` with ``delayed=True``,
:attr:`swarmloc.estimators.fls.WindowSolver.lagged_log`) files each pose as it leaves the window; once that filing
is final (the history is a horizon past the solve that filed it, or the run ended) it is published once as a final
:class:`~swarmloc.net.schema.Belief` stamped at the pose's instant on ``robot/<id>/delayed`` (a filing that a
replay changes later is published again with a higher revision), then dropped from the node: what a long run keeps
stays bounded.

**Lines.** With range scans (``scans``), once the node's belief at a scan's time is final (the same horizon rule),
the scan's lines carried into the world with that belief (:func:`swarmloc.mapping.scan_observations`, second
order) are published once as :class:`~swarmloc.net.schema.Lines` on ``robot/<id>/lines`` for the belief server's
map (at most :data:`~swarmloc.net.schema.MAX_LINES`; a scan without lines publishes nothing).
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np

from swarmloc.arrays import FloatArray
from swarmloc.kernels import cartesian as C
from swarmloc.messages import flat
from swarmloc.net.schema import MAX_LINES, Belief, Lines, Progress, group_tag
from swarmloc.node import Node

Put = Callable[[str, Any], None]
"""``put(kind, message)``: sign and publish ``message`` on the robot's ``kind`` key (``belief``, ``progress``,
``delayed``, ``lines``): the node's wiring (:meth:`~.wiring.Wiring.put`)."""


def lagging(node: Node) -> bool:
    """Whether ``node`` files a delayed output (a smoother's, ``lagged_log`` set): published on ``delayed``."""
    return getattr(node, "lagged_log", None) is not None


class Announcer:
    """Part of :class:`~swarmloc.net.process.NetNode`: announcing its progress, the key of its next input, which
    its teammates' lockstep waits on (rate-limited). ``next_key``: ``(stamp, priority)`` of the node's next input
    (:meth:`~swarmloc.net.inputs.Inputs.next_key`); ``lag``: [s] the lockstep slack; ``moved``: how many times what
    it waits on moved (:attr:`~swarmloc.net.lockstep.Lockstep.moved`), announced with it."""

    def __init__(
        self, robot: int, lag: float, put: Put, next_key: Callable[[], tuple[float, int]], moved: Callable[[], int]
    ) -> None:
        self.robot, self.lag, self.put, self.next_key, self.moved = robot, lag, put, next_key, moved
        self.last = -math.inf  # the last progress announced: its stamp, wall time and key
        """The stamp last announced."""
        self.last_wall = 0.0
        """When it was announced (monotonic s)."""
        self._last_key: tuple[float, int] = (-math.inf, 0)

    def announce(self, t: float, done: bool = False, force: bool = False) -> None:
        """Announce the next input's key (rate-limited to every ``lag / 4`` s of data or 0.2 s of wall time unless
        ``force``: a node about to wait forces it, since teammates may be waiting for it)."""
        now = time.monotonic()
        key = self.next_key()
        if not force and t - self.last < self.lag / 4 and now - self.last_wall < 0.2:
            return
        if force and key == self._last_key and not done and now - self.last_wall < 0.2:
            return
        self.last = t
        self._last_key = key
        self.last_wall = now
        self.put("progress", Progress(robot=self.robot, t=key[0], prio=key[1], done=done, moved=self.moved()))


class Publishing:
    """Part of :class:`~swarmloc.net.process.NetNode`: publishing the beliefs of ``node`` (owning robot ``robot``)
    at its record times, its delayed output and its scans' lines (see the module docstring).

    ``put``: publishes a message (:data:`Put`); ``ros``: ``ros(t, belief)`` publishes a belief on ROS too (None:
    not); ``unsettled``: what may still change the state at a key (:meth:`~.lockstep.Lockstep.unsettled`), for
    ``on_settled``; ``counts``: the node's network counters (``beliefs_published``...); ``record_times``,
    ``scans``, ``on_belief``, ``on_lines``, ``on_settled``: the node's (:class:`~swarmloc.net.process.NetNode`)."""

    def __init__(
        self,
        node: Node,
        robot: int,
        counts: Counter[str],
        put: Put,
        record_times: FloatArray,
        *,
        unsettled: Callable[[tuple[Any, ...]], str | None],
        ros: Callable[[Any, Any], None] | None = None,
        scans: Any = None,
        on_belief: Callable[[Belief], None] | None = None,
        on_lines: Callable[[Lines], None] | None = None,
        on_settled: Callable[[float, Any], None] | None = None,
    ) -> None:
        self.node, self.robot, self.counts, self.put, self.unsettled = node, robot, counts, put, unsettled
        self.ros, self.scans = ros, scans
        self.on_belief, self.on_lines, self.on_settled = on_belief, on_lines, on_settled
        self.record_times = record_times
        """Times [s] at which the belief is published (a live node's grow: :meth:`extend`)."""
        self.published: dict[float, Belief] = {}
        """The latest belief published per record time (two horizons)."""
        self._prov = 0  # record times published provisionally ...
        self.final = 0
        """Record times published final (the first ones)."""
        self._pruned_at = 0
        self._scan_i = 0  # scans whose lines are published (or had none)
        self._settled_at = 0  # record times handed to on_settled
        self.delayed: dict[float, Belief] | None = {} if lagging(node) else None
        """The delayed poses published (pruned); None: the node has no delayed output."""
        self._delayed_due: dict[float, None] = {}  # stamps filed whose filing is not final yet
        if self.delayed is not None:
            smoother: Any = node  # a smoother's attributes are not Node's
            smoother.lagged_fresh = []

    def extend(self, times: FloatArray) -> None:
        """Append record times (after the last)."""
        self.record_times = np.concatenate([self.record_times, times])

    def record_until(self, hi: float, t0: float, rate: float) -> None:
        """Append the record times every ``1 / rate`` s [Hz] from ``t0`` [s] up to ``hi`` [s] (a live node's)."""
        k0 = self.record_times.size
        k1 = math.floor((hi - t0) * rate + 1e-9) + 1
        if k1 > k0:
            self.extend(t0 + np.arange(k0, k1) / rate)

    def behind(self, s: float) -> bool:
        """Whether a final belief is due before an input stamped ``s`` is applied (its pruning could drop it)."""
        rt = self.record_times
        return self.final < rt.size and s - self.node.horizon > rt[self.final]

    def _belief(self, t: float, final: bool) -> None:
        """Publish the belief at record time ``t`` unless the same was published (a new revision otherwise)."""
        try:
            b = self.node.belief_at(float(t))
        except ValueError:
            self.counts["record_too_old"] += 1
            return
        old = self.published.get(t)
        mean, cov = flat(b.mean), flat(b.cov)
        if old is not None and old.mean == mean and old.cov == cov and (old.final or not final):
            return  # nothing new: same numbers, and not a provisional belief becoming final
        rev = 0 if old is None else old.rev + 1
        msg = Belief(robot=self.robot, stamp=float(t), rev=rev, final=final, mean=mean, cov=cov, group=group_tag(b))
        self.published[t] = msg
        self.put("belief", msg)
        self.counts["beliefs_published"] += 1
        if self.on_belief is not None:
            self.on_belief(msg)
        if self.ros is not None:
            self.ros(t, b)

    def _lines(self, k: int) -> None:
        """Publish the world lines of scan ``k`` with the node's (final) belief at its time."""
        from swarmloc.mapping import scan_observations
        from swarmloc.net.server import wire_line

        sc, t = self.scans, float(self.scans.times[k])
        try:
            b = self.node.belief_at(t)
        except ValueError:
            self.counts["scan_too_old"] += 1
            return
        obs = scan_observations(sc.ranges[k], sc.angles, sc.sigma, b.mean, b.cov, self.robot, t)[:MAX_LINES]
        if not obs:
            return
        lines = tuple(wire_line(o.rho, o.alpha, o.cov, o.endpoints, o.end_var, o.closed) for o in obs)
        msg = Lines(robot=self.robot, stamp=t, lines=lines)
        self.put("lines", msg)
        if self.on_lines is not None:
            self.on_lines(msg)
        self.counts["lines_published"] += len(lines)

    def _delayed_out(self, delayed: dict[float, Belief], end: bool, wm: float) -> None:
        """Publish the delayed poses whose filing is final (``end``: all filed), then drop them from the node;
        ``delayed``: the poses published so far (``_delayed``)."""
        node: Any = self.node  # a smoother's (fls, ``lagged_log`` set): its lagged_* attributes and lag
        for ts in node.lagged_fresh:
            self._delayed_due[ts] = None
        node.lagged_fresh.clear()
        cut = wm - node.horizon
        for ts in [ts for ts in self._delayed_due if end or node.lagged_when[ts] < cut]:
            del self._delayed_due[ts]
            x, P = node.lagged_log.pop(ts)
            node.lagged_when.pop(ts)
            node.lagged_scale.pop(ts, None)
            g, gcov = C.to_group(x, P)
            mean, cov = flat(g), flat(gcov)
            old = delayed.get(ts)
            if old is not None and old.mean == mean and old.cov == cov:
                continue
            rev = 0 if old is None else old.rev + 1
            msg = Belief(robot=self.robot, stamp=float(ts), rev=rev, final=True, mean=mean, cov=cov)
            delayed[ts] = msg
            self.put("delayed", msg)
            self.counts["delayed_published"] += 1
        if len(delayed) > 4096:  # forget poses filed two horizons back
            for ts in [t for t in delayed if t < cut - node.horizon - node.lag]:
                del delayed[ts]

    def settled(self, end: bool = False) -> None:
        """Hand ``on_settled`` the belief at each record time, in order, once it is settled: the node's own source
        has passed it, and :meth:`~.lockstep.Lockstep.unsettled` finds nothing keyed at or before it that the team
        may still read or apply (teammates' progress and broadcasts, updates expected, own groups waiting). Without
        faults the belief is then final; at the end (``end``) every record time left is handed over as it stands."""
        if self.on_settled is None:
            return
        rt = self.record_times
        while self._settled_at < rt.size:
            t = float(rt[self._settled_at])
            if not end and self.unsettled((t, 3, -1, ())) is not None:
                return
            try:
                b = self.node.belief_at(t)
            except ValueError:
                self.counts["settled_too_old"] += 1
            else:
                self.on_settled(t, b)
                self.counts["settled_published"] += 1
            self._settled_at += 1

    def due(self, end: bool = False, upto: float = -math.inf) -> None:
        """Publish the beliefs due: provisional ones up to the node's present, final ones a horizon before it (or before
        ``upto``: called before an input stamped ``upto`` is applied, whose pruning could drop them otherwise)."""
        rt = self.record_times
        wm = max(self.node.present, upto)
        while self._prov < rt.size and (end or rt[self._prov] <= wm):
            self._belief(rt[self._prov], final=False)
            self._prov += 1
        while self.final < rt.size and (end or rt[self.final] < wm - self.node.horizon):
            self._belief(rt[self.final], final=True)
            self.final += 1
        if self.scans is not None:
            sc = self.scans
            while self._scan_i < sc.times.size and (end or sc.times[self._scan_i] < wm - self.node.horizon):
                self._lines(self._scan_i)
                self._scan_i += 1
        if self.delayed is not None:
            self._delayed_out(self.delayed, end, wm)
        if self.final - self._pruned_at >= 256:  # forget beliefs no input can change any more (two horizons back)
            self._pruned_at = self.final
            cut = wm - 2 * self.node.horizon
            for t in [t for t in self.published if t < cut]:
                del self.published[t]

    def republish_changed(self) -> None:
        """After the end: publish again every final belief (and delayed pose) a late message changed."""
        if self.delayed is not None:
            self._delayed_out(self.delayed, True, self.node.present)
        for t in sorted(self.published):
            old = self.published[t]
            try:
                b = self.node.belief_at(t)
            except ValueError:
                continue
            if flat(b.mean) != old.mean or flat(b.cov) != old.cov:
                self.counts["finals_revised"] += 1
                self._belief(t, final=True)
