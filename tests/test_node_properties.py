"""Property-based tests of the node (hypothesis): arbitrary sequences of valid, late, future, duplicated,
self-addressed, misaddressed and malformed inputs.

After every input: no exception, the counters add up, the belief's covariance is symmetric positive definite.
At the end: the result equals that of the clean inputs alone, in order (the junk is refused and changes nothing;
late inputs within the horizon are replayed to the same result).
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarmloc import make_team
from swarmloc.events import Detection, Odometry
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.messages import (
    BeliefAnswer,
    BeliefQuery,
    RdlState,
    RdlStateQuery,
    RdlUpdate,
    TeamUpdate,
    flat,
)
from swarmloc.motion import UnicycleNoise

pytestmark = pytest.mark.unit


NOISE = UnicycleNoise(q_v0=1e-3, q_lat0=1e-4, q_w0=1e-3)
LANDMARKS = {10: (3.0, 1.0, 0.01, 0.01), 11: (-1.0, 2.0, 0.02, 0.02)}
NEIGHBOUR = GroupGaussian(SE2, SE2.from_xytheta([1.5, 0.5, 0.2]), np.diag([0.01, 0.02, 0.003]))
HORIZON = 2.0
NAMES = ["dr", "dekf", "expfusion", "ci", "rdl", "diekf", "mcl"]


@pytest.fixture(autouse=True)
def _quiet():
    logger = logging.getLogger("swarmloc.node")
    level = logger.level
    logger.setLevel(logging.ERROR)
    yield
    logger.setLevel(level)


def _node(name: str):
    init = {0: GroupGaussian(SE2, SE2.identity(), 1e-3 * np.eye(3)), 1: NEIGHBOUR}
    opts = {"noise": NOISE, "t0": 0.0, "horizon": HORIZON}
    if name != "dr":
        opts.update(landmarks=LANDMARKS, gate=0.999)
    if name == "mcl":
        opts.update(particles=64, seed=3)
    return make_team(name, init, **opts)[0]


def _answer(q):
    """Robot 1's answer to a query of robot 0 (a fixed belief: the same whenever asked)."""
    if isinstance(q, BeliefQuery):
        return BeliefAnswer(sender=1, receiver=0, stamp=q.stamp, sub=q.sub, mean=flat(NEIGHBOUR.mean),
                            cov=flat(NEIGHBOUR.cov))  # fmt: skip
    x = SE2.to_xytheta(NEIGHBOUR.mean)
    return RdlState(sender=1, receiver=0, stamp=q.stamp, sub=q.sub, x=flat(x), P=flat(NEIGHBOUR.cov),
                    sigma=flat(np.zeros((3, 3))))  # fmt: skip


def _feed(node, item) -> None:
    """Step ``node``; answer its queries to robot 1 at once (other messages go nowhere)."""
    todo = [item]
    while todo:
        for m in node.step(todo.pop(0)):
            if isinstance(m, BeliefQuery | RdlStateQuery) and m.receiver == 1:
                todo.append(_answer(m))


def clean_inputs(rng: np.random.Generator, n: int) -> list:
    """Contiguous odometry of robot 0 at 10 Hz and detections of a landmark and of robot 1 between the records."""
    out: list = []
    for k in range(n):
        out.append(Odometry(0, 0.1 * k, 0.1 * (k + 1), float(rng.uniform(0.0, 0.4)), float(rng.uniform(-0.3, 0.3))))
        if k % 3 == 1:
            t = 0.1 * k + 0.05
            out.append(Detection(0, t, "range_bearing", np.array([3.0 + 0.1 * rng.standard_normal(), 0.3]),
                                 np.diag([0.01, 0.001]), target=10, target_is_robot=False))  # fmt: skip
        if k % 4 == 2:
            t = 0.1 * k + 0.07
            z = np.array([1.5, 0.5, 0.2]) + 0.05 * rng.standard_normal(3)
            out.append(Detection(0, t, "pose", z, np.diag([0.01, 0.01, 0.003]), target=1))
    return out


