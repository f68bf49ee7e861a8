"""``diekf``'s odometry-fault test (:mod:`swarmloc.estimators.odometry_fault`): the jump test is the generalized
likelihood ratio as documented, an alarm needs two partners and spends the window, replays rewrite rather than add;
a simulated team one of whose robots' odometry reports a turn it did not make is detected, and the team is made
consistent again where the plain filter's robot is not; a fault-free run raises no alarm and is the plain filter's."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from swarmloc.config import DEFAULTS
from swarmloc.engine.replay import run_engine
from swarmloc.estimators import make_team, node_options
from swarmloc.estimators.odometry_fault import Evidence, FaultMonitor, evidence, jump_test
from swarmloc.evaluation.metrics import errors
from swarmloc.experiments.sources import load_source, sim_source
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.node import chi2_ppf
from swarmloc.runner import run
from swarmloc.sim import RelativeSensor, random_team

pytestmark = pytest.mark.unit


def test_the_jump_test_is_the_glr_of_a_constant_error():
    rng = np.random.default_rng(0)
    f = np.array([0.1, -0.2, 0.3])
    b, B = np.zeros(3), np.zeros((3, 3))
    for _ in range(6):  # range-bearing-like detections, each seeing 2 of the 3 dof, r = H f exactly
        H, S = rng.standard_normal((2, 3)), np.diag(rng.uniform(0.5, 2.0, 2))
        ev = evidence(H, np.linalg.inv(S), np.linalg.solve(S, H @ f), partner=1)
        b, B = b + ev.b, B + ev.B
    T, f_hat = jump_test(b, B)
    assert np.allclose(f_hat, f)  # the jump recovered
    assert T == pytest.approx(f @ B @ f)  # the GLR: b^T B^-1 b with b = B f
    one = evidence(np.array([[1.0, 0.0, 0.0]]), np.eye(1), np.array([2.0]), partner=1)
    assert jump_test(one.b, one.B)[0] == pytest.approx(4.0)  # one dof seen: T is its NIS, B^+ ignores the rest


def _ev(partner: int, size: float) -> Evidence:
    """Evidence of a heading error ``size`` / 2 [rad] seen with information 4 on the heading only."""
    return Evidence(np.array([0.0, 0.0, 2.0 * size]), np.diag([0.0, 0.0, 4.0]), partner)


def test_an_alarm_needs_two_partners_and_spends_the_window():
    assert chi2_ppf(0.9999, 3) == pytest.approx(21.1, abs=0.05)  # the threshold the numbers below are read against
    lone = FaultMonitor(window=10.0)
    for k in range(10):  # one partner disagreeing, however strongly: which of the two is at fault is not known
        assert lone.record(float(k), ("o", k), _ev(1, 5.0)) is None
    mon = FaultMonitor(window=10.0)  # T = b^2 / B with b = 2 size, B = 4 per entry; gamma = 21.1
    assert mon.record(0.0, "a", _ev(1, 1.0)) is None  # T = 1
    assert mon.record(1.0, "b", _ev(2, 2.0)) is None  # two partners, T = 6^2 / 8 = 4.5: the window adds up
    assert mon.record(2.0, "c", _ev(2, 4.0)) is None  # T = 14^2 / 12 = 16.3
    D = mon.record(3.0, "d", _ev(1, 6.0))  # T = 26^2 / 16 = 42 > gamma: the jump f = 26 / 16 on the heading
    assert D is not None and np.allclose(D, np.diag([0.0, 0.0, (26.0 / 16.0) ** 2]))
    assert mon.alarms == {(3.0, "d")}
    assert mon.record(4.0, "e", _ev(2, 6.0)) is None  # the window starts afresh after the alarm: one partner
    assert mon.record(12.5, "f", _ev(2, 6.0)) is None  # [2.5, 12.5) after the alarm: e only, still one partner
    assert mon.record(13.0, "g", _ev(1, 6.0)) is not None  # e, f and g: two partners, T = 36^2 / 12
    assert mon.record(30.0, "h", _ev(2, 6.0)) is None  # nothing left in [20, 30): one partner


def test_replays_rewrite_and_drop():
    a, b = FaultMonitor(window=10.0), FaultMonitor(window=10.0)
    seq = [(0.0, "a", _ev(1, 3.0)), (1.0, "b", _ev(2, 3.0)), (2.0, "c", _ev(1, 3.0))]
    out_a = [a.record(*x) for x in seq]
    b.record(0.0, "a", _ev(1, 3.0))
    b.record(1.0, "b", _ev(2, 0.0))  # another past at 1 s ...
    b.record(2.0, "x", _ev(1, 9.0))  # ... and a detection that the replay no longer has
    b.record(2.0, "x", None)  # dropped
    out_b = [b.record(*x) for x in seq]  # the replay: the in-order run's numbers
    assert all((p is None and q is None) or np.array_equal(p, q) for p, q in zip(out_a, out_b, strict=True))
    assert a.alarms == b.alarms and a.alarms


def test_config_option_reaches_diekf_only_and_the_engine_refuses_it():
    cfg = dataclasses.replace(DEFAULTS, filter=dataclasses.replace(DEFAULTS.filter, diekf_fault=True))
    assert node_options("diekf", cfg, None)["fault"] is True
    assert "fault" not in node_options("diekf", DEFAULTS, None)
    assert "fault" not in node_options("rdl", cfg, None)
    src = load_source("sim:landmarks", robots=2, duration=2.0, seed=0)
    with pytest.raises(ValueError, match="no odometry-fault test"):
        run_engine(src, "diekf", fault=True)


FAULT_AT = 60.0
"""[s] after the start: robot 0's odometry reports 1 rad/s more yaw rate than it turns, for 1.5 s."""


