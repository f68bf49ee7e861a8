"""``diekf`` over the network: its updates broadcast to the whole team, numbered per sender, lost ones repaired
(:mod:`swarmloc.net.broadcast`).

Offline (a :class:`NetNode` on a recording session, no network): numbering, duplicates applied once, an update
overtaken by a newer revision of its exchange dropped, gaps asked for, the buffer answering repairs (or "gone"),
the schema's bounds, and signatures (a broadcast on another robot's key, a replayed frame). Live (127.0.0.1 only):
a team of three processes equals the in-process run to 1e-6; under link faults nothing is fused twice and lost
broadcasts are repaired.
"""

from __future__ import annotations

import os
from collections import Counter

import msgspec
import numpy as np
import pytest
from test_net import _Payload, _Session, leftovers, max_diff, reference, thread_team

from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.messages import TeamUpdate, flat
from swarmloc.net import broadcast as bc
from swarmloc.net.auth import TeamKeys, seal
from swarmloc.net.entry import distributed_class, make_node
from swarmloc.net.faults import parse_faults
from swarmloc.net.process import NetNode
from swarmloc.net.schema import Broadcast, BroadcastHead, BroadcastRepair, Rejected, decode, encode
from swarmloc.net.transport import robot_key

pytestmark = pytest.mark.network


COV = flat(np.diag([0.01, 0.01, 0.001]))


class _Sample:
    def __init__(self, raw: bytes, key: str = "") -> None:
        self.payload = _Payload(raw)
        self.key_expr = key


class _Pub:
    def __init__(self, sess: _BSession, key: str) -> None:
        self.sess, self.key = sess, key

    def put(self, payload: bytes, **kw) -> None:
        self.sess.published.append((self.key, payload))

    def undeclare(self) -> None:
        pass


class _BSession(_Session):
    """A recording session that also declares publishers (broadcasts) and keeps what is pushed."""

    def __init__(self) -> None:
        super().__init__()
        self.published: list[tuple[str, bytes]] = []
        self.pushed: list[tuple[str, bytes]] = []

    def declare_publisher(self, key, **kw) -> _Pub:
        return _Pub(self, key)

    def put(self, key, payload, **kw) -> None:
        super().put(key, payload)
        self.pushed.append((key, payload))


def offline_diekf(robot: int = 0, **kw) -> tuple[NetNode, object]:
    src = load_source("sim:random", robots=3, duration=4.0, seed=0)
    node = make_node("diekf", robot, src.initial[robot], src.config, src.landmarks, team=src.robots)
    node.start(src.t_start)
    net = NetNode(node, src.own_events(robot), session=_BSession(), team="t", roster=src.robots,
                  record_times=src.record_times(), **kw)  # fmt: skip
    net.wiring.pub["belief"] = _Pub(net.session, "belief")  # never opened: the beliefs it publishes are recorded
    return net, src


