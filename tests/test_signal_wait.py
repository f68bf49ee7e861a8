"""Ctrl-C reaches a command that waits on its main thread whichever thread the OS delivers it to
(:func:`swarmloc.net.timeouts.wait_event`): a wait without a timeout is interrupted only by a signal delivered to the
main thread, and with Zenoh's and the live view's threads in the process the OS may pick another one (a lingering
`swarmloc team --view` would then ignore Ctrl-C for good). Each case runs in its own interpreter, bounded in time."""

from __future__ import annotations

import subprocess
import sys

import pytest

pytestmark = pytest.mark.unit

SCRIPT = """
import signal, threading, time
from swarmloc.net.timeouts import wait_event
signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal, even if the suite inherited it ignored
ev = threading.Event()
def poke():
    time.sleep(0.3)
    signal.pthread_kill(threading.get_ident(), signal.SIGINT)  # to this thread, not the main one
threading.Thread(target=poke, daemon=True).start()
t0 = time.monotonic()
try:
    WAIT
    print("woke")
except KeyboardInterrupt:
    print(f"interrupted {time.monotonic() - t0:.2f}")
"""


def _run(wait: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", SCRIPT.replace("WAIT", wait)], capture_output=True, text=True,
                          timeout=20)  # fmt: skip


def test_ctrl_c_delivered_to_another_thread_ends_the_wait() -> None:
    out = _run("wait_event(ev)").stdout.split()
    assert out[0] == "interrupted" and 0.3 <= float(out[1]) < 2.0


def test_a_plain_wait_without_timeout_misses_it() -> None:
    """What :func:`wait_event` is for: the plain wait is still blocked 3 s after the signal."""
    with pytest.raises(subprocess.TimeoutExpired):
        subprocess.run([sys.executable, "-c", SCRIPT.replace("WAIT", "ev.wait()")], timeout=3.3)


def test_a_bounded_wait_returns_at_its_bound_and_a_set_event_at_once() -> None:
    import threading
    import time

    from swarmloc.net.timeouts import wait_event

    ev = threading.Event()
    t0 = time.monotonic()
    assert wait_event(ev, 0.5) is False and 0.5 <= time.monotonic() - t0 < 1.5
    ev.set()
    t0 = time.monotonic()
    assert wait_event(ev) is True and time.monotonic() - t0 < 0.1
