"""MACed frames: what a member sends to a member it has a per-pair session with (:mod:`swarmloc.net.pairing`).

**MACed frame** (big-endian; ``n`` = length of the schema envelope; a query, an answer, a push on an inbox)::

    offset  size  field
    0       4     magic  b"SLM1"  (swarmloc MACed, version 1)
    4       4     sender   int32 (as in a signed frame, :mod:`swarmloc.net.auth`)
    8       8     seq      uint64, the sender's sequence (the one its signed frames take their numbers from)
    16      8     stamp    int64, the sender's wall clock, ns since the Unix epoch
    24      8     session id
    32      n     the schema envelope
    32 + n  16    BLAKE2b-128 keyed with the session key, of  b"swarmloc-signed-v1\\0" + key expression + b"\\0" +
                  bytes 0 .. 32 + n

48 bytes of framing against the signed frame's 104, and a keyed hash (about a microsecond) against an Ed25519
signature and its verification (about 85 us). A receiver opens one only under a session it holds (``other_run``
otherwise: another run's, or another pair's), from that session's peer (``key_mismatch``: e.g. its own side's frame
played back to it), with a MAC that verifies (``bad_signature``), a stamp within the roster's ``max_age_s``
(``stale``, ``future``) and a sequence number not seen in that session (``replay``).
"""

from __future__ import annotations

import hashlib
import hmac
import struct
import threading
from collections.abc import Callable, Container
from dataclasses import dataclass, field

from swarmloc.net.auth import MAX_SIGNED, AuthRejected, ReplayWindow, check_stamp, member_name
from swarmloc.net.schema import SERVER
from swarmloc.net.transport import robot_of

MAC_MAGIC = b"SLM1"
MAC_HEADER = struct.Struct(">4siQq8s")  # magic, sender, seq, stamp [ns], session id
TAG_SIZE = 16


@dataclass
class Session:
    """A pair's session, on one side: the ``peer`` member, its process (``incarnation``), the session key and id,
    and the replay window of what the peer sent in it."""

    peer: int
    incarnation: bytes
    key: bytes = field(repr=False)
    sid: bytes
    window: ReplayWindow = field(repr=False)


def recipient(key_expr: str) -> int | None:
    """The member a frame on ``key_expr`` goes to: ``robot/<id>/inbox`` and ``robot/<id>/query`` robot ``id``,
    ``server/query`` the server; None for a publication (to many)."""
    parts = key_expr.split("/")
    if len(parts) >= 3 and parts[-1] in ("inbox", "query") and parts[-3] == "robot":
        return robot_of(key_expr)
    if parts[-2:] == ["server", "query"]:
        return SERVER
    return None


def tag(key: bytes, context: bytes, key_expr: str, frame: bytes | memoryview) -> bytes:
    """The MAC of ``frame`` sent on ``key_expr`` in ``context`` under session ``key``: keyed BLAKE2b, 16 bytes."""
    h = hashlib.blake2b(context, key=key, digest_size=TAG_SIZE)
    h.update(key_expr.encode())
    h.update(b"\0")
    h.update(frame)
    return h.digest()


def mac_frame(sender: int, seq: int, stamp: int, key: bytes, sid: bytes, context: bytes, key_expr: str,
              payload: bytes) -> bytes:  # fmt: skip
    """``payload`` in a MACed frame of ``sender`` (sequence number ``seq``, ``stamp`` [ns]) under session ``key``,
    ``sid``, for ``key_expr`` in signing ``context``."""
    frame = MAC_HEADER.pack(MAC_MAGIC, sender, seq, stamp, sid) + payload
    return frame + tag(key, context, key_expr, frame)


def mac_payload(data: bytes, key: bytes, sid: bytes, context: bytes, key_expr: str, sender: int) -> bytes | None:
    """The payload of ``data`` if it is a MACed frame of ``sender`` under session ``key``/``sid`` in ``context`` for
    ``key_expr``, else None (the handshake's confirms and acks: their session is not in use yet)."""
    if not MAC_HEADER.size + TAG_SIZE <= len(data) <= MAX_SIGNED or data[:4] != MAC_MAGIC:
        return None
    _, who, _, _, got = MAC_HEADER.unpack_from(data)
    frame = memoryview(data)[: len(data) - TAG_SIZE]
    if who != sender or got != sid or not hmac.compare_digest(tag(key, context, key_expr, frame), data[-TAG_SIZE:]):
        return None
    return bytes(frame[MAC_HEADER.size :])


def open_mac(
    key_expr: str,
    data: bytes,
    context: bytes,
    roster: Container[int],
    session_of: Callable[[bytes], Session | None],
    now_ns: int,
    max_age_ns: int,
    lock: threading.Condition | threading.Lock,
    publication: bool = False,
) -> tuple[int, bytes]:
    """``(sender, schema envelope)`` of a MACed frame received on ``key_expr`` (in ``context``), under the session
    ``session_of(session id)`` gives (``lock`` guards its replay window; ``now_ns`` the receiver's clock), or
    :class:`~swarmloc.net.auth.AuthRejected` (module docstring). ``publication``: only ``id`` may send on
    ``key_expr`` = ``robot/<id>/...``."""
    if len(data) > MAX_SIGNED:
        raise AuthRejected("oversize", f"{len(data)} bytes on {key_expr}")
    if len(data) < MAC_HEADER.size + TAG_SIZE or data[:4] != MAC_MAGIC:
        raise AuthRejected("unsigned", f"{len(data)} bytes on {key_expr}")
    _, sender, seq, stamp, sid = MAC_HEADER.unpack_from(data)
    who = f"claimed sender {member_name(sender)} on {key_expr}"
    if sender not in roster:
        raise AuthRejected("unknown_sender", who)
    s = session_of(sid)
    if s is None:
        raise AuthRejected("other_run", f"{who}: MACed under session {sid.hex()}, not one of this process")
    if s.peer != sender:
        raise AuthRejected("key_mismatch", f"{who}: MACed under the session with {member_name(s.peer)}")
    frame = memoryview(data)[: len(data) - TAG_SIZE]
    if not hmac.compare_digest(tag(s.key, context, key_expr, frame), data[-TAG_SIZE:]):
        raise AuthRejected("bad_signature", f"{who}: the MAC does not verify")
    check_stamp(now_ns - stamp, max_age_ns, who)
    if publication and robot_of(key_expr) != sender:
        raise AuthRejected("not_owner", who)
    with lock:
        if not s.window.fresh(seq):
            raise AuthRejected("replay", f"{who}: sequence number {seq}")
        s.window.accept(seq)
    return sender, bytes(frame[MAC_HEADER.size :])


def mac_vouches(key_expr: str, data: bytes, context: bytes, session_of: Callable[[bytes], Session | None]) -> bool:
    """Whether a MACed frame's MAC verifies under the session it names, with that session's peer as its sender: the
    intake's check of a frame over its sender's budget (:mod:`swarmloc.net.intake`). Stamp and replay window are
    the receiver's own thread's to check (:func:`open_mac`); nothing here changes any state."""
    if len(data) < MAC_HEADER.size:
        return False
    _, sender, _, _, sid = MAC_HEADER.unpack_from(data)
    s = session_of(sid)
    return s is not None and s.peer == sender and mac_payload(data, s.key, sid, context, key_expr, sender) is not None
