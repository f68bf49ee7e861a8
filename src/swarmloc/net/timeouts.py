"""The waits of a networked node, one name per wait, all in seconds of wall time: defaults and meanings.

* ``answer_timeout``: how long a node waits for the reply to one of its own queries (a Zenoh ``get``; under link
  faults plus twice their delay), from the neighbour and, with ``use_server``, again from the belief server; then
  the query ends unanswered (counted ``no_reply``) and its detection ``unknown``;
* ``hold_timeout``: how long a node holds a neighbour's query for its own state to settle before answering it as
  things stand (counted ``answered_unsettled``; a revision follows if the state changes); keep it below the
  askers' ``answer_timeout``, or their queries end unanswered first;
* ``update_timeout``: how long a node that gave its ``rdl`` state waits for the observer's pairwise update, holding
  its own later detection groups meanwhile (then given up: counted ``update_not_received``);
* ``start_timeout``: how long a node waits at its start for the robots it waits for to be alive (it then starts
  without them, with a warning);
* ``lost_timeout``: how long a node waits for a live teammate (its liveliness token up) that is silent (no
  announcement of its progress, which a waiting node repeats every 0.2 s), while lockstep waits for it, before
  declaring it lost and going on without it (counted ``peers_lost``, logged; its queries to it are answered "not
  found" at once, or by the belief server); one that announces but whose progress does not advance (it waits
  itself) is declared lost after ``STALL_TIMEOUTS`` times as long, unless what it waits on moves (its announced
  ``moved`` changes: :meth:`~swarmloc.net.lockstep.Lockstep.check_lost`). It is back if it announces progress again.

A query that ends unanswered is asked again while its robot is alive (not declared lost): ``ANSWER_RETRIES`` more
times, and beyond that while less than ``lost_timeout`` s have passed since its first ask (as long as a silent
teammate is waited for); its detection group waits meanwhile, and the node gets its "not found" answer only once no
ask is left (a Zenoh get drops a reply that comes after its timeout, so without asking again an answer held or
stalled past ``answer_timeout`` is lost).

Not here, each with its own name: ``quiet`` and ``linger`` (the end of a node's run,
:class:`~swarmloc.net.process.NetNode`), ``max_wall`` (the wall-clock limit of a whole node, server or team run),
``RESUME_TIMEOUT`` (a restarted node's wait for its belief on the server, :mod:`swarmloc.net.entry`) and
``grace`` (:func:`swarmloc.net.team.stop_all`).
"""

from __future__ import annotations

import math
import threading
import time
from typing import TypedDict

ANSWER_TIMEOUT = 2.0
HOLD_TIMEOUT = 1.0
UPDATE_TIMEOUT = 2.0
START_TIMEOUT = 30.0
LOST_TIMEOUT = 10.0
ANSWER_RETRIES = 2
"""How many more times a node asks a query that went unanswered at least (not a wait: a count; ``--answer-retries``);
more while within ``lost_timeout`` s of the first ask."""
STALL_TIMEOUTS = 6
"""A teammate that announces but does not advance is declared lost after this many ``lost_timeout`` (a bound against
a node that loops without progress; a legitimate wait, for answers lost on the link, is far shorter)."""

TIMEOUTS: dict[str, tuple[float, str]] = {
    "answer_timeout": (ANSWER_TIMEOUT, "seconds a node waits for the reply to one of its queries, from a neighbour "
                       "(and again from the belief server)"),
    "hold_timeout": (HOLD_TIMEOUT, "seconds a node holds a neighbour's query for its own state to settle before "
                     "answering it as it stands (keep it below the askers' answer timeout)"),
    "update_timeout": (UPDATE_TIMEOUT, "seconds a node that gave its rdl state waits for the observer's pairwise "
                       "update"),
    "start_timeout": (START_TIMEOUT, "seconds a node waits at its start for its teammates to be alive"),
    "lost_timeout": (LOST_TIMEOUT, "seconds a node waits for a live teammate that is silent (a hung process) "
                     "before declaring it lost and going on without it; one that announces but does not advance: "
                     f"{STALL_TIMEOUTS} times as long"),
}  # fmt: skip
"""Name: (default [s], meaning), as ``swarmloc node`` and ``swarmloc team`` take them (``--answer-timeout``...)."""


class Waits(TypedDict, total=False):
    """A node's waits [s] and its ``answer_retries`` (a count), as the keywords ``swarmloc node``'s and ``swarmloc
    team``'s entry points take and pass on (:class:`~swarmloc.net.settings.NetSettings`); one left out: its default
    above."""

    answer_timeout: float
    hold_timeout: float
    update_timeout: float
    answer_retries: int
    start_timeout: float
    lost_timeout: float


def check_retries(n: object) -> int:
    """``n`` as a node's ``answer_retries``: an int from 0 to 100; ValueError naming it otherwise."""
    if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= 100:
        raise ValueError(f"answer_retries is a count from 0 to 100, got {n!r}")
    return n


SIGNAL_POLL = 0.2
"""[s] How often a wait of the main thread wakes to take a signal (:func:`wait_event`)."""


def wait_event(event: threading.Event, seconds: float | None = None) -> bool:
    """``event.wait(seconds)`` (None or inf: no limit) in slices of :data:`SIGNAL_POLL` s; whether ``event`` is set.

    A wait without a timeout is interrupted by Ctrl-C (or SIGTERM's handler runs) only when the OS delivers the
    signal to the main thread itself; with Zenoh's and the live view's threads in the process it may pick any of
    them, and the main thread then waits on forever. Waking every :data:`SIGNAL_POLL` s lets Python take the pending
    signal whichever thread received it."""
    end = math.inf if seconds is None else time.monotonic() + max(0.0, seconds)
    while True:
        left = end - time.monotonic()
        if left <= 0:
            return event.is_set()
        if event.wait(min(left, SIGNAL_POLL)):
            return True
