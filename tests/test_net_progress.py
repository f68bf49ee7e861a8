"""The lock step's progress, scoped (:func:`swarmloc.net.lockstep.watched`): with ``diekf`` in clusters and a recorded
source a node subscribes to, and waits for, the progress of its cluster's mates and of the robots it detects or is
detected by only; any other node (and a live source) to every teammate's, as before.

Offline (a :class:`NetNode` on a session that records its declarations): the keys it subscribes to are exactly the
rule's; lockstep neither waits for a teammate it does not watch nor declares it lost. Live (127.0.0.1, threads of
this process): 10 robots of the grouped swarm scene in clusters of 5, each watching fewer than its 9 teammates,
equal the in-process run. Clusters that re-form (``diekf_reform``): the lock step reaches a boundary once settled and
holds the node's groups for its new mates' pieces; networked, the run equals the in-process one.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from _benchmarks import load_benchmark
from test_net import max_diff, reference, thread_team

from swarmloc.config import Config
from swarmloc.datasets.source import Source
from swarmloc.messages import ClusterPiece
from swarmloc.net.entry import make_node
from swarmloc.net.lockstep import detected_pairs, heard_in, timed_detections, watched
from swarmloc.net.process import NetNode
from swarmloc.net.schema import BroadcastHead, Progress
from swarmloc.net.team import TeamRun
from swarmloc.net.transport import robot_key


def _scene_module() -> ModuleType:
    return load_benchmark("swarm_scene")


def clustered(src: Source, k: int, period: float = 0.0) -> Source:
    """``src`` with ``[filter] diekf_cluster = k`` (and ``diekf_reform = period``)."""
    cfg: Config = src.config
    f = dataclasses.replace(cfg.filter, diekf_cluster=k, diekf_reform=period)
    return dataclasses.replace(src, config=dataclasses.replace(cfg, filter=f))


class _Decl:
    def undeclare(self) -> None:
        pass


class _Liveliness:
    def declare_subscriber(self, key: str, **kw: Any) -> _Decl:
        return _Decl()

    def declare_token(self, key: str) -> _Decl:
        return _Decl()


class _Declarations:
    """A session that records the keys a node subscribes to (nothing is sent or received)."""

    def __init__(self) -> None:
        self.subscribed: list[str] = []

    def declare_subscriber(self, key: str, **kw: Any) -> _Decl:
        self.subscribed.append(key)
        return _Decl()

    def declare_queryable(self, key: str, **kw: Any) -> _Decl:
        return _Decl()

    def declare_publisher(self, key: str, **kw: Any) -> _Decl:
        return _Decl()

    def liveliness(self) -> _Liveliness:
        return _Liveliness()


class _Pub(_Decl):
    def put(self, payload: bytes, **kw: Any) -> None:
        pass


class _Quiet(_Declarations):
    """A session that sends nothing anywhere (its publishers and puts drop what they are given)."""

    def declare_publisher(self, key: str, **kw: Any) -> _Pub:
        return _Pub()

    def put(self, key: str, payload: bytes, **kw: Any) -> None:
        pass


def opened(src: Source, robot: int, est: str = "diekf", **kw: Any) -> tuple[NetNode, list[str]]:
    """Robot ``robot``'s node, opened on a recording session, and the progress keys it subscribed to."""
    node = make_node(est, robot, src.initial[robot], src.config, src.landmarks, team=src.robots)
    node.start(src.t_start)
    s = _Declarations()
    net = NetNode(node, src.own_events(robot), session=s, team="t", roster=src.robots, record_times=(), **kw)
    net.wiring.open()
    net.wiring.close()
    return net, sorted(k for k in s.subscribed if k.endswith("/progress"))


@pytest.mark.unit
def test_a_node_in_clusters_subscribes_to_the_progress_of_its_cluster_and_its_detections_only() -> None:
    """20 robots in clusters of 5: robot 8 (cluster 5-9) without detections subscribes to its 4 mates' progress, not
    its 19 teammates'; with the grouped scene's detections, to its mates' and the outsiders it detects or that detect
    it; without the detections known (a live source), or without clusters, to every teammate's (one key for all)."""
    src = clustered(_scene_module().scene(20, 3.0, 1, "grouped"), 5)
    net, keys = opened(src, 8, detected=())
    assert net.watched == {5, 6, 7, 9}
    assert keys == sorted(robot_key("t", r, "progress") for r in (5, 6, 7, 9))
    pairs = detected_pairs(src.events)
    outsiders = {t for o, t in pairs if o == 8} | {o for o, t in pairs if t == 8}
    outsiders -= {5, 6, 7, 8, 9}
    assert len(outsiders) == 2  # in 3 s robot 8 meets 2 outsiders
    net, keys = opened(src, 8, detected=pairs)
    assert net.watched == {5, 6, 7, 9} | outsiders
    assert keys == sorted(robot_key("t", r, "progress") for r in net.watched)
    for kw, est, k in (({}, "diekf", 5), ({"detected": pairs}, "diekf", 0), ({"detected": pairs}, "rdl", 5)):
        net, keys = opened(clustered(src, k), 8, est, **kw)
        assert net.watched is None and keys == [robot_key("t", "*", "progress")]
    assert watched(3, None, pairs) is None and watched(3, (0, 1, 2, 3), None) is None
    assert watched(3, (0, 1, 2, 3), [(3, 9), (12, 3), (12, 13)]) == {0, 1, 2, 9, 12}


