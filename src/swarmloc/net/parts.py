"""What the mixin parts of :class:`~swarmloc.net.process.NetNode` share, declared once for the type checker.

The node is composed of parts. Three own their state and take what they need of the node explicitly, as
constructor arguments (collaborators and callbacks), held by the node as attributes: :class:`~.wiring.Wiring`
(``node.wiring``: the Zenoh declarations, publishing on its own keys), :class:`~.publishing.Publishing`
(``node.publishing``: beliefs, delayed output, scans' lines, settled beliefs) and :class:`~.publishing.Announcer`
(``node.announcer``: progress); its settings are one object, :class:`~.settings.NetSettings` (``node.settings``).
The others (:mod:`.inbound`, :mod:`.lockstep`, :mod:`.outbound`, :mod:`.broadcast`) are still classes that
:class:`~swarmloc.net.process.NetNode` inherits: each reads state that the node or another part sets, and calls
other parts' methods. :class:`NodeParts`, the base of each of these, declares those attributes and methods
(annotations only: at run time it is an empty class), so that a type checker sees each use and checks it against
the one definition.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import threading
    from collections import Counter
    from collections.abc import Callable
    from typing import Any

    from swarmloc.messages import Message, TeamUpdate
    from swarmloc.net.auth import Auth
    from swarmloc.net.faults import Faults, LinkFaults
    from swarmloc.net.feed import LiveFeed
    from swarmloc.net.intake import Intake
    from swarmloc.net.publishing import Announcer, Publishing
    from swarmloc.net.schema import Broadcast, BroadcastRepair, Envelope, Rejected
    from swarmloc.net.settings import NetSettings
    from swarmloc.net.wiring import Wiring
    from swarmloc.node import Node


class NodeParts:
    """The base of each part of :class:`~swarmloc.net.process.NetNode`: the state and methods the parts share
    (declarations only; see the module docstring)."""

    if TYPE_CHECKING:
        # set by NetNode.__init__ (documented there)
        node: Node
        robot: int
        session: Any
        team: str
        scope: str
        roster: frozenset[int]
        auth: Auth | None
        settings: NetSettings
        faults: Faults | None
        link: LinkFaults | None
        counts: Counter[str]
        reasons: Counter[str]
        _intake: Intake
        _inq: Intake
        _stop: threading.Event
        _i: int
        feed: LiveFeed | None
        publishing: Publishing
        wiring: Wiring
        announcer: Announcer
        items: list[tuple[float, Any]]
        _feed_w: float
        broadcasts: bool
        # the lockstep's
        _alive: set[int]
        _lost: set[int]
        _lost_why: dict[int, str]
        _deferred: list[tuple[float, Message, Any]]
        _expect: dict[tuple[Any, ...], float]
        _held: list[Message]
        # the outbound's
        coalesce: float
        _outstanding: dict[int, tuple[Message, str, bool]]
        _gets: dict[int, int]
        _again: dict[int, tuple[int, float]]

        # inbound
        def _step(self, item: Any, query: Any = ...) -> None: ...
        def _reject(self, reason: str, where: str) -> None: ...
        def _refuse(self, exc: Rejected, where: str) -> None: ...

        # lockstep
        def _release(self) -> None: ...
        def _answer_ready(self) -> None: ...
        def _first_copy(self, env: Envelope) -> bool: ...
        def _on_alive(self, x: Any) -> None: ...
        def _on_progress(self, x: Any) -> None: ...
        def _unsettled(self, qkey: tuple[Any, ...]) -> str | None: ...

        # outbound
        def _env(self, body: Any, key: str, to: int | None = ...) -> bytes: ...
        def _faulty(self, send: Callable[[], None], finish: Callable[[], None] | None = ...) -> int: ...
        def _ask(self, m: Message, via_server: bool = ..., again: int = ..., first: float | None = ...) -> None: ...
        def _ask_again(self, m: Message, again: int, first: float) -> bool: ...
        def _feed_local(self, kind: type, m: Message, reason: str, seq: int = ...) -> None: ...
        def _flush(self, force: bool = ...) -> None: ...
        def _route(self, msgs: list[Message], query: Any = ..., asked: Message | None = ...) -> None: ...
        def _send_failed(self, exc: Exception) -> None: ...

        # the node's
        def _next_key(self) -> tuple[float, int]: ...

        # broadcast
        def _queue_broadcast(self, m: TeamUpdate) -> None: ...
        def _flush_broadcasts(self, force: bool = ...) -> None: ...
        def _broadcasts_unsettled(self, key: tuple[Any, ...]) -> str | None: ...
        def _on_broadcast(self, b: Broadcast) -> None: ...
        def _on_broadcast_sample(self, x: Any) -> None: ...
        def _on_repair(self, r: BroadcastRepair) -> None: ...
        def _revision_came(self, a: Any) -> None: ...
