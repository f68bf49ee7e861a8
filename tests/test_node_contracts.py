"""The node's clock and input contracts (swarmloc.node): each test here failed on the node before the contracts.

* One input stamped far in the future is refused and counted; it never becomes the present.
* A robot's clock that jumps back (or forward) beyond the horizon is recognised after a few inputs in a row and
  the node carries on from its belief at the jump; a single stray stamp is only refused.
* A query stamped past the present plus the tolerance is answered "not yet" once, never revised.
* Messages addressed from a robot to itself, or to a robot the node does not own, are refused and change nothing.
* Neighbours are learned only from messages the node accepted.
* Odometry past its end ``t1`` stops the robot (growing noise, counted); intervals that overlap, or that start
  before the node's start, are refused with a reason naming them.
"""

from __future__ import annotations

import logging

import msgspec
import numpy as np
import pytest

from swarmloc import make_team
from swarmloc.estimators import ESTIMATORS, DistributedEKF, ExpFusion
from swarmloc.events import Detection, Odometry
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.messages import BeliefAnswer, BeliefQuery, RdlState, RdlStateQuery, RdlUpdate, TeamUpdate, flat
from swarmloc.motion import UnicycleNoise
from swarmloc.node import same

pytestmark = pytest.mark.unit


NOISE = UnicycleNoise(q_v0=1e-3, q_lat0=1e-4, q_w0=1e-3)
LANDMARKS = {10: (3.0, 1.0, 0.01, 0.01)}
DISTRIBUTED = [n for n, c in ESTIMATORS.items() if c.distributed]
SPD = flat(1e-2 * np.eye(3))


@pytest.fixture(autouse=True)
def _quiet():
    logger = logging.getLogger("swarmloc.node")
    level = logger.level
    logger.setLevel(logging.ERROR)
    yield
    logger.setLevel(level)


def _belief(x: tuple[float, float, float] = (0.0, 0.0, 0.0), var: float = 1e-3) -> GroupGaussian:
    return GroupGaussian(SE2, SE2.from_xytheta(x), var * np.eye(3))


def _lm(t: float, observer: int = 0) -> Detection:
    return Detection(observer, t, "range_bearing", np.array([3.1, 0.3]), np.diag([0.01, 0.001]), target=10,
                     target_is_robot=False)  # fmt: skip


def _odo(k: int, robot: int = 0, dt: float = 0.1, t_start: float = 0.0) -> Odometry:
    return Odometry(robot, t_start + dt * k, t_start + dt * (k + 1), 0.2, 0.05)


def _node(name: str = "dekf", **kw):
    opts = {"noise": NOISE, "t0": 0.0, "landmarks": LANDMARKS, "gate": None, **kw}
    if name == "dr":
        opts = {k: v for k, v in opts.items() if k in ("noise", "t0")}
    init = {0: _belief(), 1: _belief((1.0, 0.0, 0.0)), 2: _belief((0.0, 1.0, 0.0))}
    return make_team(name, init, **opts)[0]


def _close(a: GroupGaussian, b: GroupGaussian, tol: float = 0.0) -> bool:
    return bool(np.abs(a.mean - b.mean).max() <= tol and np.abs(a.cov - b.cov).max() <= tol)


def _accounted(node) -> bool:
    s = node.stats()
    return (
        s["detections"] == s["fused"] + s["gated"] + s["rejected"] + s["unknown"] + s["pending"]
        and s["odometry"] == s["odometry_used"] + s["odometry_rejected"] + s["odometry_pending"]
    )