def junk(kind: str, rng: np.random.Generator, present: float, sent: list) -> object:
    """One input the node must refuse, stamped relative to ``present`` (``"duplicate"``: an input sent again)."""
    far = present + float(10 ** rng.uniform(2, 9)) * (1 + rng.uniform())  # far apart from any other far stamp
    eye = flat(np.eye(3))
    spd = flat(0.01 * np.eye(3))
    if kind == "future_odometry":
        return Odometry(0, far, far + 0.1, 0.3, 0.0)
    if kind == "future_detection":
        return Detection(0, far, "range_bearing", np.array([2.0, 0.1]), np.diag([0.01, 0.001]), target=10,
                         target_is_robot=False)  # fmt: skip
    if kind == "old_detection":
        t = present - HORIZON - float(rng.uniform(1, 50))
        return Detection(0, t, "range", np.array([2.0]), np.eye(1) * 0.01, target=10, target_is_robot=False)
    if kind == "duplicate":
        return sent[int(rng.integers(len(sent)))]
    if kind == "malformed":
        choices = [
            Detection(0, 0.5, "range_bearing", np.array([np.nan, 0.1]), np.eye(2), target=10, target_is_robot=False),
            Detection(0, 0.5, "laser", np.array([1.0]), np.eye(1), target=10, target_is_robot=False),
            Detection(0, 0.5, "pose", np.array([1.0, 0.0, 0.0]), -np.eye(3), target=1),
            Detection(0, math.inf, "range", np.array([1.0]), np.eye(1), target=10, target_is_robot=False),
            Odometry(0, float("nan"), 1.0, 0.1, 0.0),
            Odometry(0, 1.0, 0.5, 0.1, 0.0),
            BeliefAnswer(sender=1, receiver=0, stamp=float("nan"), mean=eye, cov=spd),
            BeliefAnswer(sender=1, receiver=0, stamp=0.5, mean=(1.0,) * 9, cov=spd),
            RdlUpdate(sender=1, receiver=0, stamp=0.5, x=(0.0, 0.0), P=spd),
            "not an input",
        ]
        return choices[int(rng.integers(len(choices)))]
    if kind == "self_addressed":
        choices = [
            BeliefQuery(sender=0, receiver=0, stamp=present),
            RdlStateQuery(sender=0, receiver=0, stamp=present),
            BeliefAnswer(sender=0, receiver=0, stamp=present, mean=eye, cov=spd),
            RdlUpdate(sender=0, receiver=0, stamp=present, x=(0.0, 0.0, 0.0), P=spd),
            TeamUpdate(
                sender=0,
                receiver=0,
                stamp=present,
                target=0,
                m=3,
                Hi=eye,
                Hj=eye,
                Sinv=spd,
                nu=(1.0, 1.0, 1.0),
                Pii=spd,
                Pjj=spd,
            ),  # fmt: skip
        ]
        return choices[int(rng.integers(len(choices)))]
    if kind == "misaddressed":
        return BeliefAnswer(sender=1, receiver=5, stamp=present, mean=eye, cov=spd)
    raise AssertionError(kind)


JUNK = ("future_odometry", "future_detection", "old_detection", "duplicate", "malformed", "self_addressed",
        "misaddressed")  # fmt: skip
CLOCK_JUNK = ("future_odometry", "future_detection", "old_detection")


def _check_invariants(node) -> None:
    s = node.stats()
    assert s["detections"] == s["fused"] + s["gated"] + s["rejected"] + s["unknown"] + s["pending"], s
    assert s["odometry"] == s["odometry_used"] + s["odometry_rejected"] + s["odometry_pending"], s
    if node.started:
        C = node.belief().cov
        assert np.array_equal(C, C.T) or np.abs(C - C.T).max() <= 1e-12 * np.abs(C).max()
        assert np.linalg.eigvalsh(0.5 * (C + C.T)).min() > 0


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_any_mix_of_junk_and_late_input_leaves_the_clean_result(name: str, data: st.DataObject) -> None:
    seed = data.draw(st.integers(0, 2**31 - 1), label="seed")
    rng = np.random.default_rng(seed)
    clean = clean_inputs(rng, data.draw(st.integers(8, 30), label="records"))
    # arrival order: each clean input delayed by up to half the horizon (late but within it)
    delays = data.draw(st.lists(st.floats(0.0, HORIZON / 2), min_size=len(clean), max_size=len(clean)))
    stamp = [e.t0 if isinstance(e, Odometry) else e.t for e in clean]
    order = np.argsort(np.array(stamp) + np.array(delays), kind="stable")
    kinds = data.draw(st.lists(st.sampled_from((None, None, None, *JUNK)), min_size=len(clean),
                               max_size=len(clean)), label="junk")  # fmt: skip
    node, reference = _node(name), _node(name)
    for e in clean:
        _feed(reference, e)
    reference.expire()
    run_of_clock_junk = 0
    sent: list = []
    for i, k in zip(order, kinds, strict=True):
        _feed(node, clean[i])
        sent.append(clean[i])
        _check_invariants(node)
        if k is None or (k in CLOCK_JUNK and run_of_clock_junk >= node._clock.confirm - 1):
            run_of_clock_junk = 0
            continue
        run_of_clock_junk = run_of_clock_junk + 1 if k in CLOCK_JUNK else 0
        _feed(node, junk(k, rng, node.present, sent))
        _check_invariants(node)
    node.expire()
    _check_invariants(node)
    s, r = node.stats(), reference.stats()
    for key in ("fused", "gated", "odometry_used", "clock_jumps", "clock_resets"):
        assert s[key] == r[key], (key, s[key], r[key], dict(node.reasons))
    assert s["pending"] == s["odometry_pending"] == 0
    t_end = 0.1 * sum(isinstance(e, Odometry) for e in clean)
    a, b = node.belief_at(t_end), reference.belief_at(t_end)
    assert np.abs(a.mean - b.mean).max() <= 1e-9 and np.abs(a.cov - b.cov).max() <= 1e-9
