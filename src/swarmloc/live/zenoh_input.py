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

**Signed inputs.** These keys are on the team's network, where anybody who reaches it could write a robot's
inputs (one unsigned end of stream, and the robot reads none of its odometry). In a team with a roster, every
payload is a signed frame of the robot itself (:mod:`swarmloc.net.auth`: :class:`InputPublisher` with the robot's
``auth`` seals it, :class:`ZenohInput` with the ``roster`` opens it before decoding), signed in the inputs' own
context :data:`~swarmloc.net.auth.INPUT_CONTEXT` on the input's key: a frame not signed with *that robot's* key is
refused (``auth_unsigned``, ``auth_key_mismatch``, ``auth_bad_signature``...; robot 2's key on robot 1's inputs:
``auth_not_owner``), as are a replay (``auth_replay``) and a stamp older or further ahead than the roster's
``max_age_s`` (``auth_stale``, ``auth_future``). A frame refused by its signature never counts towards the end's
count: a stranger cannot end the stream, nor race the robot's odometry into ``overlap`` refusals.

*Replay state.* The robot's driver (which publishes its inputs) and its node (which signs the team's frames) both
hold the robot's key, each in its own process with its own sequence numbers. They never meet in one replay window:
the inputs are signed with a :class:`~swarmloc.net.auth.Signer` of their own
(:meth:`~swarmloc.net.auth.Signer.for_context`), and the :class:`ZenohInput` opens them with a
:class:`~swarmloc.net.auth.Verifier` of its own, not the node's; the contexts differ, so neither verifier accepts
the other's frames. One input publisher per robot: its sequence numbers are the input verifier's window for it.
Without a roster (``--no-auth``: a trusted network) plain JSON is accepted, as before.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from typing import Any

import msgspec
import numpy as np

from swarmloc.events import Detection, Event, Kind, Odometry
from swarmloc.net.auth import (
    HEADER,
    INPUT_CONTEXT,
    SIG_SIZE,
    Auth,
    AuthRejected,
    Roster,
    Verifier,
    note_refusal,
    signs_as,
)
from swarmloc.net.feed import InputRefusals, LiveFeed
from swarmloc.net.transport import PREFIX, block
from swarmloc.rmw.inbox import Refused
from swarmloc.sensors.models import SIZES

log = logging.getLogger(__name__)

MAX_BYTES = 8192
"""Largest input payload accepted [bytes]."""


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
    n = SIZES.get(m.kind)
    if n is None:
        raise Refused("bad_kind", f"kind {m.kind!r} not one of {sorted(SIZES)}")
    if len(m.z) != n or len(m.cov) != n * n:
        raise Refused("bad_size", f"{m.kind}: z needs {n} numbers and cov {n * n}, got {len(m.z)} and {len(m.cov)}")
    cov = np.asarray(m.cov, dtype=float).reshape(n, n)
    if not (np.all(np.isfinite(cov)) and np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)):
        raise Refused("bad_covariance", "cov is not symmetric positive definite")
    if m.kind != Kind.ABSOLUTE and m.target is None and not m.target_is_robot:
        raise Refused("bad_target", "a landmark detection needs the landmark's id")
    return Detection(robot, m.t, m.kind, np.asarray(m.z, dtype=float), cov, m.target, m.target_is_robot)


