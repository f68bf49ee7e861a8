"""Start a test attacker script as its own process (its own Zenoh session) and stop it: shared by the networked
authentication tests (tests/test_net_auth.py, tests/test_net_central.py); and, for the attacker scripts, a wait for a
process's liveliness token and the envelope inside a frame they overhear."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from swarmloc.net.auth import HEADER, HEADER_V1, MAGIC, SIG_SIZE
from swarmloc.net.macframe import MAC_HEADER, MAC_MAGIC, TAG_SIZE


@contextmanager
def attacker_process(script: Path, args: Sequence[str], wait: float = 60.0) -> Iterator[subprocess.Popen]:
    """Run ``script args`` with this interpreter's path, wait for its ``ready`` line, yield it while the team
    runs; then wait up to ``wait`` s for it to finish (killed if it has not) and assert that it exited 0."""
    cmd = [sys.executable, str(script), *args]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})  # fmt: skip
    try:
        assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
        yield proc
        proc.wait(timeout=wait)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, proc.stderr.read()


def team_scope_of(session, team: str, robots: Sequence[int], end: float) -> str:
    """The key scope of the run of ``team`` (``<team>`` or ``<team>/run/<id>``) that ``session`` hears, once every
    robot of ``robots`` has announced progress (or ``time.monotonic()`` passed ``end``: then what was heard)."""
    import threading

    import zenoh

    seen: dict[int, str] = {}
    lock = threading.Lock()

    def on_progress(x) -> None:
        parts = str(x.key_expr).split("/")
        with lock:
            seen[int(parts[-2])] = "/".join(parts[1:-3])  # swarmloc/<scope>/robot/<r>/progress

    sub = session.declare_subscriber(f"swarmloc/{team}/**/robot/*/progress", on_progress,
                                     allowed_origin=zenoh.Locality.REMOTE)  # fmt: skip
    try:
        while len(seen) < len(robots) and time.monotonic() < end:
            time.sleep(0.05)
    finally:
        sub.undeclare()
    with lock:
        return next(iter(seen.values()), team)


def close_when_alone(session, wait: float = 60.0) -> None:
    """Close ``session`` once no peer is connected to it (the team has ended), or after ``wait`` s: a session closed
    at once discards what a loaded receiver has not read yet, and an attacker counts every frame it put as received
    (tests/net_flood_attacker.py has the measurement)."""
    end = time.monotonic() + wait
    while list(session.info.peers_zid()) and time.monotonic() < end:
        time.sleep(0.05)
    session.close()


def wait_alive(session, key: str, end: float) -> bool:
    """Ask ``session`` for the liveliness token ``key`` until one answers or ``time.monotonic()`` passes ``end``;
    whether it was seen. A process declares its token after its subscribers: before the token is seen, a put to it
    may find no route yet (the belief server starts beside the robots: their progress alone does not vouch for it)."""
    while time.monotonic() < end:
        if any(r.ok for r in session.liveliness().get(key, timeout=1.0)):
            return True
    return False


def envelope_of(data: bytes) -> bytes:
    """The schema envelope inside a MACed or a signed frame, unverified (what an eavesdropper reads)."""
    if data[:4] == MAC_MAGIC:
        return data[MAC_HEADER.size : len(data) - TAG_SIZE]
    return data[(HEADER if data[:4] == MAGIC else HEADER_V1).size : len(data) - SIG_SIZE]
