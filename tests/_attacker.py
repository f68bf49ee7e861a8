"""Start a test attacker script as its own process (its own Zenoh session) and stop it: shared by the networked
authentication tests (tests/test_net_auth.py, tests/test_net_central.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path


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
