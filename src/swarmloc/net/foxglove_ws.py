"""The server side of the Foxglove WebSocket protocol, version 1, on the ``websockets`` library: the live view's
transport (:class:`~swarmloc.net.view.TeamView` decides what it carries).

Why not foxglove-sdk's server: its handshake accepts the subprotocol ``foxglove.sdk.v1`` only (a constant of the
SDK, no option changes it), so every client of the published ``@foxglove/ws-protocol`` library and the open-source
Lichtblick app, which offer ``foxglove.websocket.v1``, is refused with a bare "handshake failed". The two names
carry the same messages (the SDK's own protocol module is the ws-protocol specification's "v1"), so this server
accepts both and speaks the part of v1 a viewer needs:

* sent on connect: ``serverInfo`` (no optional capability; ``metadata`` as given) and ``advertise`` of every
  channel; later ``advertise`` for channels added while clients are connected;
* from clients: ``subscribe`` / ``unsubscribe``; each subscription gets the channel's **history** first (its
  last ``history`` messages, at most ``history_bytes`` of them, so that a client connecting after the team ended
  still sees the run), then every new message as a binary Message Data frame ``0x01 | uint32 subscription id |
  uint64 log time [ns] | payload``;
* anything else a client sends (other ops, client binary frames, malformed JSON, unknown channels, reused ids) is
  refused with a ``status`` message (level 1 warning or 2 error), counted in :attr:`FoxgloveServer.refused` by
  reason and logged once per reason; the connection stays up. A client frame is at most 64 KiB and a subscribe
  message at most :data:`MAX_SUBSCRIPTIONS` entries; a client's outgoing queue holds at most ``queue_bytes``
  bytes of data and status frames (those that do not fit are dropped and counted: a slow viewer, or one that sends
  without reading, never stalls the team nor grows the server's memory).

A client offering neither subprotocol gets HTTP 400 "invalid subprotocol; expected one of ..." (the names).
The server runs its own asyncio loop in a daemon thread; :meth:`FoxgloveServer.add_channel` and
:meth:`FoxgloveServer.publish` may be called from any thread.
"""

from __future__ import annotations

import asyncio
import json
import logging
import struct
import threading
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any, TypeGuard

__all__ = ["MAX_SUBSCRIPTIONS", "SUBPROTOCOLS", "Channel", "FoxgloveServer"]

log = logging.getLogger(__name__)

SUBPROTOCOLS = ("foxglove.websocket.v1", "foxglove.sdk.v1")
"""Accepted WebSocket subprotocols (the first one the client also offers is chosen, in this order)."""
MAX_SUBSCRIPTIONS = 4096
"""Most entries in one subscribe or unsubscribe message."""
MAX_CLIENT_FRAME = 64 * 1024
_UINT32 = 2**32
_DATA = struct.Struct("<BIQ")  # opcode 0x01, subscription id, log time [ns]


@dataclass(frozen=True)
class Channel:
    """One advertised channel: ``topic``, message ``encoding`` (``cdr``), ``schema_name`` (the message type),
    ``schema`` text in ``schema_encoding`` (``ros2msg``)."""

    id: int
    topic: str
    schema_name: str
    schema: str
    encoding: str = "cdr"
    schema_encoding: str = "ros2msg"

    def advertised(self) -> dict[str, Any]:
        return {"id": self.id, "topic": self.topic, "encoding": self.encoding, "schemaName": self.schema_name,
                "schema": self.schema, "schemaEncoding": self.schema_encoding}  # fmt: skip


@dataclass(eq=False)
class _Client:
    ws: Any
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    frames: deque[tuple[bytes, bool]] = field(default_factory=deque)  # (frame, is text)
    queued: int = 0  # bytes in ``frames``
    subs: dict[int, int] = field(default_factory=dict)  # subscription id -> channel id
    dropped: int = 0


