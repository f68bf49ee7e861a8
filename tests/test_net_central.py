"""A centralized estimator hosted by the belief server (:mod:`swarmloc.net.central`): the robots forward their raw
measurements, the server fuses them in key order.

Without a network: the forwards of the robots interleaved in any order (and one robot's overtaking each other) give
the in-process run exactly; a missing forward is asked for again; one lost for good is counted with what it carried,
and every detection stays accounted for.
Live (127.0.0.1 only, bounded, every process stopped): ``swarmloc team --estimator cekf|iekf`` equals the in-process
run to 1e-9; under loss the missing forwards are asked for again and the run still equals it; an attacker holding
robot 2's key forwarding in robot 1's name is refused and counted at the server, and the run equals the clean one to
1e-9.
"""

from __future__ import annotations

import ast
import json
import math
import os
import random
import re
from pathlib import Path

import numpy as np
import pytest
from _attacker import attacker_process

from swarmloc.estimators import make_team, node_options
from swarmloc.events import Detection
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.lie import SE2
from swarmloc.net.auth import make_team_keys
from swarmloc.net.central import LOST_REASON, Fusion, batches, to_wire
from swarmloc.net.entry import hosted_class, network_class
from swarmloc.net.schema import SERVER, Raw, RawDetection, RawOdometry, Rejected, decode, encode
from swarmloc.net.transport import free_ports
from swarmloc.runner import run

pytestmark = pytest.mark.network


ATTACKER = Path(__file__).with_name("net_raw_attacker.py")


@pytest.fixture(scope="module")
def src():
    return load_source("sim:random", robots=3, duration=15.0, seed=1)


def reference(src, est: str):
    return run(make_team(est, src.initial, **node_options(est, src.config, src.landmarks)), src.events,
               src.record_times(), truth=src.truth)  # fmt: skip


def forwards(src, robot: int, size: int = 16) -> list[Raw]:
    """Robot ``robot``'s forwards as a :class:`~swarmloc.net.central.Forwarder` sends them (through the wire)."""
    evs = src.own_events(robot)
    bs = batches(evs, size)
    first = min(e.stamp for e in evs)
    out, odo, det = [], 0, 0
    for n, b in enumerate(bs):
        nxt = (
            (math.inf, 1) if n + 1 == len(bs) else (bs[n + 1][0].stamp, 1 if isinstance(bs[n + 1][0], Detection) else 2)
        )
        d = sum(isinstance(e, Detection) for e in b)
        odo, det = odo + len(b) - d, det + d
        raw = Raw(robot=robot, n=n, first=first, upto=nxt[0], prio=nxt[1], odometry=odo, detections=det,
                  items=tuple(to_wire(e) for e in b))  # fmt: skip
        out.append(decode(encode("t", robot, 0, raw), "t", set(src.robots)).body)
    return out


def fusion(src, est: str, **kw) -> Fusion:
    (node,) = make_team(est, src.initial, **node_options(est, src.config, src.landmarks))
    return Fusion(node, src.robots, src.record_times(), **kw)


def max_error(beliefs, ref) -> float:
    """Largest difference of pose (x, y, theta) and covariance between the beliefs and the in-process tracks."""
    got = {(b.robot, b.stamp): b for b in beliefs}
    err = 0.0
    for r, tr in ref.tracks.items():
        for i, t in enumerate(tr.times.tolist()):
            b = got[(r, t)]
            xyt = SE2.to_xytheta(np.reshape(b.mean, (3, 3)))
            err = max(err, np.abs(xyt - tr.mean[i]).max(), np.abs(np.reshape(b.cov, (3, 3)) - tr.cov[i]).max())
    return err


# ------------------------------------------------------------------------------------------------ without a network
@pytest.mark.parametrize("est", ["cekf", "iekf", "fej"])
def test_forwards_in_any_order_give_the_in_process_run(src, est):
    """Three robots' forwards arrive interleaved at random, and within one robot two forwards swapped (the later one
    waits for the gap): the beliefs are the in-process run's, bit for bit, every record time of every robot."""
    ref = reference(src, est)
    f = fusion(src, est, gap_timeout=math.inf)
    streams = {r: forwards(src, r) for r in src.robots}
    s0 = streams[0]
    s0[2], s0[3] = s0[3], s0[2]
    rng, out = random.Random(7), []
    while any(streams.values()):
        r = rng.choice([r for r in streams if streams[r]])
        f.offer(streams[r].pop(0))
        out += f.pump()
    assert f.done and f.counts["raw_received"] == sum(len(forwards(src, r)) for r in src.robots)
    assert len(out) == 3 * src.record_times().size
    assert max_error(out, ref) == 0.0
    rep = f.report()
    assert rep.stats["detections"] == ref.stats["detections"] == sum(isinstance(e, Detection) for e in src.events)
    assert rep.stats["fused"] == ref.stats["fused"]


