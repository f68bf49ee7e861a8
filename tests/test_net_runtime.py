"""The network runtime keeps its promises: duplicates never crash a node nor fuse twice, every loop honours the run's
wall-time bound, a silent teammate is declared lost after a bound, a dead node is named in the report, nodes die
with their launcher, two teams of one name do not hear each other, and a lone node says so and fails.

Real Zenoh peers on 127.0.0.1 only (scouting off, explicit endpoints), every run bounded in time; waits poll with
a deadline, none sleeps.
"""

from __future__ import annotations

import json
import logging
import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import pytest

from swarmloc.estimators import make_team, node_options
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.messages import BeliefQuery
from swarmloc.net import lifeline
from swarmloc.net.entry import make_node
from swarmloc.net.process import NetNode
from swarmloc.net.schema import Progress, encode
from swarmloc.net.transport import alive_key, free_ports, open_session, robot_key, robot_of, team_scope
from swarmloc.runner import run

pytestmark = pytest.mark.network


OUTCOMES = ("detections", "fused", "gated", "rejected", "unknown", "pending")


def leftovers(team: str) -> list[int]:
    """Pids of processes whose command line names ``team`` (none must be left after a run)."""
    out = []
    for d in os.scandir("/proc"):
        if not d.name.isdigit():
            continue
        try:
            with open(f"/proc/{d.name}/cmdline", "rb") as f:
                cmd = f.read().split(b"\0")
        except OSError:
            continue
        if team.encode() in cmd and b"swarmloc.cli" in cmd:
            out.append(int(d.name))
    return out


def reference_stats(src, est: str) -> dict:
    nodes = make_team(est, src.initial, **node_options(est, src.config, src.landmarks))
    return run(nodes, src.events, src.record_times(), truth=src.truth).stats


def test_duplicated_queries_and_replies_are_answered_once_and_never_crash_a_node():
    """``--faults dup=0.5``: every query, reply and push may arrive twice. Before, the second copy of a reply raised
    in Zenoh ("Dropped query") and the node died (rc 1, 74 of 76 detections unknown). Now every node ends rc 0
    and every detection ends as in the clean (in-process) run: nothing unknown, nothing fused twice."""
    src = load_source("sim:random", robots=3, duration=10.0, seed=0)
    team = f"dup{os.getpid()}"
    for est in ("expfusion", "rdl"):
        tr = run_team(src=src, source="sim:random", robots=3, duration=10.0, seed=0, estimator=est, team=team,
                      faults="dup=0.5", max_wall=120)  # fmt: skip
        assert not leftovers(team)
        assert tr.exit_codes == {f"robot{r}": 0 for r in src.robots}, tr.exit_codes
        res = team_result(tr, src, est)
        assert res.stats["reports"] == 3 and res.accounted()
        assert res.stats["net_duplicated"] > 20  # the duplicates did happen
        ref = reference_stats(src, est)
        assert {k: res.stats[k] for k in OUTCOMES} == {k: ref[k] for k in OUTCOMES}


class _Payload:
    def __init__(self, raw: bytes) -> None:
        self.raw = raw

    def to_bytes(self) -> bytes:
        return self.raw


class _DeadQuery:
    """A neighbour's Zenoh query whose asker is gone: every reply raises, as Zenoh's does on a closed query."""

    key_expr = "swarmloc/t/robot/0/query"

    def __init__(self, raw: bytes) -> None:
        self.payload = _Payload(raw)
        self.replies = self.drops = 0

    def reply(self, key, payload) -> None:
        self.replies += 1
        raise RuntimeError("Dropped query")

    def reply_err(self, reason: bytes) -> None:
        raise RuntimeError("Dropped query")

    def drop(self) -> None:
        self.drops += 1


def offline_net(robot: int = 0, **kw) -> NetNode:
    """Robot ``robot`` of a simulated team of 3 in a :class:`NetNode` that is never opened (nothing sent)."""
    src = load_source("sim:random", robots=3, duration=4.0, seed=0)
    node = make_node("expfusion", robot, src.initial[robot], src.config, src.landmarks)
    node.start(src.t_start)
    return NetNode(node, src.own_events(robot), session=None, team="t", roster=src.robots, **kw)


