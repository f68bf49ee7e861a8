"""Which of a networked node's unanswered queries go to the belief server: belief queries only. The server stores
each robot's Gaussian, not the pairwise factors an ``RdlStateQuery`` asks for (it refuses one), so such a query is
answered "not found" at once, with the reason, instead of costing a round trip for a certain refusal.

The node's sending part (:class:`swarmloc.net.outbound.Outbound`) is driven with stand-ins for its Zenoh session,
its queue and its teammates' liveliness: nothing is opened."""

from __future__ import annotations

from collections import Counter
from types import SimpleNamespace
from typing import Any

import pytest

from swarmloc.messages import BeliefAnswer, BeliefQuery, RdlState, RdlStateQuery
from swarmloc.net.outbound import Outbound
from swarmloc.net.settings import NetSettings
from swarmloc.net.transport import robot_key, server_key

pytestmark = pytest.mark.unit

SCOPE = "swarmloc/t"


class Session:
    """Records every get the node sends."""

    def __init__(self) -> None:
        self.keys: list[str] = []

    def get(self, key: str, **_: Any) -> None:
        self.keys.append(key)


def outbound(*, use_server: bool, lost: set[int]) -> tuple[Outbound, Session, list[Any]]:
    session, stepped = Session(), []
    lockstep = SimpleNamespace(lost=lost, lost_why={r: "silent for 5 s" for r in lost}, alive={1, 2, 3} - lost)
    intake = SimpleNamespace(offer=lambda item: None, put=lambda item: None)
    node = SimpleNamespace(present=10.0, horizon=5.0)
    settings = NetSettings(use_server=use_server, answer_retries=0, lost_timeout=0.0)
    out = Outbound(node, 1, frozenset({1, 2, 3}), SCOPE, settings, Counter(),  # type: ignore[arg-type]
                   wiring=SimpleNamespace(session=session, block=None), seal=lambda m, key, to=None: b"",  # type: ignore[arg-type]
                   intake=intake, lockstep=lockstep, step=stepped.append, broadcast=lambda u: None)  # type: ignore[arg-type]  # fmt: skip
    return out, session, stepped


@pytest.mark.parametrize("use_server", [True, False])
def test_a_lost_robots_pair_state_is_not_asked_of_the_server(use_server: bool) -> None:
    out, session, stepped = outbound(use_server=use_server, lost={2})
    out.ask(RdlStateQuery(sender=1, receiver=2, stamp=9.0))
    assert session.keys == []
    [answer] = stepped
    assert isinstance(answer, RdlState) and not answer.found
    assert answer.reason.startswith("robot 2 is lost (silent for 5 s)")
    assert ("not asked of the belief server" in answer.reason) is use_server
    assert out.counts["asked_lost"] == 1


def test_a_lost_robots_belief_is_asked_of_the_server() -> None:
    out, session, stepped = outbound(use_server=True, lost={2})
    out.ask(BeliefQuery(sender=1, receiver=2, stamp=9.0))
    assert session.keys == [server_key(SCOPE)] and stepped == []


@pytest.mark.parametrize(("query", "answer", "asks_server"),
                         [(BeliefQuery, BeliefAnswer, True), (RdlStateQuery, RdlState, False)])  # fmt: skip
def test_an_unanswered_query_goes_to_the_server_only_if_it_can_answer(
    query: type, answer: type, asks_server: bool
) -> None:
    out, session, stepped = outbound(use_server=True, lost=set())
    out.ask(query(sender=1, receiver=2, stamp=9.0))
    assert session.keys == [robot_key(SCOPE, 2, "query")]
    [qid] = out.outstanding
    out.ended(qid)  # the robot's get ended with no reply
    assert out.counts["no_reply"] == 1
    if asks_server:
        assert session.keys[1:] == [server_key(SCOPE)] and stepped == []
    else:
        assert session.keys[1:] == []
        [a] = stepped
        assert isinstance(a, answer) and not a.found
        assert a.reason.startswith("no answer from the robot within")
        assert a.reason.endswith("not asked of the belief server, which does not answer RdlStateQuery")
