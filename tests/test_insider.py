"""A lying insider (a robot with its own valid key): every teammate's update and broadcast is checked against what
the receiver knows, refused when it does not fit, counted against its sender (``suspect_<robot>``); a robot whose
updates are refused again and again is quarantined for the run (:mod:`swarmloc.node.trust`).

Before, robot 2 shifting its two ``rdl`` updates by 100 m moved robots 0 and 1 by 100 m each, and nothing was
counted. Here robot 2 shifts everything it sends by 100 m (its answers' beliefs and states, its pairwise updates, its
broadcasts' innovations: tests/_insider.py), in process and, for ``rdl`` and ``diekf``, as its own network process
signing with its own key (tests/net_insider.py).
"""

from __future__ import annotations

import logging
import math
import os
import sys
from pathlib import Path

import msgspec
import numpy as np
import pytest
from _insider import SHIFT, lie, lying

import swarmloc.net.team as net_team
from swarmloc.config import Config, FilterConfig
from swarmloc.estimators import (
    DistributedInvariantEKF,
    InvariantRDL,
    RecursiveDecentralized,
    make_team,
    node_options,
)
from swarmloc.events import Detection
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.gaussian import GroupGaussian
from swarmloc.kernels import invariant as I
from swarmloc.lie import SE2
from swarmloc.messages import BeliefAnswer, BeliefQuery, Message, RdlState, RdlStateQuery, RdlUpdate, TeamUpdate, flat
from swarmloc.motion import UnicycleNoise
from swarmloc.node import chi2_ppf
from swarmloc.runner import RunResult, run

pytestmark = pytest.mark.unit  # the last test (a team of processes) is also network

ESTIMATORS = ("rdl", "irdl", "diekf", "dekf", "ci")
LIAR = 2
HONEST = (0, 1)
GATE = 0.997
INSIDER = Path(__file__).with_name("net_insider.py")
UPDATE_REFUSED = "message rejected: update of robot 2 beyond the gate of this robot's own belief"
REFUSED = {"rdl": UPDATE_REFUSED, "irdl": UPDATE_REFUSED,
           "diekf": "message rejected: broadcast of robot 2 beyond the gate"}  # fmt: skip


@pytest.fixture(autouse=True)
def _quiet(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.ERROR, logger="swarmloc.node")


def _team(name: str, src, liar: bool, **kw) -> list:
    nodes = make_team(name, src.initial, **{**node_options(name, src.config, src.landmarks, t0=src.t_start), **kw})
    if liar:
        nodes[LIAR].__class__ = lying(type(nodes[LIAR]))
    return nodes


def _run(nodes: list, src) -> RunResult:
    return run(nodes, src.events, src.record_times(), src.truth)


def _moved(a: RunResult, b: RunResult, robot: int) -> float:
    """[m] The largest distance between two runs' recorded positions of ``robot``."""
    np.testing.assert_array_equal(a.tracks[robot].times, b.tracks[robot].times)
    return float(np.hypot(*(a.tracks[robot].mean[:, :2] - b.tracks[robot].mean[:, :2]).T).max())


@pytest.fixture(scope="module")
def landmarks_src():
    return load_source("sim:landmarks", robots=3, duration=30.0, seed=1)