def test_settings_are_one_checked_object_and_keywords_replace_its_fields():
    """A node's settings are one frozen :class:`NetSettings`: a wait below 0, a retry count out of range, a record
    rate of 0 or a keyword that is no setting is refused naming it; keywords replace the given object's fields."""
    import dataclasses

    from swarmloc.net.settings import NetSettings

    base = NetSettings(lag=1.0, answer_timeout=3)
    net = offline_net(settings=base, hold_timeout=0.5)
    assert net.settings == dataclasses.replace(base, hold_timeout=0.5)
    assert net.settings.answer_timeout == 3.0 and isinstance(net.settings.answer_timeout, float)
    assert offline_net(settings=base).settings is base
    with pytest.raises(dataclasses.FrozenInstanceError):
        net.settings.lag = 2.0
    with pytest.raises(ValueError, match="lost_timeout"):
        NetSettings(lost_timeout=-1.0)
    with pytest.raises(ValueError, match="answer_retries"):
        offline_net(answer_retries=101)
    with pytest.raises(ValueError, match="record_rate"):
        NetSettings(record_rate=0.0)
    with pytest.raises(TypeError, match="no such setting.*'lagg'"):
        offline_net(lagg=1.0)


def test_a_query_that_arrives_twice_is_answered_once_and_a_failing_reply_is_counted_not_raised():
    """Two copies of one query (the same sender, sequence number and body): the node steps it once, the copy is
    closed unanswered; the reply failing (the asker gone) is counted ``send_failed`` and the query closed.
    Before, both copies were answered and the failing reply raised out of the node's loop."""
    net = offline_net(hold_timeout=0.0)  # answered at once, as things stand
    raw = encode("t", 1, 7, BeliefQuery(sender=1, receiver=0, stamp=net.inputs.items[0][0]))
    first, copy = _DeadQuery(raw), _DeadQuery(raw)
    net.inbound.handle("query", first)
    net.inbound.handle("query", copy)
    assert (first.replies, first.drops) == (1, 1) and (copy.replies, copy.drops) == (0, 1)
    assert net.counts["send_failed"] == 1 and net.counts["duplicate_queries"] == 1
    assert net.counts["queries_answered"] == 1 and not net.lockstep.deferred


class _Flood:
    """A node's queue that never runs dry: a teammate's progress announcement, again and again."""

    def __init__(self, raw: bytes) -> None:
        self.sample = type("Sample", (), {"payload": _Payload(raw)})()

    def get(self, timeout: float | None = None):
        return ("progress", self.sample)

    get_nowait = get

    def put(self, item) -> None:
        pass

    def fold(self, counts, reasons) -> None:  # nothing dropped at its intake
        pass


def test_a_flood_of_messages_never_keeps_a_node_from_its_deadlines():
    """One ``_drain`` handles what is queued for a bounded slice of wall time and returns, so that the loops around
    it check their deadlines and timers. Before, a queue that never ran dry kept it (and the node) forever."""
    net = offline_net()
    net.inbound.intake = _Flood(encode("t", 1, 0, Progress(robot=1, t=1.0)))
    th = threading.Thread(target=net.inbound.drain, args=(0.0,), daemon=True)
    t0 = time.monotonic()
    th.start()
    th.join(5.0)
    returned = not th.is_alive()
    net._stop.set()  # ends a drain that did not return by itself
    th.join(5.0)
    assert returned, "_drain did not return within 5 s under a flood"
    assert time.monotonic() - t0 < 1.0


