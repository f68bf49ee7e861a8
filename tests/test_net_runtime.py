"""The network runtime keeps its promises: duplicates never crash a node nor fuse twice, every loop honours the run's
wall-time bound, a silent teammate is declared lost after a bound, a dead node is named in the report, nodes die
with their launcher, two teams of one name do not hear each other, and a lone node says so and fails.

Real Zenoh peers on 127.0.0.1 only (scouting off, explicit endpoints), every run bounded in time; waits poll with
a deadline, none sleeps.
"""

from __future__ import annotations

import os

from swarmloc.estimators import make_team, node_options
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.messages import BeliefQuery
from swarmloc.net.entry import make_node
from swarmloc.net.process import NetNode
from swarmloc.net.schema import encode
from swarmloc.runner import run

OUTCOMES = ("detections", "fused", "gated", "rejected", "unknown", "pending")


def leftovers(team: str) -> list[int]:
    """Pids of processes whose command line names ``team`` (none must be left after a run)."""
    out = []
    for d in os.scandir("/proc"):
        if not d.name.isdigit():
            continue
        try:
            with open(f"/proc/{d.name}/cmdline", "rb") as f:
                cmd = f.read().split(b"\0")
        except OSError:
            continue
        if team.encode() in cmd and b"swarmloc.cli" in cmd:
            out.append(int(d.name))
    return out


def reference_stats(src, est: str) -> dict:
    nodes = make_team(est, src.initial, **node_options(est, src.config, src.landmarks))
    return run(nodes, src.events, src.record_times(), truth=src.truth).stats


def test_duplicated_queries_and_replies_are_answered_once_and_never_crash_a_node():
    """``--faults dup=0.5``: every query, reply and push may arrive twice. Before, the second copy of a reply raised
    in Zenoh ("Dropped query") and the node died (rc 1, 74 of 76 detections unknown). Now every node ends rc 0
    and every detection ends as in the clean (in-process) run: nothing unknown, nothing fused twice."""
    src = load_source("sim:random", robots=3, duration=10.0, seed=0)
    team = f"dup{os.getpid()}"
    for est in ("expfusion", "rdl"):
        tr = run_team(src=src, source="sim:random", robots=3, duration=10.0, seed=0, estimator=est, team=team,
                      faults="dup=0.5", max_wall=120)  # fmt: skip
        assert not leftovers(team)
        assert tr.exit_codes == {f"robot{r}": 0 for r in src.robots}, tr.exit_codes
        res = team_result(tr, src, est)
        assert res.stats["reports"] == 3 and res.accounted()
        assert res.stats["net_duplicated"] > 20  # the duplicates did happen
        ref = reference_stats(src, est)
        assert {k: res.stats[k] for k in OUTCOMES} == {k: ref[k] for k in OUTCOMES}


class _Payload:
    def __init__(self, raw: bytes) -> None:
        self.raw = raw

    def to_bytes(self) -> bytes:
        return self.raw


class _DeadQuery:
    """A neighbour's Zenoh query whose asker is gone: every reply raises, as Zenoh's does on a closed query."""

    key_expr = "swarmloc/t/robot/0/query"

    def __init__(self, raw: bytes) -> None:
        self.payload = _Payload(raw)
        self.replies = self.drops = 0

    def reply(self, key, payload) -> None:
        self.replies += 1
        raise RuntimeError("Dropped query")

    def reply_err(self, reason: bytes) -> None:
        raise RuntimeError("Dropped query")

    def drop(self) -> None:
        self.drops += 1


def offline_net(robot: int = 0, **kw) -> NetNode:
    """Robot ``robot`` of a simulated team of 3 in a :class:`NetNode` that is never opened (nothing sent)."""
    src = load_source("sim:random", robots=3, duration=4.0, seed=0)
    node = make_node("expfusion", robot, src.initial[robot], src.config, src.landmarks)
    node.start(src.t_start)
    return NetNode(node, src.own_events(robot), session=None, team="t", roster=src.robots, **kw)


def test_a_query_that_arrives_twice_is_answered_once_and_a_failing_reply_is_counted_not_raised():
    """Two copies of one query (the same sender, sequence number and body): the node steps it once, the copy is
    closed unanswered; the reply failing (the asker gone) is counted ``send_failed`` and the query closed.
    Before, both copies were answered and the failing reply raised out of the node's loop."""
    net = offline_net(hold_timeout=0.0)  # answered at once, as things stand
    raw = encode("t", 1, 7, BeliefQuery(sender=1, receiver=0, stamp=net.items[0][0]))
    first, copy = _DeadQuery(raw), _DeadQuery(raw)
    net._handle("query", first)
    net._handle("query", copy)
    assert (first.replies, first.drops) == (1, 1) and (copy.replies, copy.drops) == (0, 1)
    assert net.counts["send_failed"] == 1 and net.counts["duplicate_queries"] == 1
    assert net.counts["queries_answered"] == 1 and not net._deferred
