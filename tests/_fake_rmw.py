"""An in-process stand-in for :class:`swarmloc.rmw` middlewares: publishers hand messages to the subscriptions of
the same topic on the same bus, synchronously. For the ROS node's logic tests; the real middlewares are tested
against separate processes elsewhere."""

from __future__ import annotations

import threading
from collections import Counter, defaultdict
from typing import Any


class Bus:
    def __init__(self) -> None:
        self.subs: dict[str, list[Any]] = defaultdict(list)
        self.log: list[tuple[str, Any]] = []
        self.lock = threading.Lock()

    def middleware(self) -> FakeMiddleware:
        return FakeMiddleware(self)


class _Pub:
    def __init__(self, bus: Bus, topic: str) -> None:
        self.bus, self.topic = bus, topic

    def publish(self, msg: Any) -> None:
        with self.bus.lock:
            subs = list(self.bus.subs[self.topic])
            self.bus.log.append((self.topic, msg))
        for cb in subs:
            cb(msg, None)

    def close(self) -> None:
        pass


class _Sub:
    def __init__(self, bus: Bus, topic: str, cb: Any) -> None:
        self.bus, self.topic, self.cb = bus, topic, cb

    def close(self) -> None:
        with self.bus.lock:
            if self.cb in self.bus.subs[self.topic]:
                self.bus.subs[self.topic].remove(self.cb)


class FakeMiddleware:
    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self.reasons: Counter[str] = Counter()

    def publisher(self, topic: str, msgtype: str, qos: Any = None) -> _Pub:
        return _Pub(self.bus, topic)

    def subscription(self, topic: str, msgtype: str, callback: Any, qos: Any = None) -> _Sub:
        with self.bus.lock:
            self.bus.subs[topic].append(callback)
        return _Sub(self.bus, topic, callback)

    def close(self) -> None:
        pass
