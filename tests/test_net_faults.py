"""The fault table's new rows, in short bounded runs on 127.0.0.1: half the messages duplicated, a robot killed and
never restarted, a robot's clock jumping 30 s ahead or back. Each run: no crash, no NaN, every measurement with
exactly one outcome (a ledger per measurement id: nothing fused twice), no process left behind. The launcher
SIGKILLed is ``tests/test_net_runtime.py::test_nodes_die_with_their_launcher``."""

from __future__ import annotations

import threading
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import ended_notes, run_team, team_result
from swarmloc.net.entry import make_node
from swarmloc.net.faults import Faults, parse_faults
from swarmloc.net.process import NetNode
from swarmloc.net.transport import free_ports, open_session

pytestmark = pytest.mark.network


def leftovers(team: str) -> list[int]:
    """Pids of ``swarmloc`` processes whose command line names ``team``."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                cmd = (d / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if team.encode() in cmd and b"swarmloc.cli" in cmd:
                out.append(int(d.name))
    return out


def test_kill_without_restart_and_clock_jump_specs():
    f = parse_faults("killonly=1@10,jump=2@5:-30")
    assert f.kill == (1, 10.0) and not f.restart and f.jump == (2, 5.0, -30.0)
    assert parse_faults(f.to_spec()) == f and parse_faults("kill=1@10").restart
    assert f.node_faults() == Faults(jump=(2, 5.0, -30.0))  # the node applies the jump; the launcher the kill
    # the robot whose process starts during the run: a restarted or late one, not one killed for good
    assert f.joiner is None and parse_faults("kill=1@10").joiner == 1 and parse_faults("late=2@5,loss=0.1").joiner == 2
    for bad in ("kill=1@2,killonly=1@3", "jump=1@10", "jump=1@10:0", "jump=1@10:x", "jump=1@10:4000"):
        with pytest.raises(ValueError, match="faults"):
            parse_faults(bad)
    ev = [Odometry(2, t, t + 1.0, 0.5, 0.0) for t in range(8)]
    ev.append(Detection(2, 6.5, "range_bearing", np.array([1.0, 0.0]), np.eye(2), target=1))
    jumped = f.jumped(2, sorted(ev, key=lambda e: e.t0 if isinstance(e, Odometry) else e.t))
    assert [e.t0 for e in jumped if isinstance(e, Odometry)] == [0, 1, 2, 3, 4, -25, -24, -23]
    assert [e.t for e in jumped if isinstance(e, Detection)] == [-23.5]
    assert f.jumped(1, ev) == ev  # another robot's clock is right


def thread_team(src, faults: Faults, max_wall: float = 90.0, **kw):
    """Each robot a NetNode (its own Zenoh session, threads of this process, 127.0.0.1) keeping a ledger of
    outcomes per measurement; the jump fault applied to the jumped robot's events, as ``swarmloc node`` does."""
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(len(src.robots))]
    sessions, nets, reports = [], [], {}
    try:
        for i, r in enumerate(src.robots):
            s = open_session([eps[i]], [e for e in eps if e != eps[i]])
            sessions.append(s)
            ev = src.own_events(r)
            node = make_node("rdl", r, src.initial[r], src.config, src.landmarks)
            node.ledger = Counter()
            node.start(min(e.t0 if isinstance(e, Odometry) else e.t for e in ev))
            nets.append(NetNode(node, faults.jumped(r, ev), session=s, team="faultrows", roster=src.robots,
                                record_times=src.record_times(), faults=faults, **kw))  # fmt: skip
        threads = [threading.Thread(target=lambda n=n: reports.__setitem__(n.robot, n.run(max_wall=max_wall)))
                   for n in nets]  # fmt: skip
        for t in threads:
            t.start()
        for t in threads:
            t.join(max_wall + 30)
        assert not any(t.is_alive() for t in threads), "a node did not stop"
        return nets, reports
    finally:
        for n in nets:
            n.stop()
        for s in sessions:
            s.close()


def check_run(nets, src, jumped: int | None = None) -> None:
    """Every detection one outcome (ledger: nothing fused twice), nothing pending, finite beliefs. The ``jumped``
    robot's ledger may miss a detection taken across its clock jump (its outcome is in the counts, once)."""
    for n in nets:
        st = n.node.stats()
        assert st["detections"] == st["fused"] + st["gated"] + st["rejected"] + st["unknown"] + st["pending"]
        assert st["pending"] == 0
        per: Counter = Counter()
        for (obs, t, k, outcome), c in n.node.ledger.items():
            assert c in (0, 1), f"measurement {(obs, t, k)} counted {c} times as {outcome}"
            per[(obs, t, k)] += c
        # one outcome each (a detection refused at the node's door, e.g. across the clock jump, has no ledger entry)
        assert set(per.values()) <= {1}
        assert len(per) >= st["detections"] - st["rejected"] - (n.robot == jumped)
        node = n.node
        kept = [t for t in src.record_times() if node.present - node.horizon < t <= node.present]
        for b in [node.belief(), *(node.belief_at(t) for t in kept[-5:])]:
            assert np.isfinite(b.mean).all() and np.isfinite(b.cov).all()


