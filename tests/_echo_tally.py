"""What the stand-in ROS 2 peers (tests/ros2_dds_peer.py, tests/ros2_zenoh_peer.py) count of the samples they echo:
per topic, so that a peer lingers until the outputs it expects came (``--expect TOPIC:N``), not a fixed time a loaded
machine may outlast. Imports nothing from swarmloc."""

from __future__ import annotations

import threading
import time

QUIET = 1.0
"""[s] how long no sample may come, once the expected ones came, before a peer closes: it then closes while nothing
is arriving, as after the fixed linger (a session closed while samples still came once ended a peer with SIGSEGV)."""


class Tally:
    """Samples echoed per topic name; :meth:`wait` blocks until each expected topic has its count or time is up."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._n: dict[str, int] = {}
        self._last = time.monotonic()

    def add(self, topic: str) -> None:
        with self._cond:
            self._n[topic] = self._n.get(topic, 0) + 1
            self._last = time.monotonic()
            self._cond.notify_all()

    def wait(self, expect: dict[str, int], timeout: float, quiet: float = QUIET) -> bool:
        """True once every ``topic: n`` of ``expect`` has ``n`` samples and none came for ``quiet`` s; False after
        ``timeout`` s (then the caller's comparison tells what is missing). With nothing expected: sleeps ``timeout``
        s (a fixed linger)."""
        if not expect:
            time.sleep(timeout)
            return True
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                now = time.monotonic()
                if all(self._n.get(t, 0) >= n for t, n in expect.items()) and now - self._last >= quiet:
                    return True
                if now >= deadline:
                    return False
                self._cond.wait(min(deadline - now, max(quiet - (now - self._last), 0.05)))


def parse_expect(specs: list[str]) -> dict[str, int]:
    """``["/r0/odom:21", ...]`` -> ``{"/r0/odom": 21}`` (the count after the last colon)."""
    return {s.rsplit(":", 1)[0]: int(s.rsplit(":", 1)[1]) for s in specs}
