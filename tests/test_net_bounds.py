"""Every number from a message bounded against the receiver's own state before any loop or allocation.

Before: one ``diekf`` broadcast head announcing 2^62 broadcasts made every teammate track and allocate toward it
(2.7 GB, ``MemoryError``, exit with no report); a message stamped 1e9 s made a node publish every belief of the
run as final at once; a pushed message's sub-key, reason or team could be a million numbers or characters (decoded
and kept); a stream of refused messages, each with its stamp in its reason, grew the reasons without bound; a
forward numbered 2^62 made the belief server build a tuple of 2^62 missing numbers.

A property test feeds extreme values (0, -1, 2^31, 2^62, 2^63 - 1, NaN, inf, 1e308, a hundred thousand numbers)
in every field of every message type to every handler of a real :class:`NetNode` in a realistic state (a ``diekf``
and an ``rdl`` node a few seconds into their source), to the hosted estimator's :class:`Fusion`, the belief server's
stores and the collector: nothing escapes, no handler allocates more than :data:`PEAK` bytes, every message ends
counted (refused with a reason, or taken), and what the node keeps per sender stays within its bounds. The cases
that broke are then checked one by one.
"""

from __future__ import annotations

import math
import tracemalloc
from collections import Counter

import msgspec
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_net import _Payload, offline_net
from test_net_central import forwards, fusion
from test_net_diekf import _BSession, _Pub, bsample, offline_diekf, update

from swarmloc.experiments.sources import load_source
from swarmloc.messages import BeliefAnswer, BeliefQuery, RdlState, RdlStateQuery, RdlUpdate, TeamUpdate, flat
from swarmloc.net import broadcast as bc
from swarmloc.net.central import KEEP
from swarmloc.net.lockstep import MAX_HELD, MAX_HELD_FROM
from swarmloc.net.schema import (
    MAX_REVISION,
    Belief,
    Broadcast,
    BroadcastHead,
    BroadcastRepair,
    FusedLine,
    Lines,
    MapAnswer,
    Progress,
    Raw,
    RawAck,
    RawDetection,
    RawOdometry,
    Rejected,
    Report,
    decode,
    encode,
)
from swarmloc.net.server import BeliefServer, MapStore, ServerProcess
from swarmloc.net.teamlink import TeamLink
from swarmloc.net.transport import robot_key
from swarmloc.node.accounting import MAX_REASONS, OTHER_REASONS

pytestmark = pytest.mark.network

PEAK = 8 * 1024 * 1024
"""[bytes] the most one handler may allocate (Python objects, tracemalloc) for one message, whatever it holds."""
I3 = flat(np.eye(3))
COV = flat(np.diag([0.01, 0.01, 0.001]))
HUGE = 100_000

INTS = [0, -1, 1, 2, 2**31, 2**62, 2**63 - 1, -(2**63)]
FLOATS = [0.0, -1.0, math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, 2.0**62]
TUPLES = [(), I3, COV, (math.nan,) * 9, (1.0,) * 37, (0.5,) * HUGE]
TEXTS = ["", "SE2", "SE3", "x" * HUGE]


class _Sample:
    """What Zenoh hands a handler: a sample, a query (replied to, refused, closed) or a reply (``ok``)."""

    def __init__(self, raw: bytes, key: str = "") -> None:
        self.payload = _Payload(raw)
        self.key_expr = key
        self.ok = self
        self.replies: list[bytes] = []
        self.errors: list[bytes] = []

    def reply(self, key, payload) -> None:
        self.replies.append(payload)

    def reply_err(self, reason: bytes) -> None:
        self.errors.append(reason)

    def drop(self) -> None:
        pass


