"""What a process of a team is given to reach the others, declared once (:class:`TeamLink`): the robots' processes
(:class:`~swarmloc.net.process.NetNode`, :class:`~swarmloc.net.central.Forwarder`) and the belief server
(:class:`~swarmloc.net.server.ServerProcess`) each hold one. How such a process (and the launcher's collector) joins
its team on Zenoh and leaves it, in one order: :class:`Presence`."""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from swarmloc.net.auth import Auth, signs_as
from swarmloc.net.pairing import attach
from swarmloc.net.transport import alive_key, team_scope, undeclare_all

log = logging.getLogger(__name__)


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


class Presence:
    """A process's presence in its team on Zenoh ``session`` (keys under ``scope``; ``auth``: its per-pair sessions,
    None: an unauthenticated team). :meth:`join` answers the per-pair handshake (:mod:`.pairing`) before anything
    else is declared; what the process declares goes in :attr:`decl`; :meth:`announce` makes a session with every
    member up now (what comes is opened on Zenoh's threads, which never wait for a handshake), then declares its
    liveliness token, so that the team hears of it last; :meth:`leave` undeclares it all and closes the per-pair
    sessions (the Zenoh session itself is the caller's)."""

    def __init__(self, session: Any, scope: str, auth: Auth | None) -> None:
        self.session, self.scope, self.auth = session, scope, auth
        self.decl: list[Any] = []
        """What the process declared on its session, its liveliness token too (undeclared by :meth:`leave`)."""

    def join(self) -> None:
        """Answer the per-pair handshake, before anything else is declared."""
        attach(self.auth, self.session, self.scope, hello=False)

    def announce(self, member: int | str) -> None:
        """Sessions with every member up, then the liveliness token of ``member`` (a robot id, ``server``)."""
        attach(self.auth, self.session, self.scope, hello=True)
        self.decl.append(self.session.liveliness().declare_token(alive_key(self.scope, member)))

    def undeclare(self) -> None:
        """Undeclare what it declared; the per-pair sessions stay (until :meth:`leave`)."""
        undeclare_all(self.decl)
        self.decl.clear()

    def leave(self, last: Callable[[], Any] | None = None, who: str = "", counts: Counter[str] | None = None,
              prefix: str = "") -> None:  # fmt: skip
        """Leave the team: first ``last()`` sends the process's last messages (its report, ``who``'s; a failure,
        the session gone, is logged and passed over) and Zenoh is let flush them (0.2 s); then everything is
        undeclared, and the per-pair sessions closed, their counters first added to ``counts`` (each name after
        ``prefix``)."""
        if last is not None:
            try:
                last()
                time.sleep(0.2)
            except Exception as exc:  # noqa: BLE001 - the session may be gone (Ctrl-C)
                log.debug("%s: final report not sent: %s", who, exc)
        self.undeclare()
        if self.auth is not None and self.auth.sessions is not None:
            if counts is not None:
                counts.update({prefix + k: v for k, v in self.auth.session_counts().items()})
            self.auth.sessions.close()