def test_a_node_waits_for_its_teammates_no_longer_than_its_wall_time_bound(caplog):
    """``max_wall`` bounds the start wait too: a node waiting (``start_timeout`` 30 s) for a teammate that never
    comes stops at its bound, and says for whom it waited. Before, the start wait ran its 30 s whatever the bound."""
    port = free_ports(1)[0]
    session = open_session([f"tcp/127.0.0.1:{port}"], [])
    try:
        net = offline_net(start_timeout=30.0)
        net.session = net.wiring.session = net.wiring.presence.session = session  # it sends, its wiring declares on it
        t0 = time.monotonic()
        with caplog.at_level(logging.INFO, logger="swarmloc.net.process"):
            net.run(max_wall=1.0)
        elapsed = time.monotonic() - t0
    finally:
        session.close()
    assert elapsed < 1.0 + 1.5, f"ran {elapsed:.1f} s with a bound of 1 s"
    assert "waiting up to 30 s for robots [1, 2]" in caplog.text


def test_a_team_returns_within_its_wall_time_bound(tmp_path):
    """``swarmloc team --timeout 4`` on a source of 600 s at real time: the team (its nodes stopped, its report
    written) returns within the bound plus the launcher's grace to stop its processes (3 s) and a margin."""
    from swarmloc.cli import main

    team = f"team{os.getpid()}"  # swarmloc team's default name
    t0 = time.monotonic()
    rc = main(["team", "--robots", "3", "--duration", "600", "--speed", "1", "--timeout", "4", "--out", str(tmp_path)])
    elapsed = time.monotonic() - t0
    assert not leftovers(team)
    rep = json.loads((tmp_path / "team.json").read_text())
    assert rc == 1 and rep["estimators"]["diekf"]["stats"]["timed_out"] == 1  # swarmloc team's default estimator
    assert elapsed < 4 + 3 + 3, f"returned after {elapsed:.1f} s with a bound of 4 s"


def test_the_collector_stops_at_the_wall_time_bound_whatever_keeps_coming(tmp_path):
    """Once every node has ended, the launcher collects what is still queued, within the run's bound. Before, it
    went on as long as anything came at least every 0.3 s (another team of the same name, a stray node)."""
    from swarmloc.net.auth import TeamKeys
    from swarmloc.net.faults import Faults
    from swarmloc.net.team import _Launcher

    keys = TeamKeys([], tmp_path)
    launcher = _Launcher("t", [], [], Faults(), False, (), None, keys, [])  # no robots: every node has ended
    until = time.monotonic() + 10.0
    stray = type("Sample", (), {"payload": _Payload(b"not for this team"), "key_expr": "swarmloc/t/robot/0/belief"})()

    class Trickle:  # a message every 0.1 s, for 10 s
        def get(self, timeout: float | None = None):
            if time.monotonic() > until:
                raise queue.Empty
            time.sleep(0.1)  # the pace of the stray traffic, not a wait of the test
            return ("sample", stray)

    launcher.inq = Trickle()
    t0 = time.monotonic()
    launcher.watch(0.0, 1.0, t0)
    assert time.monotonic() - t0 < 1.0 + 0.5


def test_a_teammate_whose_token_outlives_it_is_declared_lost_and_the_node_goes_on(caplog):
    """Robot 1's liveliness token is up but nothing of robot 1 ever progresses (a hung process, or a token that
    outlived its process). After ``lost_timeout`` s robot 0 declares it lost (logged, counted), reads its whole
    source and answers its own queries to robot 1 "not found" at once: every detection ends unknown, none pending.
    Before, lockstep waited for robot 1 with no bound but the run's wall time (here 20 s)."""
    from swarmloc.net.transport import alive_key

    src = load_source("sim:random", robots=2, duration=10.0, seed=1)
    ep0, ep1 = (f"tcp/127.0.0.1:{p}" for p in free_ports(2))
    zombie = open_session([ep1], [ep0])
    token = zombie.liveliness().declare_token(alive_key("t", 1))
    session = open_session([ep0], [ep1])
    try:
        node = make_node("expfusion", 0, src.initial[0], src.config, src.landmarks)
        node.start(src.t_start)
        net = NetNode(node, src.own_events(0), session=session, team="t", roster=src.robots, lost_timeout=1.0,
                      start_timeout=10.0)  # fmt: skip
        t0 = time.monotonic()
        with caplog.at_level(logging.WARNING, logger="swarmloc.net.process"):
            report = net.run(max_wall=20.0)
        elapsed = time.monotonic() - t0
    finally:
        token.undeclare()
        zombie.close()
        session.close()
    assert elapsed < 1.0 + 3.0, f"ran {elapsed:.1f} s with a lost timeout of 1 s"
    assert report.net["peers_lost"] == 1 and report.net["teammates_seen"] == 1
    assert "robot 1 declared lost" in caplog.text
    s = report.stats
    assert net.inputs.i == len(net.inputs.items) and s["detections"] > 5
    assert s["unknown"] == s["detections"] and s["pending"] == 0
    assert report.net["asked_lost"] == s["detections"]


