"""A team through a Zenoh router mesh (:func:`swarmloc.net.transport.router_mesh`, ``swarmloc router``,
``swarmloc team --routers``): everything a team uses (publications, queries, liveliness) crosses meshed routers
between clients of different routers; two ``swarmloc router`` processes mesh; a 20-robot team whose every process is
a client of one of three routers equals the peer-to-peer run of the same team. 127.0.0.1 only."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.net.transport import MAX_ROUTERS, client_config, free_ports, router_mesh

pytestmark = pytest.mark.network

DEADLINE_S = 15.0
"""[s] how long a route across the mesh may take to form (tries are repeated within it)."""


def client(router: str) -> Any:
    """A Zenoh client session of ``router`` (the configuration a team's process gets)."""
    import zenoh

    cfg = zenoh.Config.from_json5(json.dumps(client_config([router])))
    return zenoh.open(cfg)


def within(deadline_s: float, attempt: Callable[[], bool]) -> bool:
    """``attempt()`` repeated (every 0.1 s) until it returns True or ``deadline_s`` passes; whether it did."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if attempt():
            return True
        time.sleep(0.1)
    return False


def crosses(a: Any, b: Any, key: str) -> dict[str, bool]:
    """Whether a publication, a query and a liveliness token of ``b`` reach ``a`` (and back)."""
    got = threading.Event()
    sub = b.declare_subscriber(f"{key}/pub", lambda s: got.set())
    qbl = b.declare_queryable(f"{key}/query", lambda q: q.reply(f"{key}/query", b"answer"))
    tok = b.liveliness().declare_token(f"{key}/alive/b")
    try:
        pub = within(DEADLINE_S, lambda: a.put(f"{key}/pub", b"x") or got.wait(0.1))
        query = within(DEADLINE_S, lambda: [r.ok.payload.to_bytes() for r in a.get(f"{key}/query", timeout=1.0)
                                            if r.ok is not None] == [b"answer"])  # fmt: skip
        alive = within(DEADLINE_S, lambda: len(list(a.liveliness().get(f"{key}/alive/*", timeout=1.0))) == 1)
    finally:
        tok.undeclare()
        qbl.undeclare()
        sub.undeclare()
    return {"publication": pub, "query": query, "liveliness": alive}


def test_a_team_s_traffic_crosses_a_mesh_of_three_routers() -> None:
    with router_mesh(3) as routers:
        assert len(set(routers)) == 3 and all(r.startswith("tcp/127.0.0.1:") for r in routers)
        a, b = client(routers[0]), client(routers[2])  # clients of the first and the last router
        try:
            assert crosses(a, b, f"mesh{os.getpid()}") == {"publication": True, "query": True, "liveliness": True}
        finally:
            a.close()
            b.close()
    with pytest.raises(ValueError, match="between 1 and"), router_mesh(MAX_ROUTERS + 1):
        pass
    with pytest.raises(ValueError, match="at least one router"):
        client_config([])


def test_the_documented_client_configuration_joins_its_router(tmp_path: Path) -> None:
    """docs/network.md's client.json5, its router's endpoint replaced by a loopback router's, read by Zenoh."""
    import re

    from swarmloc.net.transport import open_session

    doc = (Path(__file__).resolve().parents[1] / "docs" / "network.md").read_text()
    blocks = [b for b in re.findall(r"```json5\n(.*?)\n```", doc, flags=re.S) if 'mode: "client"' in b]
    assert len(blocks) == 1
    with router_mesh(2) as routers:
        conf = tmp_path / "client.json5"
        conf.write_text(blocks[0].replace("tcp/10.0.1.2:7447", routers[0]))
        a, b = open_session(config_file=conf), client(routers[1])
        try:
            assert len(list(a.info.routers_zid())) == 1 and not list(a.info.peers_zid())  # a client of one router
            assert crosses(a, b, f"doc{os.getpid()}") == {"publication": True, "query": True, "liveliness": True}
        finally:
            a.close()
            b.close()


def test_two_router_processes_mesh_and_stop_on_sigterm() -> None:
    p1, p2 = (f"tcp/127.0.0.1:{p}" for p in free_ports(2))
    cmd = [sys.executable, "-m", "swarmloc.cli", "router", "--max-wall", "120"]
    r1 = subprocess.Popen([*cmd, "--listen", p1], stdout=subprocess.PIPE, text=True)
    r2 = subprocess.Popen([*cmd, "--listen", p2, "--connect", p1], stdout=subprocess.PIPE, text=True)
    try:
        for r in (r1, r2):  # each says so once it relays
            assert r.stdout is not None and "relaying on" in r.stdout.readline()
        a, b = client(p1), client(p2)
        try:
            assert all(crosses(a, b, f"procs{os.getpid()}").values())
        finally:
            a.close()
            b.close()
        taken = subprocess.run([*cmd, "--listen", p1], capture_output=True, text=True, timeout=60)
        said = taken.stderr.strip()
        assert taken.returncode == 2 and said.startswith("swarmloc router: cannot open a Zenoh session: ")
        assert "Address already in use" in said and ".rs:" not in said and "\n" not in said
        for r in (r1, r2):
            r.send_signal(signal.SIGTERM)
            assert r.wait(timeout=30) == 0
    finally:
        for r in (r1, r2):
            if r.poll() is None:
                r.kill()
                r.wait()
    bad = subprocess.run([*cmd[:-2], "--max-wall", "-1"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--max-wall must be a positive" in bad.stderr


@pytest.mark.slow
def test_a_20_robot_team_through_three_routers_equals_the_peer_to_peer_run(tmp_path: Path) -> None:
    est, n, duration = "expfusion", 20, 6.0
    src = load_source("sim:random", robots=n, duration=duration, seed=4)
    runs = {}
    for routers in (0, 3):
        team = f"mesh{routers}x{os.getpid()}"
        tr = run_team(src=src, source="sim:random", robots=n, duration=duration, seed=4, estimator=est, team=team,
                      max_wall=600, routers=routers, log_dir=tmp_path / f"logs{routers}")  # fmt: skip
        assert all(c == 0 for c in tr.exit_codes.values()), tr.exit_codes
        runs[routers] = team_result(tr, src, est)
    configs = sorted((tmp_path / "logs3").glob("zenoh-*.json5"))
    assert len(configs) == n + 1  # the robots and the collector, each a client ...
    used = [json.loads(f.read_text()) for f in configs]
    assert all(c["mode"] == "client" and c["listen"]["endpoints"] == [] for c in used)  # ... listening nowhere
    assert len({c["connect"]["endpoints"][0] for c in used}) == 3  # of one of the three routers
    assert not list((tmp_path / "logs0").glob("zenoh-*.json5"))
    p2p, mesh = runs[0], runs[3]
    assert mesh.stats["reports"] == p2p.stats["reports"] == n
    assert mesh.stats["recorded_provisional_only"] == 0 and mesh.stats["fused"] > 100
    for k in ("fused", "gated", "rejected", "unknown", "detections", "recorded"):
        assert mesh.stats[k] == p2p.stats[k], k
    assert sorted(mesh.tracks) == sorted(p2p.tracks) == sorted(src.robots)
    for r in p2p.tracks:
        a, b = p2p.tracks[r], mesh.tracks[r]
        assert np.array_equal(a.times, b.times)
        assert np.max(np.abs(a.mean - b.mean)) <= 1e-9 and np.max(np.abs(a.cov - b.cov)) <= 1e-9


def test_a_session_zenoh_cannot_open_is_refused_in_one_line_with_zenoh_s_reason(tmp_path: Path, capsys) -> None:
    """A malformed endpoint, a port out of range and a missing configuration file raise :class:`TransportError`
    (a ValueError) with Zenoh's reason and without the location in Zenoh's Rust sources it carries; ``swarmloc
    node``, ``server`` and ``router`` say it in one line, status 2 (``node --listen garbage`` was a traceback)."""
    from swarmloc.cli import main
    from swarmloc.net.transport import TransportError, open_session, zenoh_config, zenoh_reason

    cases = [
        ((["garbage"], []), "Endpoints must be of the form <protocol>/<address>"),
        ((["tcp/127.0.0.1:99999"], []), "invalid port value"),
    ]
    for (listen, connect), says in cases:
        with pytest.raises(TransportError) as exc:
            open_session(listen, connect)
        assert says in str(exc.value) and ".rs:" not in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(TransportError, match="no Zenoh configuration file"):
        zenoh_config([], [], tmp_path / "missing.json5")
    raw = 'Json5Err(Message { msg: "bad \\"x\\" at /a/b/c.rs:12.", location: None }) at /d/e.rs:61.'
    assert zenoh_reason(RuntimeError(raw)) == 'bad \\"x\\"'
    for argv in (
        ["node", "--team", "t", "--robot", "0", "--no-auth", "--source", "sim:random", "--listen", "garbage"],
        ["server", "--team", "t", "--no-auth", "--robots", "0,1", "--listen", "garbage", "--max-wall", "1"],
        ["router", "--listen", "tcp/127.0.0.1:99999", "--max-wall", "1"],
    ):
        assert main(argv) == 2
        said = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("warning: --no-auth")]
        assert len(said) == 1 and said[0].startswith(f"swarmloc {argv[0]}: cannot open a Zenoh session: ")
