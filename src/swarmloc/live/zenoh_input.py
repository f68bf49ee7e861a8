"""``--source zenoh:``: a robot's inputs in swarmloc's own schema on Zenoh keys, for robots without ROS.

Keys (``<scope>`` the team's, :func:`~swarmloc.net.transport.team_scope`), payloads JSON objects::

    swarmloc/<scope>/input/<robot>/odom      {"t0": s, "t1": s, "v": m/s, "w": rad/s}
    swarmloc/<scope>/input/<robot>/det       {"t": s, "kind": "pose", "z": [...], "cov": [... n*n row-major],
                                              "target": id or null, "target_is_robot": true}
    swarmloc/<scope>/input/<robot>/progress  {"t": s} (every input stamped before t was sent) or
                                              {"end": true, "count": n} (over once the n inputs sent came; 5 s at most)

The fields are those of :class:`~swarmloc.events.Odometry` and :class:`~swarmloc.events.Detection` (``z`` of
``kind``'s length: pose 3, range_bearing 2, range 1, bearing 1, absolute 3; ``cov`` symmetric positive definite).
A payload over :data:`MAX_BYTES`, not JSON, with an unknown or missing field, a wrong length or a bad number is
refused, counted with its reason (:attr:`ZenohInput.reasons`) and logged once per reason; the node goes on.
:class:`InputPublisher` is the sending side.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from typing import Any

import msgspec
import numpy as np

from swarmloc.events import Detection, Event, Odometry
from swarmloc.net.feed import LiveFeed
from swarmloc.net.transport import PREFIX, block

log = logging.getLogger(__name__)

MAX_BYTES = 8192
"""Largest input payload accepted [bytes]."""
Z_SIZE = {"pose": 3, "range_bearing": 2, "range": 1, "bearing": 1, "absolute": 3}


class OdomIn(msgspec.Struct, forbid_unknown_fields=True):
    t0: float
    t1: float
    v: float
    w: float


class DetIn(msgspec.Struct, forbid_unknown_fields=True):
    t: float
    kind: str
    z: list[float]
    cov: list[float]
    target: int | None = None
    target_is_robot: bool = True


class ProgressIn(msgspec.Struct, forbid_unknown_fields=True, omit_defaults=True):
    t: float | None = None
    end: bool = False
    count: int | None = None


_TYPES = {"odom": OdomIn, "det": DetIn, "progress": ProgressIn}


def input_key(scope: str, robot: int | str, what: str) -> str:
    """``swarmloc/<scope>/input/<robot>/<what>`` (``what``: odom, det, progress; ``robot`` may be ``*``)."""
    return f"{PREFIX}/{scope}/input/{robot}/{what}"


def encode_event(e: Event) -> tuple[str, bytes]:
    """``(what, JSON payload)`` of an odometry or a detection."""
    if isinstance(e, Odometry):
        return "odom", msgspec.json.encode(OdomIn(float(e.t0), float(e.t1), float(e.v), float(e.w)))
    if isinstance(e, Detection):
        body = DetIn(float(e.t), e.kind, [float(v) for v in np.ravel(e.z)], [float(v) for v in np.ravel(e.cov)],
                     None if e.target is None else int(e.target), bool(e.target_is_robot))  # fmt: skip
        return "det", msgspec.json.encode(body)
    raise TypeError(f"only odometry and detections are inputs, got {type(e).__name__}")


class Refused(ValueError):
    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def decode_input(what: str, payload: bytes, robot: int) -> Event | ProgressIn:
    """The event (or progress) of one input payload of ``robot``; :class:`Refused` with the reason otherwise."""
    if what not in _TYPES:
        raise Refused("unknown_key", f"no input {what!r}")
    if len(payload) > MAX_BYTES:
        raise Refused("too_large", f"{len(payload)} bytes > {MAX_BYTES}")
    try:
        m = msgspec.json.decode(payload, type=_TYPES[what])
    except msgspec.DecodeError as exc:
        raise Refused("bad_schema", str(exc)) from None
    if isinstance(m, OdomIn):
        return Odometry(robot, m.t0, m.t1, m.v, m.w)  # the feed checks the numbers and the order
    if isinstance(m, ProgressIn):
        return m
    n = Z_SIZE.get(m.kind)
    if n is None:
        raise Refused("bad_kind", f"kind {m.kind!r} not one of {sorted(Z_SIZE)}")
    if len(m.z) != n or len(m.cov) != n * n:
        raise Refused("bad_size", f"{m.kind}: z needs {n} numbers and cov {n * n}, got {len(m.z)} and {len(m.cov)}")
    cov = np.asarray(m.cov, dtype=float).reshape(n, n)
    if not (np.all(np.isfinite(cov)) and np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)):
        raise Refused("bad_covariance", "cov is not symmetric positive definite")
    if m.kind != "absolute" and m.target is None and not m.target_is_robot:
        raise Refused("bad_target", "a landmark detection needs the landmark's id")
    return Detection(robot, m.t, m.kind, np.asarray(m.z, dtype=float), cov, m.target, m.target_is_robot)  # type: ignore[arg-type]


class ZenohInput:
    """Subscribe to robot ``feed.robot``'s input keys under ``scope`` on ``session`` and push them to ``feed``."""

    def __init__(self, session: Any, feed: LiveFeed, scope: str) -> None:
        self.session, self.feed, self.scope, self.robot = session, feed, scope, feed.robot
        self.counts: Counter[str] = Counter()
        self.reasons: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._sub: Any = None

    def open(self) -> None:
        self._sub = self.session.declare_subscriber(input_key(self.scope, self.robot, "*"), handler=self._on)

    def close(self) -> None:
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None

    def _on(self, sample: Any) -> None:
        what = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            self.counts["received"] += 1
            try:
                x = decode_input(what, sample.payload.to_bytes(), self.robot)
                if isinstance(x, ProgressIn):
                    self.feed.end(x.count) if x.end else self.feed.advance(x.t if x.t is not None else float("nan"))
                    ok = True
                else:
                    ok = self.feed.push(x)
                self.counts["pushed" if ok else "refused_by_feed"] += 1
            except Refused as exc:
                self._bad(exc.reason, f"{what}: {exc}", what)
            except Exception as exc:  # noqa: BLE001 - a live node never dies of one message
                self._bad("internal_error", f"{what}: {type(exc).__name__}: {exc}", what)

    def _bad(self, reason: str, detail: str, what: str) -> None:
        if what in ("odom", "det"):
            self.feed.dropped()  # it counts towards the end's count
        self.counts["rejected"] += 1
        self.reasons[reason] += 1
        if self.reasons[reason] == 1:
            log.warning("robot %s: input refused (%s): %s (further ones counted)", self.robot, reason, detail[:200])