# ------------------------------------------------------------------------------------------------ clock
@pytest.mark.parametrize("bad", ["odometry", "detection"])
@pytest.mark.parametrize("name", ["dekf", "expfusion", "rdl", "cekf"])
def test_one_input_stamped_far_in_the_future_is_refused_and_the_node_carries_on(name: str, bad: str):
    """Before: one input stamped 1e9 s moved the watermark there; every later input was 'older than the horizon'."""
    node, clean = _node(name), _node(name)
    for k in range(30):
        node.step(_odo(k))
        clean.step(_odo(k))
    node.step(_odo(10**10) if bad == "odometry" else _lm(1e9))
    for k in range(30, 60):
        for n in (node, clean):
            n.step(_odo(k))
            if k % 10 == 0:
                n.step(_lm(0.1 * k + 0.05))
    s = node.stats()
    assert s["odometry_used"] == 60 and s["fused"] == 3  # the inputs after the stray one were taken
    assert s["rejected"] + s["odometry_rejected"] == 1 and s["future"] == 1 and _accounted(node)
    assert node.present == clean.present == pytest.approx(5.9)
    assert any("past the node's present" in r for r in node.reasons)
    assert _close(node.belief_at(6.0, 0), clean.belief_at(6.0, 0))


@pytest.mark.parametrize("name", ["dekf", "expfusion", "rdl", "mcl", "cekf"])
def test_a_robot_clock_that_jumps_back_resets_the_history_and_the_node_carries_on(name: str):
    """Before: after a robot's clock went back (a reboot), every input was refused forever."""
    node = _node(name)
    for k in range(1000):  # 100 s
        node.step(_odo(k))
    before = node.belief(robot=0)
    for k in range(50):  # the robot's clock restarts at 0
        node.step(_odo(k))
        if k % 10 == 5:
            node.step(_lm(0.1 * k + 0.01))
    s = node.stats()
    assert s["odometry_used"] == 1050 and s["fused"] == 5  # the inputs after the jump were taken
    assert s["clock_resets"] == 1 and s["clock_jumps"] == 0 and _accounted(node)
    assert node.present == pytest.approx(4.9)
    # the belief at the jump is the belief the node had: only its time changed
    after = node.belief_at(0.0, 0)
    assert np.allclose(after.mean, before.mean) and np.allclose(after.cov, before.cov)
    assert node.t0 == 0.0


def test_a_robot_clock_that_jumps_forward_is_taken_after_jump_inputs_inputs():
    node = _node("dekf")  # jump_inputs=3 by default
    for k in range(100):
        node.step(_odo(k))
    for k in range(3):  # the clock jumps by 1 day (a time sync)
        node.step(_odo(k, t_start=86400.0))
    s = node.stats()
    assert s["odometry_used"] == 103 and s["clock_jumps"] == 1 and s["odometry_pending"] == 0
    assert node.present == pytest.approx(86400.2) and _accounted(node)


def test_stray_stamps_that_do_not_agree_are_refused_not_taken_as_a_jump():
    node = _node("dekf")
    for k in range(100):
        node.step(_odo(k))
    for far in (1e4, 3e6, 7e8, 2e9):  # four future stamps in a row, but far from each other: no jump
        node.step(Odometry(0, far, far + 0.1, 0.2, 0.0))
    node.expire()
    node.step(_odo(100))
    s = node.stats()
    assert s["odometry_used"] == 101 and s["odometry_rejected"] == 4  # refused, and the node carries on
    assert s["clock_jumps"] == 0 and s["future"] == 4 and node.present == pytest.approx(10.0) and _accounted(node)


def test_held_inputs_count_as_pending_until_the_clock_decides():
    node = _node("dekf")
    for k in range(10):
        node.step(_odo(k))
    node.step(_lm(500.0))
    s = node.stats()
    assert s["pending"] == 1 and s["rejected"] == 0 and _accounted(node)
    node.step(_odo(10))
    s = node.stats()
    assert s["pending"] == 0 and s["rejected"] == 1 and s["future"] == 1 and _accounted(node)