# ------------------------------------------------------------------------------------------------ strategies
def _bodies(t: float) -> st.SearchStrategy:
    """Every message type, each field extreme (or, for stamps, also near the node's present ``t``)."""
    i, f, tup, txt = (st.sampled_from(x) for x in (INTS, FLOATS, TUPLES, TEXTS))
    robot = st.sampled_from([0, 1, 2, -1, 7, 2**31, 2**63 - 1])
    stamp = st.sampled_from([*FLOATS, t, t + 0.5, t + 4.0, t - 4.0, t + 1e9])
    sub = st.sampled_from([(), (0.0,), (0.0, 0.0, 1.0, 1.0, 0.0, 0.0), (math.nan,), (0.5,) * HUGE])
    common = dict(sender=robot, receiver=robot, stamp=stamp, sub=sub)
    good = st.sampled_from([update(1, t + 0.5), update(2, t + 0.1), update(1, t + 1e9)])
    team_update = st.one_of(good, st.builds(TeamUpdate, target=i, m=i, n=i, Hi=tup, Hj=tup, Sinv=tup, nu=tup,
                                            Pii=tup, Pjj=tup, scale=f, **common))  # fmt: skip
    items = st.sampled_from([(), (RawOdometry(1.0, 1.1, 0.1, 0.0),) * 600, (RawDetection(1.0, "pose", (1.0, 0.0, 0.0),
                             COV),), (RawDetection(1.0, "x" * HUGE, (), ()),)])  # fmt: skip
    lines = st.sampled_from([(), ((0.0,) * 9,), ((1.0,) * 9,) * 65, ((1.0,) * 14,)])
    counters = st.sampled_from([{}, {"x": 1}, {str(k): k for k in range(5000)}, {"y" * HUGE: 1}])
    return st.one_of(
        st.builds(BeliefQuery, **common),
        st.builds(RdlStateQuery, **common),
        st.builds(BeliefAnswer, seq=i, found=st.booleans(), group=txt, mean=tup, cov=tup, reason=txt, **common),
        st.builds(RdlState, seq=i, found=st.booleans(), x=tup, P=tup, sigma=tup, reason=txt, **common),
        st.builds(RdlUpdate, based_on=i, x=tup, P=tup, **common),
        st.builds(Belief, robot=robot, stamp=stamp, rev=i, final=st.booleans(), mean=tup, cov=tup, group=txt),
        st.builds(Progress, robot=robot, t=stamp, prio=i, done=st.booleans()),
        st.builds(Report, robot=robot, stats=counters, reasons=counters, net=counters, wall_s=f),
        st.builds(
            Broadcast, robot=robot, n=i, to=st.sampled_from([-1, 0, 1, 2**62]), update=st.one_of(st.none(), team_update)
        ),  # fmt: skip
        st.builds(BroadcastHead, robot=robot, n=i, t=stamp, prio=i),
        st.builds(BroadcastRepair, sender=robot, receiver=robot, first=i, last=i),
        st.builds(Raw, robot=robot, n=i, first=stamp, upto=stamp, prio=i, odometry=i, detections=i, items=items),
        st.builds(RawAck, robot=robot, next=i, missing=st.sampled_from([(), (1, 2), tuple(range(300))])),
        st.builds(Lines, robot=robot, stamp=stamp, lines=lines),
        st.builds(
            MapAnswer, lines=st.sampled_from([(), (FusedLine(line=(1.0,) * 9, robots=(0,) * 5000),)]), observations=i
        ),  # fmt: skip
    )


def _templates(t: float) -> list:
    """A valid message of each type from robot 1 to robot 0, stamped about the node's present ``t``."""
    det = RawDetection(t, "pose", (1.0, 0.0, 0.0), COV, 0)
    return [
        BeliefQuery(sender=1, receiver=0, stamp=t + 0.5),
        RdlStateQuery(sender=1, receiver=0, stamp=t + 0.5, sub=(0.0, 0.0, 0.0, 1.0, 0.0, 0.0)),
        BeliefAnswer(sender=1, receiver=0, stamp=t + 0.25, mean=I3, cov=COV),
        RdlState(sender=1, receiver=0, stamp=t + 0.25, x=(0.0, 0.0, 0.0), P=COV, sigma=I3),
        RdlUpdate(sender=1, receiver=0, stamp=t - 0.5, sub=(0.0, 0.0, 0.0, 1.0, 0.0, 0.0), x=(0.0,) * 3, P=COV),
        Belief(robot=1, stamp=t, mean=I3, cov=COV),
        Progress(robot=1, t=t, prio=1),
        Report(robot=1, stats={"fused": 1}),
        Broadcast(robot=1, n=0, update=update(1, t + 0.5)),
        Broadcast(robot=1, n=1, to=0, update=update(1, t - 0.5)),
        BroadcastHead(robot=1, n=1, t=t, prio=1),
        BroadcastRepair(sender=1, receiver=0, first=0, last=0),
        Raw(
            robot=1,
            n=0,
            first=t,
            upto=t + 1.0,
            odometry=1,
            detections=1,
            items=(det, RawOdometry(t + 0.1, t + 0.2, 0.1, 0.0)),
        ),  # fmt: skip
        RawAck(robot=1, next=0, missing=(1,)),
        Lines(robot=1, stamp=t, lines=((1.0, 0.0, 0.01, 0.0, 0.01, 1.0, -1.0, 1.0, 1.0),)),
        MapAnswer(lines=(FusedLine(line=(1.0, 0.0, 0.01, 0.0, 0.01, 1.0, -1.0, 1.0, 1.0), robots=(1,)),)),
    ]