def _team(seed: int, fault: bool) -> tuple[Any, list[Any]]:
    """Four robots that see one another (range and bearing, 1 Hz, no range limit) for 150 s, starting at their true
    poses, no landmarks; with ``fault``, robot 0's odometry reports a turn of 1.5 rad it did not make."""
    sim = random_team(4, 150.0, seed=seed, area=3.0,
                      sensor=RelativeSensor(rate=1.0, max_range=50.0, kinds=("range_bearing",)))  # fmt: skip
    src = sim_source(sim, "sim:fault", None)
    at = {r: src.truth(r, np.array([src.t_start]))[0] for r in src.initial}
    src = dataclasses.replace(src, initial={r: GroupGaussian(SE2, SE2.from_xytheta(at[r]), g.cov)
                                            for r, g in src.initial.items()})  # fmt: skip
    t0 = src.t_start + FAULT_AT

    def phantom(e: Any) -> Any:
        odometry = type(e).__name__ == "Odometry" and e.robot == 0 and t0 <= e.stamp < t0 + 1.5
        return dataclasses.replace(e, w=e.w + 1.0) if odometry else e

    return src, [phantom(e) for e in src.events] if fault else list(src.events)


def _run(src: Any, events: list[Any], fault: bool) -> tuple[Any, list[Any]]:
    nodes = make_team("diekf", src.initial, fault=fault, **node_options("diekf", src.config, None, src.t_start))
    return run(nodes, events, src.record_times(), truth=src.truth, name="diekf"), nodes


def _anees_after(res: Any, t: float) -> float:
    """The team's ANEES per dof over the records from ``t`` [s] on."""
    nees = [errors(tr)["nees"][tr.times >= t] for tr in res.tracks.values()]
    return float(np.mean(np.concatenate(nees)) / 3)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_phantom_turn_is_detected_and_the_team_stays_consistent(seed):
    src, events = _team(seed, fault=True)
    plain, _ = _run(src, events, fault=False)
    tolerant, nodes = _run(src, events, fault=True)
    stamps = sorted({k[0] - src.t_start for k in nodes[0].faults.alarms})
    assert stamps and FAULT_AT < stamps[0] < FAULT_AT + 5.0  # the faulty robot's alarm, within seconds
    after = src.t_start + FAULT_AT + 5.0
    assert _anees_after(plain, after) > 20.0  # measured 44 (seed 0), 67 (1): robot 0 confident and wrong
    assert 0.5 <= _anees_after(tolerant, after) <= 2.0  # measured 0.99 and 0.73


def test_a_fault_free_run_raises_no_alarm_and_is_the_plain_filters():
    src, events = _team(0, fault=False)
    plain, _ = _run(src, events, fault=False)
    tolerant, nodes = _run(src, events, fault=True)
    assert not any(n.faults.alarms for n in nodes)
    assert any(n.faults._log for n in nodes)  # the test ran: evidence was filed
    for r, tr in plain.tracks.items():
        assert np.array_equal(tr.mean, tolerant.tracks[r].mean) and np.array_equal(tr.cov, tolerant.tracks[r].cov)


def test_late_detections_replayed_give_the_in_order_run():
    src, events = _team(1, fault=True)
    late = list(events)
    for i in reversed([i for i, e in enumerate(late) if type(e).__name__ == "Detection"][::7]):
        late.insert(min(i + 10, len(late) - 1), late.pop(i))  # every 7th detection 10 inputs late: replayed
    out = []
    for evs in (events, late):
        res, nodes = _run(src, evs, fault=True)
        means = np.concatenate([res.tracks[r].mean for r in sorted(res.tracks)])
        out.append((means, [n.faults.alarms for n in nodes], sum(n.counts["replayed"] for n in nodes)))
    assert out[1][2] > 0
    assert np.allclose(out[0][0], out[1][0], atol=1e-9)
    assert out[0][1] == out[1][1] and out[0][1][0]  # the same alarms, the faulty robot's among them