def test_no_measurement_is_fused_before_every_stream_is_past_it(src):
    """Robot 0 forwards everything, robots 1 and 2 nothing yet: nothing is fused (the node is not even started);
    once robot 1 has forwarded, still nothing past robot 2's unknown position."""
    f = fusion(src, "cekf")
    for raw in forwards(src, 0):
        f.offer(raw)
    assert f.pump() == [] and not f.node.started and f.counts["fused_inputs"] == 0
    for raw in forwards(src, 1):
        f.offer(raw)
    assert f.pump() == [] and f.counts["fused_inputs"] == 0
    first2 = forwards(src, 2)[0]
    f.offer(first2)
    f.pump()
    assert 0 < f.counts["fused_inputs"] < len(src.events)
    mark = (first2.upto, first2.prio)
    for s in f.streams.values():  # everything left unfused is keyed at or past robot 2's position
        assert all(k >= mark for k, _ in s.items)


def test_a_lost_forward_is_counted_with_what_it_carried(src):
    """Robot 1's forward 2 never arrives: after the gap wait it is counted lost, with exactly its detections and
    odometry records; its detections end ``unknown`` with the reason, so the report accounts for every detection."""
    now = [0.0]
    f = fusion(src, "cekf", gap_timeout=1.0, clock=lambda: now[0])
    streams = {r: forwards(src, r) for r in src.robots}
    lost = streams[1].pop(2)
    lost_det = sum(isinstance(i, RawDetection) for i in lost.items)
    lost_odo = sum(isinstance(i, RawOdometry) for i in lost.items)
    assert lost_det > 0
    for r in src.robots:
        for raw in streams[r]:
            f.offer(raw)
            f.pump()
    assert not f.done  # robot 1's stream waits for forward 2
    now[0] = 2.0
    f.pump()
    assert f.done
    c = f.counts
    assert (c["raw_lost_forwards"], c["raw_lost_detections"], c["raw_lost_odometry"]) == (1, lost_det, lost_odo)
    rep = f.report()
    s = rep.stats
    n_det = sum(isinstance(e, Detection) for e in src.events)
    assert s["detections"] == n_det and rep.reasons[LOST_REASON] == lost_det
    assert s["detections"] == s["fused"] + s["gated"] + s["rejected"] + s["unknown"] and s["pending"] == 0


def test_a_missing_forward_is_asked_for_again_and_repaired(src):
    """Robot 1's forward 2 is missing: after ``repair_wait`` s the server asks robot 1 for exactly that number (again
    every ``repair_wait`` s, not more often); when it comes, it is counted repaired and nothing is lost."""
    now = [0.0]
    f = fusion(src, "cekf", repair_wait=0.2, clock=lambda: now[0])
    streams = {r: forwards(src, r) for r in src.robots}
    missing = streams[1].pop(2)
    for r in src.robots:
        for raw in streams[r]:
            f.offer(raw)
    f.pump()
    assert f.wanted() == []  # not yet: a delayed forward may still come
    now[0] = 0.3
    f.pump()
    (ack,) = f.wanted()
    assert (ack.robot, ack.next, ack.missing) == (1, 2, (2,))
    assert f.wanted() == []  # asked 0 s ago
    f.offer(missing)
    f.pump()
    assert f.done and f.counts["raw_repaired"] == 1 and f.counts["raw_lost_forwards"] == 0


def test_a_silent_robot_is_lost_and_the_others_go_on(src):
    now = [0.0]
    f = fusion(src, "cekf", lost_timeout=5.0, start_timeout=5.0, clock=lambda: now[0])
    for r in (0, 1):
        for raw in forwards(src, r):
            f.offer(raw)
    assert f.pump() == []
    now[0] = 6.0
    out = f.pump()
    assert f.done and f.counts["robots_lost"] == 1 and len(out) == 3 * src.record_times().size


def test_a_paced_robot_heard_from_is_not_lost(src):
    """A robot with nothing to forward for longer than ``lost_timeout`` but announcing its progress is waited for."""
    now = [0.0]
    f = fusion(src, "cekf", lost_timeout=5.0, clock=lambda: now[0])
    fw = {r: forwards(src, r) for r in src.robots}
    for r in src.robots:
        f.offer(fw[r][0])
    f.pump()
    for t in (4.0, 8.0, 12.0):
        now[0] = t
        f.hear(1)
        f.pump()
    assert f.counts["robots_lost"] == 2 and not f.streams[1].lost  # robots 0 and 2 said nothing