def _extremes(v, t: float) -> list:
    """The extreme values of a field's kind (its value ``v``)."""
    if isinstance(v, bool):
        return [not v]
    if isinstance(v, int):
        return INTS
    if isinstance(v, float):
        return [*FLOATS, t + 4.0, t - 4.0, t + 1e9, t - 1e9]
    if isinstance(v, str):
        return TEXTS
    if isinstance(v, dict):
        return [{}, {str(k): k for k in range(5000)}, {"y" * HUGE: 2**63 - 1}]
    if isinstance(v, tuple) and v and isinstance(v[0], msgspec.Struct | tuple):  # items, lines
        return [(), v * 300]
    return TUPLES


def _every_extreme(t: float) -> list:
    """Each template with each of its fields (and each field of a struct inside) set to each extreme of its kind."""
    out = []
    for m in _templates(t):
        out.append(m)
        for name in m.__struct_fields__:
            v = getattr(m, name)
            if isinstance(v, msgspec.Struct):
                out += [msgspec.structs.replace(m, **{name: msgspec.structs.replace(v, **{f: x})})
                        for f in v.__struct_fields__ for x in _extremes(getattr(v, f), t)]  # fmt: skip
            else:
                out += [msgspec.structs.replace(m, **{name: x}) for x in _extremes(v, t)]
    return out


@st.composite
def _mutated(draw, obj, t: float, most: int = 2):
    """``obj`` with one to ``most`` of its fields set to an extreme value of their kind (a struct inside: mutated
    alike)."""
    names = draw(st.lists(st.sampled_from(obj.__struct_fields__), min_size=1, max_size=most, unique=True))
    change = {}
    for name in names:
        v = getattr(obj, name)
        if isinstance(v, msgspec.Struct):
            change[name] = draw(_mutated(v, t))
        elif isinstance(v, tuple) and v and isinstance(v[0], msgspec.Struct):  # a forward's items: one mutated
            change[name] = (draw(_mutated(v[0], t)), *v[1:])
        else:
            change[name] = draw(st.sampled_from(_extremes(v, t)))
    return msgspec.structs.replace(obj, **change)


def _payloads(t: float) -> st.SearchStrategy:
    """A valid message with extreme fields (most), any extreme message (some), or bytes that are no envelope; in an
    envelope from its sender (or another robot, or with a huge team name), its ``seq`` fresh or extreme."""
    seqs = iter(range(10**9))
    templates = st.sampled_from(_templates(t))
    bodies = st.one_of(templates, templates.flatmap(lambda m: _mutated(m, t, 1)),
                       templates.flatmap(lambda m: _mutated(m, t, 2)), _bodies(t))  # fmt: skip

    def envelope(body, frm, seq, team):
        if frm is None:
            frm = getattr(body, "sender", getattr(body, "robot", 0))
            frm = frm if -(2**63) <= frm < 2**63 else 0
        return encode(team, frm, next(seqs) if seq is None else seq, body)

    env = st.builds(envelope, bodies, st.sampled_from([None] * 6 + [2, -1]), st.sampled_from([None] * 6 + INTS[:7]),
                    st.sampled_from(["t"] * 8 + ["z" * HUGE]))  # fmt: skip
    return st.one_of(env, env, env, st.sampled_from([b"", b"\x00" * 10, b"\xff" * 2**20]))


