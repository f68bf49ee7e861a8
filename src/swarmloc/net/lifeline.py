"""A process started by a launcher dies with it: ``swarmloc node`` and ``swarmloc server`` given ``--parent-pid``.

:func:`die_with_parent` asks the kernel (Linux: ``prctl(PR_SET_PDEATHSIG, SIGTERM)``) to send the process SIGTERM
when its parent dies, and starts a watchdog thread that sends it when the parent pid changes (other systems, or a
kernel that refused); either way the process stops as on ``kill`` (its SIGTERM handler, or at once while it has
none: while it starts), and is ended ``GRACE`` s later if it has not. That end is :mod:`faulthandler`'s timer, a
thread of its own outside the interpreter: it ends a process whose stop is stuck holding the interpreter's lock
too, and writes where every thread was to stderr first. A launcher killed with SIGKILL, which can clean nothing
up, leaves no process behind.

The commands call it before anything heavy is imported (``import swarmloc`` loads the numerical core only when a
name of it is used), so a process whose launcher is killed while it starts ends within moments too.
"""

from __future__ import annotations

import faulthandler
import logging
import os
import signal
import sys
import threading
import time

log = logging.getLogger(__name__)

PR_SET_PDEATHSIG = 1
WATCH_EVERY = 0.5
"""[s] how often the watchdog looks at the parent pid."""
GRACE = 5.0
"""[s] after its SIGTERM, how long a process whose parent is gone may take to stop before it is ended."""


def die_with_parent(parent: int) -> None:
    """Stop this process (SIGTERM) when process ``parent``, its parent, is gone; at once if it already is."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
                raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()))
        except (OSError, AttributeError) as exc:  # the watchdog still watches
            log.warning("parent-death signal not set (%s); a watchdog polls the parent pid", exc)
    threading.Thread(target=_watch, args=(parent,), name="parent-watchdog", daemon=True).start()


def _watch(parent: int) -> None:
    while os.getppid() == parent:  # at once if the parent died before the kernel was asked
        time.sleep(WATCH_EVERY)
    log.warning("the parent process (pid %d) is gone: stopping (ended in %.0f s if still running)", parent, GRACE)
    faulthandler.dump_traceback_later(GRACE, exit=True, file=sys.stderr if sys.stderr else open(os.devnull, "w"))
    os.kill(os.getpid(), signal.SIGTERM)