class ZenohInput:
    """Subscribe to robot ``feed.robot``'s input keys under ``scope`` on ``session`` and push them to ``feed``;
    with ``roster`` (a team with keys) only frames signed by that robot are taken (module docstring)."""

    def __init__(self, session: Any, feed: LiveFeed, scope: str, roster: Roster | None = None) -> None:
        self.session, self.feed, self.scope, self.robot = session, feed, scope, feed.robot
        self.verifier = None if roster is None else Verifier(roster, context=INPUT_CONTEXT)
        """The inputs' own verifier (its own replay windows: not the node's), None without a roster."""
        self.counts: Counter[str] = Counter()
        self.reasons: Counter[str] = Counter()
        """Refusals by reason: ``auth_<category>`` (:data:`swarmloc.net.auth.CATEGORIES`), ``bad_schema``..."""
        self._lock = threading.Lock()
        self._refuse = InputRefusals(f"robot {self.robot}: input", self.counts, self.reasons, log, total="rejected")
        self._sub: Any = None

    def open(self) -> None:
        self._sub = self.session.declare_subscriber(input_key(self.scope, self.robot, "*"), handler=self._on)

    def close(self) -> None:
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None

    def _on(self, sample: Any) -> None:
        key = str(sample.key_expr)
        what = key.rsplit("/", 1)[-1]
        with self._lock:
            self.counts["received"] += 1
            opened = False  # authenticated (or no roster): a refusal from now on counts towards the end's count
            try:
                payload = self._open(key, what, sample.payload.to_bytes())
                opened = True
                x = decode_input(what, payload, self.robot)
                if isinstance(x, ProgressIn):
                    self.feed.end(x.count) if x.end else self.feed.advance(x.t if x.t is not None else float("nan"))
                    ok = True
                else:
                    ok = self.feed.push(x)
                self.counts["pushed" if ok else "refused_by_feed"] += 1
            except AuthRejected as exc:
                self.counts["rejected"] += 1
                note_refusal(self.reasons, exc, f"robot {self.robot}", f"{what} input")
                self.feed.refused_input(f"auth_{exc.category}", counted=False)  # not the robot's: not in its count
            except Refused as exc:
                self._bad(exc.reason, f"{what}: {exc}", opened and what in ("odom", "det"))
            except Exception as exc:  # noqa: BLE001 - a live node never dies of one message
                self._bad("internal_error", f"{what}: {type(exc).__name__}: {exc}", opened and what in ("odom", "det"))

    def _open(self, key: str, what: str, data: bytes) -> bytes:
        """The JSON payload of ``data`` received on ``key``: as it is without a roster, else out of its signed frame
        (robot ``robot``'s own: :class:`~swarmloc.net.auth.AuthRejected` otherwise)."""
        if self.verifier is None:
            return data
        if what in _TYPES and len(data) > MAX_BYTES + HEADER.size + SIG_SIZE:  # bounded before the signature's hash
            raise Refused("too_large", f"{len(data)} bytes > {MAX_BYTES} and a signed frame's")
        return self.verifier.open(key, data, publication=True)[1]

    def _bad(self, reason: str, detail: str, counted: bool) -> None:
        self.feed.refused_input(reason, counted)  # counted: the robot's own input, in its end's count
        self._refuse(reason, detail[:200])


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
    """Publish robot ``robot``'s inputs for a :class:`ZenohInput` of team scope ``scope``; with ``auth`` (the
    robot's own key and the team's roster) each is a signed frame of the robot (module docstring)."""

    def __init__(self, session: Any, scope: str, robot: int, auth: Auth | None = None) -> None:
        self.robot = int(robot)
        signs_as(auth, self.robot, "InputPublisher")
        self._signer = None if auth is None or auth.signer is None else auth.signer.for_context(INPUT_CONTEXT)
        self._keys = {w: input_key(scope, self.robot, w) for w in _TYPES}
        self._pubs = {w: session.declare_publisher(k, congestion_control=block()) for w, k in self._keys.items()}
        self.sent = 0

    def wait_matched(self, timeout: float = 10.0) -> bool:
        """Wait (up to ``timeout`` s) until a subscriber matches each of its keys (what is put before is lost)."""
        return wait_matched_all(self._pubs.values(), timeout)

    def _put(self, what: str, payload: bytes) -> None:
        self._pubs[what].put(payload if self._signer is None else self._signer.seal(self._keys[what], payload))

    def push(self, e: Event) -> None:
        self._put(*encode_event(e))
        self.sent += 1

    def progress(self, t: float) -> None:
        self._put("progress", msgspec.json.encode(ProgressIn(t=float(t))))

    def end(self) -> None:
        """The stream is over, after the ``sent`` inputs (which may still be on their way: other keys)."""
        self._put("progress", msgspec.json.encode(ProgressIn(end=True, count=self.sent)))

    def close(self) -> None:
        for p in self._pubs.values():
            p.undeclare()
