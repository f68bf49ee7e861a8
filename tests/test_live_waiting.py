"""A live node that waits says what it waits for: the keys its inputs come on and the teammates not alive, as a
warning (shown without ``--verbose``), once it has waited a moment and then every so often. Before, a ``zenoh:``
node waiting for inputs that never came was silent (77 s in one report)."""

from __future__ import annotations

import logging
import os
import time

import numpy as np
import pytest

import swarmloc.net.process as process
from swarmloc.live import LiveNode
from swarmloc.live.zenoh_input import input_key
from swarmloc.net.transport import free_ports, team_scope

pytestmark = pytest.mark.network


def test_a_waiting_zenoh_node_names_its_input_keys_and_the_teammates_it_waits_for(caplog, monkeypatch):
    monkeypatch.setattr(process, "WAIT_NOTE", 0.3)
    monkeypatch.setattr(process, "WAIT_NOTE_EVERY", 0.5)
    caplog.set_level(logging.WARNING, logger="swarmloc.net.process")
    team = f"wait{os.getpid()}"
    node = LiveNode(0, ((0.0, 0.0, 0.0), 1e-2 * np.eye(3)), team=team, roster=[0, 1], t0=0.0, inputs="zenoh",
                    listen=[f"tcp/127.0.0.1:{free_ports(1)[0]}"], start_timeout=0.2)  # fmt: skip
    try:
        keys = input_key(team_scope(team, None), 0, "*")
        notes: list[str] = []
        deadline = time.monotonic() + 20.0
        while len(notes) < 2 and time.monotonic() < deadline:  # two notes: the first, then one repeat
            notes = [r.getMessage() for r in caplog.records if "for its inputs on" in r.getMessage()]
            time.sleep(0.05)
    finally:
        node.feed.end()
        node.close(timeout=5.0)
    assert len(notes) >= 2, caplog.text
    assert f"robot 0: waiting 0 s for its inputs on Zenoh keys {keys} (0 taken so far; teammates alive [], " \
           "not alive [1])" == notes[0]  # fmt: skip
    assert all(r.levelno == logging.WARNING for r in caplog.records if "for its inputs on" in r.getMessage())