def watching_robot_1(monkeypatch) -> tuple[Any, NetNode, Callable[..., None]]:
    """Robot 0 (lost timeout 1 s) on a clock of the test's own (``clock.t``, monotonic s), and ``announce(t,
    moved=0)``: robot 1's progress (priority 2) received by it."""
    from types import SimpleNamespace

    from swarmloc.net import lockstep

    clock = SimpleNamespace(t=100.0)
    monkeypatch.setattr(lockstep, "time", SimpleNamespace(monotonic=lambda: clock.t))
    net = offline_net(lost_timeout=1.0)
    key = robot_key(team_scope("t"), 1, "progress")
    seq = iter(range(1, 10**6))

    def announce(t: float, moved: int = 0) -> None:
        raw = encode("t", 1, next(seq), Progress(robot=1, t=t, prio=2, moved=moved))
        net.inbound.handle("progress", type("Sample", (), {"key_expr": key, "payload": _Payload(raw)})())

    return clock, net, announce


def test_a_teammate_that_waits_announcing_is_not_lost_one_that_falls_silent_or_never_advances_is(monkeypatch):
    """Robot 0 waits for robot 1 (lost timeout 1 s, on a clock of the test's own). Robot 1 repeats the same
    progress every 0.2 s for 4 s (it waits itself, for answers lost on the link): not declared lost (before, its
    progress not advancing for 1 s was read as hung: lost at 1 s, and its detections ended "robot 1 is lost").
    Silent for more than 1 s it is declared lost, and back as soon as it announces again. Announcing without
    advancing, it is declared lost after ``STALL_TIMEOUTS`` lost timeouts, and back only once it advances."""
    from swarmloc.net.timeouts import STALL_TIMEOUTS

    clock, net, announce = watching_robot_1(monkeypatch)

    def run(seconds: float, t: float | None) -> None:  # 0.05 s steps; robot 1 announces t every 0.2 s (None: not)
        for k in range(round(seconds / 0.05)):
            clock.t += 0.05
            if t is not None and k % 4 == 3:
                announce(t)
            net.lockstep.check_lost(5.0)  # robot 0's next input at 5 s: it waits for robot 1

    net.lockstep.alive.add(1)
    announce(0.5)
    run(4.0, 0.5)
    assert net.counts["peers_lost"] == 0 and 1 in net.lockstep.alive
    run(1.2, None)
    assert net.counts["peers_lost"] == 1 and 1 in net.lockstep.lost and net.lockstep.lost_why[1] == "silent for 1 s"
    announce(0.5)
    assert 1 in net.lockstep.alive and 1 not in net.lockstep.lost and net.counts["peers_back"] == 1
    run(STALL_TIMEOUTS - 5.2 - 0.15, 0.5)  # announcing, no advance since the first announcement 5.2 s ago ...
    assert net.counts["peers_lost"] == 1 and 1 in net.lockstep.alive
    run(0.3, 0.5)  # ... and past STALL_TIMEOUTS lost timeouts
    assert net.counts["peers_lost"] == 2 and net.lockstep.lost_why[1] == f"no progress for {STALL_TIMEOUTS:g} s"
    announce(0.5)  # announcing alone does not bring a stalled teammate back
    assert 1 in net.lockstep.lost
    announce(0.6)
    assert 1 in net.lockstep.alive and 1 not in net.lockstep.lost and net.counts["peers_back"] == 2


