"""What a receiver has of one sender's numbered stream (0, 1, 2, ...), and which numbers to ask again.

One part for both numbered streams of the network: a robot's raw measurement forwards to the belief server
(:mod:`swarmloc.net.central`, delivered in number order) and a teammate's broadcasts
(:mod:`swarmloc.net.broadcast`, applied as they come). Each keeps its own messages, counters and give-up rule; the
numbers received, the ones missing since when, and the requests for them are kept here.
"""

from __future__ import annotations

from typing import Generic, TypeVar

T = TypeVar("T")


class Numbered(Generic[T]):
    """Numbers below ``low`` all received or given up, those above it received (``got``: number -> what it carried,
    held until every number before it is in; None: nothing to hand on), the highest number heard of (``top``), and
    per missing number since when it is missing (``missing_since``, wall time) and its requests (``asked``: number
    -> (requests sent, the last one's wall time))."""

    def __init__(self, low: int = 0) -> None:
        self.low = low
        self.got: dict[int, T | None] = {}
        self.top = low - 1
        self.missing_since: dict[int, float] = {}
        self.asked: dict[int, tuple[int, float]] = {}

    def has(self, n: int) -> bool:
        return n < self.low or n in self.got

    def heard_of(self, top: int, now: float) -> None:
        """Number ``top`` exists (wall time ``now``): those before it not received are missing from now on."""
        for n in range(max(self.top + 1, self.low), top + 1):
            if n not in self.got:
                self.missing_since.setdefault(n, now)
        self.top = max(self.top, top)

    def mark(self, n: int, item: T | None = None) -> list[T]:
        """Number ``n`` received (carrying ``item``) or given up (no item): the items now next in number order,
        lowest first."""
        self.got[n] = item
        self.missing_since.pop(n, None)
        self.asked.pop(n, None)
        out: list[T] = []
        while self.low in self.got:
            x = self.got.pop(self.low)
            self.low += 1
            if x is not None:
                out.append(x)
        return out

    def missing(self) -> list[int]:
        return [n for n in range(self.low, self.top + 1) if n not in self.got]

    def due(self, now: float, wait: float, retry: float, most: float = float("inf")) -> list[int]:
        """The missing numbers to ask for at wall time ``now``, lowest first (at most ``most``): missing ``wait`` s and
        not asked yet, or asked last ``retry`` s ago; each is counted one request more in ``asked``."""
        out: list[int] = []
        for n, since in self.missing_since.items():  # in number order: heard_of adds them so
            if len(out) >= most:
                break
            tries, last = self.asked.get(n, (0, since))
            if now - last >= (wait if tries == 0 else retry):
                self.asked[n] = (tries + 1, now)
                out.append(n)
        return out