def test_batches_keep_groups_whole_and_bound_size_and_span(src):
    evs = src.own_events(0)
    for size, span in ((1, math.inf), (16, math.inf), (64, 0.2)):
        bs = batches(evs, size, span)
        assert [e for b in bs for e in b] == sorted(evs, key=lambda e: (e.stamp, 1 if isinstance(e, Detection) else 2))
        for a, b in zip(bs, bs[1:], strict=False):  # a key (a detection group) never split across two forwards
            assert (a[-1].stamp, type(a[-1])) != (b[0].stamp, type(b[0]))
        for b in bs:  # beyond ``size`` only the rest of the group that filled it
            assert len(b) <= size or len({(e.stamp, type(e)) for e in b[size - 1 :]}) == 1
            assert b[-1].stamp - b[0].stamp <= span
        assert span == math.inf or len(bs) > len(batches(evs, size))  # the span did cut


def test_a_robot_with_nothing_to_forward_ends_its_stream(src):
    """A robot without a single measurement forwards only its end (first stamp inf): the others are fused as usual."""
    f = fusion(src, "cekf")
    for r in (0, 1):
        for raw in forwards(src, r):
            f.offer(raw)
    end = Raw(robot=2, n=0, first=math.inf, upto=math.inf)
    f.offer(decode(encode("t", 2, 0, end), "t", {0, 1, 2}).body)
    out = f.pump()
    assert f.done and len(out) == 3 * src.record_times().size and f.counts["robots_lost"] == 0


def test_bad_forwards_are_refused_by_the_schema():
    ok = dict(robot=1, n=0, first=0.0, upto=5.0)
    det = RawDetection(1.0, "pose", (1.0, 0.0, 0.0), (0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.001))
    decode(encode("t", 1, 0, Raw(**ok, items=(det,))), "t", {0, 1, 2})
    bad = [
        ("out of order", Raw(**ok, items=(RawOdometry(2.0, 2.1, 0.1, 0.0), det))),
        ("out of order", Raw(**{**ok, "upto": 1.0}, items=(det,))),  # an item at or past where the stream stands
        ("bad RawDetection", Raw(**ok, items=(RawDetection(1.0, "pose", (1.0, 0.0), det.cov),))),  # z's size
        ("bad RawOdometry", Raw(**ok, items=(RawOdometry(1.0, 1.1, math.nan, 0.0),))),
        ("bad RawDetection", Raw(**ok, items=(RawDetection(1.0, "pose3", (1.0,) * 6, (0.1,) * 36),))),  # not planar
        ("bad RawOdometry", Raw(**ok, items=(RawOdometry(1.0, 0.9, 0.1, 0.0),))),  # t1 < t0
    ]
    for why, raw in bad:
        with pytest.raises(Rejected, match=f"raw: .*{why}"):
            decode(encode("t", 1, 0, raw), "t", {0, 1, 2})
    with pytest.raises(Rejected, match=r"^malformed: Invalid enum value 'sonar' - at `\$.body.items\[0\]\[2\]`$"):
        decode(encode("t", 1, 0, Raw(**ok, items=(RawDetection(1.0, "sonar", (1.0,), (0.1,)),))), "t", {0, 1, 2})
    with pytest.raises(Rejected, match=r"length <= 512 - at `\$.body.items`"):  # refused before it is built
        decode(encode("t", 1, 0, Raw(**ok, items=(det,) * 513)), "t", {0, 1, 2})
    with pytest.raises(Rejected, match="in the name of robot 1"):
        decode(encode("t", 2, 0, Raw(**ok)), "t", {0, 1, 2})


def test_which_estimators_the_server_hosts():
    assert {e for e in ("cekf", "iekf", "fej", "expfusion", "rdl") if hosted_class(e)} == {"cekf", "iekf", "fej"}
    assert network_class("cekf").__name__ == "CentralizedEKF"
    with pytest.raises(ValueError, match="unknown estimator"):
        hosted_class("nope")


# ------------------------------------------------------------------------------------------------ live
def _live(src, est, tmp_path, **kw):
    tr = run_team(src=src, source="sim:random", robots=3, duration=15.0, seed=1, estimator=est, max_wall=90,
                  log_dir=tmp_path / "logs", **kw)  # fmt: skip
    assert tr.exit_codes and all(c == 0 for c in tr.exit_codes.values()), (tr.exit_codes, tr.ended)
    assert not tr.counts.get("timed_out")
    return tr, team_result(tr, src, est)