def test_a_teammate_waiting_on_a_moving_chain_is_not_stalled_one_whose_chain_does_not_move_is(monkeypatch):
    """Robot 0 waits for robot 1 (lost timeout 1 s, a clock of the test's own). Robot 1 repeats the same progress
    every 0.2 s for twice the stall timeout, but what it waits on moves (its ``moved`` changes each second: a slow
    new mate at a cluster boundary, whom robot 0 does not hear): not declared lost, the stall clock restarted by the
    moving chain counted. Before, robot 0 declared it stalled after ``STALL_TIMEOUTS`` lost timeouts, went on without
    it, and its late broadcasts set off a cascade of re-broadcasts. Once its chain stops moving, robot 1 is declared
    stalled after the same time as before."""
    from swarmloc.net.timeouts import STALL_TIMEOUTS

    clock, net, progress = watching_robot_1(monkeypatch)

    def run(seconds: float, moving: bool) -> None:  # 0.05 s steps, an announcement every 0.2 s
        for k in range(round(seconds / 0.05)):
            clock.t += 0.05
            if k % 4 == 3:
                progress(0.5, moves[0])
            if moving and k % 20 == 19:
                moves[0] += 1
            net.lockstep.check_lost(5.0)  # robot 0's next input at 5 s: it waits for robot 1

    moves = [7]
    net.lockstep.alive.add(1)
    progress(0.5, moves[0])
    run(2 * STALL_TIMEOUTS, moving=True)
    assert net.counts["peers_lost"] == 0 and 1 in net.lockstep.alive
    assert net.counts["stall_clock_chain_moved"] == 2 * STALL_TIMEOUTS - 1
    run(STALL_TIMEOUTS + 0.05, moving=False)  # its last move is announced 0.2 s in: no move for 5.85 s ...
    assert net.counts["peers_lost"] == 0 and 1 in net.lockstep.alive
    assert net.counts["stall_clock_chain_moved"] == 2 * STALL_TIMEOUTS
    run(0.3, moving=False)  # ... and past STALL_TIMEOUTS lost timeouts
    assert net.counts["peers_lost_stalled"] == 1 and net.lockstep.lost_why[1] == f"no progress for {STALL_TIMEOUTS:g} s"


def test_a_node_counts_the_advances_of_those_it_waits_for_while_they_are_behind_it_and_announces_them():
    """Robot 0's ``moved``, announced with its progress: an advance of a teammate's progress behind robot 0's next
    input counts; a repeated progress, or an advance from at or beyond its next input, does not."""
    net = offline_net()
    sent: list[Progress] = []
    net.announcer.put = lambda kind, m: sent.append(m)
    s0 = net.inputs.next_key()[0]
    for t in (s0 - 1.0, s0 - 0.5, s0 - 0.5, s0 + 1.0, s0 + 2.0):
        net.lockstep.on_progress(Progress(robot=1, t=t, prio=2))
    assert net.lockstep.moved == 3  # the first (from nothing), then s0 - 0.5 and s0 + 1.0 (from s0 - 0.5)
    net.announcer.announce(s0, force=True)
    assert sent[-1].moved == 3 and net.counts["stall_clock_chain_moved"] == 0


def test_a_lone_node_says_whom_it_waits_for_and_fails_when_no_teammate_ever_answered():
    """A node whose teammates never come logs that it waits (for which robots), and exits 3 with a message saying
    no teammate ever answered. Before, it waited silently and exited 0 with every detection unknown."""
    port = free_ports(1)[0]
    cmd = [sys.executable, "-m", "swarmloc.cli", "node", "--team", f"lone{os.getpid()}", "--robot", "0", "--source",
           "sim:random", "--duration", "10", "--seed", "1", "--start-timeout", "3", "--no-auth", "--listen",
           f"tcp/127.0.0.1:{port}"]  # fmt: skip
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert p.returncode == 3, p.stderr
    assert "still waiting for robots [1, 2]" in p.stderr
    assert "no teammate ever answered: none of robots [1, 2] was seen" in p.stderr