# ------------------------------------------------------------------------------------------------ queries
@pytest.mark.parametrize("name", DISTRIBUTED)
def test_a_query_from_the_future_is_answered_not_yet_once_and_never_revised(name: str):
    """Before: the node answered from an extrapolated state, kept the answer and re-sent it on every later input
    (62 messages out for one query in)."""
    node = _node(name)
    for k in range(10):
        node.step(_odo(k))
    q_type = RdlStateQuery if name in ("rdl", "irdl", "diekf") else BeliefQuery
    out = node.step(q_type(sender=1, receiver=0, stamp=1000.0))
    assert len(out) == 1 and not out[0].found and out[0].reason.startswith("not yet")
    later = []
    for k in range(10, 100):
        later += node.step(_odo(k))
        later += node.step(_lm(0.1 * k + 0.05)) if k % 7 == 0 else []
    assert [m for m in later if isinstance(m, BeliefAnswer | RdlState)] == []  # no answer re-sent
    assert node.stats()["not_yet_sent"] == 1 and node.stats()["revisions_sent"] == 0


def test_an_answer_that_changed_in_its_last_bit_is_a_revision():
    """``same`` tells a revision from a repeat to the bit: the revision number aside, equal messages are the same;
    one number a unit in the last place apart is not (left unrevised, such a difference grew to 4.3e-7 m in a
    fixed-lag smoother's relinearized window: tests/test_node.py's shuffled real-data test)."""
    a = BeliefAnswer(sender=1, receiver=0, stamp=1.0, mean=flat(SE2.identity()), cov=SPD, seq=0)
    assert same(a, msgspec.structs.replace(a, seq=3)) and same(None, None) and not same(a, None)
    cov = list(SPD)
    cov[0] = float(np.nextafter(cov[0], np.inf))
    assert not same(a, msgspec.structs.replace(a, cov=tuple(cov)))
    assert not same(a, RdlStateQuery(sender=1, receiver=0, stamp=1.0))


# ------------------------------------------------------------------------------------------------ addressing
def _self_addressed(robot: int) -> list:
    mean = flat(SE2.from_xytheta([0.5, 0.0, 0.0]))
    eye = flat(np.eye(3))
    return [
        BeliefQuery(sender=robot, receiver=robot, stamp=1.5),
        RdlStateQuery(sender=robot, receiver=robot, stamp=1.5),
        BeliefAnswer(sender=robot, receiver=robot, stamp=1.0, mean=mean, cov=SPD),
        RdlState(sender=robot, receiver=robot, stamp=1.0, x=(0.5, 0.0, 0.0), P=SPD, sigma=SPD),
        RdlUpdate(sender=robot, receiver=robot, stamp=1.5, x=(0.5, 0.0, 0.0), P=SPD),
        TeamUpdate(
            sender=robot,
            receiver=robot,
            stamp=1.5,
            target=robot,
            m=3,
            Hi=eye,
            Hj=eye,
            Sinv=SPD,
            nu=(1.0, 1.0, 1.0),
            Pii=SPD,
            Pjj=SPD,
        ),  # fmt: skip
    ]


@pytest.mark.parametrize("name", DISTRIBUTED)
def test_messages_addressed_to_oneself_or_to_another_robot_are_refused_and_change_nothing(name: str):
    """Before: a robot's own RdlStateQuery was answered and stored, after which its own RdlUpdate was applied (rdl);
    its own TeamUpdate corrupted diekf's state."""
    node = _node(name)
    for k in range(20):
        node.step(_odo(k))
    before = node.belief_at(2.0)
    bad = _self_addressed(0)
    bad += [BeliefQuery(sender=1, receiver=2, stamp=1.5), RdlUpdate(sender=1, receiver=2, stamp=1.5, x=(0.0,) * 3,
                                                                      P=SPD)]  # fmt: skip
    outs = [m for b in bad for m in node.step(b)]
    assert outs == []
    assert node.stats()["messages_rejected"] == len(bad) and node.stats()["answers_sent"] == 0
    assert sum(v for k, v in node.reasons.items() if "to itself" in k) == len(bad) - 2
    assert sum(v for k, v in node.reasons.items() if "not a robot of this node" in k) == 2
    assert _close(node.belief_at(2.0), before)