@pytest.mark.unit
def test_lockstep_waits_for_a_watched_teammate_only_and_never_declares_another_lost() -> None:
    """Robot 7 watching {5, 6, 8, 9}: robot 12, alive but never heard, holds none of its inputs and is not declared
    lost however long it stays silent; robot 5, alive and behind, holds them until it announces progress."""
    src = clustered(_scene_module().scene(20, 3.0, 1, "grouped"), 5)
    net, _ = opened(src, 7, detected=())
    ls = net.lockstep
    ls.alive |= {5, 6, 8, 9, 12}
    for r in (6, 8, 9):
        ls.on_progress(Progress(robot=r, t=math.inf))
    s = src.t_start + 1.0
    assert not ls.may_feed(s)  # robot 5 is behind
    ls.on_progress(Progress(robot=5, t=s + 1.0))
    assert ls.may_feed(s) and ls.waited() == {5, 6, 8, 9}
    ls._beat[12] = ls._heard[12] = -1e9  # silent since long ago
    ls.check_lost(math.inf)
    assert ls.alive >= {5, 6, 8, 9, 12} and not ls.lost and ls.counts["progress_received"] == 4


@pytest.mark.network
def test_diekf_in_clusters_watching_fewer_teammates_equals_in_process() -> None:
    """10 robots of the grouped scene (5 s: robots 0, 1 and 7 meet outsiders) in clusters of 5, threads of this
    process on 127.0.0.1, each node given the team's detections: every node watches fewer than its 9 teammates, and
    the run equals the in-process one (every recorded mean and covariance to 1e-6)."""
    src = clustered(_scene_module().scene(10, 5.0, 1, "grouped"), 5)
    run = TeamRun()
    team = f"progress{np.random.default_rng().integers(1 << 30)}"
    nets, reports = thread_team(src, "diekf", max_wall=120.0, team=team, detected=detected_pairs(src.events),
                                on_belief=run.keep)  # fmt: skip
    assert len(reports) == 10
    assert all(n.watched is not None and len(n.watched) < 9 for n in nets)
    assert sum(len(n.watched or ()) > 4 for n in nets) == 3
    net: Counter[str] = Counter()
    for rep in reports.values():
        net.update(rep.net)
    assert net["broadcasts_applied"] > 0 and net.get("peers_lost", 0) == 0
    ref = reference(src, "diekf")
    assert ref.stats["fused"] > 100
    assert max_diff(dataclasses.replace(ref, tracks=run.tracks(src.truth)), ref) <= 1e-9


@pytest.mark.unit
def test_lockstep_reaches_a_boundary_once_settled_and_holds_groups_for_the_pieces() -> None:
    """6 robots of the grouped scene in clusters of 3 re-formed every second (``diekf_reform = 1``): at 1 s robot 2
    joins robots 3, 4 and 5, and robots 3 and 4 owe it their pieces (their cross-covariances with 4, 5 and with 5).
    Robot 2 hears the broadcasts of the 5 robots it ever shares a cluster with; its lock step reaches the boundary only
    once the teammates it watches have read their sources past it, then holds its groups from 1 s on until both
    pieces came (or it waited ``update_timeout`` s: it goes on without them, counted)."""
    src = clustered(_scene_module().scene(6, 10.0, 1, "grouped"), 3, 1.0)
    node = make_node("diekf", 2, src.initial[2], src.config, src.landmarks, team=src.robots)
    node.start(src.t_start)
    node.plan(src.events)
    assert node.team == (0, 1, 2, 3, 4, 5) and node.boundary() == 1.0
    net = NetNode(node, src.own_events(2), session=_Quiet(), team="t", roster=src.robots, record_times=(),
                  detected=detected_pairs(src.events))  # fmt: skip
    ls = net.lockstep
    assert net.watched is not None
    ls.alive |= set(net.watched)
    for r in net.watched:
        net.broadcaster.on_sample(BroadcastHead(robot=r, n=0, t=math.inf))
        ls.on_progress(Progress(robot=r, t=0.9))
    ls.may_feed(1.05)
    assert node.boundary() == 1.0  # the teammates have not read their sources to 1 s: not reached
    for r in net.watched:
        ls.on_progress(Progress(robot=r, t=1.1))
    ls.may_feed(1.05)
    assert node.boundary() == 2.0 and node.awaits(1.0) is not None and node.awaits(0.95) is None
    assert not ls.boundaries_in(1.0) and ls.boundaries_in(0.95)
    for a, later in ((3, (4, 5)), (4, (5,))):
        net._step(ClusterPiece(sender=a, receiver=2, stamp=1.0, robots=later, sigma=(0.0,) * 9 * len(later)))
    assert node.awaits(1.0) is None and ls.boundaries_in(1.0) and node.stats()["pieces_received"] == 2
    with pytest.raises(RuntimeError, match="before the first input"):
        node.plan(src.events)
    for r in net.watched:
        ls.on_progress(Progress(robot=r, t=2.1))
    ls.may_feed(2.05)  # boundary 2 s: nothing changes, nothing is owed
    assert node.boundary() == 3.0 and ls.boundaries_in(2.0)
    assert ls.counts["boundary_not_received"] == 0
    gone = clustered(_scene_module().scene(6, 10.0, 1, "grouped"), 3, 1.0)
    late = make_node("diekf", 2, gone.initial[2], gone.config, gone.landmarks, team=gone.robots)
    late.start(gone.t_start)
    late.plan(gone.events)
    net = NetNode(late, gone.own_events(2), session=_Quiet(), team="t", roster=gone.robots, record_times=())
    net.lockstep.may_feed(1.05)  # nobody alive: reached at once
    why = late.awaits(1.0)
    assert why is not None and not net.lockstep.boundaries_in(1.0)
    net.lockstep._awaiting[why] -= 1e6  # as if waited for long
    assert net.lockstep.boundaries_in(1.0) and net.lockstep.counts["boundary_not_received"] == 1