@pytest.mark.parametrize("wait_for", [None, "1", "none"])
def test_a_node_that_saw_no_teammate_says_what_it_waited_for(wait_for, capsys):
    """The exit-3 message says what the node waited for at its start. A joiner (``--wait-for none``: ``swarmloc
    team`` starts a late or restarted robot so) waited for nobody and may have come up after its team ended (at
    ``--speed 0`` the fault table's team read its 30 s source in ~1 s, before the joiner's process was up). Before,
    every node said it had "waited 30 s at the start", a joiner too, and to check --connect and --team only."""
    from argparse import Namespace
    from types import SimpleNamespace

    from swarmloc.cli.commands.node import _node_summary
    from swarmloc.net.schema import Report

    stats = {"detections": 5, "fused": 0, "gated": 0, "rejected": 0, "unknown": 5}
    report = Report(robot=2, stats=stats, net={"teammates_seen": 0})
    args = Namespace(robot=2, wait_for=wait_for, start_timeout=30.0)
    assert _node_summary(args, SimpleNamespace(robots=[0, 1, 2]), report) == 3
    err = capsys.readouterr().err
    assert "no teammate ever answered: none of robots [0, 1] was seen" in err
    if wait_for == "none":
        assert "waited for nobody at the start (--wait-for none)" in err and "30 s" not in err
        assert "may have come up after the team ended" in err
    else:
        whom = "its teammates" if wait_for is None else "robots [1]"
        assert f"waited up to 30 s for {whom} at the start (--start-timeout)" in err
    assert "check --connect and --team" in err
    seen = Report(robot=2, stats=stats, net={"teammates_seen": 1})
    assert _node_summary(args, SimpleNamespace(robots=[0, 1, 2]), seen) == 0


def node_pids(team: str, robot: int | None = None) -> list[int]:
    """Pids of the ``swarmloc node`` processes of ``team`` (of robot ``robot`` only, if given)."""
    out = []
    for pid in leftovers(team):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmd = f.read().decode().split("\0")
        except OSError:
            continue
        if "node" in cmd and (robot is None or cmd[cmd.index("--robot") + 1] == str(robot)):
            out.append(pid)
    return out


def test_a_node_killed_mid_run_is_named_in_the_report_and_its_detections_are_not_claimed(tmp_path):
    """Robot 1's process is SIGKILLed once it reads its source. The others finish (rc 0); the report names robot 1
    with exit code -9 and says its detections are missing from the totals, which are not claimed accounted.
    Before, the report said nothing of it and claimed every detection accounted."""
    from swarmloc.experiments.team import write_team_report

    src = load_source("sim:random", robots=3, duration=20.0, seed=1)
    team = f"killed{os.getpid()}"
    out: dict = {}
    th = threading.Thread(target=lambda: out.update(run=run_team(
        src=src, source="sim:random", robots=3, duration=20.0, seed=1, team=team, speed=2.0, max_wall=120,
        verbose=True, log_dir=tmp_path / "logs")))  # fmt: skip
    th.start()
    killed = None
    t_end = time.monotonic() + 60
    log1 = tmp_path / "logs" / "robot1.log"
    while killed is None and th.is_alive() and time.monotonic() < t_end:
        if log1.exists() and " inputs, present " in log1.read_text():  # robot 1 is in its main loop
            (killed,) = node_pids(team, 1)
            os.kill(killed, signal.SIGKILL)
        th.join(0.05)
    th.join(150)
    assert killed is not None and not th.is_alive()
    tr = out["run"]
    assert not leftovers(team)
    assert tr.exit_codes == {"robot0": 0, "robot1": -9, "robot2": 0}
    assert tr.ended == [{"process": "robot1", "pid": killed, "exit_code": -9, "how": "died (SIGKILL)", "said": ""}]
    rep = write_team_report(tr, src, "expfusion", tmp_path / "out", {})
    ev = rep["estimators"]["expfusion"]
    assert ev["accounted"] is False and ev["detections_missing_of"] == [1]
    md = (tmp_path / "out" / "team.md").read_text()
    assert f"robot1 (pid {killed}) died (SIGKILL), exit code -9: its detections are missing from the totals" in md
    assert sorted(tr.reports) == [0, 2] and ev["stats"]["pending"] == 0