def wait_matched_all(pubs: Any, timeout: float) -> bool:
    """Wait (up to ``timeout`` s) until every Zenoh publisher of ``pubs`` has a matching subscriber."""
    import time

    end = time.monotonic() + timeout
    while not all(p.matching_status.matching for p in pubs):
        if time.monotonic() > end:
            return False
        time.sleep(0.01)
    return True


class InputPublisher:
    """Publish robot ``robot``'s inputs for a :class:`ZenohInput` of team scope ``scope``."""

    def __init__(self, session: Any, scope: str, robot: int) -> None:
        self.robot = int(robot)
        self._pubs = {w: session.declare_publisher(input_key(scope, self.robot, w), congestion_control=block())
                      for w in _TYPES}  # fmt: skip
        self.sent = 0

    def wait_matched(self, timeout: float = 10.0) -> bool:
        """Wait (up to ``timeout`` s) until a subscriber matches each of its keys (what is put before is lost)."""
        return wait_matched_all(self._pubs.values(), timeout)

    def push(self, e: Event) -> None:
        what, payload = encode_event(e)
        self._pubs[what].put(payload)
        self.sent += 1

    def progress(self, t: float) -> None:
        self._pubs["progress"].put(msgspec.json.encode(ProgressIn(t=float(t))))

    def end(self) -> None:
        """The stream is over, after the ``sent`` inputs (which may still be on their way: other keys)."""
        self._pubs["progress"].put(msgspec.json.encode(ProgressIn(end=True, count=self.sent)))

    def close(self) -> None:
        for p in self._pubs.values():
            p.undeclare()
