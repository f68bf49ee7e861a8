"""A process started by a launcher dies with it: ``swarmloc node`` and ``swarmloc server`` given ``--parent-pid``.

:func:`die_with_parent` asks the kernel (Linux: ``prctl(PR_SET_PDEATHSIG, SIGTERM)``) to send the process SIGTERM
when its parent dies, and starts a watchdog thread that sends it when the parent pid changes (other systems, or a
kernel that refused); either way the process stops as on ``kill`` (its SIGTERM handler), and is ended 5 s later
if it has not. A launcher killed with SIGKILL, which can clean nothing up, leaves no process behind.
"""

from __future__ import annotations

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
    if os.getppid() != parent:  # the parent died before the kernel was asked
        os.kill(os.getpid(), signal.SIGTERM)
    threading.Thread(target=_watch, args=(parent,), name="parent-watchdog", daemon=True).start()


def _watch(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(WATCH_EVERY)
    log.warning("the parent process (pid %d) is gone: stopping", parent)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(GRACE)
    log.warning("still running %.0f s after the parent was gone: ending", GRACE)
    os._exit(1)