class FoxgloveServer:
    """A Foxglove WebSocket (v1) server on ``host:port`` (0: a free port, then :attr:`port`) named ``name``.

    ``history``, ``history_bytes``: most messages and payload bytes kept per channel for clients that subscribe
    later; ``queue_bytes``: most bytes of frames waiting per client; ``metadata``: the ``serverInfo`` metadata
    (strings). Raises OSError when the address cannot be bound. :meth:`close` stops it."""

    def __init__(self, *, host: str = "127.0.0.1", port: int = 8765, name: str = "swarmloc",
                 history: int = 10_000, history_bytes: int = 16 * 2**20, queue_bytes: int = 64 * 2**20,
                 metadata: dict[str, str] | None = None) -> None:  # fmt: skip
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port < 65536:
            raise ValueError(f"port must be an integer in [0, 65535], got {port!r}")
        if not (history >= 0 and history_bytes >= 0 and queue_bytes >= 1):
            raise ValueError(f"history and history_bytes must be >= 0 and queue_bytes >= 1, got {history!r}, "
                             f"{history_bytes!r}, {queue_bytes!r}")  # fmt: skip
        self.name, self.history, self.queue_bytes = name, int(history), int(queue_bytes)
        self.history_bytes = int(history_bytes)
        self.metadata = dict(metadata or {})
        self.channels: dict[int, Channel] = {}
        self.subscriptions = 0
        """Subscriptions of all connected clients now."""
        self.refused: Counter[str] = Counter()
        """Client messages refused, by reason."""
        self.dropped = 0
        """Frames (data, status) not sent because a client's queue was full."""
        self._history: dict[int, deque[tuple[int, bytes]]] = {}
        self._kept: Counter[int] = Counter()  # payload bytes in each channel's history
        self._clients: set[_Client] = set()
        self._next_id = 1
        self._ids = threading.Lock()
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="foxglove-ws", daemon=True)
        self._thread.start()
        try:
            self._server = asyncio.run_coroutine_threadsafe(self._serve(host, port), self._loop).result(30)
        except BaseException:
            self._stop_loop()
            raise
        self.port: int = self._server.sockets[0].getsockname()[1]

    async def _serve(self, host: str, port: int) -> Any:
        from websockets.asyncio.server import serve

        return await serve(self._session, host, port, subprotocols=list(SUBPROTOCOLS),  # type: ignore[arg-type]
                           max_size=MAX_CLIENT_FRAME, compression=None)  # fmt: skip

    # ------------------------------------------------------------------------------------------ any thread
    def add_channel(self, topic: str, schema_name: str, schema: str, *, encoding: str = "cdr",
                    schema_encoding: str = "ros2msg") -> int:  # fmt: skip
        """Advertise a channel (to clients connected now and later); returns its id for :meth:`publish`."""
        with self._ids:
            ch = Channel(self._next_id, topic, schema_name, schema, encoding, schema_encoding)
            self._next_id += 1
        self._loop.call_soon_threadsafe(self._advertise, ch)
        return ch.id

    def publish(self, channel: int, log_time: int, payload: bytes) -> None:
        """Send ``payload`` on ``channel`` at ``log_time`` [ns since the Unix epoch] to every subscriber."""
        self._loop.call_soon_threadsafe(self._fanout, channel, int(log_time), bytes(payload))

    def close(self) -> None:
        """Close every connection (going away) and stop the server."""
        if self._loop.is_closed():
            return

        async def stop() -> None:
            self._server.close()
            await self._server.wait_closed()

        try:
            asyncio.run_coroutine_threadsafe(stop(), self._loop).result(10)
        finally:
            self._stop_loop()

    def _stop_loop(self) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        if not self._thread.is_alive():
            self._loop.close()

    # ------------------------------------------------------------------------------------------ loop thread
    def _advertise(self, ch: Channel) -> None:
        self.channels[ch.id] = ch
        self._history[ch.id] = deque()
        for c in self._clients:
            self._control(c, {"op": "advertise", "channels": [ch.advertised()]})

    def _fanout(self, channel: int, log_time: int, payload: bytes) -> None:
        history = self._history.get(channel)
        if history is None:  # not advertised (an id this server never gave)
            return
        history.append((log_time, payload))
        self._kept[channel] += len(payload)
        while history and (len(history) > self.history or self._kept[channel] > self.history_bytes):
            self._kept[channel] -= len(history.popleft()[1])
        for c in self._clients:
            for sub, ch in c.subs.items():
                if ch == channel:
                    self._data(c, sub, log_time, payload)

    def _control(self, c: _Client, msg: dict[str, Any], droppable: bool = False) -> None:
        """Queue a JSON message (server info and advertisements always, a status only while the queue has room)."""
        self._queue(c, json.dumps(msg).encode(), text=True, droppable=droppable)

    def _data(self, c: _Client, sub: int, log_time: int, payload: bytes) -> None:
        self._queue(c, _DATA.pack(1, sub, log_time) + payload, text=False, droppable=True)

    def _queue(self, c: _Client, frame: bytes, *, text: bool, droppable: bool) -> None:
        if droppable and c.queued + len(frame) > self.queue_bytes:
            c.dropped += 1
            self.dropped += 1
            if c.dropped == 1:
                log.warning("foxglove view: a client does not keep up, its queue is full: dropping frames")
            return
        c.frames.append((frame, text))
        c.queued += len(frame)
        c.wake.set()

    def _refuse(self, c: _Client, reason: str, detail: str = "", level: int = 1) -> None:
        self.refused[reason] += 1
        if self.refused[reason] == 1:
            log.warning("foxglove view: refused a client message: %s%s", reason, f" ({detail})" if detail else "")
        msg = {"op": "status", "level": level, "message": f"{reason}{': ' + detail if detail else ''}"}
        self._control(c, msg, droppable=True)

    async def _session(self, ws: Any) -> None:
        c = _Client(ws)
        self._clients.add(c)
        writer = asyncio.create_task(self._write(c))
        try:
            self._control(c, {"op": "serverInfo", "name": self.name, "capabilities": [], "metadata": self.metadata,
                              "sessionId": str(id(self))})  # fmt: skip
            if self.channels:
                self._control(c, {"op": "advertise", "channels": [ch.advertised() for ch in self.channels.values()]})
            async for raw in ws:
                self._on_message(c, raw)
        except Exception as exc:  # noqa: BLE001 - a broken connection ends this client only
            log.debug("foxglove view: client connection ended: %r", exc)
        finally:
            self._clients.discard(c)
            self.subscriptions -= len(c.subs)
            writer.cancel()

    async def _write(self, c: _Client) -> None:
        while True:
            await c.wake.wait()
            c.wake.clear()
            while c.frames:
                frame, text = c.frames.popleft()
                c.queued -= len(frame)
                await c.ws.send(frame.decode() if text else frame)

    def _on_message(self, c: _Client, raw: str | bytes) -> None:
        if isinstance(raw, bytes):
            return self._refuse(c, "binary client messages are not supported", "no clientPublish capability")
        try:
            msg = json.loads(raw)
        except ValueError as exc:
            return self._refuse(c, "malformed JSON", str(exc)[:80], level=2)
        op = msg.get("op") if isinstance(msg, dict) else None
        if op == "subscribe":
            return self._subscribe(c, msg.get("subscriptions"))
        if op == "unsubscribe":
            return self._unsubscribe(c, msg.get("subscriptionIds"))
        return self._refuse(c, "unsupported op", repr(op)[:40])

    def _entries(self, c: _Client, items: Any, what: str) -> list[Any] | None:
        if not isinstance(items, list) or len(items) > MAX_SUBSCRIPTIONS:
            self._refuse(c, f"{what} must be a list of at most {MAX_SUBSCRIPTIONS}", level=2)
            return None
        return items

    def _subscribe(self, c: _Client, items: Any) -> None:
        for s in self._entries(c, items, "subscriptions") or ():
            sub = s.get("id") if isinstance(s, dict) else None
            ch = s.get("channelId") if isinstance(s, dict) else None
            if not (_uint32(sub) and _uint32(ch)):
                self._refuse(c, "a subscription needs integer id and channelId", repr(s)[:60], level=2)
            elif ch not in self.channels:
                self._refuse(c, "unknown channel", str(ch))
            elif sub in c.subs:
                self._refuse(c, "subscription id in use", str(sub))
            elif ch in c.subs.values():
                self._refuse(c, "channel already subscribed", str(ch))
            else:
                c.subs[sub] = ch
                self.subscriptions += 1
                for t, payload in self._history[ch]:
                    self._data(c, sub, t, payload)

    def _unsubscribe(self, c: _Client, items: Any) -> None:
        for sub in self._entries(c, items, "subscriptionIds") or ():
            if _uint32(sub) and sub in c.subs:
                del c.subs[sub]
                self.subscriptions -= 1
            else:
                self._refuse(c, "unknown subscription id", repr(sub)[:20])


def _uint32(x: Any) -> TypeGuard[int]:
    return isinstance(x, int) and not isinstance(x, bool) and 0 <= x < _UINT32
