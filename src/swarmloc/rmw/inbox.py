"""The receive path both middlewares share: a sample's size bounded before decoding, its CDR decoded, the
subscription's callback called, every outcome counted.

``counts``: ``received`` (every sample), ``delivered`` (callback returned), ``refused`` (with a reason in
``reasons``: ``too_large``, ``bad_cdr``, ``callback_error``, and a middleware's own, e.g. ``bad_attachment``). Each
reason is logged once (the first time), then only counted; nothing raised by a sample or a callback leaves here.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from swarmloc.net.feed import InputRefusals
from swarmloc.rmw.types import decode

log = logging.getLogger("swarmloc.rmw")

MAX_BYTES = 1 << 20
"""Default largest CDR sample accepted [bytes] (1 MiB)."""


@dataclass(frozen=True)
class Received:
    """What came with a sample: the ``publisher``'s 16-byte gid (the DDS writer GUID, or rmw_zenoh's attachment gid;
    zeros when unknown), its ``source_time_ns`` (ns since the Unix epoch, None when not sent) and its CDR ``size``
    [bytes]."""

    publisher: bytes
    source_time_ns: int | None
    size: int


Callback = Callable[[Any, Received], None]


class Refused(ValueError):
    """An input refused (a sample, a message, a value in it), with the ``reason`` it is counted under: the one
    refusal of the ROS node's conversions (:mod:`swarmloc.ros.convert`) and of the live inputs
    (:mod:`swarmloc.live.ros_input`, :mod:`swarmloc.live.zenoh_input`)."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


class Inbox:
    """Counts and the receive path of one middleware (thread-safe; callbacks run on the caller's thread)."""

    def __init__(self, max_bytes: int = MAX_BYTES) -> None:
        if isinstance(max_bytes, bool) or not isinstance(max_bytes, int) or not 8 <= max_bytes <= 1 << 31:
            raise ValueError(f"max_bytes must be an integer in 8..2**31, got {max_bytes!r}")
        self.max_bytes = max_bytes
        self.counts: Counter[str] = Counter()
        self.reasons: Counter[str] = Counter()
        self._lock = threading.Lock()
        self.refuse = InputRefusals("ROS sample", self.counts, self.reasons, log, lock=self._lock)
        """Count a refused sample: ``refuse(reason, detail)``; the first of each reason is logged."""

    def count(self, what: str) -> None:
        with self._lock:
            self.counts[what] += 1

    def deliver(self, topic: str, msgtype: str, raw: Any, info: Received, callback: Callback) -> bool:
        """Bound, decode and hand one sample to ``callback``; True if the callback returned."""
        self.count("received")
        if info.size > self.max_bytes:
            self.refuse("too_large", f"{topic}: {info.size} bytes > max_bytes {self.max_bytes}")
            return False
        try:
            msg = decode(raw, msgtype)
        except Exception as exc:  # noqa: BLE001 - any decoding failure is bad CDR, never a crash
            self.refuse("bad_cdr", f"{topic}: not a {msgtype}: {type(exc).__name__}: {exc}")
            return False
        try:
            callback(msg, info)
        except Exception as exc:  # noqa: BLE001 - a subscription outlives its callback's errors
            self.refuse("callback_error", f"{topic}: callback raised {type(exc).__name__}: {exc}")
            return False
        self.count("delivered")
        return True