@pytest.mark.parametrize("name", ESTIMATORS)
def test_a_lying_robot_moves_no_honest_robot_and_is_reported(name: str, landmarks_src):
    """Robot 2 shifts all it sends by 100 m: robots 0 and 1 stay within 0.1 m of the clean run (where the same lie
    without a gate moves them by metres), and each names robot 2, and only robot 2, as its suspect; a diekf teammate
    quarantines it (its broadcasts refused 3 in a row). The clean run refuses nothing."""
    src = landmarks_src
    clean = _run(_team(name, src, False), src)
    nodes = _team(name, src, True)
    lied = _run(nodes, src)
    unguarded = _run(_team(name, src, True, gate=None), src)
    for r in HONEST:
        assert _moved(lied, clean, r) <= 0.1, f"robot {r}"
        assert nodes[r].suspects.keys() == {LIAR} and nodes[r].stats()[f"suspect_{LIAR}"] > 0, f"robot {r}"
    assert max(_moved(unguarded, clean, r) for r in HONEST) > 1.0
    for k in ("updates_refused", "updates_unusable", "quarantined", "messages_rejected"):
        assert clean.stats[k] == 0, k
    if name in ("rdl", "irdl", "diekf"):  # robot 2's own detections of its teammates: updates that it lied in
        assert lied.stats["updates_refused"] > 0
        assert lied.reasons[REFUSED[name]] == lied.stats["updates_refused"]
    if name == "diekf":
        assert all(nodes[r].quarantined == {LIAR} for r in HONEST)
        assert lied.stats["quarantined"] == lied.stats[f"quarantined_{LIAR}"] > 0


def _silent(m: Message) -> Message | None:
    """What a robot that says nothing sends instead of ``m``: answers "not found", no update, no broadcast."""
    if isinstance(m, BeliefAnswer | RdlState):
        return type(m)(sender=m.sender, receiver=m.receiver, stamp=m.stamp, sub=m.sub, found=False, reason="silent")
    if isinstance(m, RdlUpdate | TeamUpdate):
        return None
    return m


def _silenced(cls: type) -> type:
    def step(self, item):
        return [x for x in map(_silent, cls.step(self, item)) if x is not None]

    def expire(self, before=None):
        return [x for x in map(_silent, cls.expire(self, before)) if x is not None]

    return type(f"Silent{cls.__name__}", (cls,), {"step": step, "expire": expire})


@pytest.mark.parametrize("name", ESTIMATORS)
def test_without_landmarks_a_refused_lie_is_worth_silence(name: str):
    """With no landmarks the honest robots need robot 2: refusing its lies costs them its information (up to 0.3 m
    here). The lie costs nothing more: they end where they would have had robot 2 said nothing at all."""
    src = load_source("sim:random", robots=3, duration=30.0, seed=1)
    nodes = _team(name, src, True)
    lied = _run(nodes, src)
    silent = _team(name, src, False)
    silent[LIAR].__class__ = _silenced(type(silent[LIAR]))
    quiet = _run(silent, src)
    for r in HONEST:
        assert _moved(lied, quiet, r) <= 1e-9, f"robot {r}"


@pytest.mark.parametrize("name", ("dekf", "rdl", "diekf"))
def test_clean_runs_refuse_nothing_and_suspect_only_the_gated(name: str):
    """A clean team of 5: no update refused, no one quarantined, the beliefs those of a team that never quarantines;
    the suspicions are exactly the robot detections the gate refused (its false alarms, ~0.3% of them)."""
    src = load_source("sim:random", robots=5, duration=60.0, seed=1)
    res = _run(_team(name, src, False), src)
    never = _run(_team(name, src, False, quarantine=None), src)
    assert res.stats["updates_refused"] == res.stats["quarantined"] == res.stats["messages_rejected"] == 0
    assert res.stats["gated"] > 0  # some false alarms of the gate ...
    assert sum(v for k, v in res.stats.items() if k.startswith("suspect_")) == res.stats["gated"]  # ... all suspected
    for r in src.robots:
        assert _moved(res, never, r) == 0.0


def test_quarantine_is_a_setting():
    """``[filter] quarantine`` reaches the nodes (false: never); a node refuses a nonsensical one, naming it."""
    never = Config().replace(filter=FilterConfig(quarantine=False))
    assert node_options("rdl", never, None)["quarantine"] is None
    assert node_options("diekf", Config(), None)["quarantine"] == 3
    with pytest.raises(ValueError, match="'quarantine' must be an integer >= 1"):
        _node(RecursiveDecentralized, quarantine=0)
    node = _node(RecursiveDecentralized, quarantine=None)
    for t in (1.0, 2.0, 3.0, 4.0):
        a = _ask(node, t)
        far = np.array(a.x) + _along(np.reshape(a.P, (3, 3)), 2.0 * chi2_ppf(GATE, 3))
        node.step(RdlUpdate(sender=1, receiver=0, stamp=t, sub=a.sub, based_on=a.seq, x=flat(far), P=a.P))
    assert node.stats()["updates_refused"] == 4 and node.quarantined == frozenset()