def update(sender: int, t: float, sub: float = 0.0, nu: float = 0.1) -> TeamUpdate:
    """A landmark update of ``sender`` (``target = sender``, ``H_j = 0``), as it travels: to the team."""
    Hi = flat(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    return TeamUpdate(sender=sender, receiver=-1, stamp=t, sub=(sub,), target=sender, m=2, Hi=Hi,
                      Hj=(0.0,) * 6, Sinv=flat(np.eye(2)), nu=(nu, 0.0), Pii=COV, Pjj=COV)  # fmt: skip


def bsample(b, seq: int = 0) -> _Sample:
    return _Sample(encode("t", b.robot, seq, b))


def test_diekf_is_a_networked_estimator():
    assert distributed_class("diekf").name == "diekf"
    net, src = offline_diekf()
    assert net.broadcasts and net.node.team == tuple(src.robots)


def test_broadcasts_are_applied_once_in_number_order_and_gaps_are_asked_for():
    net, src = offline_diekf(robot=0)
    t = src.t_start + 0.5
    net.inbound.handle("broadcast", bsample(Broadcast(robot=1, n=0, update=update(1, t))))
    net.inbound.handle("broadcast", bsample(Broadcast(robot=1, n=0, update=update(1, t)), seq=1))  # a duplicate copy
    assert net.counts["broadcasts_applied"] == 1 and net.counts["broadcast_duplicates"] == 1
    assert net.node.counts["messages"] == 1  # the node saw it once
    # number 2 comes before 1: applied; 1 is missing and asked for once it has waited repair_wait s
    net.inbound.handle("broadcast", bsample(Broadcast(robot=1, n=2, update=update(1, t + 0.1, nu=0.2)), seq=2))
    assert net.broadcaster._peers[1].missing() == [1] and net.broadcaster.busy()
    net.broadcaster.ask_missing(net.broadcaster._peers[1].missing_since[1] + net.broadcaster.repair_wait / 2)
    assert net.counts["repair_requests"] == 0  # too early: a late copy may still come
    net.broadcaster.ask_missing(net.broadcaster._peers[1].missing_since[1] + net.broadcaster.repair_wait + 1e-3)
    assert net.counts["repair_requests"] == 1
    key, raw = net.session.pushed[-1]
    assert key == robot_key("t", 1, "inbox")
    assert decode(raw, "t", src.robots, to_robot=1).body == BroadcastRepair(sender=0, receiver=1, first=1, last=1)
    # the repair of number 1 comes on the inbox: an older revision of the exchange that number 2 revised
    old = Broadcast(robot=1, n=1, to=0, update=update(1, t + 0.1, nu=0.3))
    net.inbound.handle("inbox", bsample(old, seq=3))
    assert net.counts["broadcasts_repaired"] == 1 and net.counts["broadcast_stale"] == 1
    assert not net.broadcaster.busy() and net.broadcaster._peers[1].low == 3
    assert net.counts["broadcasts_received"] == 4 and net.counts["received"] == 4  # every one counted
    assert net.node.counts["messages"] == 2  # n = 0 and 2, each once; the stale revision never reached the node


def test_a_head_reveals_the_last_broadcasts_lost_and_holds_what_is_keyed_after_them():
    net, src = offline_diekf(robot=0)
    net.lockstep.alive |= {1, 2}
    key = (src.t_start + 1.0, 1, 0)
    assert "no broadcast head from robot 1" in net.broadcaster.unsettled(key)
    net.inbound.handle("broadcast", bsample(BroadcastHead(robot=1, n=0, t=src.t_start + 0.5, prio=1)))
    net.inbound.handle("broadcast", bsample(BroadcastHead(robot=2, n=0, t=src.t_start + 2.0, prio=1)))
    assert "robot 1 may still broadcast" in net.broadcaster.unsettled(key)
    net.inbound.handle("broadcast", bsample(BroadcastHead(robot=1, n=2, t=src.t_start + 2.0, prio=1), seq=1))
    assert net.broadcaster._peers[1].missing() == [0, 1]  # its two broadcasts never came
    assert "robot 1's broadcasts below 2" in net.broadcaster.unsettled(key)
    for n in (0, 1):
        net.broadcaster.on_broadcast(Broadcast(robot=1, n=n, to=0, update=update(1, src.t_start + 0.2 * (n + 1))))
    assert net.broadcaster.unsettled(key) is None


class _Clock:
    """The broadcaster's wall clock (``time.monotonic``), set by the test."""

    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now


def _heads(net: NetNode, since: int = 0) -> list[BroadcastHead]:
    """The heads ``net`` published (from its ``since``-th publication on)."""
    bodies = [decode(p, "t", {0, 1, 2}).body for _, p in net.session.published[since:]]
    return [b for b in bodies if isinstance(b, BroadcastHead)]


def test_a_mate_that_starts_hearing_a_sender_asks_for_its_head_and_gets_it_at_once(monkeypatch):
    """A receiver without the head of a live mate it hears (it subscribed after the head was announced) asks its
    sender for it once it has waited ``repair_wait`` s, and again while it has none; the sender announces its
    unchanged head at its next flush (at most once per ``repair_wait`` s, however many ask), not a heartbeat later.
    Before, the receiver waited for the sender's heartbeat (every second of wall time)."""
    clock = _Clock()
    monkeypatch.setattr(bc, "time", clock)
    sender, src = offline_diekf(robot=1)
    sender.broadcaster.flush()
    assert len(_heads(sender)) == 1  # announced before the receiver heard it: lost to it
    receiver, _ = offline_diekf(robot=0)
    receiver.lockstep.alive |= {1, 2}
    rb = receiver.broadcaster
    rb.ask_missing(clock.now)
    assert receiver.counts["head_requests"] == 0  # not yet: the head may still be on its way
    clock.now += rb.repair_wait + 1e-3
    rb.ask_missing(clock.now)
    pushed = receiver.session.pushed
    asks = [decode(p, "t", src.robots, to_robot=r).body for r, (_, p) in zip((1, 2), pushed, strict=True)]
    assert asks == [BroadcastRepair(sender=0, receiver=r, first=0, last=-1, head=True) for r in (1, 2)]
    rb.ask_missing(clock.now + 1e-3)
    assert receiver.counts["head_requests"] == 2  # asked again only after 2 repair_wait + 0.2 s
    sender.inbound.handle("inbox", _Sample(receiver.session.pushed[0][1]))
    sender.inbound.handle("inbox", _Sample(encode("t", 0, 9, asks[0])))  # asked twice: announced once
    assert sender.counts["head_requests_received"] == 2 and sender.counts["repairs_sent"] == 0
    sender.broadcaster.flush()
    sender.broadcaster.flush()
    assert len(_heads(sender)) == 2  # announced again at once (long before a heartbeat), once
    receiver.inbound.handle("broadcast", _Sample(sender.session.published[-1][1]))
    sender.inbound.handle("inbox", _Sample(encode("t", 0, 10, asks[0])))
    sender.broadcaster.flush()
    assert len(_heads(sender)) == 2  # asked again: its last announcement less than repair_wait s ago
    clock.now += sender.broadcaster.repair_wait + 1e-3
    sender.broadcaster.flush()
    assert len(_heads(sender)) == 3
    assert "no broadcast head from robot 1" not in rb.unsettled((src.t_start + 1.0, 1, 0))
    clock.now += 10.0
    rb.ask_missing(clock.now)
    assert receiver.counts["head_requests"] == 3  # robot 2 still has not answered; robot 1 is not asked again
    assert [decode(p, "t", src.robots, to_robot=2).body.receiver for _, p in receiver.session.pushed[2:]] == [2]


def test_an_unchanged_head_is_announced_again_per_second_of_data_and_reveals_the_last_broadcast_lost(monkeypatch):
    """A sender's unchanged head is announced again once its present has moved ``HEAD_EVERY`` s of data on, or after
    ``lost_timeout`` s of wall time (a sender that waits), not every second of wall time: a replay slower than real
    time no longer receives more of them per second of data. A receiver that lost the sender's last broadcast and
    the head that came with it (a link down) learns of it from that repeat and asks for it."""
    clock = _Clock()
    monkeypatch.setattr(bc, "time", clock)
    sender, src = offline_diekf(robot=1)
    b, t0 = sender.broadcaster, sender.node.present

    def flush_at(wall: float, present: float) -> int:
        clock.now, sender.node._clock.present = wall, present
        b.flush()
        return len(_heads(sender))

    start = clock.now
    assert flush_at(start, t0) == 1
    assert flush_at(start + 9.0, t0 + 0.9) == 1  # 9 s of wall time, 0.9 s of data: not yet (before, 9 heartbeats)
    assert flush_at(start + 9.5, t0 + 1.0 + 1e-9) == 2  # a second of data
    lost = sender.lockstep.settings.lost_timeout
    assert flush_at(start + 9.5 + lost - 0.1, t0 + 1.5) == 2
    assert flush_at(start + 9.5 + lost, t0 + 1.5) == 3  # the present has not moved on: lost_timeout s of wall time
    assert len({(h.n, h.t, h.prio) for h in _heads(sender)}) == 1 and sender.counts["broadcast_heads_sent"] == 3
    b.queue(msgspec.structs.replace(update(1, src.t_start + 0.5), receiver=0))
    for dt in (0.25, 0.5):  # the broadcast and its head, then its head once the group is quiet: lost to the receiver
        flush_at(start + 9.5 + lost + dt, t0 + 1.5)
    assert [h.n for h in _heads(sender, since=3)] == [1, 1]
    receiver, _ = offline_diekf(robot=0)
    receiver.inbound.handle("broadcast", _Sample(sender.session.published[0][1]))  # the first head: n = 0
    assert flush_at(clock.now + 0.1, t0 + 2.5 + 1e-9) == 6  # the repeat, a second of data on
    receiver.inbound.handle("broadcast", _Sample(sender.session.published[-1][1]))
    assert receiver.broadcaster._peers[1].missing() == [0]
    receiver.broadcaster.ask_missing(clock.now + receiver.broadcaster.repair_wait + 1e-3)
    assert receiver.counts["repair_requests"] == 1


def test_the_sender_answers_repairs_from_its_buffer_and_says_when_one_is_gone(monkeypatch):
    monkeypatch.setattr(bc, "BUFFER", 2)
    net, src = offline_diekf(robot=1)
    t = src.t_start + 0.5
    for k in range(3):  # the node's copies for teammates 0 and 2: one broadcast per exchange
        for r in (0, 2):
            net.broadcaster.queue(msgspec.structs.replace(update(1, t + k), receiver=r))
        net.broadcaster.flush()
    sent = [decode(p, "t", src.robots).body for _, p in net.session.published]
    assert [b.n for b in sent if isinstance(b, Broadcast)] == [0, 1, 2] and net.counts["broadcasts_sent"] == 3
    assert all(b.update.receiver == -1 for b in sent if isinstance(b, Broadcast))
    net.inbound.handle("inbox", _Sample(encode("t", 0, 9, BroadcastRepair(sender=0, receiver=1, first=0, last=5))))
    got = [decode(p, "t", src.robots, to_robot=0).body for _, p in net.session.pushed]
    assert [(b.n, b.to, b.update is None) for b in got] == [(0, 0, True), (1, 0, False), (2, 0, False)]
    assert net.counts["repairs_gone"] == 1 and net.counts["repairs_sent"] == 2
    # the asker gives a gone broadcast up (counted) instead of asking for it forever
    asker, _ = offline_diekf(robot=0)
    asker.broadcaster.on_broadcast(got[0])
    assert asker.counts["broadcasts_given_up"] == 1 and asker.broadcaster._peers[1].low == 1


@pytest.mark.parametrize(
    ("body", "reason"),
    [
        (Broadcast(robot=1, n=-1, update=update(1, 1.0)), "outside"),
        (Broadcast(robot=1, n=0), "only a repair may say"),
        (Broadcast(robot=1, n=0, update=update(2, 1.0)), "from the broadcasting robot"),
        (Broadcast(robot=1, n=0, update=msgspec.structs.replace(update(1, 1.0), receiver=0)), "receiver -1"),
        (Broadcast(robot=1, n=0, update=msgspec.structs.replace(update(1, 1.0), m=4)), "m must be 1, 2 or 3"),
        (Broadcast(robot=1, n=0, update=msgspec.structs.replace(update(1, 1.0), nu=(np.nan, 0.0))), "finite"),
        (Broadcast(robot=1, n=0, to=2, update=update(1, 1.0)), "addressed to robot 2"),
        (Broadcast(robot=0, n=0, update=update(0, 1.0)), "received by itself"),
        (BroadcastHead(robot=1, n=0, t=float("nan")), "NaN"),
        (BroadcastRepair(sender=1, receiver=0, first=5, last=4), "not an interval"),
        (BroadcastRepair(sender=1, receiver=0, first=5, last=3, head=True), "not an interval"),
        (BroadcastRepair(sender=1, receiver=0, first=0, last=10**6), "at most 256"),
        (BroadcastRepair(sender=1, receiver=2, first=0, last=1), "addressed to robot 2"),
    ],
)
def test_broadcast_schema_bounds(body, reason):
    sender = body.sender if isinstance(body, BroadcastRepair) else body.robot
    with pytest.raises(Rejected, match=reason):
        decode(encode("t", sender, 0, body), "t", {0, 1, 2}, to_robot=0)


def test_signed_broadcasts_owner_checked_and_replays_refused(tmp_path):
    keys = TeamKeys([0, 1, 2], tmp_path / "keys")
    net, src = offline_diekf(robot=0, auth=keys.auth(0))
    k1 = robot_key("t", 1, "broadcast")
    b = Broadcast(robot=2, n=0, update=update(2, src.t_start + 0.5))
    forged = seal(keys.auth(2), k1, encode("t", 2, 0, b))  # robot 2 signs, on robot 1's broadcast key
    net.inbound.handle("broadcast", _Sample(forged, k1))
    assert net.counts["auth_not_owner"] == 1 and net.counts["broadcasts_applied"] == 0
    k2 = robot_key("t", 2, "broadcast")
    good = seal(keys.auth(2), k2, encode("t", 2, 0, b))
    net.inbound.handle("broadcast", _Sample(good, k2))
    net.inbound.handle("broadcast", _Sample(good, k2))  # the same frame again
    assert net.counts["broadcasts_applied"] == 1 and net.counts["auth_replay"] == 1
    assert net.counts["received"] == 3


# ------------------------------------------------------------------------------------------------ live
def test_diekf_networked_equals_in_process_on_a_simulated_team():
    src = load_source("sim:random", robots=3, duration=20.0, seed=1)
    team = f"eqdiekf{os.getpid()}"
    tr = run_team(src=src, source="sim:random", robots=3, duration=20.0, seed=1, estimator="diekf", team=team,
                  max_wall=120)  # fmt: skip
    assert not leftovers(team)
    assert all(c == 0 for c in tr.exit_codes.values()), tr.exit_codes
    res = team_result(tr, src, "diekf")
    assert res.stats["reports"] == 3 and res.stats["recorded_provisional_only"] == 0
    assert max_diff(res, reference(src, "diekf")) <= 1e-9  # every recorded mean and covariance
    assert res.stats["fused"] > 50
    s = res.stats  # all to all: each broadcast applied by both teammates, none repaired or dropped
    assert s["net_broadcasts_sent"] >= s["fused"] and s["net_broadcasts_applied"] == 2 * s["net_broadcasts_sent"]
    assert s.get("net_repair_requests", 0) == 0 and s.get("net_broadcast_duplicates", 0) == 0


def test_diekf_in_clusters_networked_equals_in_process(tmp_path):
    """``[filter] diekf_cluster = 2`` on 5 node processes (clusters {0, 1}, {2, 3}, {4}): each node subscribes to its
    cluster's broadcasts only, asks outsiders their belief, and the run equals the in-process one; every broadcast
    is applied by the sender's cluster mates only (none by robot 4, alone in its cluster)."""
    from swarmloc.config import load_config

    cfg = tmp_path / "clusters.toml"
    cfg.write_text("[filter]\ndiekf_cluster = 2\n")
    src = load_source("sim:random", robots=5, duration=8.0, seed=1, config=load_config(cfg))
    team = f"eqdiekfcl{os.getpid()}"
    tr = run_team(src=src, source="sim:random", robots=5, duration=8.0, seed=1, estimator="diekf", team=team,
                  max_wall=180, config_file=str(cfg))  # fmt: skip
    assert not leftovers(team)
    assert all(c == 0 for c in tr.exit_codes.values()), tr.exit_codes
    res = team_result(tr, src, "diekf")
    assert res.stats["reports"] == 5 and res.stats["recorded_provisional_only"] == 0
    assert max_diff(res, reference(src, "diekf")) <= 1e-9
    assert res.stats["fused"] > 100
    sent = {r: rep.net.get("broadcasts_sent", 0) for r, rep in tr.reports.items()}
    applied = {r: rep.net.get("broadcasts_applied", 0) for r, rep in tr.reports.items()}
    assert applied[0] == sent[1] and applied[1] == sent[0] and applied[2] == sent[3] and applied[3] == sent[2]
    assert applied[4] == 0 and sent[0] > 0 and sent[2] > 0


def test_diekf_under_link_faults_fuses_nothing_twice_and_repairs_lost_broadcasts():
    # short waits: a lost query or reply holds the lockstep team for its answer timeout (2 s by default; 4 s of the
    # scene took 110 s of wall time), and the test is of what is fused and repaired, not of how long a loss costs
    src = load_source("sim:random", robots=3, duration=3.0, seed=3)
    f = parse_faults("loss=0.2,delay=0.1,dup=0.1,seed=1")
    nets, reports = thread_team(src, "diekf", faults=f, ledger=True, max_wall=300, answer_timeout=0.3,
                                hold_timeout=0.15, update_timeout=0.3)  # fmt: skip
    net = Counter()
    for r in reports.values():
        net.update(r.net)
    assert net["injected_lost"] > 10 and net["duplicated"] > 0  # the faults did happen
    assert net["repair_requests"] > 0 and net["broadcasts_repaired"] > 0  # lost broadcasts were asked for and came
    assert net["broadcast_duplicates"] > 0  # duplicated copies came, and were applied once
    assert net["broadcasts_applied"] + net["broadcast_stale"] + net["broadcasts_given_up"] <= net["broadcasts_received"]
    for n in nets:
        st_ = n.node.stats()
        assert st_["detections"] == st_["fused"] + st_["gated"] + st_["rejected"] + st_["unknown"] + st_["pending"]
        assert st_["pending"] == 0
        per_measurement: Counter = Counter()
        for (obs, t, k, outcome), c in n.node.ledger.items():
            assert c in (0, 1), f"measurement {(obs, t, k)} counted {c} times as {outcome}"
            per_measurement[(obs, t, k)] += c
        assert per_measurement and set(per_measurement.values()) == {1}  # one outcome each: none fused twice
        for t in src.record_times()[-5:]:
            b = n.node.belief_at(t)
            assert np.isfinite(b.mean).all() and np.isfinite(b.cov).all()


def test_a_broadcast_stamped_ahead_publishes_the_beliefs_it_makes_final_first():
    """A teammate's broadcast stamped past the node's present moves the present: the beliefs that become final
    (a horizon before it) are published first, before the history's pruning can drop what they are computed from.
    Before: nothing was published there, and on all of MRCLAM 6 (``flsd``, 5 processes) 22 of 15,120 records stayed
    provisional, 11 of them different from the in-process run."""
    net, src = offline_diekf(robot=0)
    t = src.t_start + 3.0
    for e in src.own_events(0):
        if e.stamp <= t:
            net.node.step(e)  # the node's own inputs, without the driver's publishing
    assert net.counts["beliefs_published"] == 0 and net.node.present <= t
    ahead = t + 4.0  # within the clock tolerance, a horizon (5 s) past the first record times
    net.inbound.handle("broadcast", bsample(Broadcast(robot=1, n=0, update=update(1, ahead))))
    assert net.counts["broadcasts_applied"] == 1 and net.node.present == ahead
    final = [b for b in net.publishing.published.values() if b.final]
    due = src.record_times()[src.record_times() < ahead - net.node.horizon]
    assert len(due) >= 4 and sorted(b.stamp for b in final) == due.tolist()