@pytest.mark.unit
def test_a_reforming_node_hears_only_its_current_and_next_periods_mates() -> None:
    """20 robots of the grouped scene for 10 s in clusters of 5 re-formed every second: in every period a node hears
    the broadcasts of its clusters of that period and the next only, and waits for their progress and for that of the
    robots it detects or is detected by in those periods only; over the run that is every robot it ever shares a
    cluster with (the node's ``team``): robot 14, whose clusters hold 13 others over the run, hears 10 at most."""
    src = clustered(_scene_module().scene(20, 10.0, 1, "grouped"), 5, 1.0)
    dets = timed_detections(src.events)
    assert {(o, t) for _, o, t in dets} == detected_pairs(src.events)
    most: dict[int, int] = {}
    ever_most: dict[int, int] = {}
    for r in src.robots:
        node = make_node("diekf", r, src.initial[r], src.config, src.landmarks, team=src.robots)
        node.plan(src.events)
        sched = node.protocol.schedule
        ever: set[int] = set()
        for k in range(len(sched.cuts)):
            mates, waits = heard_in(r, sched, k, dets)
            ks = [q for q in (k, k + 1) if q < len(sched.cuts)]
            assert mates == {m for q in ks for m in sched.cluster(r, q)} - {r}
            met = {b for s, o, t in dets if sched.period(s) in ks for a, b in ((o, t), (t, o)) if a == r}
            assert mates <= waits and waits - mates <= met
            ever |= mates
            most[r] = max(most.get(r, 0), len(mates))
        assert ever | {r} == set(node.team)
        ever_most[r] = len(ever)
    assert len(sched.cuts) == 11 and ever_most[14] == 13 and most[14] == 10


@pytest.mark.unit
def test_a_reforming_node_subscribes_per_period_to_its_current_and_next_mates() -> None:
    """Robot 14 of the same 20 robots, its node stepped through its own inputs offline (nobody else alive): after
    each input it subscribes to the broadcasts of its clusters of the input's period and the next only, and to the
    progress of those and of the robots it detects or is detected by; fewer than the 13 it shares a cluster with over
    the run, and a mate of the period before only is let go once past the boundary."""
    src = clustered(_scene_module().scene(20, 10.0, 1, "grouped"), 5, 1.0)
    node = make_node("diekf", 14, src.initial[14], src.config, src.landmarks, team=src.robots)
    node.start(src.t_start)
    node.plan(src.events)
    pairs = detected_pairs(src.events)
    net = NetNode(node, src.own_events(14), session=_Quiet(), team="t", roster=src.robots, detected=pairs)
    net.wiring.open()
    sched = node.protocol.schedule
    met = {t for o, t in pairs if o == 14} | {o for o, t in pairs if t == 14}
    assert len(node.team) == 14 and net.hearing is not None
    sizes = set()
    for s, item in net.inputs.items:
        net._step(item)
        mates = heard_in(14, sched, sched.period(s), ())[0]
        assert net.wiring.heard("broadcast") == sorted(str(r) for r in mates)
        assert net.wiring.heard("progress") == sorted(str(r) for r in mates | met)
        assert net.lockstep.watched == mates | met and net.broadcaster.heard == mates
        sizes.add(len(mates))
    net.wiring.close()
    assert max(sizes) == 10 and min(sizes) == 5 and net.wiring.heard("broadcast") == []


@pytest.mark.network
def test_diekf_reforming_networked_equals_in_process() -> None:
    """The same 6 robots for 10 s (threads of this process on 127.0.0.1, benchmarks/diekf_swarm.py's networked run):
    the clusters re-form every second, the pieces travel (as many taken as in process), and every recorded mean and
    covariance equals the in-process run's to 1e-9."""
    swarm = load_benchmark("diekf_swarm")
    r = swarm.networked(_scene_module().scene(6, 10.0, 1, "grouped"), 6, 3, 10.0, 120.0, 1.0)
    assert r["reports"] == 6 and r["diff"] <= 1e-9, r
    assert r["pieces"] == r["ref_pieces"] == 2
