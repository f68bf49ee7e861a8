"""What a process of a team is given to reach the others, declared once (:class:`TeamLink`): the robots' processes
(:class:`~swarmloc.net.process.NetNode`, :class:`~swarmloc.net.central.Forwarder`) and the belief server
(:class:`~swarmloc.net.server.ServerProcess`) each hold one."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from swarmloc.net.auth import Auth, signs_as
from swarmloc.net.transport import team_scope


@dataclass(frozen=True, init=False)
class TeamLink:
    """A process's way to its team: its Zenoh ``session``; the team's name ``team`` and the run's id ``run_id``
    (None: the name alone), together the ``scope`` of its key expressions (:func:`~swarmloc.net.transport.team_scope`,
    ValueError if either is malformed); the team's robot ids ``roster`` (anybody else's messages are dropped); and
    ``auth``, the process's key and the team's roster (:class:`~swarmloc.net.auth.Auth`; None: an unauthenticated
    team, for tests on one machine or a trusted network)."""

    session: Any
    team: str
    roster: frozenset[int]
    auth: Auth | None
    run_id: str | None
    scope: str = field(compare=False)

    def __init__(
        self, session: Any, team: str, roster: Iterable[int], auth: Auth | None = None, run_id: str | None = None
    ) -> None:
        put = object.__setattr__  # frozen: set once, here
        put(self, "session", session)
        put(self, "team", team)
        put(self, "roster", frozenset(int(r) for r in roster))
        put(self, "auth", auth)
        put(self, "run_id", run_id)
        put(self, "scope", team_scope(team, run_id))

    def signing_as(self, member: int, who: str) -> TeamLink:
        """This link, once its ``auth`` is found to hold ``member``'s own key, the one ``who`` signs with
        (:func:`~swarmloc.net.auth.signs_as`: ValueError otherwise)."""
        signs_as(self.auth, member, who)
        return self
