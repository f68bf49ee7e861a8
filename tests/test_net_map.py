"""The belief server's line map over Zenoh: robots with range scans publish their world lines, the server fuses
them (in (stamp, robot, index) order) and answers a map query; bad line messages are counted and refused."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from swarmloc.events import Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.live.zenoh_input import wait_matched_all
from swarmloc.mapping import LineMap, map_error
from swarmloc.net.auth import TeamKeys, open_envelope, seal
from swarmloc.net.pairing import attach
from swarmloc.net.schema import MAX_LINES, SERVER, Lines, MapAnswer, Rejected, decode, encode
from swarmloc.net.server import MapStore, ServerProcess, linemap_of, observations_of
from swarmloc.net.team import launch_team
from swarmloc.net.teamlink import TeamLink
from swarmloc.net.transport import free_ports, open_session, robot_key, server_key
from swarmloc.sim.walls import office_walls

pytestmark = pytest.mark.network


LINE = (2.5, math.pi / 2, 1e-4, 0.0, 1e-3, 1.0, 2.5, 2.0, 2.5)  # the wall y = 2.5 m from x = 1 to 2 m


def _fuse_in_process(msgs: list[Lines]) -> LineMap:
    lm = LineMap()
    for m in sorted(msgs, key=lambda m: (m.stamp, m.robot)):
        for o in observations_of(m):
            lm.add(o)
    return lm


def test_two_robot_corridor_team_server_map_is_the_in_process_fusion():
    src = load_source("sim:corridor", robots=2, duration=8.0, seed=3)
    run = launch_team(src=src, robots=2, duration=8.0, seed=3, server=True, max_wall=150.0)
    assert not run.counts["timed_out"] and not run.counts["map_incomplete"], run.counts
    assert {m.robot for m in run.lines} == {0, 1} and len(run.lines) >= 20
    assert run.map is not None and run.map.messages == len(run.lines)
    assert run.map.observations == sum(len(m.lines) for m in run.lines)
    mine = _fuse_in_process(run.lines)
    theirs = linemap_of(run.map)
    assert len(theirs.lines) == len(mine.lines) >= 2
    for a, b in zip(mine.lines, theirs.lines, strict=True):
        assert (a.rho, a.alpha, a.robots, a.n_obs) == (b.rho, b.alpha, b.robots, b.n_obs)
        np.testing.assert_array_equal(a.cov, b.cov)
        np.testing.assert_allclose(a.endpoints(), b.endpoints(), atol=1e-12)
    # both robots drove the corridor: its walls are lines both saw (one line per wall piece, not one per robot)
    assert any(ln.robots == {0, 1} and ln.n_obs >= 10 for ln in theirs.lines)
    err = map_error(theirs.segments(), office_walls().segments)
    assert err["endpoint_mean"] < 0.1, err


def _server(tmp_path):
    keys = TeamKeys([0, 1], tmp_path / "keys")
    port_s, port_c = free_ports(2)
    s = open_session([f"tcp/127.0.0.1:{port_s}"], [])
    c = open_session([f"tcp/127.0.0.1:{port_c}"], [f"tcp/127.0.0.1:{port_s}"])
    sp = ServerProcess(TeamLink(s, "mapt", [0, 1], keys.auth(SERVER)), map_out=tmp_path / "map.geojson")
    th = threading.Thread(target=sp.run, kwargs={"max_wall": 60})
    th.start()
    return keys, s, c, sp, th


def _until(cond, th, timeout=10.0):
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        th.join(0.05)
    return cond()


def test_server_refuses_malformed_and_forged_lines_and_answers_the_map(tmp_path):
    keys, s, c, sp, th = _server(tmp_path)
    try:
        k0 = robot_key("mapt", 0, "lines")
        good = Lines(robot=0, stamp=1.0, lines=(LINE,))
        signed = {r: keys.auth(r) for r in (0, 1)}
        bad = [
            ("unsigned garbage", b"garbage"),
            (
                "forged: robot 1 signs on robot 0's key",
                seal(signed[1], k0, encode("mapt", 1, 0, Lines(robot=1, stamp=1.0, lines=(LINE,)))),
            ),  # fmt: skip
            (
                "a NaN line",
                seal(signed[0], k0, encode("mapt", 0, 0, Lines(robot=0, stamp=2.0, lines=((math.nan,) + LINE[1:],)))),
            ),  # fmt: skip
            (
                "covariance not SPD",
                seal(
                    signed[0],
                    k0,
                    encode("mapt", 0, 1, Lines(robot=0, stamp=3.0, lines=(LINE[:2] + (1.0, 2.0, 1.0) + LINE[5:],))),
                ),
            ),  # fmt: skip
            (
                "too many lines",
                seal(signed[0], k0, encode("mapt", 0, 2, Lines(robot=0, stamp=4.0, lines=(LINE,) * (MAX_LINES + 1)))),
            ),  # fmt: skip
        ]
        import zenoh

        # put only once the server's subscriber is reachable, and never dropped (else lost under load)
        pub = c.declare_publisher(k0, congestion_control=zenoh.CongestionControl.BLOCK)
        assert wait_matched_all([pub], 10.0), "the server's line subscriber never matched"
        # the signers are team members in this run: each in session with the server (:mod:`swarmloc.net.pairing`)
        assert all(attach(signed[r], c, "mapt").ensure(SERVER) for r in (0, 1)), "no session with the server"
        for _, payload in bad:
            pub.put(payload)
        assert _until(lambda: sp.counts["rejected"] >= len(bad), th), (sp.counts, sp.reasons)
        assert sp.counts["auth_unsigned"] == 1 and sp.counts["auth_not_owner"] == 1
        assert any("line 0: a line must be 9 or 13 finite numbers" in r for r in sp.reasons), dict(sp.reasons)
        assert any("not positive definite" in r for r in sp.reasons)
        assert any("malformed" in r and "length" in r for r in sp.reasons), sp.reasons
        assert sp.maps.messages == 0 and not sp.maps.current().lines
        pub.put(seal(signed[0], k0, encode("mapt", 0, 3, good)))
        assert _until(lambda: sp.maps.messages == 1, th)
        pub.put(seal(signed[0], k0, encode("mapt", 0, 4, good)))  # the same (robot, stamp) again
        assert _until(lambda: sp.maps.counts["lines_duplicate"] == 1, th)
        answer = None
        for reply in c.get(f"{server_key('mapt')}?map", timeout=5.0):
            if reply.ok is not None:
                env = open_envelope(keys.auth(0), str(reply.ok.key_expr), reply.ok.payload.to_bytes(), "mapt", {0, 1})
                answer = env.body
        assert isinstance(answer, MapAnswer) and answer.messages == 1 and answer.observations == 1
        (fl,) = answer.lines
        np.testing.assert_allclose(fl.line[:5], LINE[:5], atol=1e-12)
        ends = np.reshape(fl.line[5:], (2, 2))  # ordered along the line's tangent: either way round
        np.testing.assert_allclose(ends[np.argsort(ends[:, 0])], np.reshape(LINE[5:], (2, 2)), atol=1e-12)
        assert fl.robots == (0,) and fl.n_obs == 1
    finally:
        sp.stop()
        th.join(10)
        c.close()
        s.close()
        keys.close()
    assert not th.is_alive()
    assert (tmp_path / "map.geojson").read_text().count("LineString") == 1


def test_map_store_is_order_independent_and_a_robot_cannot_send_the_servers_map():
    rng = np.random.default_rng(0)
    msgs = [Lines(robot=r, stamp=float(t), lines=((2.5 + 0.01 * rng.standard_normal(), math.pi / 2, 1e-4, 0.0,
                                                    1e-4, 1.0 + t, 2.5, 2.0 + t, 2.5),))
            for t in range(5) for r in (0, 1)]  # fmt: skip
    ordered, shuffled = MapStore([0, 1]), MapStore([0, 1])
    for m in msgs:
        ordered.store(m)
    for i in rng.permutation(len(msgs)):
        shuffled.store(msgs[i])
        shuffled.current()  # fuse as they come: an out-of-order one forces a rebuild
    assert shuffled.counts["map_rebuilt"] >= 1
    assert ordered.answer() == shuffled.answer() == _answer_of(_fuse_in_process(msgs), len(msgs))
    forged = encode("mapt", 0, 0, MapAnswer())
    try:
        decode(forged, "mapt", {0, 1})
    except Rejected as exc:
        assert "in the name of robot -1" in exc.reason
    else:
        raise AssertionError("a robot's MapAnswer was accepted")


def _answer_of(lm: LineMap, messages: int) -> MapAnswer:
    from swarmloc.net.schema import FusedLine
    from swarmloc.net.server import wire_line

    lines = tuple(FusedLine(line=wire_line(ln.rho, ln.alpha, ln.cov, ln.endpoints()), robots=tuple(sorted(ln.robots)),
                            n_obs=ln.n_obs) for ln in lm.lines)  # fmt: skip
    return MapAnswer(lines=lines, observations=messages, messages=messages)


def test_a_node_with_a_range_finder_waits_for_a_late_server_so_that_no_lines_are_lost(tmp_path):
    """A robot that publishes its scans' lines to the belief server starts only once the server is alive (lines
    published before the server subscribed would never reach it: the map would stay incomplete)."""
    from swarmloc.net.entry import _own_scans, make_node
    from swarmloc.net.process import NetNode

    src = load_source("sim:corridor", robots=2, duration=3.0, seed=3)
    keys = TeamKeys([0], tmp_path / "keys")
    port_n, port_s = free_ports(2)
    ep_n, ep_s = f"tcp/127.0.0.1:{port_n}", f"tcp/127.0.0.1:{port_s}"
    sn = open_session([ep_n], [ep_s])
    ss = None
    events = [e for e in src.own_events(0) if isinstance(e, Odometry)]  # robot 0 alone: no teammate to ask
    node = make_node("rdl", 0, src.initial[0], src.config, src.landmarks)
    node.start(src.t_start)
    net = NetNode(node, events, session=sn, team="late", roster=[0], record_times=src.record_times(), wait_for=[],
                  use_server=True, auth=keys.auth(0), scans=_own_scans(src, 0, events), start_timeout=20.0)  # fmt: skip
    reports = {}
    th = threading.Thread(target=lambda: reports.setdefault(0, net.run(max_wall=60.0)))
    th.start()
    try:
        th.join(1.5)  # the node is running, the server not yet
        assert th.is_alive() and net.counts["lines_published"] == 0, dict(net.counts)
        ss = open_session([ep_s], [ep_n])
        sp = ServerProcess(TeamLink(ss, "late", [0], keys.auth(SERVER)))
        ts = threading.Thread(target=sp.run, kwargs={"max_wall": 60})
        ts.start()
        th.join(60)
        assert not th.is_alive()
        assert net.counts["lines_published"] >= 10, dict(net.counts)
        assert _until(lambda: sp.maps.counts["lines_stored"] == net.counts["lines_published"], ts), (
            dict(sp.maps.counts), dict(net.counts))  # fmt: skip
    finally:
        net.stop()
        if ss is not None:
            sp.stop()
            ts.join(10)
            ss.close()
        sn.close()
        keys.close()