@pytest.mark.parametrize("name", ["dekf", "rdl", "diekf"])
def test_neighbours_are_learned_only_from_accepted_messages(name: str):
    """Before: an answer to no query, a stale answer or an update for a state never sent still made its sender a
    known neighbour."""
    node = _node(name)
    node.step(_odo(0))
    mean = flat(SE2.from_xytheta([1.0, 0.0, 0.0]))
    junk = [
        BeliefAnswer(sender=7, receiver=0, stamp=0.05, mean=mean, cov=SPD),  # to no query
        RdlState(sender=8, receiver=0, stamp=0.05, x=(1.0, 0.0, 0.0), P=SPD, sigma=SPD),  # to no query
        RdlUpdate(sender=5, receiver=0, stamp=0.05, x=(0.0, 0.0, 0.0), P=SPD),  # for a state never sent
        TeamUpdate(sender=9, receiver=0, stamp=0.05),  # from outside the team
    ]
    for m in junk:
        node.step(m)
    assert node.neighbours == frozenset() and node.stats()["messages_rejected"] == len(junk)


# ------------------------------------------------------------------------------------------------ odometry
@pytest.mark.parametrize("name", ["dr", "dekf", "expfusion", "rdl", "irdl", "diekf", "cekf", "iekf", "fej"])
def test_past_the_end_of_its_odometry_a_robot_is_stopped_with_growing_noise(name: str):
    """Before: ``Odometry.t1`` was ignored and a robot whose odometry stopped moved on at its last speed forever."""
    node = _node(name)
    node.step(Odometry(0, 0.0, 1.0, 1.0, 0.0))  # 1 m/s for one second, then nothing
    at_end, later = node.belief_at(1.0, 0), node.belief_at(5.0, 0)
    assert SE2.to_xytheta(at_end.mean)[0] == pytest.approx(1.0, abs=1e-9)
    assert SE2.to_xytheta(later.mean)[0] == pytest.approx(1.0, abs=1e-9)  # stopped at t1, not at 5 m
    assert np.trace(later.cov) > np.trace(at_end.cov)  # the zero-speed diffusion keeps it growing
    assert node.stats()["odometry_stops"] == 1


@pytest.mark.parametrize("name", ["dekf", "expfusion", "cekf"])
def test_a_gap_in_the_odometry_stops_the_robot_until_the_next_record(name: str):
    node = _node(name)
    node.step(Odometry(0, 0.0, 1.0, 1.0, 0.0))
    node.step(Odometry(0, 3.0, 4.0, 1.0, 0.0))  # a 2 s gap
    x = SE2.to_xytheta(node.belief_at(4.0, 0).mean)[0]
    assert x == pytest.approx(2.0, abs=1e-9) and node.stats()["odometry_stops"] == 1
    late = _node(name)  # the same records out of order give the same result
    late.step(Odometry(0, 3.0, 4.0, 1.0, 0.0))
    late.step(Odometry(0, 0.0, 1.0, 1.0, 0.0))
    assert _close(late.belief_at(4.0, 0), node.belief_at(4.0, 0), 1e-12)


def test_filling_a_gap_late_takes_the_stop_back():
    node, ordered = _node("expfusion"), _node("expfusion")
    for e in (_odo(0), _odo(1), _odo(2)):
        ordered.step(e)
    for e in (_odo(0), _odo(2), _odo(1)):  # the gap [0.1, 0.2] is filled by the late record
        node.step(e)
    assert _close(node.belief_at(0.5), ordered.belief_at(0.5), 1e-12)


def test_overlapping_odometry_and_odometry_before_the_start_are_refused_with_reasons():
    """Before: a record starting at t0 = -5 s, or two overlapping records, ran silently (ANEES 356 and 19)."""
    node = _node("dekf")
    node.step(Odometry(0, 0.0, 1.0, 0.5, 0.0))
    node.step(Odometry(0, 0.5, 1.5, 0.5, 0.0))  # overlaps [0, 1]
    node.step(Odometry(0, -5.0, -4.0, 0.5, 0.0))  # before the start
    node.expire()
    s = node.stats()
    assert s["odometry_used"] == 1 and s["odometry_rejected"] == 2
    assert any("overlaps the odometry interval [0, 1]" in r for r in node.reasons)
    assert any("before the node's start time 0.0" in r for r in node.reasons)


