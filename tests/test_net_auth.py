"""Authenticated senders (:mod:`swarmloc.net.auth`): the signed frame, the roster, the keys, and a live attack.

Before, a payload's sender was whatever its envelope said: a forged ``RdlStateQuery`` + ``RdlUpdate`` in robot 1's
name moved robot 0 by 100 m (team RMSE 93.9 m instead of 0.088 m), forged beliefs reached the report, and one
belief stamped outside the run aborted it. Here every payload is signed by its sender's Ed25519 key and verified
against the roster before it is decoded; a refusal is counted per category and never crashes anything.

The live test runs a real attacker process (``tests/net_attacker.py``, its own Zenoh session on 127.0.0.1) holding
robot 2's valid key during a team run; every forged message is refused and counted where it arrives, and the run
equals the in-process run on the same events. Networking on 127.0.0.1 only, every wait bounded, every process
started is stopped.
"""

from __future__ import annotations

import ast
import json
import math
import os
import re
import struct
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from _attacker import attacker_process
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmloc.estimators import make_team, node_options
from swarmloc.evaluation.metrics import evaluate
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result, write_team_report
from swarmloc.messages import BeliefAnswer, BeliefQuery, RdlStateQuery, RdlUpdate, flat
from swarmloc.net.auth import (
    CATEGORIES,
    COLLECTOR,
    HEADER,
    MAX_SIGNED,
    Auth,
    AuthRejected,
    Roster,
    Signer,
    TeamKeys,
    Verifier,
    key_id,
    load_private,
    make_team_keys,
    new_key,
    open_envelope,
)
from swarmloc.net.central import Forwarder
from swarmloc.net.entry import make_node
from swarmloc.net.faults import Faults
from swarmloc.net.process import NetNode
from swarmloc.net.schema import SERVER, Belief, Progress, Rejected, encode
from swarmloc.net.server import ServerProcess
from swarmloc.net.team import _Launcher
from swarmloc.net.teamlink import TeamLink
from swarmloc.net.transport import free_ports, robot_key
from swarmloc.runner import run

pytestmark = pytest.mark.network


