"""What a receiver takes in from Zenoh: one queue, with budgets per sender, so that its memory stays bounded
whatever arrives.

Zenoh hands a node (the belief server, the collector of ``swarmloc team``) every sample on its own threads; the
receiver handles them on one thread of its own. Before, everything waited on an unbounded queue: a peer without
any key sending frames just under the signature's size bound (1 MiB) faster than they were verified grew a node to
3.1 GB in 25 s. An :class:`Intake` is that queue with a budget, checked on Zenoh's thread before anything is
queued, in this order (every frame dropped is counted by reason and by sender: :meth:`Intake.fold`):

1. **size**: a frame larger than ``max_frame`` (a node: 64 KiB; what a node receives is a few hundred bytes,
   a team broadcast about one KiB) is dropped before its bytes are copied (``oversize``);
2. **rate, per sender**: each sender has a token bucket of frames and bytes per second (``frames_per_s``,
   ``bytes_per_s``: 400 and 512 KiB for a node, ``burst_s`` = 2 s of them banked; the busiest sender measured, a
   teammate of a 5-robot ``diekf`` team at full speed on the 2-core test machine, sent about 100 frames and 34 KB
   a second). The sender of a frame is only a *claim* until its signature is verified (the signed frame's sender
   field; for an unsigned team, the key's robot for a publication, else ``anyone``), and Zenoh vouches for no
   transport source either (a sample's source info and a session's id are set by the sender). So a frame over its
   claimed sender's budget is **verified here**, on the Zenoh thread of the link it came on, before it is queued: a
   genuine one is queued (``vouched``: a busy genuine sender loses nothing, it costs a second verification), a
   forgery dropped (``unvouched``). A flood in a teammate's name therefore never crowds out that teammate's genuine
   frames: it costs one verification a frame, on the flooding link's thread (which slows that link), and the
   receiver's own thread handles at most the budget's worth of it. Frames claiming no roster member (``unsigned``,
   ``unknown``: never genuine in a signed team) share a twentieth of a member's budget; past it they are checked
   alike (refused before any signature is computed: no magic, or a sender outside the roster). Without keys (an
   unsigned team) nothing can be verified: past its budget a frame is dropped (``rate``), as are liveliness changes
   past theirs (each robot's tokens have a budget of their own).
3. **memory**: a sender's frames queued at once hold at most ``sender_bytes`` (8 MiB), all senders'
   ``queue_bytes`` (``backlog``, ``queue_full``); each frame is charged its size plus ``ITEM_OVERHEAD`` for the
   objects around it.

**The bound.** What waits in a node's queue holds at most ``queue_bytes`` (32 MiB), whatever arrives; Zenoh's own
reassembly of one message is bounded by :data:`~swarmloc.net.transport.MAX_MESSAGE` (2 MiB). The rest of a node's
memory is its own state (a horizon of history; every number from a message bounded against it before it drives a
loop or an allocation), so a node's resident memory stays within its size without a flood plus the queue's 32 MiB
and Zenoh's buffers (measured under a flood of 1 MiB and small frames, 20 s: +26 to +30 MiB over 132 MiB;
``tests/test_net_flood.py`` allows +64 MiB).

What the receiver itself puts on the queue (timers' wake-ups, the end of its own queries) is never dropped.
"""

from __future__ import annotations

import queue
import struct
import threading
import time
from collections import Counter
from collections.abc import Callable, Container
from dataclasses import dataclass
from typing import Any

from swarmloc.net.auth import MAGIC, MAGIC_V1, NAMES, Verifier
from swarmloc.net.macframe import MAC_MAGIC
from swarmloc.net.schema import Rejected
from swarmloc.net.transport import close_query, robot_of