# ------------------------------------------------------------------------------------------------ the bound
TINY_Q = UnicycleNoise(q_v0=1e-12, q_lat0=1e-12, q_w0=1e-12)
X0 = np.array([1.0, 2.0, 0.3])
P0 = np.array([[0.04, 0.01, 0.0], [0.01, 0.02, 0.002], [0.0, 0.002, 0.01]])


def _node(cls: type, **kw):
    return cls(0, GroupGaussian(SE2, SE2.from_xytheta(X0), P0), noise=TINY_Q, t0=0.0, gate=GATE, **kw)


def _ask(node, t: float, sender: int = 1) -> RdlState:
    """Robot ``sender``'s query to robot 0 keyed ``t``: robot 0's answer (its state before the key)."""
    out = node.step(RdlStateQuery(sender=sender, receiver=0, stamp=t, sub=(float(t),)))
    assert len(out) == 1 and isinstance(out[0], RdlState) and out[0].found
    return out[0]


def _along(P: np.ndarray, k: float, u=(1.0, -0.5, 0.2)) -> np.ndarray:
    """A correction of squared length ``k`` in the metric of ``P`` (``delta^T P^-1 delta = k``)."""
    u = np.asarray(u) / np.linalg.norm(u)
    return math.sqrt(k) * np.linalg.cholesky(P) @ u


def _moved_to(cls: type, x: np.ndarray, delta: np.ndarray) -> np.ndarray:
    return I.left_correct(x, delta) if cls is InvariantRDL else x + delta


@pytest.mark.parametrize("cls", [RecursiveDecentralized, InvariantRDL])
def test_an_update_passes_only_within_the_gate_and_three_refused_quarantine(cls: type):
    """An update moves its receiver from the state it answered by ``delta``: within the gate (``delta^T P^-1 delta
    <= gamma_3``) it is taken, and the receiver moves by exactly that; beyond, it is refused and counted against the
    sender, the belief untouched. Three refused in a row quarantine the sender: its next messages are refused
    (a query answered "not found"), the receiver's detection waiting for its answer is given up, and the receiver
    asks it nothing more and revises none of its answers to it (giving the detection up moved the answer at 4.0 in
    its last bits: before, that revision went to the quarantined sender)."""
    node = _node(cls)
    gamma = chi2_ppf(GATE, 3)
    waiting = node.step(Detection(0, 3.5, "pose", np.array([1.0, 0.0, 0.0]), 1e-4 * np.eye(3), target=1))
    assert [type(q) for q in waiting] == [RdlStateQuery] and node.pending == 1  # never answered
    a = _ask(node, 1.0)
    x, P = np.array(a.x), np.reshape(a.P, (3, 3))
    delta = _along(P, 0.99 * gamma)
    new = _moved_to(cls, x, delta)
    assert node.step(RdlUpdate(sender=1, receiver=0, stamp=1.0, sub=a.sub, based_on=a.seq, x=flat(new),
                               P=flat(0.5 * P))) == []  # fmt: skip
    got = SE2.to_xytheta(node.belief_at(1.0).mean)
    np.testing.assert_allclose(got, new, atol=1e-12)
    assert node.stats()["updates_refused"] == 0 and node.suspects == {}
    for k, t in enumerate((2.0, 3.0, 4.0)):
        a = _ask(node, t)
        before = node.belief_at(t)
        x, P = np.array(a.x), np.reshape(a.P, (3, 3))
        far = _moved_to(cls, x, _along(P, 1.01 * gamma, (0.3, 1.0, -0.4)))
        assert node.step(RdlUpdate(sender=1, receiver=0, stamp=t, sub=a.sub, based_on=a.seq, x=flat(far),
                                   P=flat(0.5 * P))) == []  # fmt: skip
        after = node.belief_at(t)
        np.testing.assert_array_equal(after.mean, before.mean)
        assert node.stats()["updates_refused"] == k + 1 and node.suspects == {1: k + 1}
        assert node.quarantined == (frozenset({1}) if k == 2 else frozenset())
    assert node.pending == 0 and node.reasons["unknown: robot 1: robot 1 is quarantined"] == 1
    out = node.step(BeliefQuery(sender=1, receiver=0, stamp=4.5))
    assert len(out) == 1 and not out[0].found and out[0].reason == "robot 1 is quarantined"
    assert node.step(RdlUpdate(sender=1, receiver=0, stamp=4.0, sub=(4.0,), based_on=0, x=flat(x), P=a.P)) == []
    s = node.stats()
    assert s["quarantined"] == s["quarantined_1"] == 2 and s["messages_rejected"] == 5
    assert node.reasons["message rejected: robot 1 is quarantined"] == 2
    det = Detection(0, 5.0, "pose", np.array([1.0, 0.0, 0.0]), 1e-4 * np.eye(3), target=1)
    assert node.step(det) == []  # nothing asked of robot 1
    assert node.stats()["unknown"] == 2 and node.reasons["unknown: robot 1: robot 1 is quarantined"] == 2