def test_half_the_messages_duplicated():
    src = load_source("sim:random", robots=3, duration=10.0, seed=3)
    f = parse_faults("dup=0.5,seed=2")
    nets, reports = thread_team(src, f, answer_timeout=0.5, hold_timeout=0.25, update_timeout=0.5)
    assert sum(r.net.get("duplicated", 0) for r in reports.values()) > 20  # the fault did happen
    check_run(nets, src)
    assert sum(n.node.stats()["fused"] for n in nets) > 20


@pytest.mark.parametrize("shift", [30.0, -30.0])
def test_a_robot_clock_jump(shift):
    """Robot 1's stamps jump by ``shift`` s a third of the way in: its node takes the jump (its own inputs agree:
    ``clock_jumps``/``clock_resets``), its teammates go on (its queries from the future are answered "not yet",
    theirs to it are too old or early for it); nothing crashes, nothing is fused twice, no NaN."""
    src = load_source("sim:random", robots=3, duration=10.0, seed=3)
    f = parse_faults(f"jump=1@3:{shift:g}")
    nets, reports = thread_team(src, f, answer_timeout=0.5, hold_timeout=0.25, update_timeout=0.5)
    check_run(nets, src, jumped=1)
    jumped = {n.robot: n.node.stats() for n in nets}
    assert jumped[1]["clock_jumps" if shift > 0 else "clock_resets"] == 1
    assert all(s.get("clock_jumps", 0) + s.get("clock_resets", 0) == 0 for r, s in jumped.items() if r != 1)
    assert all(jumped[r]["fused"] > 0 for r in (0, 2))


@pytest.mark.parametrize("spec", ["dup=0.5,seed=2", "jump=1@3:30", "jump=1@3:-30"])
def test_duplicates_and_a_clock_jump_in_node_processes_finish_and_leave_nothing_behind(spec):
    """The same faults as the threaded tests above, in node processes started by the launcher: every process
    exits 0, every detection has one outcome in the counts, the beliefs are finite, the fault did happen, and no
    process is left behind."""
    src = load_source("sim:random", robots=3, duration=10.0, seed=3)
    team = f"faultproc{threading.get_native_id()}"
    try:
        tr = run_team(src=src, source="sim:random", robots=3, duration=10.0, seed=3, estimator="rdl", faults=spec,
                      max_wall=120, team=team, answer_timeout=0.5, hold_timeout=0.25, update_timeout=0.5)  # fmt: skip
        assert all(c == 0 for c in tr.exit_codes.values()) and sorted(tr.reports) == src.robots, tr.exit_codes
        for rep in tr.reports.values():
            s = rep.stats
            assert s["detections"] == s["fused"] + s["gated"] + s["rejected"] + s["unknown"] and s["pending"] == 0
        res = team_result(tr, src, "rdl")
        assert all(np.isfinite(t.mean).all() and np.isfinite(t.cov).all() for t in res.tracks.values())
        if spec.startswith("dup"):
            assert sum(r.net.get("duplicated", 0) for r in tr.reports.values()) > 20
        else:
            key = "clock_jumps" if ":30" in spec else "clock_resets"
            assert tr.reports[1].stats[key] == 1 and all(tr.reports[r].stats["fused"] > 0 for r in (0, 2))
    finally:
        left = leftovers(team)
    assert not left, f"processes {left} left behind"


def test_a_robot_killed_and_not_restarted(tmp_path):
    """killonly: robot 1's process is SIGKILLed and stays down; the others finish (rc 0) with every detection
    accounted, the report names robot 1 (not restarted) and its detections as missing; no process is left."""
    src = load_source("sim:random", robots=3, duration=10.0, seed=3)
    team = f"killonly{threading.get_native_id()}"
    tr = run_team(src=src, source="sim:random", robots=3, duration=10.0, seed=3, estimator="rdl",
                  faults="killonly=1@3", max_wall=120, team=team, answer_timeout=0.5, hold_timeout=0.25,
                  update_timeout=0.5)  # fmt: skip
    try:
        assert [(e["process"], e["exit_code"]) for e in tr.ended] == [("robot1", -9)]
        assert "not restarted" in tr.ended[0]["how"] and tr.counts.get("restarted", 0) == 0
        assert sorted(tr.reports) == [0, 2]
        assert tr.exit_codes["robot0"] == 0 and tr.exit_codes["robot2"] == 0
        notes, missing = ended_notes(tr, src.robots)
        assert missing == [1] and "its detections are missing from the totals" in notes[0]
        res = team_result(tr, src, "rdl")
        for rep in tr.reports.values():
            s = rep.stats
            assert s["detections"] == s["fused"] + s["gated"] + s["rejected"] + s["unknown"] and s["pending"] == 0
        assert all(np.isfinite(t.mean).all() and np.isfinite(t.cov).all() for t in res.tracks.values())
    finally:
        left = leftovers(team)
    assert not left, f"processes {left} left behind"