KIB, MIB = 1024, 1024 * 1024
MAX_FRAME = 64 * KIB
"""[bytes] the largest frame a node takes in."""
QUEUE_BYTES = 32 * MIB
"""[bytes] a node's queue holds at most this much (frames plus :data:`ITEM_OVERHEAD` each)."""
ITEM_OVERHEAD = 1024
"""[bytes] charged per queued frame on top of its size (the Zenoh sample and the queue's own objects)."""
STRANGERS = 0.05
"""Budget of the frames that claim no roster member, as a share of a member's."""
REASONS = {
    "oversize": "frame larger than the receiver takes",
    "rate": "over its sender's rate budget",
    "unvouched": "over its claimed sender's rate budget, and not signed by it",
    "backlog": "its sender's share of the queue is full",
    "queue_full": "the receiver's queue is full",
}
"""Why a frame was dropped at the intake -> the reason counted (``intake: <reason>``)."""
_CLAIM = struct.Struct(">4si")  # a signed frame's magic and claimed sender (swarmloc.net.auth's frame header)


@dataclass(frozen=True)
class Budget:
    """One receiver's limits: ``max_frame``, ``queue_bytes``, ``sender_bytes`` [bytes]; per sender
    ``frames_per_s`` [1/s] and ``bytes_per_s`` [bytes/s], with ``burst_s`` [s] of them banked."""

    max_frame: int = MAX_FRAME
    queue_bytes: int = QUEUE_BYTES
    sender_bytes: int = 8 * MIB
    frames_per_s: float = 400.0
    bytes_per_s: float = 512.0 * KIB
    burst_s: float = 2.0

    def __post_init__(self) -> None:
        for name in ("max_frame", "queue_bytes", "sender_bytes", "frames_per_s", "bytes_per_s", "burst_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"Budget: {name} must be > 0, got {getattr(self, name)!r}")


SERVER_BUDGET = Budget(max_frame=512 * KIB, queue_bytes=64 * MIB, sender_bytes=16 * MIB, bytes_per_s=4.0 * MIB)
"""The belief server's: a raw forward (a hosted estimator's) carries up to 512 measurements, about 200 KiB."""
COLLECTOR_BUDGET = Budget(max_frame=1 * MIB, queue_bytes=64 * MIB, sender_bytes=16 * MIB, bytes_per_s=4.0 * MIB)
"""The collector's: a node's report under a flood of distinct refusals is tens of KiB."""


class TokenBucket:
    """``rate`` tokens per second, at most ``cap`` banked (full at the start)."""

    __slots__ = ("cap", "level", "rate", "t")

    def __init__(self, rate: float, cap: float, now: float) -> None:
        self.rate, self.cap, self.level, self.t = rate, cap, cap, now

    def refill(self, now: float) -> float:
        """The tokens banked at ``now``."""
        self.level = min(self.cap, self.level + max(now - self.t, 0.0) * self.rate)
        self.t = now
        return self.level

    def take(self, n: float, now: float) -> bool:
        """Take ``n`` tokens if there are; whether it did."""
        if self.refill(now) < n:
            return False
        self.level -= n
        return True


def claimed_sender(data: bytes, signed: bool) -> int | str:
    """Whom a frame claims to come from: the sender field of a signed frame, else ``"unsigned"`` (``"anyone"`` in an
    unsigned team)."""
    if len(data) >= _CLAIM.size:
        magic, sender = _CLAIM.unpack_from(data)
        if magic in (MAGIC, MAGIC_V1, MAC_MAGIC):  # every frame layout has the sender at offset 4
            return sender
    return "unsigned" if signed else "anyone"


def vouch_for(auth: Any) -> Callable[[str, bytes], bool]:
    """A check that a frame verifies under the roster key of the member it claims: a :class:`Verifier` per Zenoh
    thread (no lock between links; the receiver's own verifier and its replay windows stay its thread's alone)."""
    local = threading.local()

    def vouch(key: str, data: bytes) -> bool:
        if data[:4] == MAC_MAGIC:  # a MACed frame: under one of this process's per-pair sessions
            return auth.sessions is not None and auth.sessions.vouches(key, data)
        verifier = getattr(local, "verifier", None)
        if verifier is None:
            verifier = local.verifier = Verifier(auth.roster, context=auth.verifier.context)
        try:
            verifier.open(key, data)
        except Rejected:
            return False
        return True

    return vouch


def who(claim: int | str) -> str:
    """A claimed sender as counted: ``robot3``, ``server``, ``collector``, ``unknown``, ``unsigned``, ``anyone``."""
    return claim if isinstance(claim, str) else NAMES.get(claim, f"robot{claim}")


class Intake:
    """A receiver's queue (``get``, ``get_nowait``, ``put`` as :class:`queue.SimpleQueue`) with the budgets of the
    module docstring on what Zenoh hands it (:meth:`offer`). ``members``: the roster's ids (robots, and -1 the
    belief server where it may send); ``signed``: frames are signed (a team with keys); ``vouch``: the check of a
    frame over its sender's budget (:func:`vouch_for`; None: dropped)."""

    def __init__(
        self,
        members: Container[int],
        budget: Budget = Budget(),
        *,
        signed: bool = False,
        vouch: Callable[[str, bytes], bool] | None = None,
        team_size: int = 1,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.members, self.budget, self.signed, self.vouch, self.clock = members, budget, signed, vouch, clock
        self.team_size = max(1, team_size)  # an unsigned team's inbox traffic shares one claim: "anyone"
        # what waits, as (item, claim, bytes charged): a SimpleQueue, whose put is reentrant (the receiver's own put
        # may come from a signal handler: ``stop``); the budgets' state under a lock of its own (Zenoh's threads)
        self._items: queue.SimpleQueue[tuple[Any, Any, int]] = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._queued = 0  # bytes charged for what waits
        self._by: Counter[Any] = Counter()  # ... per claim
        self._buckets: dict[Any, tuple[TokenBucket, TokenBucket]] = {}
        self._drops: Counter[tuple[str, str]] = Counter()  # (reason, who) not folded yet
        self.vouched = 0
        self.peak = 0
        """[bytes] the most the queue ever held (charged)."""

    # ------------------------------------------------------------------------------------------------ Zenoh's side
    def put(self, item: Any) -> None:
        """The receiver's own item (a wake-up, the end of one of its queries): queued, never dropped."""
        self._items.put((item, None, 0))

    def offer(self, item: tuple) -> bool:
        """A sample Zenoh handed over, as ``(kind, sample)`` or ``("reply", qid, reply)``: queued within the
        budgets, or dropped and counted (a dropped query is closed); whether it was queued."""
        x = item[2] if item[0] == "reply" else item[1]
        s = (x.ok if x.ok is not None else x.err) if item[0] == "reply" else x
        key = str(getattr(s, "key_expr", "") or getattr(x, "key_expr", ""))
        payload = getattr(s, "payload", None)
        size = 0 if payload is None else len(payload)
        data = b""
        if item[0] == "alive":  # a liveliness token: no payload, nothing to verify (past its budget: dropped)
            claim: Any = robot_of(key)
            claim = f"alive_robot{claim}" if claim in self.members else "unknown"  # a budget of its own
        elif size > self.budget.max_frame:  # dropped before its bytes are copied: its claim is not read
            return self._drop("oversize", "unread", x, item[0])
        else:
            data = b"" if payload is None else payload.to_bytes()
            claim = claimed_sender(data, self.signed)
            if claim == "anyone" and item[0] in ("progress", "broadcast", "belief", "lines", "raw", "delayed"):
                claim = robot_of(key)  # an unsigned team's publication: the key's robot
                claim = claim if claim in self.members else "unknown"
            elif isinstance(claim, int) and claim not in self.members:
                claim = "unknown"
        charge = size + ITEM_OVERHEAD
        with self._lock:
            if self._within(claim, size):
                return self._queue(item, claim, charge, x)
        if self.vouch is None or item[0] == "alive":
            return self._drop("rate", who(claim), x, item[0])
        if not self.vouch(key, data):  # on this link's thread, outside the queue's lock
            return self._drop("unvouched", who(claim), x, item[0])
        with self._lock:
            self.vouched += 1
            return self._queue(item, claim, charge, x)

    def _within(self, claim: Any, size: int) -> bool:
        """Take one frame of ``size`` bytes from ``claim``'s rate budget (its buckets made on its first frame);
        whether there was room (nothing is taken otherwise). Called holding the lock."""
        now = self.clock()
        buckets = self._buckets.get(claim)
        if buckets is None:
            b = self.budget
            share = STRANGERS if claim in ("unsigned", "unknown") else self.team_size if claim == "anyone" else 1.0
            f, n = b.frames_per_s * share, b.bytes_per_s * share
            buckets = self._buckets[claim] = (TokenBucket(f, f * b.burst_s, now), TokenBucket(n, n * b.burst_s, now))
        frames, nbytes = buckets
        if frames.refill(now) < 1 or nbytes.refill(now) < size:
            return False
        return frames.take(1, now) and nbytes.take(size, now)

    def _queue(self, item: Any, claim: Any, charge: int, x: Any) -> bool:
        """Append within the memory bounds (called holding the lock)."""
        b = self.budget
        why = "queue_full" if self._queued + charge > b.queue_bytes else None
        if why is None and self._by[claim] + charge > b.sender_bytes:
            why = "backlog"
        if why is not None:
            self._drops[(why, who(claim))] += 1
            _close(x, item[0])
            return False
        self._queued += charge
        self._by[claim] += charge
        self.peak = max(self.peak, self._queued)
        self._items.put((item, claim, charge))
        return True

    def _drop(self, why: str, sender: str, x: Any, kind: str) -> bool:
        with self._lock:
            self._drops[(why, sender)] += 1
        _close(x, kind)
        return False

    # ------------------------------------------------------------------------------------------------ the receiver's
    def get(self, timeout: float | None = None) -> Any:
        """The next item, waiting up to ``timeout`` s (None: for ever); :class:`queue.Empty` if none came."""
        item, claim, charge = self._items.get(timeout=timeout) if timeout != 0 else self._items.get_nowait()
        if charge:
            with self._lock:
                self._queued -= charge
                self._by[claim] -= charge
                if not self._by[claim]:
                    del self._by[claim]
        return item

    def get_nowait(self) -> Any:
        return self.get(timeout=0)

    def empty(self) -> bool:
        return self._items.empty()

    @property
    def queued(self) -> int:
        """[bytes] charged for what waits now."""
        return self._queued

    def fold(self, counts: Counter[str], reasons: Counter[str] | None = None, prefix: str = "") -> int:
        """Move the drops counted since the last fold into the receiver's counters (on its thread): ``rejected``,
        ``intake_<reason>`` and ``intake_<reason>_<sender>`` in ``counts`` (each name after ``prefix``),
        ``intake: <meaning>`` in ``reasons``; and ``intake_vouched``, ``intake_peak_bytes``. Returns how many drops
        it moved."""
        with self._lock:
            drops, self._drops = self._drops, Counter()
            vouched, self.vouched = self.vouched, 0
            peak = self.peak
        for (why, sender), n in drops.items():
            counts[f"{prefix}rejected"] += n
            counts[f"{prefix}intake_{why}"] += n
            counts[f"{prefix}intake_{why}_{sender}"] += n
            if reasons is not None:
                reasons[f"intake: {REASONS[why]}"] += n
        if vouched:
            counts[f"{prefix}intake_vouched"] += vouched
        if peak > counts[f"{prefix}intake_peak_bytes"]:
            counts[f"{prefix}intake_peak_bytes"] = peak
        return sum(drops.values())


def _close(x: Any, kind: str) -> None:
    """Close a dropped query at once (its asker's get ends), as a refused one is."""
    if kind == "query":
        close_query(x)