def _broadcast(P: np.ndarray, k: float, Sinv: np.ndarray | None = None, **kw) -> TeamUpdate:
    """Robot 1's broadcast of a pose measurement of robot 0 (``H_0 = I``, ``H_1 = 0``): ``S = P + R`` with ``R =
    P / 4`` unless ``Sinv`` is given, ``r`` along one direction with ``r^T S^-1 r = k``."""
    S = P + 0.25 * P
    Sinv = np.linalg.inv(S) if Sinv is None else Sinv
    r = _along(np.linalg.inv(Sinv), k)
    return TeamUpdate(sender=1, receiver=0, stamp=1.0, sub=(1.0,), target=0, m=3, Hi=flat(np.zeros((3, 3))),
                      Hj=flat(np.eye(3)), Sinv=flat(Sinv), nu=flat(Sinv @ r), Pii=flat(P), Pjj=flat(P),
                      **kw)  # fmt: skip


def test_a_broadcast_passes_only_within_the_gate_and_moves_at_most_its_bound():
    """A diekf broadcast is taken when its own normalized innovation ``nu^T S nu`` is within the gate; it then moves
    its receiver by at most ``sqrt(gamma)`` of its own standard deviations. Beyond the gate, or one that would leave
    the receiver's covariance not positive definite, or scaled in a team without clusters: not applied."""
    gamma = chi2_ppf(GATE, 3)
    node = DistributedInvariantEKF(0, GroupGaussian(SE2, SE2.from_xytheta(X0), P0), noise=TINY_Q, t0=0.0,
                                   gate=GATE, team=(0, 1, 2))  # fmt: skip
    a = _ask(node, 1.0)
    x, P = np.array(a.x), np.reshape(a.P, (3, 3))
    taken = _broadcast(P, 0.99 * gamma)
    assert node.step(taken) == []
    delta = I.world_delta(x, SE2.to_xytheta(node.belief_at(1.0).mean))
    assert 0.3 * gamma < delta @ np.linalg.solve(P, delta) <= gamma
    assert node.stats()["updates_refused"] == 0
    node = DistributedInvariantEKF(0, GroupGaussian(SE2, SE2.from_xytheta(X0), P0), noise=TINY_Q, t0=0.0,
                                   gate=GATE, team=(0, 1, 2))  # fmt: skip
    before = node.belief_at(1.0)
    for u in (_broadcast(P, 1.01 * gamma), _broadcast(P, 0.5 * gamma, scale=0.5)):
        assert node.step(u) == []
    assert node.stats()["updates_refused"] == 2 and node.suspects == {1: 2}
    assert node.reasons["message rejected: broadcast of robot 1 scaled as no robot of this team scales one"] == 1
    overdrawn = _broadcast(P, 0.5 * gamma, Sinv=np.linalg.inv(0.5 * P))  # claims more than a noiseless measurement
    assert node.step(msgspec.structs.replace(overdrawn, sub=(2.0,))) == []
    s = node.stats()
    assert s["updates_unusable"] == 1 and s["updates_refused"] == 2
    after = node.belief_at(1.0)
    np.testing.assert_array_equal(after.mean, before.mean)
    np.testing.assert_array_equal(after.cov, before.cov)