def test_nodes_die_with_their_launcher(tmp_path):
    """``swarmloc team`` SIGKILLed (it can clean nothing up): every node it started is gone within a few seconds
    (the kernel's parent-death signal, and a watchdog on the parent pid, ending a node whose stop hangs). Before,
    they ran on to their end."""
    cmd = [sys.executable, "-m", "swarmloc.cli", "team", "--robots", "3", "--duration", "600", "--speed", "1",
           "--out", str(tmp_path)]  # fmt: skip
    launcher = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    team = f"team{launcher.pid}"
    pids: list[int] = []
    try:
        t_end = time.monotonic() + 60
        while len(pids) < 3 and launcher.poll() is None and time.monotonic() < t_end:
            pids = node_pids(team)
            time.sleep(0.05)  # polling /proc, with a deadline
        assert len(pids) == 3, f"the team's nodes did not start: {pids}"
        launcher.kill()
        launcher.wait()
        t_kill = time.monotonic()
        while node_pids(team) and time.monotonic() < t_kill + 10:
            time.sleep(0.05)  # polling /proc, with a deadline
        left = node_pids(team)
        gone_after = time.monotonic() - t_kill
    finally:
        for pid in node_pids(team):
            os.kill(pid, signal.SIGKILL)
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait()
    assert not left, f"nodes {left} outlived their launcher by 10 s"
    # the hard end: GRACE s after the watchdog's SIGTERM, which comes WATCH_EVERY s after the parent's death at most
    assert gone_after < lifeline.WATCH_EVERY + lifeline.GRACE + 1.0, gone_after


def test_a_run_id_or_team_named_like_a_key_word_does_not_change_whose_key_it_is():
    # robot_of reads the id from the key's end: a run or team named "robot" or "alive" must not be taken for it
    assert robot_of(robot_key(team_scope("robot", "alive"), 3, "belief")) == 3
    assert robot_of(alive_key(team_scope("alive", "robot"), 7)) == 7
    assert robot_of(robot_key(team_scope("t", "robot"), 12, "inbox")) == 12
    assert robot_of(alive_key("t", "server")) is None
    assert robot_of(robot_key("t", "*", "progress")) is None
    try:
        team_scope("t", "a/b")
    except ValueError as exc:
        assert "run id" in str(exc)
    else:
        raise AssertionError("a run id with '/' was taken")


def test_two_teams_of_one_name_on_one_network_do_not_hear_each_other(tmp_path):
    """Two teams named alike run at once on one network (six Zenoh peers, each connected to all the others). Each
    run has its own id in its key expressions, so each team ends as it ends alone: the in-process outcomes, and
    no message of the other team received (no duplicate query or reply, nothing dropped, no robot lost). Before
    (no run id), each node heard its namesake's progress, queries and replies too. ``swarmloc team`` gives every
    run an id of its own (checked last)."""
    from swarmloc.events import Odometry
    from swarmloc.net.auth import TeamKeys
    from swarmloc.net.faults import Faults
    from swarmloc.net.team import _Launcher

    src = load_source("sim:random", robots=3, duration=10.0, seed=1)
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(6)]
    sessions = [open_session([e], [o for o in eps if o != e]) for e in eps]
    nets, reports = [], {}
    try:
        for i, s in enumerate(sessions):
            r = src.robots[i % 3]
            ev = src.own_events(r)
            node = make_node("rdl", r, src.initial[r], src.config, src.landmarks)
            node.start(min(e.t0 if isinstance(e, Odometry) else e.stamp for e in ev))
            nets.append(NetNode(node, ev, session=s, team="same", roster=src.robots, record_times=src.record_times(),
                                run_id=f"run{i // 3}"))  # fmt: skip
        threads = [threading.Thread(target=lambda i=i, n=n: reports.__setitem__(i, n.run(max_wall=60)))
                   for i, n in enumerate(nets)]  # fmt: skip
        for t in threads:
            t.start()
        for t in threads:
            t.join(90)
    finally:
        for n in nets:
            n.stop()
        for s in sessions:
            s.close()
    assert sorted(reports) == list(range(6))
    ref = reference_stats(src, "rdl")
    for team in (0, 1):
        got = Counter()
        for i in range(3 * team, 3 * team + 3):
            got.update({k: reports[i].stats[k] for k in OUTCOMES})
            heard = {k: reports[i].net.get(k, 0) for k in ("duplicate_replies", "duplicate_queries", "rejected",
                                                          "peers_lost")}  # fmt: skip
            assert heard == dict.fromkeys(heard, 0), (i, heard, reports[i].net_reasons)
            assert reports[i].stats.get("messages_rejected", 0) == 0, reports[i].reasons
        assert dict(got) == {k: ref[k] for k in OUTCOMES}
    keys = TeamKeys([0, 1], tmp_path)
    a, b = (_Launcher("same", [0, 1], [], Faults(), False, (), None, keys, []) for _ in range(2))
    assert a.run_id != b.run_id and a.args_for("robot0")[:4] == ["--team", "same", "--run-id", a.run_id]