# ------------------------------------------------------------------------------------------------ the property
def _ends(net) -> int:
    """Everything a received message can end as: refused (``rejected``, or by the node ``messages_rejected``:
    counted in ``messages``), taken by the node (``messages``), a duplicate or stale copy, a broadcast given up or a
    head, a repair request, a query held or answered, an answer held."""
    c = net.counts
    keys = ("rejected", "broadcast_duplicates", "broadcast_stale", "broadcasts_given_up", "broadcast_heads_received",
            "duplicate_queries", "duplicate_replies", "repair_requests_received", "queries_answered")  # fmt: skip
    return sum(c[k] for k in keys) + net.node.counts["messages"] + len(net.lockstep.deferred) + len(net.lockstep.held)


def _handle_all(net, raw: bytes, t: float) -> list[tuple[str, int]]:
    """Hand ``raw`` to each handler of ``net`` as Zenoh would; per handler, the bytes it allocated at most."""
    q = BeliefQuery(sender=net.robot, receiver=1, stamp=t + 0.25)
    net.outbound.outstanding[7] = (q, "robot", False)
    net.outbound.gets[7] = 1
    out = []
    for kind, args in (
        ("inbox", (_Sample(raw, f"swarmloc/t/robot/{net.robot}/inbox"),)),
        ("query", (_Sample(raw, f"swarmloc/t/robot/{net.robot}/query"),)),
        ("reply", (7, _Sample(raw, "swarmloc/t/robot/1/query"))),
        ("broadcast", (_Sample(raw, "swarmloc/t/robot/1/broadcast"),)),
        ("progress", (_Sample(raw, "swarmloc/t/robot/1/progress"),)),
    ):
        before, rejected, reasons = _ends(net), net.counts["rejected"], sum(net.reasons.values())
        node_rejected, node_reasons = net.node.counts["messages_rejected"], sum(net.node.reasons.values())
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        net.inbound.handle(kind, *args)  # as the drain does, without its guard: nothing may escape
        out.append((kind, tracemalloc.get_traced_memory()[1] - base))
        if kind != "progress":  # every message received ends counted (progress: taken or refused, not counted)
            assert _ends(net) > before, (kind, raw[:200])
        assert sum(net.reasons.values()) - reasons == net.counts["rejected"] - rejected  # each with its reason
        assert sum(net.node.reasons.values()) - node_reasons >= net.node.counts["messages_rejected"] - node_rejected
    net.outbound.outstanding.pop(7, None)
    net.outbound.gets.pop(7, None)
    return out


def _realistic(net, src, upto: float):
    """``net``'s node a few seconds into its own source (its inputs stepped as the driver would)."""
    net.session = _BSession()  # records what is sent, published and pushed
    net.wiring.pub["belief"] = net.wiring.pub["progress"] = _Pub(net.session, "belief")
    for e in src.own_events(net.robot):
        if e.stamp > upto:
            break
        net.node.step(e)
    net.lockstep.alive |= {1, 2}
    return net


def _net(est: str):
    """Robot 0's node of ``est`` two seconds into its source; and that instant."""
    if est == "diekf":
        net, src = offline_diekf(robot=0)
    else:
        src = load_source("sim:random", robots=3, duration=4.0, seed=0)
        net = offline_net(robot=0, est="rdl")
    t = src.t_start + 2.0
    return _realistic(net, src, t), t


def _check_bounded(net) -> None:
    """What the node keeps per sender and per reason stays within its bounds."""
    assert len(net.reasons) <= MAX_REASONS + 1 and len(net.node.reasons) <= MAX_REASONS + 1
    assert len(net.lockstep.deferred) <= MAX_HELD and len(net.lockstep._queries_seen) <= 4096 + 1
    for p in net.broadcaster._peers.values():  # what the node tracks per sender: within the window
        assert p.top - p.low < bc.WINDOW and len(p.missing_since) <= bc.WINDOW and len(p.got) <= bc.WINDOW
    assert all(k[1] <= net.node.present + net.node.tolerance for k in net.broadcaster._bkey)
    assert all(abs(k[0] - net.node.present) <= net.node.horizon for k in net.broadcaster._revised)