def test_an_odometry_interval_ending_far_in_the_future_is_refused():
    node = _node("dekf", tolerance=5.0)
    node.step(Odometry(0, 0.0, 1e9, 0.5, 0.0))  # would block every later record as overlapping
    node.step(Odometry(0, 0.0, 0.1, 0.5, 0.0))
    s = node.stats()
    assert s["odometry_used"] == 1 and s["odometry_rejected"] == 1 and s["future"] == 1


# ------------------------------------------------------------------------------------------------ public state
def test_public_state_is_read_only_and_filterpy_shaped():
    node = _node("dekf")
    for k in range(10):
        node.step(_odo(k))
    x, P = node.x, node.P
    assert x.shape == (3,) and P.shape == (3, 3) and not x.flags.writeable and not P.flags.writeable
    b = node.belief()
    assert np.allclose(x, SE2.to_xytheta(b.mean)) and np.allclose(P, P.T)
    with pytest.raises(ValueError):
        x[0] = 1.0
    team = _node("cekf")
    for k in range(10):
        team.step(_odo(k))
    assert team.x.shape == (9,) and team.P.shape == (9, 9)


def test_iekf_public_covariance_is_cartesian_like_cekf():
    """``P`` is one convention for every node: the world-frame (x, y, theta) covariance, first order."""
    a, b = _node("cekf"), _node("iekf")
    for k in range(30):
        for n in (a, b):
            n.step(_odo(k))
    assert np.allclose(a.x, b.x, atol=1e-9)
    assert np.allclose(a.P, b.P, rtol=1e-3, atol=1e-9)


def test_distributed_node_P_matches_the_ros_mapping_of_its_belief():
    from swarmloc.gaussian import world_covariance

    node = _node("expfusion")
    for k in range(30):
        node.step(_odo(k))
    b = node.belief()
    assert np.array_equal(node.P, world_covariance(b.mean, b.cov)[1])


@pytest.mark.parametrize("cls", [DistributedEKF, ExpFusion])
def test_belief_defaults_to_the_present(cls):
    node = cls(0, _belief(), noise=NOISE, t0=0.0)
    for k in range(5):
        node.step(_odo(k))
    assert node.present == pytest.approx(0.4)
    assert np.array_equal(node.belief().mean, node.belief_at(0.4).mean)
    assert np.array_equal(node.belief(0.2).mean, node.belief_at(0.2).mean)


def test_the_first_odometry_stamped_far_in_the_future_is_refused_too():
    """Found by the property test: the in-order fast path took a first record from 1e8 s as the present."""
    node = _node("dekf")
    assert node._intake.odometry_fast(Odometry(0, 1e8, 1e8 + 0.1, 0.3, 0.0)) is False
    node.step(Odometry(0, 1e8, 1e8 + 0.1, 0.3, 0.0))
    node.step(_odo(0))
    assert node.stats()["odometry_used"] == 1 and node.stats()["future"] == 1 and node.present == 0.0


def test_an_offline_run_refuses_odometry_before_the_sources_start() -> None:
    """evaluate_stream starts the nodes at ``t_start``: odometry from t0 = -5 s is refused with its reason, not run
    silently into an inconsistent result (it was ANEES 356 before)."""
    from swarmloc.experiments.evaluate import evaluate_stream

    initial = {0: GroupGaussian(SE2, SE2.identity(), np.diag([1e-4, 1e-4, 1e-4]))}
    events = [Odometry(0, -5.0, 0.0, 0.5, 0.0), *(Odometry(0, k * 0.1, (k + 1) * 0.1, 0.2, 0.0) for k in range(50))]
    report, _ = evaluate_stream(events, initial, t_start=0.0, t_end=5.0, truth=None, estimators=["dr", "dekf"])
    for name in ("dr", "dekf"):
        ev = report["estimators"][name]
        assert ev["stats"]["odometry_rejected"] == 1 and ev["stats"]["odometry_used"] == 50
        assert any("before the node's start time 0.0" in r for r in ev["reasons"])