TEAM = "t"
I3 = flat(np.eye(3))
COV = flat(np.diag([0.01, 0.01, 0.001]))
SHIFT = flat(np.array([[1.0, 0.0, 100.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
ATTACKER = Path(__file__).with_name("net_attacker.py")
DIEKF_ATTACKER = Path(__file__).with_name("net_diekf_attacker.py")
INBOX0 = robot_key(TEAM, 0, "inbox")
PROGRESS1 = robot_key(TEAM, 1, "progress")


@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[int, Path]]:
    return make_team_keys(tmp_path_factory.mktemp("keys"), [0, 1, 2])


def signer(keys, member: int, as_member: int | None = None, clock=None) -> Signer:
    """``member``'s key, signing under ``as_member``'s name (default its own)."""
    kw = {} if clock is None else {"clock": clock}
    return Signer(member if as_member is None else as_member, load_private(keys[1][member]), **kw)


def verifier(keys, **kw) -> Verifier:
    return Verifier(Roster.load(keys[0]), **kw)


def category(v: Verifier, key: str, data: bytes, publication: bool = False) -> str:
    with pytest.raises(AuthRejected) as exc:
        v.open(key, data, publication)
    assert exc.value.reason == f"auth: {CATEGORIES[exc.value.category]}"
    return exc.value.category


PROGRESS = encode(TEAM, 1, 0, Progress(robot=1, t=1.0))


# ------------------------------------------------------------------------------------------------ the signed frame
def test_sealed_frame_opens_to_its_sender_and_payload(keys):
    s, v = signer(keys, 1), verifier(keys)
    data = s.seal(PROGRESS1, PROGRESS)
    magic, sender, seq, stamp, kid, incarnation = HEADER.unpack_from(data)
    assert (magic, sender, kid, incarnation) == (b"SLS2", 1, key_id(Roster.load(keys[0]).keys[1]), s.incarnation)
    assert len(data) == HEADER.size + len(PROGRESS) + 64
    assert v.open(PROGRESS1, data, publication=True) == (1, PROGRESS)
    env = open_envelope(Auth(Roster.load(keys[0])), PROGRESS1, s.seal(PROGRESS1, PROGRESS), TEAM, {0, 1, 2})
    assert env.body == Progress(robot=1, t=1.0)


def test_tampered_frame_is_refused(keys):
    """Any byte changed (payload, sender's seq or stamp, the signature), or the frame moved to another key."""
    s, v = signer(keys, 1), verifier(keys)
    data = s.seal(INBOX0, PROGRESS)
    for at in (HEADER.size + 5, len(data) - 70, 8, 16, len(data) - 1):
        bad = bytearray(data)
        bad[at] ^= 0x01
        assert category(v, INBOX0, bytes(bad)) == "bad_signature"
    assert category(v, robot_key(TEAM, 2, "inbox"), data) == "bad_signature"  # robot 1's push, moved to robot 2
    assert category(v, robot_key("other", 0, "inbox"), data) == "bad_signature"  # to another team
    assert v.open(INBOX0, data)[0] == 1  # the original still opens (nothing above was remembered)


def test_wrong_key_is_refused_and_the_signer_named(keys, caplog):
    """Robot 2's valid key under robot 1's name: a key mismatch (the log names robot 2, verified); with robot 1's key
    id claimed: a bad signature; a key outside the roster: a key mismatch."""
    v = verifier(keys)
    forged = signer(keys, 2, as_member=1)
    with pytest.raises(AuthRejected) as exc:
        v.open(INBOX0, forged.seal(INBOX0, PROGRESS))
    assert exc.value.category == "key_mismatch" and "signed with the key of robot 2 (verified)" in exc.value.detail
    forged.key_id = key_id(Roster.load(keys[0]).keys[1])
    assert category(v, INBOX0, forged.seal(INBOX0, PROGRESS)) == "bad_signature"
    for member in (SERVER, COLLECTOR):
        assert category(v, INBOX0, signer(keys, 2, as_member=member).seal(INBOX0, PROGRESS)) == "key_mismatch"
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    stranger = Signer(1, Ed25519PrivateKey.generate())
    with pytest.raises(AuthRejected) as exc:
        v.open(INBOX0, stranger.seal(INBOX0, PROGRESS))
    assert exc.value.category == "key_mismatch" and "outside the roster" in exc.value.detail


def test_unknown_sender_unsigned_and_oversize_are_refused(keys):
    v = verifier(keys)
    assert category(v, INBOX0, signer(keys, 2, as_member=9).seal(INBOX0, PROGRESS)) == "unknown_sender"
    for raw in (PROGRESS, b"", b"SLS1", b"SLS1" + bytes(90), b"XXXX" + bytes(200)):
        assert category(v, INBOX0, raw) == "unsigned"
    big = encode(TEAM, 1, 0, BeliefAnswer(sender=1, receiver=0, stamp=1.0, reason="x" * MAX_SIGNED, mean=I3, cov=COV))
    assert category(v, INBOX0, signer(keys, 1).seal(INBOX0, big)) == "oversize"  # signed, still too large
    assert category(v, INBOX0, b"\xff" * (MAX_SIGNED + 1)) == "oversize"  # refused before anything is parsed


def test_replay_is_refused_within_and_below_the_window(keys):
    s, v = signer(keys, 1), verifier(keys, window=4)
    frames = [s.seal(INBOX0, PROGRESS) for _ in range(8)]
    v.open(INBOX0, frames[1])
    v.open(INBOX0, frames[0])  # reordered, within the window: accepted
    assert category(v, INBOX0, frames[1]) == "replay"  # the same sequence number again
    for f in frames[3:]:
        v.open(INBOX0, f)  # 7 accepted, 4 remembered: frames 0, 1 and 3 forgotten
    assert category(v, INBOX0, frames[2]) == "replay"  # never seen, but older than the newest forgotten: refused
    restarted = signer(keys, 1)  # a new process of robot 1: its numbers start at its clock, past the old ones
    assert v.open(INBOX0, restarted.seal(INBOX0, PROGRESS))[0] == 1


def test_stale_and_future_stamps_are_refused(keys):
    now = [10**18]
    v = verifier(keys, clock=lambda: now[0])
    s = signer(keys, 1, clock=lambda: now[0])
    old = s.seal(INBOX0, PROGRESS)
    now[0] += 31 * 10**9  # the roster's max_age is 30 s
    assert category(v, INBOX0, old) == "stale"
    ahead = signer(keys, 1, clock=lambda: now[0] + 31 * 10**9).seal(INBOX0, PROGRESS)
    assert category(v, INBOX0, ahead) == "future"
    assert v.open(INBOX0, s.seal(INBOX0, PROGRESS))[0] == 1


def test_publications_only_on_the_senders_own_key_and_the_envelope_names_the_signer(keys):
    v, auth = verifier(keys), Auth(Roster.load(keys[0]))
    own2 = signer(keys, 2)
    p2 = encode(TEAM, 2, 0, Progress(robot=2, t=1.0))
    assert category(v, PROGRESS1, own2.seal(PROGRESS1, p2), publication=True) == "not_owner"
    assert category(v, robot_key(TEAM, "x", "progress"), own2.seal(robot_key(TEAM, "x", "progress"), p2), True)
    with pytest.raises(AuthRejected) as exc:  # robot 2 signs honestly, the envelope inside speaks as robot 1
        open_envelope(auth, PROGRESS1, own2.seal(PROGRESS1, PROGRESS), TEAM, {0, 1, 2})
    assert exc.value.category == "sender_mismatch"


@settings(max_examples=300, deadline=None, database=None)
@given(st.binary(max_size=300), st.sampled_from([b"", b"SLS1"]), st.integers(-3, 12))
def test_garbage_never_crashes_the_verifier(keys, raw, magic, sender):
    v = verifier(keys)
    data = magic + struct.pack(">i", sender) + raw if magic else raw
    with pytest.raises(Rejected):
        open_envelope(Auth(v.roster), INBOX0, data, TEAM, {0, 1, 2}, to_robot=0)


# ------------------------------------------------------------------------------------------------ keys and rosters
def test_keys_roster_file_and_permissions(tmp_path, keys):
    roster = Roster.load(keys[0])
    assert roster.robots == [0, 1, 2] and SERVER in roster.keys and COLLECTOR in roster.keys
    assert all(os.stat(f).st_mode & 0o777 == 0o600 for f in keys[1].values())
    assert Roster.load(keys[0]) == roster
    with pytest.raises(FileExistsError):
        new_key(keys[1][0])  # never overwritten
    loose = tmp_path / "loose.key"
    new_key(loose)
    os.chmod(loose, 0o644)
    with pytest.raises(ValueError, match="chmod 600"):
        load_private(loose)
    with pytest.raises(ValueError, match="not the roster's key of robot 1"):
        Auth.load(keys[1][2], keys[0], 1)
    with pytest.raises(ValueError, match="share a key"):
        Roster({0: roster.keys[0], 1: roster.keys[0]})
    (tmp_path / "bad.json").write_text(json.dumps({"swarmloc_roster": 1, "members": {"robot-1": "AAAA"}}))
    with pytest.raises(ValueError, match="robot-1"):
        Roster.load(tmp_path / "bad.json")


def test_keys_command_line(tmp_path, capsys):
    from swarmloc.cli import main

    assert main(["keys", "team", "--robots", "0,1", "--out", str(tmp_path / "team")]) == 0
    assert Roster.load(tmp_path / "team" / "roster.json").robots == [0, 1]
    for name in ("a", "b", "s"):
        assert main(["keys", "new", str(tmp_path / f"{name}.key")]) == 0
    members = [
        "0=" + str(tmp_path / "a.key.pub"),
        "1=" + str(tmp_path / "b.key"),
        "server=" + str(tmp_path / "s.key.pub"),
    ]
    assert main(["keys", "roster", "--out", str(tmp_path / "r.json"), *members]) == 0
    r = Roster.load(tmp_path / "r.json")
    assert r.robots == [0, 1] and SERVER in r.keys
    Auth.load(tmp_path / "b.key", tmp_path / "r.json", 1)  # the key matches its entry
    capsys.readouterr()
    assert main(["node", "--team", "t", "--robot", "1", "--source", "sim:random"]) == 2
    assert "--key FILE" in capsys.readouterr().err
    assert main(["server", "--team", "t", "--roster", "0,1,2"]) == 2
    assert "--robots" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------ the driver, offline
class _Sample:
    def __init__(self, key: str, raw: bytes) -> None:
        self.key_expr, self.raw, self.errors = key, raw, []
        self.payload, self.ok = self, self

    def to_bytes(self) -> bytes:
        return self.raw

    def reply_err(self, reason: bytes) -> None:
        self.errors.append(reason)

    def drop(self) -> None:
        pass


class _Session:
    def get(self, key, **kw) -> None:
        pass

    def put(self, key, payload, **kw) -> None:
        pass


def offline_node(auth: Auth | None) -> NetNode:
    """Robot 0 of a simulated team of 3 (rdl) in a driver that is never opened (nothing sent)."""
    src = load_source("sim:random", robots=3, duration=4.0, seed=0)
    node = make_node("rdl", 0, src.initial[0], src.config, src.landmarks)
    node.start(src.t_start)
    net = NetNode(node, src.own_events(0), session=_Session(), team=TEAM, roster=src.robots,
                  record_times=src.record_times(), auth=auth)  # fmt: skip
    net.wiring.pub["belief"] = SimpleNamespace(put=lambda *a, **k: None)  # never opened: beliefs go nowhere
    return net


def test_each_process_signs_only_with_its_own_key(keys):
    """A robot's node, its forwarder and the belief server, given their team's link (:class:`TeamLink`) with
    another member's key or none, each refuse to start, naming the key needed and the one held (one check,
    :func:`~swarmloc.net.auth.signs_as`); with their own key, or unauthenticated, they start."""
    roster = Roster.load(keys[0])
    robot1 = TeamLink(None, TEAM, [0, 1, 2], Auth(roster, signer(keys, 1)))
    with pytest.raises(ValueError, match=r"^Forwarder: auth must hold robot 0's own key .* \(it holds robot 1's\)$"):
        Forwarder(0, [], robot1)
    with pytest.raises(ValueError, match=r"^ServerProcess: auth must hold server's own key .* \(it holds robot 1's\)"):
        ServerProcess(robot1)
    with pytest.raises(ValueError, match=r"^ServerProcess: .* \(it holds no key\)$"):
        ServerProcess(TeamLink(None, TEAM, [0, 1, 2], Auth(roster)))
    with pytest.raises(ValueError, match=r"^NetNode: auth must hold robot 0's own key .* \(it holds robot 1's\)$"):
        offline_node(robot1.auth)
    assert Forwarder(1, [], robot1).auth is robot1.auth and Forwarder(0, [], TeamLink(None, TEAM, [0])).auth is None
    assert ServerProcess(TeamLink(None, TEAM, [0, 1], Auth(roster, signer(keys, SERVER)), run_id="r1")).scope == (
        f"{TEAM}/run/r1"
    )
    with pytest.raises(ValueError, match="run id must be"):
        TeamLink(None, TEAM, [0], run_id="a/b")


FORGED_QUERY = RdlStateQuery(sender=1, receiver=0, stamp=1.0)
FORGED_UPDATE = RdlUpdate(sender=1, receiver=0, stamp=1.0, x=(100.0, 0.0, 0.0), P=COV)
FORGED_DONE = Progress(robot=1, t=math.inf, done=True)
FORGED_REPLY = BeliefAnswer(sender=1, receiver=0, stamp=1.0, mean=SHIFT, cov=COV)


def test_unauthenticated_node_takes_forged_messages():
    """The control, as every node was before: without ``auth`` the same forgeries, unsigned, are taken (the query
    held for an answer, the update stepped, robot 1 taken for done, the reply held for the node)."""
    net = offline_node(None)
    net.inbound.handle("query", _Sample(robot_key(TEAM, 0, "query"), encode(TEAM, 1, 0, FORGED_QUERY)))
    net.inbound.handle("inbox", _Sample(INBOX0, encode(TEAM, 1, 1, FORGED_UPDATE)))
    net.inbound.handle("progress", _Sample(PROGRESS1, encode(TEAM, 1, 3, FORGED_DONE)))
    net.outbound.outstanding[7] = (BeliefQuery(sender=0, receiver=1, stamp=1.0), "robot", False)
    net.inbound.handle("reply", 7, _Sample(robot_key(TEAM, 1, "query"), encode(TEAM, 1, 4, FORGED_REPLY)))
    assert net.counts["rejected"] == 0 and len(net.lockstep.deferred) == 1 and 1 in net.lockstep.done
    assert net.outbound.outstanding[7][2] is True


def test_node_refuses_and_counts_forged_messages_on_every_path(keys):
    """Robot 0 (offline, authenticated) receives, in robot 1's name with robot 2's key, a query, an update, a reply,
    a progress "done"; unsigned and replayed ones too: each is refused before decoding, counted by category, and
    nothing reaches the node (its state and lockstep unchanged)."""
    net = offline_node(Auth.load(keys[1][0], keys[0], 0))
    node = net.node
    forged, genuine = signer(keys, 2, as_member=1), signer(keys, 1)
    q, u = FORGED_QUERY, FORGED_UPDATE
    query = _Sample(robot_key(TEAM, 0, "query"), forged.seal(robot_key(TEAM, 0, "query"), encode(TEAM, 1, 0, q)))
    net.inbound.handle("query", query)
    net.inbound.handle("inbox", _Sample(INBOX0, forged.seal(INBOX0, encode(TEAM, 1, 1, u))))
    net.inbound.handle("inbox", _Sample(INBOX0, encode(TEAM, 1, 2, u)))
    net.inbound.handle("progress", _Sample(PROGRESS1, forged.seal(PROGRESS1, encode(TEAM, 1, 3, FORGED_DONE))))
    net.outbound.outstanding[7] = (BeliefQuery(sender=0, receiver=1, stamp=1.0), "robot", False)
    reply = encode(TEAM, 1, 4, FORGED_REPLY)
    net.inbound.handle(
        "reply", 7, _Sample(robot_key(TEAM, 1, "query"), forged.seal(robot_key(TEAM, 1, "query"), reply))
    )
    real = genuine.seal(PROGRESS1, encode(TEAM, 1, 5, Progress(robot=1, t=2.0)))
    net.inbound.handle("progress", _Sample(PROGRESS1, real))
    net.inbound.handle("progress", _Sample(PROGRESS1, real))  # replayed
    net_counts = net.report().net
    assert {k: v for k, v in net_counts.items() if k.startswith("auth_")} == {
        "auth_key_mismatch": 4, "auth_unsigned": 1, "auth_replay": 1}  # fmt: skip
    assert net_counts["rejected"] == 6 and sum(v for k, v in net.reasons.items() if k.startswith("auth: ")) == 6
    assert query.errors == [b"rejected"] and not net.lockstep.deferred and not net.lockstep.held
    assert net.lockstep.progress == {1: 2.0} and 1 not in net.lockstep.done  # only the genuine progress counted
    assert node.counts["messages_rejected"] == 0 and net.outbound.outstanding[7][2] is False


# ------------------------------------------------------------------------------------------------ the collector
def _launcher(tk: TeamKeys, src) -> _Launcher:
    return _Launcher(TEAM, src.robots, [], Faults(), False, [], None, tk, src.record_times())


def test_the_collector_keeps_delayed_output_at_detection_instants_only(tmp_path):
    """A smoother's delayed output (``robot/<id>/delayed``) is kept apart from the beliefs, at the run's start or a
    detection instant only; one stamped elsewhere (a record time without a detection, or far off), one signed with
    another robot's key, and an SE(3) one are refused with their reasons; a higher revision replaces the first."""
    from swarmloc.events import Detection
    from swarmloc.net.team import pose_stamps

    src = load_source("sim:landmarks", robots=3, duration=4.0, seed=2)
    tk = TeamKeys(src.robots, tmp_path / "keys")
    lr = _Launcher(TEAM, src.robots, [], Faults(), False, [], None, tk, src.record_times(), pose_stamps(src))
    own, forged = Signer(1, load_private(tk.files[1])), Signer(1, load_private(tk.files[2]))

    def sample(s: Signer, b: Belief) -> _Sample:
        key = robot_key(TEAM, 1, "delayed")
        return _Sample(key, s.seal(key, encode(TEAM, s.member, 0, b)))

    t_det = next(float(e.stamp) for e in src.events if isinstance(e, Detection) and e.observer == 1)
    t_rec = next(float(t) for t in src.record_times() if float(t) not in pose_stamps(src))
    lr.collect(sample(own, Belief(robot=1, stamp=t_det, final=True, mean=I3, cov=COV)))
    lr.collect(sample(own, Belief(robot=1, stamp=t_det, rev=1, final=True, mean=SHIFT, cov=COV)))
    for t in (t_rec, 1e6):
        lr.collect(sample(own, Belief(robot=1, stamp=t, final=True, mean=I3, cov=COV)))
    lr.collect(sample(forged, Belief(robot=1, stamp=src.t_start, rev=5, final=True, mean=SHIFT, cov=COV)))
    se3 = Belief(robot=1, stamp=src.t_start, final=True, mean=flat(np.eye(4)), cov=flat(np.eye(6) * 1e-2), group="SE3")
    lr.collect(sample(own, se3))
    got = lr.result
    assert list(got.delayed) == [(1, t_det)] and got.delayed[(1, t_det)].mean == SHIFT and not got.beliefs
    assert got.counts["delayed_collected"] == 2 and got.counts["collector_rejected"] == 4
    assert got.reasons["delayed output that is no SE(2) belief at a detection instant of the run"] == 3
    assert got.counts["collector_auth_key_mismatch"] == 1
    tk.close()


def reference(src, est: str):
    nodes = make_team(est, src.initial, **node_options(est, src.config, src.landmarks))
    return run(nodes, src.events, src.record_times(), truth=src.truth)


def test_forged_beliefs_leave_the_collectors_report_unchanged(tmp_path, keys):
    """The collector gets every robot's genuine final beliefs (of the in-process run) and, interleaved, beliefs in
    robot 1's name signed with robot 2's key (100 m off, a higher revision), robot 2's own belief on robot 1's key,
    unsigned ones, a replay, and beliefs stamped outside the run (forged, and robot 2's own): every one is refused
    and counted, and the report is the one of the genuine beliefs alone (before: 28 m RMSE, or an abort)."""
    src = load_source("sim:random", robots=3, duration=6.0, seed=4)
    ref = reference(src, "dekf")
    tk = TeamKeys(src.robots, tmp_path / "keys")
    clean, attacked = _launcher(tk, src), _launcher(tk, src)
    signers = {r: Signer(r, load_private(tk.files[r])) for r in src.robots}
    forged, own2 = Signer(1, load_private(tk.files[2])), signers[2]

    def sample(s: Signer, key_robot: int, b: Belief) -> _Sample:
        key = robot_key(TEAM, key_robot, "belief")
        return _Sample(key, s.seal(key, encode(TEAM, s.member, 0, b)))

    from swarmloc.lie import SE2

    n_forged = Counter()
    for r, tr in ref.tracks.items():
        for t, xyt, cov in zip(tr.times, tr.mean, tr.cov, strict=True):
            b = Belief(robot=r, stamp=float(t), final=True, mean=flat(SE2.from_xytheta(xyt)), cov=flat(cov))
            genuine = sample(signers[r], r, b)
            clean.collect(genuine)
            attacked.collect(genuine)
            if r == 1:
                off = Belief(robot=1, stamp=float(t), rev=9, final=True, mean=SHIFT, cov=COV)
                attacked.collect(sample(forged, 1, off))  # robot 2's key in robot 1's name
                attacked.collect(sample(own2, 1, Belief(robot=2, stamp=float(t), rev=9, final=True, mean=SHIFT,
                                                         cov=COV)))  # fmt: skip
                attacked.collect(_Sample(robot_key(TEAM, 1, "belief"), encode(TEAM, 1, 0, off)))  # unsigned
                attacked.collect(genuine)  # replayed
                n_forged.update(["auth_key_mismatch", "auth_not_owner", "auth_unsigned", "auth_replay"])
    outside = Belief(robot=1, stamp=1e6, final=True, mean=SHIFT, cov=COV)
    attacked.collect(sample(forged, 1, outside))
    attacked.collect(sample(own2, 2, Belief(robot=2, stamp=1e6, final=True, mean=I3, cov=COV)))  # robot 2, lying
    n_forged["auth_key_mismatch"] += 1
    counts = attacked.result.counts
    assert {k[len("collector_") :]: v for k, v in counts.items() if k.startswith("collector_auth_")} == n_forged
    assert counts["collector_rejected"] == sum(n_forged.values()) + 1
    assert attacked.result.reasons["belief stamped at no record time of the run"] == 1
    assert attacked.result.beliefs == clean.result.beliefs
    reports = []
    for name, lr in (("clean", clean), ("attacked", attacked)):
        lr.result.wall_s = 1.0
        rep = write_team_report(lr.result, src, "dekf", tmp_path / name, {})  # no abort
        reports.append(rep["estimators"]["dekf"]["team"])
    assert reports[0] == reports[1]
    assert reports[1]["pos_rmse"] == pytest.approx(evaluate(ref)["team"]["pos_rmse"], abs=1e-9)
    tk.close()
    assert (tmp_path / "keys" / "roster.json").exists()  # a folder given is the caller's: kept


# ------------------------------------------------------------------------------------------------ a live attack
def assert_tracks_equal(res, ref, tol: float) -> None:
    """Every robot's recorded times equal and its means and covariances within ``tol`` of the reference run."""
    for r, t in ref.tracks.items():
        a = res.tracks[r]
        np.testing.assert_array_equal(a.times, t.times)
        assert np.abs(a.mean - t.mean).max() <= tol and np.abs(a.cov - t.cov).max() <= tol, f"robot {r}"


def _server_counts(log: Path) -> dict:
    m = re.search(r"belief server: stopped; (\{.*?\}); store", log.read_text())
    assert m, f"no summary in the belief server's log:\n{log.read_text()[-2000:]}"
    return ast.literal_eval(m.group(1))


def test_attacker_with_robot_2s_key_changes_nothing(tmp_path):
    """A team of 3 (rdl, belief server) and an attacker process holding robot 2's valid key, speaking in robot 1's
    name to robot 0, the collector and the server (queries, rdl updates, a far-off belief, progress "done", a report,
    answers as the server and the collector, a "complete" queryable on robot 1's key answering every query to robot
    1), replaying robot 1's genuine pushes as they are, moved, and once stale. Every forged message is refused and
    counted, by category, exactly where it arrives; no get of the attacker is answered; the beliefs equal the
    in-process run on the same events to 1e-9 and the report is that run's."""
    src = load_source("sim:random", robots=3, duration=30.0, seed=1)
    team = f"attack{os.getpid()}"
    roster, _ = make_team_keys(tmp_path / "keys", src.robots, max_age=4.0)
    ep = f"tcp/127.0.0.1:{free_ports(1)[0]}"
    out = tmp_path / "attacker.json"
    rts = ",".join(repr(float(t)) for t in src.record_times())
    args = ["--listen", ep, "--team", team, "--keys", str(tmp_path / "keys"), "--robots", "0,1,2", "--out", str(out),
            "--record-times", rts]  # fmt: skip
    with attacker_process(ATTACKER, args):
        tr = run_team(src=src, source="sim:random", robots=3, duration=30.0, seed=1, estimator="rdl", team=team,
                      server=True, speed=2.0, max_wall=120, connect_extra=[ep], keys_dir=tmp_path / "keys",
                      log_dir=tmp_path / "logs")  # fmt: skip
    sent = json.loads(out.read_text())
    expected = sent["expected"]
    assert sent["server_seen"]  # the attacker sent nothing before the server's token reached it
    rounds = 8
    assert sent["schema_bad"] == rounds  # only the message as the collector: the schema has no collector
    assert sent["schema_ok"] >= 15 * rounds  # every other forgery passes the schema's checks: only signatures stop it
    assert sent["answers"] and not [a for a in sent["answers"] if a.startswith("ok")]
    r0 = expected["robot 0"]
    assert r0["replay"] > 0 and r0["stale"] > 0 and r0["key_mismatch"] >= 6 * rounds
    assert set(r0) == {"key_mismatch", "bad_signature", "unsigned", "unknown_sender", "other_run", "replay",
                       "stale"}  # fmt: skip
    assert all(c == 0 for c in tr.exit_codes.values()), tr.exit_codes
    for r in src.robots:
        got = {k[len("auth_") :]: v for k, v in tr.reports[r].net.items() if k.startswith("auth_")}
        assert got == expected.get(f"robot {r}", {}), f"robot {r}"
    got = {k[len("collector_auth_") :]: v for k, v in tr.counts.items() if k.startswith("collector_auth_")}
    assert got == expected["collector"]
    assert expected["collector"]["other_run"] == rounds  # robot 2's key on its own belief, not from its process
    server = {k[len("auth_"):]: v for k, v in _server_counts(tmp_path / "logs" / "server.log").items()
              if k.startswith("auth_")}  # fmt: skip
    assert server == expected["server"]
    res = team_result(tr, src, "rdl")
    ref = reference(src, "rdl")
    assert res.stats["reports"] == 3 and res.stats["recorded_provisional_only"] == 0
    assert_tracks_equal(res, ref, 1e-9)
    rep = write_team_report(tr, src, "rdl", tmp_path / "report", {})
    assert rep["estimators"]["rdl"]["team"]["pos_rmse"] == pytest.approx(evaluate(ref)["team"]["pos_rmse"], abs=1e-9)
    assert rep["estimators"]["rdl"]["stats"]["net_auth_key_mismatch"] == sum(
        expected[f"robot {r}"].get("key_mismatch", 0) for r in src.robots
    )
    assert not (tmp_path / "keys").joinpath("robot0.key").stat().st_mode & 0o077


def test_attacker_on_diekf_broadcasts_with_robot_2s_key_changes_nothing(tmp_path):
    """A diekf team of 3 and an attacker process holding robot 2's valid key, publishing on robot 1's broadcast key
    team updates in robot 1's name that would pull robot 1 by 100 m (signed with robot 2's key, with robot 1's key
    id, unsigned, from outside the roster, robot 2's own) and robot 1's genuine broadcasts again. Every robot that
    receives them (the teammates subscribe to every broadcast key) refuses and counts each by category; the
    beliefs equal the in-process run on the same events to 1e-9."""
    src = load_source("sim:random", robots=3, duration=20.0, seed=1)
    team = f"attackd{os.getpid()}"
    make_team_keys(tmp_path / "keys", src.robots, max_age=4.0)
    ep = f"tcp/127.0.0.1:{free_ports(1)[0]}"
    out = tmp_path / "attacker.json"
    args = ["--listen", ep, "--team", team, "--keys", str(tmp_path / "keys"), "--robots", "0,1,2", "--out", str(out)]
    with attacker_process(DIEKF_ATTACKER, args):
        tr = run_team(src=src, source="sim:random", robots=3, duration=20.0, seed=1, estimator="diekf", team=team,
                      speed=2.0, max_wall=120, connect_extra=[ep], keys_dir=tmp_path / "keys",
                      log_dir=tmp_path / "logs")  # fmt: skip
    sent = json.loads(out.read_text())["sent"]
    assert sent["replay"] > 0 and sent["key_mismatch"] == 8
    assert all(c == 0 for c in tr.exit_codes.values()), tr.exit_codes
    for r in src.robots:
        got = {k[len("auth_") :]: v for k, v in tr.reports[r].net.items() if k.startswith("auth_")}
        if r == 1:  # its own broadcasts and heads played back to it: refused as its own, not as replays
            own = {k: v for k, v in tr.reports[r].net_reasons.items() if "of robot 1 received by itself" in k}
            assert got == {k: v for k, v in sent.items() if k != "replay"} and 0 < sum(own.values()) <= sent["replay"]
            assert not tr.reports[r].net.get("repair_requests") and not tr.reports[r].net.get("broadcasts_given_up")
        else:
            assert got == sent, f"robot {r}"
    res = team_result(tr, src, "diekf")
    ref = reference(src, "diekf")
    assert res.stats["reports"] == 3 and res.stats["recorded_provisional_only"] == 0
    assert_tracks_equal(res, ref, 1e-9)