@pytest.mark.parametrize("est", ["diekf", "rdl"])
def test_every_extreme_in_every_field_of_every_message_to_every_handler(est):
    """Each message type, each field (and each field of the update inside a broadcast) set to each extreme of its
    kind in turn, handed to each handler: nothing escapes, each handler allocates less than ``PEAK``, every message
    ends counted, the node's per-sender state stays bounded."""
    net, t = _net(est)
    peaks: Counter[str] = Counter()
    bodies = _every_extreme(t)
    tracemalloc.start()
    try:
        for k, body in enumerate(bodies):
            frm = getattr(body, "sender", getattr(body, "robot", 0))
            frm = frm if -(2**63) <= frm < 2**63 else 0
            for kind, peak in _handle_all(net, encode("t", frm, k, body), t):
                peaks[kind] = max(peaks[kind], peak)
    finally:
        tracemalloc.stop()
    print(f"{est}: {len(bodies)} messages; peak allocation per handler [bytes]: {dict(peaks)}; net {dict(net.counts)};"
          f" node {dict(net.node.counts)}")  # fmt: skip
    assert len(bodies) > 500 and max(peaks.values()) < PEAK, dict(peaks)
    assert net.node.counts["messages"] >= 20  # valid ones reached the node (the rest was refused before)
    assert net.counts["rejected"] > 0 and net.node.counts["messages_rejected"] > 0
    _check_bounded(net)


@pytest.mark.parametrize("est", ["diekf", "rdl"])
def test_random_extremes_in_any_message_to_every_handler(est):
    """The same with random combinations (hypothesis): valid messages, one or two fields extreme, any message with
    extreme fields, bytes that are no envelope; envelopes from another robot, with an extreme ``seq`` or a huge team
    name."""
    net, t = _net(est)
    peaks: Counter[str] = Counter()
    tracemalloc.start()
    try:

        @settings(max_examples=250, deadline=None, suppress_health_check=list(HealthCheck), database=None)
        @given(_payloads(t))
        def feed(raw):
            for kind, peak in _handle_all(net, raw, t):
                peaks[kind] = max(peaks[kind], peak)

        feed()
    finally:
        tracemalloc.stop()
    assert max(peaks.values()) < PEAK, dict(peaks)
    assert net.counts["rejected"] > 0
    _check_bounded(net)


def test_extreme_numbers_to_the_servers_stores_fusion_and_collector():
    """The hosted estimator's :class:`Fusion` (forwards and what it asks again), the belief server's stores and the
    collector's checks take every decoded message with extreme numbers within the same allocation bound."""
    src = load_source("sim:random", robots=3, duration=6.0, seed=1)
    f = fusion(src, "cekf")
    for raw in forwards(src, 0)[:3]:
        f.offer(raw)
    server, maps = BeliefServer(roster={0, 1, 2}), MapStore(roster={0, 1, 2})
    peaks: list[int] = []
    tracemalloc.start()
    try:

        @settings(max_examples=250, deadline=None, suppress_health_check=list(HealthCheck), database=None)
        @given(_payloads(src.t_start + 1.0))
        def feed(raw):
            try:
                body = decode(raw, "t", {0, 1, 2}).body
            except Rejected:
                return
            tracemalloc.reset_peak()
            base = tracemalloc.get_traced_memory()[0]
            if isinstance(body, Raw):
                f.offer(body)
                f.wanted()
                f.pump()
            elif isinstance(body, Belief):
                server.store(body)
            elif isinstance(body, Lines):
                maps.store(body)
            peaks.append(tracemalloc.get_traced_memory()[1] - base)

        feed()
    finally:
        tracemalloc.stop()
    assert max(peaks) < PEAK
    for s in f.streams.values():
        assert len(s.seq.got) <= KEEP and (not s.seq.got or max(s.seq.got) < s.seq.low + KEEP)