@pytest.mark.parametrize("est", ["cekf", "iekf"])
def test_live_hosted_estimator_equals_the_in_process_run(src, est, tmp_path):
    """``swarmloc team --estimator cekf|iekf``: three robot processes forward, the server fuses; every final belief
    of every robot at every record time equals the in-process run's to 1e-9, and every detection is fused."""
    tr, res = _live(src, est, tmp_path)
    ref = reference(src, est)
    assert res.stats["recorded"] == 3 * src.record_times().size and res.stats["recorded_provisional_only"] == 0
    for r, t in ref.tracks.items():
        a = res.tracks[r]
        np.testing.assert_array_equal(a.times, t.times)
        assert np.abs(a.mean - t.mean).max() <= 1e-9 and np.abs(a.cov - t.cov).max() <= 1e-9, f"robot {r}"
    assert set(tr.reports) == {*src.robots, SERVER}
    assert res.stats["fused"] == ref.stats["fused"] == res.stats["detections"] and res.accounted()
    assert res.stats.get("net_raw_lost_forwards", 0) == 0 and res.stats.get("net_robots_lost", 0) == 0


def test_live_hosted_estimator_under_loss_repairs_what_was_lost(src, tmp_path):
    """Loss 0.3 on every forward (and every repeat): the server asks the robots again for the numbers missing, they
    send them again, and the run equals the in-process run (1e-9); every detection of the source is accounted for.
    (Without the repair, this run lost 5 forwards with 114 of the 200 detections and 177 odometry records, and the
    filter diverged: ANEES 1627.)"""
    tr, res = _live(src, "cekf", tmp_path, faults="loss=0.3,seed=3")
    ref = reference(src, "cekf")
    s = res.stats
    assert sum(tr.reports[r].net["lost"] for r in src.robots) > 0  # the faults did drop forwards
    assert s["net_raw_repaired"] > 0 and s["net_raw_repairs_asked"] >= s["net_raw_repaired"] > 0
    assert sum(tr.reports[r].net["resent"] for r in src.robots) > 0
    assert s.get("net_raw_lost_forwards", 0) == 0
    n_det = sum(isinstance(e, Detection) for e in src.events)
    forwarded = sum(tr.reports[r].net["forwarded_detections"] for r in src.robots)
    assert s["detections"] == forwarded == n_det and res.accounted()
    for r, t in ref.tracks.items():
        a = res.tracks[r]
        assert np.abs(a.mean - t.mean).max() <= 1e-9 and np.abs(a.cov - t.cov).max() <= 1e-9, f"robot {r}"


def _server_refusals(log: Path) -> dict:
    m = re.search(r"belief server: stopped; (\{.*?\}); store \{.*?\}; refused (\{.*?\})\n", log.read_text())
    assert m, f"no summary in the belief server's log:\n{log.read_text()[-2000:]}"
    return {**ast.literal_eval(m.group(1)), **ast.literal_eval(m.group(2))}


def test_forged_forwards_in_another_robots_name_change_nothing(src, tmp_path):
    """An attacker process holding robot 2's valid key forwards a detection 100 m off in robot 1's name (signed as
    robot 1 with robot 2's key, as robot 2 on robot 1's key, unsigned, robot 1 inside robot 2's frame, robot 2's own
    forward in robot 1's name: the last two signed by a process that is not robot 2's of the run) while the team
    runs: the server refuses each one, counts it by category, and the beliefs equal the clean run's to 1e-9."""
    team = f"rawattack{os.getpid()}"
    make_team_keys(tmp_path / "keys", src.robots)
    ep = f"tcp/127.0.0.1:{free_ports(1)[0]}"
    out = tmp_path / "attacker.json"
    args = ["--listen", ep, "--team", team, "--keys", str(tmp_path / "keys"), "--out", str(out)]
    with attacker_process(ATTACKER, args):
        tr, res = _live(src, "cekf", tmp_path, team=team, speed=3.0, connect_extra=[ep], keys_dir=tmp_path / "keys")
    sent = json.loads(out.read_text())
    expected = sent["expected"]
    assert sent["server_seen"]  # the attacker forged nothing before the server's token reached it
    got = _server_refusals(tmp_path / "logs" / "server.log")
    for category in ("key_mismatch", "not_owner", "unsigned", "other_run"):
        assert got[f"auth_{category}"] == expected[category] > 0, category
    assert got["rejected"] == sum(expected.values())
    _, clean = _live(src, "cekf", tmp_path / "clean")
    for r, t in clean.tracks.items():
        a = res.tracks[r]
        np.testing.assert_array_equal(a.times, t.times)
        assert np.abs(a.mean - t.mean).max() <= 1e-9 and np.abs(a.cov - t.cov).max() <= 1e-9, f"robot {r}"
    assert res.stats["fused"] == clean.stats["fused"] and res.stats.get("net_raw_lost_forwards", 0) == 0