def test_traffic_that_never_settles_does_not_hold_a_node_at_its_end():
    """At its end a node waits for the traffic to settle, now at most ``linger`` s once the team has read its
    sources, then finishes (counted ``never_settled``). Before, a neighbour that never stopped sending held it
    with no bound but the run's wall time."""
    from types import SimpleNamespace

    net = offline_net(linger=0.5)
    net.session = net.wiring.pub["progress"] = net.wiring.pub["belief"] = SimpleNamespace(put=lambda *a, **k: None)
    net.inputs.i = len(net.inputs.items)  # its source read; robots 1 and 2 not alive: the team has read its sources
    flood = _Flood(b"not a message")
    flood.get = flood.get_nowait = lambda timeout=None: ("inbox", flood.sample)  # neighbours' traffic, forever
    net.inbound.intake = flood
    th = threading.Thread(target=net._finish, args=(math.inf,), daemon=True)
    t0 = time.monotonic()
    th.start()
    th.join(10.0)
    returned = not th.is_alive()
    net._stop.set()  # ends a wait that did not end by itself
    th.join(5.0)
    assert returned, "the node's end waited 10 s for traffic that never settles"
    assert time.monotonic() - t0 < 2 * 0.5 + 1.0 and net.counts["never_settled"] == 1


def test_a_process_that_fails_is_named_with_what_it_said_and_an_empty_run_still_gets_its_report(tmp_path):
    """A node that exits with an error is named with the last lines it wrote, also without a log folder (before,
    its output went to /dev/null and the team said only "exit code 2"); a run that collected nothing still writes
    its report, saying whose detections are missing (before: a matplotlib error, "Number of columns must be a
    positive integer, not 0", and no report)."""
    from swarmloc.experiments.team import write_team_report
    from swarmloc.net.auth import TeamKeys
    from swarmloc.net.faults import Faults
    from swarmloc.net.team import TeamRun, _Launcher

    launcher = _Launcher("t", [0], [], Faults(), False, (), None, TeamKeys([0], tmp_path / "keys"), [])
    said = "import sys; print('swarmloc node: the roster has no key for robots [0]', file=sys.stderr); sys.exit(2)"
    launcher.spawn("robot0", [sys.executable, "-c", said])
    launcher.procs["robot0"].wait(timeout=30)
    launcher.note_ended()
    assert launcher.result.ended[0]["exit_code"] == 2
    assert "the roster has no key for robots [0]" in launcher.result.ended[0]["said"]
    src = load_source("sim:random", robots=3, duration=6.0, seed=0)
    rep = write_team_report(TeamRun(run_id="x"), src, "dekf", tmp_path / "o", {})
    assert rep["figures"] == [] and rep["estimators"]["dekf"]["detections_missing_of"] == [0, 1, 2]
    assert "robot0 sent no report" in (tmp_path / "o" / "team.md").read_text()