# ------------------------------------------------------------------------------------------------ the cases that broke
def _peak(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_broadcast_head_announcing_2_62_broadcasts_costs_a_window_and_is_then_refused():
    """Robot 1 announces 2^62 broadcasts. Heard first, it opens one window of numbers before it (a late joiner's
    case: those further back are beyond robot 1's buffer anyway); heard after robot 1's real head, it is refused and
    counted, and nothing of robot 1's tracked state moves. Before: 2.7 GB and ``MemoryError`` on every teammate."""
    net, src = offline_diekf(robot=0)
    net.inbound.handle("broadcast", bsample(BroadcastHead(robot=1, n=3, t=src.t_start, prio=1)))
    p = net.broadcaster._peers[1]
    assert (p.low, p.top) == (0, 2)
    top = 2**62 - 1  # the schema's bound on a count: 2^62 - 1
    peak = _peak(lambda: net.inbound.handle("broadcast", bsample(BroadcastHead(robot=1, n=top, t=math.inf), seq=1)))
    assert peak < 64 * 1024, peak
    assert (p.low, p.top, net.broadcaster._heads[1][0]) == (0, 2, 3)
    assert net.counts["rejected"] == 1
    assert net.reasons == Counter(
        {f"broadcast number more than {bc.WINDOW} past the first one missing from its sender": 1}
    )
    # the same number on a repair (the inbox) and in a broadcast: refused alike
    net.inbound.handle(
        "inbox", bsample(Broadcast(robot=1, n=top - 1, to=0, update=update(1, src.t_start + 0.5)), seq=2)
    )
    net.inbound.handle("broadcast", bsample(Broadcast(robot=1, n=top - 2, update=update(1, src.t_start + 0.5)), seq=3))
    assert net.counts["rejected"] == 3 and p.top == 2 and net.node.counts["messages"] == 0
    # heard first: a window opened before it, the repairs asked for it bounded by the window
    fresh, _ = offline_diekf(robot=2)
    peak = _peak(lambda: fresh.inbound.handle("broadcast", bsample(BroadcastHead(robot=1, n=top, t=math.inf))))
    q = fresh.broadcaster._peers[1]
    assert (q.low, q.top) == (top - bc.WINDOW, top - 1) and len(q.missing()) == bc.WINDOW
    assert peak < 4 * 1024 * 1024, peak
    fresh.broadcaster.ask_missing(max(q.missing_since.values()) + fresh.broadcaster.repair_wait + 1e-3)
    assert fresh.counts["repair_requests"] == bc.WINDOW // 256  # 256 numbers per request


def test_a_head_announced_again_unchanged_is_counted_a_heartbeat():
    """A sender's head heard again as it was (its heartbeat) is counted ``broadcast_heads_repeated``; a changed one is
    not, and one that went back (a copy overtaken) neither moves the head nor counts as a heartbeat."""
    net, src = offline_diekf(robot=0)
    heads = [(3, 0.0), (3, 0.0), (4, 0.0), (4, 0.5), (4, 0.5), (3, 0.0)]
    for seq, (n, dt) in enumerate(heads):
        net.inbound.handle("broadcast", bsample(BroadcastHead(robot=1, n=n, t=src.t_start + dt, prio=1), seq=seq))
    assert net.counts["broadcast_heads_received"] == 6
    assert net.counts["broadcast_heads_repeated"] == 2
    assert net.broadcaster._heads[1] == (4, src.t_start + 0.5, 1)


def test_repair_requests_are_served_within_the_askers_budget(monkeypatch):
    """A teammate asking again and again for broadcasts makes this node send at most ``REPAIR_RATE`` numbers a
    second to it (``2 REPAIR_RATE`` banked); the requests past it are refused and counted."""
    monkeypatch.setattr(bc, "REPAIR_RATE", 4)  # 8 numbers banked
    net, src = offline_diekf(robot=1)
    for k in range(3):
        net.broadcaster.queue(msgspec.structs.replace(update(1, src.t_start + k), receiver=0))
        net.broadcaster.flush()
    ask = BroadcastRepair(sender=0, receiver=1, first=0, last=255)
    for seq in range(10):
        net.inbound.handle("inbox", _Sample(encode("t", 0, seq, ask)))
    sent = net.counts["repairs_sent"] + net.counts["repairs_gone"]
    assert net.counts["repair_requests_received"] == 10
    assert sent == 2 * 3  # each request for 0..255 resends the 3 this node has: two fit in the budget
    assert net.counts["rejected"] == 8 and net.reasons["broadcast repair request past its asker's budget"] == 8


def test_queries_held_at_once_are_bounded_per_asker_and_in_all():
    """A robot sending thousands of distinct queries stamped ahead (held until the node may answer) gets at most
    ``MAX_HELD_FROM`` held; the rest are refused ("busy") and counted; another robot's queries are still held."""
    net = offline_net(robot=0)
    t = net.node.present + 3.0
    for k in range(MAX_HELD_FROM + 50):
        net.inbound.handle("query", _Sample(encode("t", 1, k, BeliefQuery(sender=1, receiver=0, stamp=t + k * 1e-3))))
    assert len(net.lockstep.deferred) == MAX_HELD_FROM
    assert net.counts["rejected"] == 50 and net.reasons[
        f"more than {MAX_HELD_FROM} queries of one robot (or {MAX_HELD} in all) held"] == 50  # fmt: skip
    q = _Sample(encode("t", 2, 0, BeliefQuery(sender=2, receiver=0, stamp=t)))
    net.inbound.handle("query", q)
    assert len(net.lockstep.deferred) == MAX_HELD_FROM + 1 and not q.errors


def test_a_message_stamped_1e9_publishes_nothing_ahead_of_time():
    """An ``rdl`` update stamped 1e9 s (or in the future beyond the node's clock tolerance) is refused by the node
    (``future``) and publishes nothing: before, it first made every belief of the run final, at once."""
    src = load_source("sim:random", robots=3, duration=4.0, seed=0)
    net = _realistic(offline_net(robot=0, est="rdl"), src, src.t_start + 1.0)
    published = net.counts["beliefs_published"]
    for stamp in (1e9, net.node.present + net.node.tolerance + 1.0):
        u = RdlUpdate(sender=1, receiver=0, stamp=stamp, sub=(0.0,), x=(0.0, 0.0, 0.0), P=COV)
        net.inbound.handle("inbox", _Sample(encode("t", 1, int(stamp) % 97, u)))
    assert net.counts["beliefs_published"] == published and net.publishing.final == 0
    assert net.node.counts["messages_rejected"] == 2


def test_refusals_with_numbers_in_their_reasons_are_counted_under_a_bounded_set_of_reasons():
    """Ten thousand broadcasts of robot 1, each stamped ahead differently (each refusal's reason quotes its stamp):
    every one counted, the reasons kept at most ``MAX_REASONS`` distinct (then one for the rest)."""
    net, src = offline_diekf(robot=0)
    for k in range(10_000):
        net.inbound.handle("broadcast", bsample(Broadcast(robot=1, n=k, update=update(1, 1e6 + k)), seq=k))
    assert (
        net.counts["broadcasts_applied"] == 10_000 and not net.broadcaster._bkey
    )  # none remembered: all from the future
    assert net.node.counts["messages_rejected"] == 10_000 == sum(net.node.reasons.values())
    assert len(net.node.reasons) == MAX_REASONS + 1


@pytest.mark.parametrize(
    ("body", "why"),
    [
        (BeliefQuery(sender=1, receiver=0, stamp=1.0, sub=(0.5,) * HUGE), r"length <= 36 - at `\$.body.sub`"),
        (BeliefAnswer(sender=1, receiver=0, stamp=1.0, mean=I3, cov=COV, reason="x" * 2**20), r"length <= 512"),
        (BeliefAnswer(sender=1, receiver=0, stamp=1.0, seq=2**62, mean=I3, cov=COV), r"revision 4611686018427387904"),
        (RdlUpdate(sender=1, receiver=0, stamp=1.0, based_on=MAX_REVISION, x=(0.0,) * 3, P=COV), "revision"),
        (Progress(robot=1, t=1.0, prio=2**62), "priority"),
        (Progress(robot=1, t=1.0, moved=2**62), "moved 4611686018427387904"),
        (Progress(robot=1, t=1.0, moved=-1), "moved -1"),
        (Raw(robot=1, n=0, first=0.0, upto=1.0, items=(RawOdometry(0.0, 0.1, 0.0, 0.0),) * 10_000), "length <= 512"),
        (RawAck(robot=1, next=0, missing=tuple(range(10_000))), "length <= 256"),
        (Report(robot=1, net={str(k): k for k in range(10_000)}), "length <= 4096"),
    ],
)
def test_oversized_fields_and_out_of_range_numbers_are_refused_at_decode_before_they_are_built(body, why):
    raw = encode("t", 1, 0, body)
    tracemalloc.start()
    try:
        with pytest.raises(Rejected, match=why):
            decode(raw, "t", {0, 1, 2}, to_robot=0 if not isinstance(body, Report | Raw | RawAck) else None)
        # never more than the frame's own size (a list of numbers is refused before it is built: it would take 3.5
        # times its frame as Python floats; a text is read, then refused)
        assert tracemalloc.get_traced_memory()[1] < len(raw) + 64 * 1024
    finally:
        tracemalloc.stop()
    big_team = msgspec.msgpack.encode({"v": 2, "team": "z" * 2**20, "from_robot": 1, "seq": 0, "body": None})
    with pytest.raises(Rejected, match="length <= 64"):
        decode(big_team, "t", {0, 1, 2})


def test_a_forward_numbered_2_62_is_refused_and_what_the_server_asks_again_stays_bounded():
    """The hosted estimator takes a robot's forward only within ``KEEP`` numbers of the first one it misses; what it
    asks again is at most 256 numbers of that window. Before, a forward numbered 2^62 made it build the tuple of
    every number missing below it."""
    src = load_source("sim:random", robots=3, duration=6.0, seed=1)
    f = fusion(src, "cekf", repair_wait=0.0)
    fw = forwards(src, 0)
    f.offer(fw[0])
    far = Raw(robot=0, n=2**62, first=fw[0].first, upto=math.inf, odometry=10**18, detections=10**18)
    near = msgspec.structs.replace(far, n=KEEP - 1)
    peak = _peak(lambda: (f.offer(far), f.offer(near), f.wanted()))
    assert peak < 1024 * 1024, peak
    s = f.streams[0]
    assert f.counts["raw_too_far_ahead"] == 1 and set(s.seq.got) == {KEEP - 1}
    (ack,) = [a for a in f.wanted() if a.robot == 0] or [None]
    assert ack is None or len(ack.missing) <= 256


def test_a_forward_with_an_unknown_kind_is_refused_at_decode_and_counted_by_the_server():
    """A measurement kind is typed on the wire: a forward naming no kind ("teleport", or a name of 100 000
    characters) is refused while it is decoded, and the belief server counts it ``rejected`` with its reason (msgspec's,
    what it quotes of the payload cut short, and the path to the field); nothing reaches the hosted estimator."""
    sp = ServerProcess(TeamLink(None, "t", [0, 1, 2]))
    key = robot_key(sp.scope, 1, "raw")
    for n, kind in enumerate(("teleport", "x" * HUGE)):
        raw = Raw(robot=1, n=n, first=0.0, upto=5.0, items=(RawDetection(1.0, kind, (1.0,), (0.1,)),))
        sp._handle("raw", _Sample(encode("t", 1, n, raw), key))  # hosted None: an offer would raise
    x60 = "x" * 60  # 80 characters of msgspec's message
    assert sp.counts == Counter(rejected=2) and sp.reasons == Counter({
        "malformed: Invalid enum value 'teleport' - at `$.body.items[0][2]`": 1,
        f"malformed: Invalid enum value '{x60}... - at `$.body.items[0][2]`": 1,
    })  # fmt: skip


def test_the_server_keeps_a_bounded_number_of_distinct_reasons():
    """A hostile robot varying what it sends makes a new reason with every frame (each quotes the bad value): the
    belief server counts every one, under at most MAX_REASONS distinct keys plus one for the rest."""
    sp = ServerProcess(TeamLink(None, "t", [0, 1, 2]))
    key = robot_key(sp.scope, 1, "raw")
    frames = MAX_REASONS + 100
    for n in range(frames):
        raw = Raw(robot=1, n=n, first=0.0, upto=5.0, items=(RawDetection(1.0, f"kind{n}", (1.0,), (0.1,)),))
        sp._handle("raw", _Sample(encode("t", 1, n, raw), key))
    assert sp.counts["rejected"] == frames == sum(sp.reasons.values())
    assert len(sp.reasons) == MAX_REASONS + 1 and sp.reasons[OTHER_REASONS] == frames - MAX_REASONS


def test_empty_lines_messages_are_not_remembered_by_the_map():
    maps = MapStore(roster={0, 1})
    for k in range(1000):
        assert not maps.store(Lines(robot=1, stamp=float(k)))
    assert maps.counts["lines_empty"] == 1000 and not maps._seen