def test_the_lie_shifts_what_it_says():
    """The test's liar moves a belief, a state, an update and a broadcast's innovation by 100 m."""
    b = BeliefAnswer(sender=2, receiver=0, stamp=1.0, mean=flat(SE2.from_xytheta(X0)), cov=flat(P0))
    assert np.reshape(lie(b).mean, (3, 3))[0, 2] == pytest.approx(X0[0] + SHIFT)
    s = RdlState(sender=2, receiver=0, stamp=1.0, x=flat(X0), P=flat(P0), sigma=flat(np.eye(3)))
    assert lie(s).x[0] == pytest.approx(X0[0] + SHIFT)
    u = _broadcast(P0, 1.0)
    r = np.linalg.solve(np.reshape(lie(u).Sinv, (3, 3)), np.array(lie(u).nu) - np.array(u.nu))
    np.testing.assert_allclose(r, [SHIFT, 0.0, 0.0], atol=1e-9)


# ------------------------------------------------------------------------------------------------ over the network
class _InsiderLauncher(net_team._Launcher):
    """The launcher, with robot 2's process the lying one (tests/net_insider.py: ``swarmloc node`` with its node's
    messages shifted, signing with robot 2's own key)."""

    def node_cmd(self, r: int, resume: bool = False) -> list[str]:
        cmd = super().node_cmd(r, resume)
        if r != LIAR:
            return cmd
        assert cmd[1:3] == ["-m", "swarmloc.cli"]
        return [sys.executable, str(INSIDER), *cmd[3:]]


@pytest.mark.network  # starts a team of node processes, the liar one of them
@pytest.mark.parametrize("name", ("rdl", "diekf"))
def test_a_lying_robot_process_with_its_own_key_moves_no_honest_robot(name: str, tmp_path, monkeypatch, landmarks_src):
    """A networked team of 3 whose robot 2 is a lying process signing with its own valid key: robots 0 and 1 end
    where the in-process run with the same liar leaves them (to 1e-9), within 0.1 m of the clean run, and their
    reports name robot 2, and only robot 2, as suspect (diekf: quarantined)."""
    src = landmarks_src
    monkeypatch.setattr(net_team, "_Launcher", _InsiderLauncher)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(Path(__file__).parent), *sys.path]))
    tr = run_team(src=src, source="sim:landmarks", robots=3, duration=30.0, seed=1, estimator=name,
                  team=f"insider{os.getpid()}", speed=2.0, max_wall=150, log_dir=tmp_path / "logs")  # fmt: skip
    assert all(c == 0 for c in tr.exit_codes.values()), tr.exit_codes
    assert "lying" in (tmp_path / "logs" / "robot2.log").read_text()
    res = team_result(tr, src, name)
    clean = _run(_team(name, src, False), src)
    lied = _run(_team(name, src, True), src)
    for r in HONEST:
        assert _moved(res, lied, r) <= 1e-9 and _moved(res, clean, r) <= 0.1, f"robot {r}"
        stats = tr.reports[r].stats
        suspects = {k: v for k, v in stats.items() if k.startswith("suspect_") and v}
        assert suspects.keys() == {f"suspect_{LIAR}"}, f"robot {r}"
        if name == "diekf":
            assert stats[f"quarantined_{LIAR}"] > 0
