"""An incremental source for a :class:`~swarmloc.net.process.NetNode`: a robot's own inputs pushed as they happen.

A recorded source gives the driver the whole list of a robot's events up front. A live robot's inputs arrive in
real time, from other threads (the Python API, a Zenoh subscriber): :class:`LiveFeed` is the thread-safe queue
between them and the driver's one thread.

**Order and determinism.** The driver reads a robot's inputs in key order (a detection group at ``t`` before
odometry starting at ``t``; odometry is filed at its start ``t0``) and tells its teammates how far it has read
(:class:`~swarmloc.net.schema.Progress`): that announcement must be a lower bound of every input it will still
read, or the team's run would depend on timing. So the feed holds what it receives in a reorder buffer and
releases an input only once its stamp is below the *watermark* ``W``: nothing stamped before ``W`` can come any
more. ``W`` is the largest of

* the watermark announced explicitly (:meth:`LiveFeed.advance`, a publisher's progress message; :meth:`end`
  makes it ``inf``);
* implicitly, ``min(latest - window, odometry end)``: ``latest`` the largest time any input is known at (a
  detection's ``t``, odometry's ``t1``: encoders report an interval once it is over), ``window`` [s] the reorder
  slack of the transport, and ``odometry end`` the ``t1`` of the latest odometry (the next interval starts there, so
  nothing is still missing before it but detections, which arrive within ``window``). A robot without odometry
  (``odometry=False``) uses ``latest - window`` alone.

An input that arrives stamped before ``W`` is refused (``stale``: the driver may have read past it); one stamped
more than ``max_ahead`` s past the latest known time (or the start) is refused (``future``); odometry that starts
before the previous one ended is refused (``overlap``); more than ``max_items`` waiting refuses the newest
(``queue_full``); non-finite stamps or values are ``bad_value``. Every refusal is counted with its reason
(:attr:`LiveFeed.reasons`) and logged once per reason, the first :data:`MAX_KEPT` refused events kept with it
(:attr:`LiveFeed.refused`); nothing raises on the pushing thread except a non-event.
The run then equals the in-process replay of the inputs the feed accepted (tested to 1e-6).
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import logging
import math
import threading
import time
from collections import Counter
from typing import Any

import numpy as np

from swarmloc.events import Detection, Event, Odometry

log = logging.getLogger(__name__)

END_GRACE = 5.0
"""[s] wall time an end announced with a count waits for inputs still on their way."""

MAX_ITEMS = 100_000
"""Inputs waiting in one feed at most (a robot at 100 Hz odometry and detections holds far fewer)."""

MAX_KEPT = 100
"""Refused events kept with their reason (:attr:`LiveFeed.refused`); the later ones are only counted."""


class InputRefusals:
    """Refused inputs counted and logged in one way: each as ``total`` in ``counts`` and under its reason in
    ``reasons`` (holding ``lock`` when one is given), the first of each reason logged to ``logger`` at WARNING as
    ``"<what> refused (<reason>): <detail> (further ones counted)"``, the later ones counted only. The feed, the live
    input layers (:mod:`swarmloc.live`) and the middlewares' receive path (:mod:`swarmloc.rmw.inbox`) each keep one.
    """

    def __init__(self, what: str, counts: Counter[str], reasons: Counter[str], logger: logging.Logger, *,
                 total: str = "refused", lock: threading.Lock | None = None) -> None:  # fmt: skip
        self.what, self.counts, self.reasons, self.log = what, counts, reasons, logger
        self.total, self.lock = total, lock

    def __call__(self, reason: str, detail: object) -> None:
        """Count one input refused for ``reason``; ``detail`` (what it was) is logged with the first of its reason."""
        with self.lock or contextlib.nullcontext():
            self.counts[self.total] += 1
            self.reasons[reason] += 1
            first = self.reasons[reason] == 1
        if first:
            self.log.warning("%s refused (%s): %s (further ones counted)", self.what, reason, detail)


class LiveFeed:
    """Robot ``robot``'s inputs as they arrive (module docstring): :meth:`push` from any thread, the driver
    :meth:`take`\\ s the released ones in key order.

    Parameters
    ----------
    robot: the robot whose odometry and detections (as observer) this feed carries; others are refused
        (``not_own``).
    t0: [s] the node's start: nothing before it is accepted; the first reference for ``max_ahead``.
    window: [s] reorder slack (see the module docstring).
    max_ahead: [s] how far past the latest known time a stamp may be.
    max_items: inputs waiting at most.
    odometry: the robot reports odometry (its intervals advance the watermark); False: detections only.
    """

    def __init__(
        self,
        robot: int,
        t0: float,
        *,
        window: float = 0.2,
        max_ahead: float = 60.0,
        max_items: int = MAX_ITEMS,
        odometry: bool = True,
    ) -> None:
        for name, v in (("t0", t0), ("window", window), ("max_ahead", max_ahead)):
            if not math.isfinite(float(v)) or (name != "t0" and float(v) < 0):
                raise ValueError(f"LiveFeed: {name} must be finite{'' if name == 't0' else ' and >= 0'}, got {v!r}")
        if int(max_items) < 1:
            raise ValueError(f"LiveFeed: max_items must be >= 1, got {max_items!r}")
        self.robot = int(robot)
        self.t0 = float(t0)
        self.window = float(window)
        self.max_ahead = float(max_ahead)
        self.max_items = int(max_items)
        self.odometry = bool(odometry)
        self.counts: Counter[str] = Counter()
        """``accepted``, ``refused``, ``released``."""
        self.reasons: Counter[str] = Counter()
        """Refusals by reason (``stale``, ``future``, ``overlap``, ``queue_full``, ``bad_value``, ``not_own``,
        ``ended``)."""
        self.refused: list[tuple[str, Odometry | Detection]] = []
        """The first :data:`MAX_KEPT` events refused, with their reason: what a replay of the inputs sent leaves out
        to be the replay of what the feed accepted."""
        self.input_reasons: Counter[str] = Counter()
        """What the input layer in front of the feed (:mod:`swarmloc.live`) refused before pushing, by reason
        (``auth_unsigned``, ``bad_schema``, ``bad_cdr``...: :meth:`refused_input`)."""
        self._lock = threading.Lock()
        self._refuse = InputRefusals(f"robot {self.robot}: live input", self.counts, self.reasons, log, lock=self._lock)
        self._heap: list[tuple[float, int, int, Event]] = []  # (stamp, prio, arrival, event)
        self._seq = itertools.count()
        self._latest = -math.inf  # the largest time an input is known at
        self._odo_end = self.t0  # t1 of the latest odometry (the next one starts there or later)
        self._explicit = -math.inf
        self._released_to = -math.inf  # the watermark the driver has read up to
        self._ended = False
        self._seen = 0  # inputs received: pushed (accepted or refused) or dropped by an input layer
        self._end_at: tuple[int, float] | None = None  # an announced end: (inputs sent, wall deadline)
        self._wake = threading.Event()
        self.on_push: Any = None
        """Called (no argument) after each accepted push or watermark change: the driver's wake-up."""
        self.listens_on = ""
        """Where the inputs come from (the keys or topics the input layer subscribed), for what the driver says
        while it waits for them."""

    # ---------------------------------------------------------------------------------------- producer side
    def push(self, event: Event) -> bool:
        """Queue robot ``robot``'s odometry or detection; True if accepted, False if refused (counted)."""
        if not isinstance(event, Odometry | Detection):
            raise TypeError(f"LiveFeed.push takes an Odometry or a Detection, got {type(event).__name__}")
        with self._lock:
            self._seen += 1
            why = self._problem(event)
            if why is None:
                prio = 1 if isinstance(event, Detection) else 2
                heapq.heappush(self._heap, (float(event.stamp), prio, next(self._seq), event))
                self.counts["accepted"] += 1
                if isinstance(event, Odometry):
                    self._odo_end = max(self._odo_end, float(event.t1))
                self._latest = max(self._latest, float(event.t))
            elif len(self.refused) < MAX_KEPT:
                self.refused.append((why, event))
        if why is not None:
            self._refuse(why, event)
        with self._lock:
            self._check_end()
        self._notify()
        return why is None

    def advance(self, t: float) -> None:
        """Announce that every input stamped before ``t`` [s] has been pushed (a publisher's progress)."""
        t = float(t)
        if math.isnan(t):
            self._refuse("bad_value", f"progress {t!r}")
            return
        with self._lock:
            self._explicit = max(self._explicit, t)
        self._notify()

    def end(self, count: int | None = None, grace: float = END_GRACE) -> None:
        """The stream is over: everything waiting is released, later pushes are refused (``ended``). With ``count``
        (the inputs the sender sent), the end waits until that many came (pushed, :meth:`dropped` or
        :meth:`refused_input`: a sender's messages on several keys may overtake each other), at most ``grace`` s of
        wall time (the shortfall is counted ``missing``)."""
        with self._lock:
            if count is None:
                self._close_stream()
            else:
                self._end_at = (int(count), time.monotonic() + float(grace))
                self._check_end()
        self._notify()

    @property
    def ending(self) -> bool:
        """An end was announced (it may still wait for its count)."""
        with self._lock:
            return self._ended or self._end_at is not None

    def dropped(self) -> None:
        """An input of the robot's sender that the input layer received but did not push (it counts towards an end's
        count): refused (:meth:`refused_input`), or a message that only marks the start."""
        with self._lock:
            self._seen += 1
            self._check_end()

    def refused_input(self, reason: str, counted: bool) -> None:
        """An input that the input layer received and refused before pushing it, for ``reason``. ``counted``: its
        sender counted it towards an end's count (the robot's own odometry or detection; not a progress message, not
        a frame refused as not the robot's: a stranger's inputs must not end the stream early)."""
        with self._lock:
            self.input_reasons[reason] += 1
        if counted:
            self.dropped()

    def summary(self) -> dict[str, int]:
        """The feed's counters for a node's report: ``input_seen`` (the robot's own odometry and detections received:
        pushed or refused), ``input_accepted``, ``input_<reason>`` of what the input layer refused,
        ``feed_<reason>`` of what the feed refused, ``input_missing`` (inputs an end's count still waited for)."""
        with self._lock:
            out = {"input_seen": self._seen, "input_accepted": self.counts["accepted"]}
            out["input_missing"] = self.counts["missing"]
            out |= {f"input_{k}": v for k, v in self.input_reasons.items()}
            return out | {f"feed_{k}": v for k, v in self.reasons.items()}

    def _close_stream(self) -> None:
        self._ended = True
        self._explicit = math.inf
        self._end_at = None

    def _check_end(self) -> None:
        """End the stream once an announced end's count has come or its grace ran out (called with the lock)."""
        if self._end_at is None or self._ended:
            return
        count, deadline = self._end_at
        if self._seen >= count or time.monotonic() > deadline:
            if self._seen < count:
                self.counts["missing"] += count - self._seen
                log.warning("robot %s: the stream ended with %d of %d inputs", self.robot, self._seen, count)
            self._close_stream()

    def _problem(self, e: Odometry | Detection) -> str | None:
        """Why ``e`` is refused, or None (called with the lock held)."""
        own = e.robot if isinstance(e, Odometry) else e.observer
        if own != self.robot:
            return "not_own"
        if self._ended:
            return "ended"
        if isinstance(e, Odometry):
            vals = (e.t0, e.t1, e.v, e.w)
            if not all(math.isfinite(float(v)) for v in vals) or not e.t1 > e.t0:
                return "bad_value"
        else:
            if not math.isfinite(float(e.t)) or not (np.all(np.isfinite(e.z)) and np.all(np.isfinite(e.cov))):
                return "bad_value"
        s = float(e.stamp)
        if s < max(self._watermark(), self._released_to, self.t0):
            return "stale"
        ref = max(self._latest, self.t0)
        if float(e.t) > ref + self.max_ahead:
            return "future"
        if isinstance(e, Odometry) and self.odometry and self.counts["odometry"] and s < self._odo_end:
            return "overlap"
        if len(self._heap) >= self.max_items:
            return "queue_full"
        if isinstance(e, Odometry):
            self.counts["odometry"] += 1
        return None

    def _notify(self) -> None:
        self._wake.set()
        if self.on_push is not None:
            self.on_push()

    # ---------------------------------------------------------------------------------------- consumer side
    def _watermark(self) -> float:
        implicit = self._latest - self.window
        if self.odometry:
            implicit = min(implicit, self._odo_end)
        return max(self._explicit, implicit)

    @property
    def watermark(self) -> float:
        """[s] Nothing stamped before it can still be accepted (``inf`` once ended)."""
        with self._lock:
            return max(self._watermark(), self._released_to)

    @property
    def exhausted(self) -> bool:
        """Ended and everything released."""
        with self._lock:
            self._check_end()
            return self._ended and not self._heap

    def take(self) -> tuple[list[Event], float]:
        """The inputs now released (stamped before the watermark), in key order ``(stamp, priority, arrival)``, and
        that watermark: every input not yet taken is stamped at or after it."""
        out: list[Event] = []
        with self._lock:
            self._check_end()
            w = self._watermark()
            self._released_to = max(self._released_to, w)
            while self._heap and self._heap[0][0] < w:
                out.append(heapq.heappop(self._heap)[3])
            self.counts["released"] += len(out)
            self._wake.clear()
        return out, w

    def wait(self, timeout: float) -> bool:
        """Block up to ``timeout`` s for a push or a watermark change; True if one came."""
        return self._wake.wait(timeout)
