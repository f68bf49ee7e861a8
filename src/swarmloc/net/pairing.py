"""Per-pair sessions: a signed handshake binds each pair of members' processes (this run), and what one member sends
to another is authenticated with a fast MAC under their pair's session key.

Each member's process attached to its Zenoh session (:func:`attach`) holds a fresh X25519 key pair and an
**incarnation** (8 random bytes, in every signed frame it sends: :mod:`swarmloc.net.auth`), and answers the
handshake on ``swarmloc/<scope>/hello/<member>`` (a robot id, ``server``, ``collector``). A process that meets a
member (at its start, every member that answers on ``hello/*``; later, one it hears from or sends to) makes a
session with it in two Zenoh gets:

1. **hello** (signed with the asker's Ed25519 key, context ``swarmloc-hello-v1``): asker's X25519 public key and a
   fresh 16-byte nonce. The answer (signed by the answering member): its X25519 public key, its incarnation, the
   asker's nonce and incarnation echoed, a nonce of its own, and its process's start time. The echoed nonce makes
   the answer fresh: it comes from the member's process of now, whatever was recorded before.
2. **confirm**: the answerer's nonce, MACed under the session key; the answer (an ack, MACed too) says whether the
   answerer took the session. The MAC proves that the asker holds the X25519 key its signed hello named, and the
   nonce that it is of now: so both sides learn the other's process of this run, freshly, from one side's
   initiative.

**Session key**: HKDF-SHA256 of the X25519 shared secret, its info the context ``swarmloc-pair-v1``, the team's
scope, and both members' ids, Ed25519 keys and X25519 keys; the session id (8 bytes) is a BLAKE2b hash of that
info. The X25519 keys live in memory only and are new for every process: a session key is never used by another
run, and a member's long-term key stolen later gives no session key of before (forward secrecy).

**MACed frames** (:mod:`swarmloc.net.macframe`): what a member sends to a member it has a session with (a query,
an answer, a push on an inbox), 48 bytes of framing against the signed frame's 104, and a keyed hash (a microsecond)
against an Ed25519 signature and its verification (about 85 us). What goes to many (beliefs, progress, broadcasts,
reports; the belief server's and the collector's publications) stays signed.

**What a receiver accepts.** A MACed frame only under a session it holds, from the member of that session (``other_run``
for a session it does not hold: another run's, or another pair's; ``key_mismatch`` for its own side's frame), with a
MAC that verifies (``bad_signature``), a stamp within the roster's ``max_age_s`` and a sequence number not seen in
that session (``replay``). A signed frame only from the incarnation of its sender it has a session with
(``other_run``: another process of the sender, e.g. of a run before; ``twin``: see below). A signed frame from a
member it has no session with yet makes a handshake with that member at once (on the receiving process's own
thread, bounded by ``HELLO_TIMEOUT``; the first time, and after ``BACKOFF`` s), then is judged;
elsewhere it is refused as ``no_session`` while the handshake is made.

**A restarted member rejoins** by its start: its new process says hello to every member, and each, seeing a second
process of a member it holds a session with, asks that member's hello key again (a probe, ``PROBE_TIMEOUT``): if
only the new process answers, the old one is gone and the new session replaces it (``sessions_renewed``).
**Two processes with one key** (a copied key, or a process started twice): if the first process answers the probe
too, or two processes answer one hello, the member's first process (the one in session; else the one started first)
is kept, the other is a **twin**: counted (``twins``), logged once naming both (incarnation, Zenoh id, start time),
refused a session, and every frame it signs is refused (``twin``). The genuine process is never displaced by a
twin, so it is never declared lost for it; a process that hears another one of its own key logs it too
(``twins_of_self``).
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
import struct
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric.x25519 import X25519PrivateKey, X25519PublicKey
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from swarmloc.net.auth import CONTEXT, NAMES, REPLAY_WINDOW, Auth, AuthRejected, ReplayWindow, Verifier, member_name
from swarmloc.net.macframe import (
    MAC_HEADER,
    MAC_MAGIC,
    TAG_SIZE,
    Session,
    mac_frame,
    mac_payload,
    mac_vouches,
    open_mac,
    recipient,
)
from swarmloc.net.transport import get_all, hello_key, undeclare_all

log = logging.getLogger(__name__)

HELLO_CONTEXT = b"swarmloc-hello-v1\0"
"""Signing context of the handshake's hellos and answers (they never open as team frames, nor team frames as them)."""
CONFIRM_CONTEXT = b"swarmloc-confirm-v1\0"
PAIR_CONTEXT = b"swarmloc-pair-v1\0"
REQUEST = struct.Struct(">B16s32s")  # 1, asker's nonce, asker's X25519 key
ANSWER = struct.Struct(">Bi8s16s16s32sq")  # 2, asker, asker's incarnation, asker's nonce, own nonce, X25519, start [ns]
CONFIRM = struct.Struct(">B16s")  # 3, the answerer's nonce
ACK = struct.Struct(">B")  # 4 + 1: the session taken, 4 + 0: refused (the asker is a twin)
MAX_CONFIRM = MAC_HEADER.size + CONFIRM.size + TAG_SIZE
HELLO_TIMEOUT = 2.0
"""[s] a hello's wait for the answers (and a receiving thread's wait for a handshake it needs)."""
PROBE_TIMEOUT = 3.0
"""[s] the wait for a member's first process to answer when a second one confirms a session: past it, the first
is taken for gone (a restart)."""
RETRY = 1.0
"""[s] at most one handshake started per member per RETRY s."""
BACKOFF = 10.0
"""[s] a receiving thread waits for a handshake with a member the first time, then again only after BACKOFF s."""
MAX_PENDING = 256
"""Hellos answered and not yet confirmed, kept (the oldest dropped beyond), each at most PENDING_TTL s."""
PENDING_TTL = 10.0
MAX_TWINS = 16
"""Twin processes remembered per member (the latest ones)."""


def member_key(member: int) -> str:
    """A member's name in its hello key: its robot id, ``server`` or ``collector``."""
    return NAMES.get(member, str(member))


@dataclass
class Answer:
    """One member's answer to a hello: who (``member``, its process ``incarnation``, its X25519 key ``eph``, its
    ``nonce`` to confirm, its start ``since`` [ns]) and the Zenoh id that sent it (``replier``: not authenticated)."""

    member: int
    incarnation: bytes
    eph: bytes
    nonce: bytes
    since: int
    replier: str

    def describe(self) -> str:
        start = datetime.fromtimestamp(self.since / 1e9, tz=UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]
        return f"process {self.incarnation.hex()} (Zenoh id {self.replier}, started {start} UTC)"


@dataclass
class _Pending:
    """A hello this process answered: the asker's session-to-be, until the asker confirms it."""

    answer: Answer
    key: bytes
    sid: bytes
    nonce: bytes
    t: float


class Pairing:
    """The per-pair sessions of the process holding ``auth`` (its key and roster) on the Zenoh ``session`` (None:
    nothing declared, sessions installed by the caller: tests, benchmarks), under team scope ``scope``. Installs
    itself as ``auth.sessions`` and as its verifier's check of runs. Thread-safe; the thread that made it may wait
    for a handshake when a frame needs one (:meth:`check`), no other does."""

    def __init__(self, auth: Auth, scope: str, session: Any = None) -> None:
        if auth.signer is None:
            raise ValueError("per-pair sessions need the member's own key")
        self.auth, self.scope, self.zs = auth, scope, session
        self.signer, self.roster = auth.signer, auth.roster
        self.member = self.signer.member
        self.incarnation = self.signer.incarnation
        self.since = time.time_ns()
        self._hello_signer = self.signer.for_context(HELLO_CONTEXT)
        self._hello_verifier = Verifier(self.roster, context=HELLO_CONTEXT)
        self._eph = X25519PrivateKey.generate()
        self.eph = self._eph.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
        self._cv = threading.Condition()
        self._peers: dict[int, Session] = {}
        self._sids: dict[bytes, Session] = {}
        self._pending: OrderedDict[bytes, _Pending] = OrderedDict()
        self._twins: dict[int, OrderedDict[bytes, str]] = {}
        self._tries: dict[int, float] = {}
        self._busy: set[int] = set()
        self._wild = 0
        self._owner = threading.get_ident()
        self.counts: Counter[str] = Counter()
        self._decl = None
        if session is not None:
            self._decl = session.declare_queryable(hello_key(scope, member_key(self.member)), handler=self._on_hello)
        auth.verifier.runs = self.check
        auth.sessions = self

    # ------------------------------------------------------------------------------------------ frames
    def seal(self, key_expr: str, payload: bytes, to: int | None = None) -> bytes:
        """``payload`` for ``key_expr``: MACed for member ``to`` (default :func:`recipient`) when in session with
        it; else signed (and a handshake with ``to`` started, so that the next ones are MACed)."""
        to = recipient(key_expr) if to is None else to
        s = None
        if to is not None and to != self.member:
            with self._cv:
                s = self._peers.get(to)
            if s is None and to in self.roster.keys:
                self._start(to)
        if s is None:
            return self.signer.seal(key_expr, payload)
        return self._frame(s.key, s.sid, CONTEXT, key_expr, payload)

    def open(self, key_expr: str, data: bytes, publication: bool = False) -> tuple[int, bytes]:
        """``(sender, schema envelope)`` of a MACed or a signed frame received on ``key_expr``, or
        :class:`~swarmloc.net.auth.AuthRejected` (:func:`~swarmloc.net.macframe.open_mac`, :meth:`check`)."""
        v = self.auth.verifier
        if data[:4] != MAC_MAGIC:
            return v.open(key_expr, data, publication)
        return open_mac(key_expr, data, CONTEXT, self.roster.keys, self._sids.get, v.clock(), v.max_age_ns, self._cv,
                        publication)  # fmt: skip

    def vouches(self, key_expr: str, data: bytes) -> bool:
        """Whether a MACed frame verifies under one of this process's sessions (thread-safe, changes nothing)."""
        return mac_vouches(key_expr, data, CONTEXT, self._sids.get)

    def check(self, sender: int, incarnation: bytes) -> str | None:
        """Whether a signed frame of ``sender``'s process ``incarnation`` is of this run: None, or the refusal's
        category (``other_run``, ``twin``, ``no_session``). Without a session with ``sender``, this process's own
        thread makes one at once (the first time, and after ``BACKOFF`` s); another thread starts one and refuses."""
        if sender == self.member and incarnation == self.incarnation:
            return None
        with self._cv:
            s = self._peers.get(sender)
            twin = incarnation in self._twins.get(sender, ())
        if twin:
            return "twin"
        if s is not None or sender == self.member:
            return None if s is not None and s.incarnation == incarnation else "other_run"
        if not incarnation:
            return "other_run"
        if threading.get_ident() == self._owner and self.ensure(sender):
            return self.check(sender, incarnation)
        self._start(sender)
        return "no_session"

    def _frame(self, key: bytes, sid: bytes, context: bytes, key_expr: str, payload: bytes) -> bytes:
        return mac_frame(self.member, self.signer.next_seq(), self.signer.clock(), key, sid, context, key_expr, payload)

    # ------------------------------------------------------------------------------------------ sessions
    def session(self, member: int) -> Session | None:
        """This process's session with ``member``, if any."""
        with self._cv:
            return self._peers.get(member)

    def derive(self, peer: int, peer_eph: bytes) -> tuple[bytes, bytes]:
        """``(session key, session id)`` of this process and ``peer``'s process of X25519 key ``peer_eph``
        (ValueError for a key that is no X25519 key or gives no shared secret)."""
        shared = self._eph.exchange(X25519PublicKey.from_public_bytes(peer_eph))
        mine = (self.member, self.roster.keys[self.member], self.eph)
        a, b = sorted((mine, (peer, self.roster.keys[peer], peer_eph)), key=lambda x: x[0])
        info = b"".join((PAIR_CONTEXT, self.scope.encode(), b"\0", struct.pack(">ii", a[0], b[0]), *a[1:], *b[1:]))
        key = HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=info).derive(shared)
        return key, hashlib.blake2b(info, digest_size=8, person=b"swarmloc-sid").digest()

    def install(self, peer: int, incarnation: bytes, peer_eph: bytes) -> Session:
        """Take ``peer``'s process (``incarnation``, X25519 key ``peer_eph``) as the one of this run, replacing its
        former one (what the handshake does once both sides are vouched for; tests and benchmarks call it)."""
        key, sid = self.derive(peer, peer_eph)
        return self._install(peer, incarnation, key, sid)

    def _install(self, peer: int, incarnation: bytes, key: bytes, sid: bytes) -> Session:
        with self._cv:
            old = self._peers.get(peer)
            if old is not None and old.sid == sid:
                return old
            s = Session(peer, incarnation, key, sid, ReplayWindow(REPLAY_WINDOW))
            if old is not None:
                del self._sids[old.sid]
                self.counts["sessions_renewed"] += 1
            self._peers[peer], self._sids[sid] = s, s
            self.counts["sessions"] += 1
            self._cv.notify_all()
        if old is not None:
            log.info("%s: %s has a new process (%s, was %s): its session is renewed", member_name(self.member),
                     member_name(peer), incarnation.hex(), old.incarnation.hex())  # fmt: skip
        return s

    def snapshot(self) -> dict[str, int]:
        """The counters: ``sessions`` (made), ``sessions_renewed`` (a member's process replaced), ``twins`` (second
        processes of a member's key seen), ``twins_of_self``, ``sessions_refused`` (this process was refused as a
        twin), ``hello_<category>`` (handshake frames refused)."""
        with self._cv:
            return dict(self.counts)

    def _count(self, name: str) -> None:
        with self._cv:
            self.counts[name] += 1

    # ------------------------------------------------------------------------------------------ asking
    def hello_all(self, wait: float = HELLO_TIMEOUT + PROBE_TIMEOUT + 1.0) -> int:
        """Say hello to every member that answers on ``hello/*`` and confirm a session with each; wait for it (at
        most ``wait`` s). Returns the number of members in session."""
        if self.zs is None:
            return len(self._peers)
        with self._cv:
            self._wild += 1
        self._hello("*", lambda answers: self._settle(answers, wildcard=True))
        end = time.monotonic() + wait
        with self._cv:
            while (self._wild or self._busy) and (left := end - time.monotonic()) > 0:
                self._cv.wait(left)
            return len(self._peers)

    def ensure(self, member: int, wait: float = HELLO_TIMEOUT) -> bool:
        """Whether a session with ``member`` is up, making one if needed: waiting for it (at most ``wait`` s) the
        first time and after ``BACKOFF`` s; else only starting it."""
        now = time.monotonic()
        with self._cv:
            if member in self._peers:
                return True
            patient = now - self._tries.get(member, -math.inf) > BACKOFF
        self._start(member)
        if not patient:
            return False
        end = now + wait
        with self._cv:
            while member not in self._peers and member in self._busy and (left := end - time.monotonic()) > 0:
                self._cv.wait(left)
            return member in self._peers

    def _start(self, member: int) -> bool:
        """Start a handshake with ``member`` unless one is under way or one started less than ``RETRY`` s ago."""
        now = time.monotonic()
        with self._cv:
            if self.zs is None or member in self._busy or now - self._tries.get(member, -math.inf) < RETRY:
                return False
            self._tries[member] = now
            self._busy.add(member)
        self._hello(member_key(member), lambda answers: self._settle(answers, asked=(member,)))
        return True

    def _hello(self, target: str, done: Callable[[list[Answer]], None]) -> None:
        """Ask ``hello/<target>`` with a fresh nonce; ``done(answers)`` with the valid answers once the get ends."""
        nonce = os.urandom(16)
        key = hello_key(self.scope, target)
        answers: list[Answer] = []

        def on_reply(r: Any) -> None:
            if r.ok is not None:
                a = self._answer(
                    str(r.ok.key_expr), r.ok.payload.to_bytes(), nonce, str(getattr(r.replier_id, "zid", "?"))
                )
                if a is not None:
                    answers.append(a)

        def on_end() -> None:
            try:
                done(answers)
            except Exception:  # a handshake never raises into Zenoh's threads
                log.exception("%s: handshake on %s", member_name(self.member), key)

        payload = self._hello_signer.seal(key, REQUEST.pack(1, nonce, self.eph))
        if (exc := get_all(self.zs, key, payload, HELLO_TIMEOUT, on_reply, on_end)) is not None:  # no answers
            log.debug("%s: hello on %s not sent: %s", member_name(self.member), key, exc)

    def _answer(self, key: str, data: bytes, nonce: bytes, replier: str) -> Answer | None:
        """An answer to this process's hello of ``nonce``, verified (None, counted, otherwise)."""
        try:
            o = self._hello_verifier.open_frame(key, data)
        except AuthRejected as exc:
            self._count(f"hello_{exc.category}")
            return None
        if len(o.payload) != ANSWER.size or key != hello_key(self.scope, member_key(o.sender)):
            self._count("hello_malformed")
            return None
        kind, asker, asker_inc, echo, theirs, eph, since = ANSWER.unpack(o.payload)
        if (kind, asker, asker_inc, echo) != (2, self.member, self.incarnation, nonce):
            self._count("hello_not_ours")
            return None
        return Answer(o.sender, o.incarnation, eph, theirs, since, replier)

    def _settle(self, answers: list[Answer], asked: tuple[int, ...] = (), wildcard: bool = False) -> None:
        """A hello ended: confirm a session with each member that answered (its first process, when two did)."""
        chosen = self._choose(answers)
        with self._cv:
            todo = [
                a for m, a in chosen.items() if not (m in self._peers and self._peers[m].incarnation == a.incarnation)
            ]
            self._busy.update(a.member for a in todo)
            self._busy.difference_update(m for m in asked if m not in {a.member for a in todo})
            self._wild -= wildcard
            self._cv.notify_all()
        for a in todo:
            self._confirm(a)

    def _choose(self, answers: list[Answer]) -> dict[int, Answer]:
        """Per member that answered: the process to be in session with. Two processes of one member are a twin:
        the one in session is kept, else the one started first; every other one is noted (:meth:`_twin`)."""
        by: dict[int, dict[bytes, Answer]] = {}
        for a in answers:
            if a.member == self.member:
                if a.incarnation != self.incarnation:
                    self._twin_of_self(a.incarnation, a.describe())
                continue
            by.setdefault(a.member, {})[a.incarnation] = a
        chosen = {}
        for m, procs in by.items():
            with self._cv:
                cur = self._peers.get(m)
                twins: Mapping[bytes, str] = self._twins.get(m, {})
            fresh = {i: a for i, a in procs.items() if i not in twins}
            if not fresh:
                continue
            keep = (
                fresh[cur.incarnation]
                if cur and cur.incarnation in fresh
                else min(fresh.values(), key=lambda a: a.since)
            )
            for other in fresh.values():
                if other is not keep:
                    self._twin(m, keep.describe(), other.incarnation, other.describe())
            chosen[m] = keep
        return chosen

    def _confirm(self, a: Answer) -> None:
        """Confirm the session with ``a``'s process; taken once its ack says so."""
        try:
            key, sid = self.derive(a.member, a.eph)
        except ValueError:
            self._count("hello_bad_key")
            self._finish(a.member)
            return
        hk = hello_key(self.scope, member_key(a.member))

        def on_reply(r: Any) -> None:
            body = None if r.ok is None else mac_payload(r.ok.payload.to_bytes(), key, sid, CONFIRM_CONTEXT,
                                                         str(r.ok.key_expr), a.member)  # fmt: skip
            if body == ACK.pack(5):
                self._install(a.member, a.incarnation, key, sid)
            elif body == ACK.pack(4):
                self._count("sessions_refused")
                log.warning("%s: %s refused a session with this process (%s): it holds another process of this "
                            "member's key", member_name(self.member), member_name(a.member),
                            self.incarnation.hex())  # fmt: skip

        payload = self._frame(key, sid, CONFIRM_CONTEXT, hk, CONFIRM.pack(3, a.nonce))
        exc = get_all(self.zs, hk, payload, HELLO_TIMEOUT + PROBE_TIMEOUT, on_reply, lambda: self._finish(a.member))
        if exc is not None:
            log.debug("%s: confirm to %s not sent: %s", member_name(self.member), member_name(a.member), exc)

    def _finish(self, member: int) -> None:
        with self._cv:
            self._busy.discard(member)
            self._cv.notify_all()

    # ------------------------------------------------------------------------------------------ answering
    def _on_hello(self, q: Any) -> None:
        """A hello or a confirm on this member's hello key (Zenoh's thread)."""
        kept = False
        try:
            data = q.payload.to_bytes() if q.payload is not None else b""
            if data[:4] == MAC_MAGIC:
                kept = self._on_confirm(q, str(q.key_expr), data)
            else:
                self._on_request(q, str(q.key_expr), data)
        except Exception:  # a handshake never raises into Zenoh's threads
            log.exception("%s: handling a hello", member_name(self.member))
        finally:
            if not kept:
                q.drop()

    def _on_request(self, q: Any, key: str, data: bytes) -> None:
        """A member's hello: answered with this process's key, incarnation and a nonce to confirm."""
        try:
            o = self._hello_verifier.open_frame(key, data)
        except AuthRejected as exc:
            self._count(f"hello_{exc.category}")
            return
        if len(o.payload) != REQUEST.size or REQUEST.unpack(o.payload)[0] != 1:
            self._count("hello_malformed")
            return
        _, nonce, eph = REQUEST.unpack(o.payload)
        if o.sender == self.member:
            if o.incarnation != self.incarnation:
                self._twin_of_self(o.incarnation, f"process {o.incarnation.hex()}")
            return
        with self._cv:
            twin = o.incarnation in self._twins.get(o.sender, ())
        if twin:
            return
        try:
            key_, sid = self.derive(o.sender, eph)
        except ValueError:
            self._count("hello_bad_key")
            return
        mine = os.urandom(16)
        now = time.monotonic()
        with self._cv:
            while self._pending and (len(self._pending) >= MAX_PENDING or next(iter(self._pending.values())).t <
                                     now - PENDING_TTL):  # fmt: skip
                self._pending.popitem(last=False)
            self._pending[sid] = _Pending(Answer(o.sender, o.incarnation, eph, nonce, 0, "?"), key_, sid, mine, now)
        rk = hello_key(self.scope, member_key(self.member))
        body = ANSWER.pack(2, o.sender, o.incarnation, nonce, mine, self.eph, self.since)
        q.reply(rk, self._hello_signer.seal(rk, body))

    def _on_confirm(self, q: Any, key: str, data: bytes) -> bool:
        """A member confirms the session of a hello this process answered: acked (taken), or refused for a twin;
        when the member already has a process in session, acked once a probe of the member says which (then True:
        the query is kept open until then)."""
        if not MAC_HEADER.size + TAG_SIZE <= len(data) <= MAX_CONFIRM:
            self._count("hello_malformed")
            return False
        fields = MAC_HEADER.unpack_from(data)
        sender, sid = fields[1], fields[4]
        with self._cv:
            p = self._pending.get(sid)
        body = None if p is None else mac_payload(data, p.key, sid, CONFIRM_CONTEXT, key, sender)
        if p is None or body != CONFIRM.pack(3, p.nonce):
            self._count("hello_other_run" if p is None else "hello_bad_signature")
            return False
        a = p.answer
        with self._cv:
            self._pending.pop(sid, None)
            cur = self._peers.get(a.member)
            twin = a.incarnation in self._twins.get(a.member, ())
        if twin:
            self._ack(q, p, taken=False)
        elif cur is None or cur.incarnation == a.incarnation:
            self._install(a.member, a.incarnation, p.key, sid)
            self._ack(q, p, taken=True)
        else:  # a second process of a member in session: a restart if the first is gone, else a twin
            self._hello(member_key(a.member), lambda answers: self._probed(q, p, cur, answers))
            return True
        return False

    def _probed(self, q: Any, p: _Pending, cur: Session, answers: list[Answer]) -> None:
        """The probe of ``p``'s member ended: its process in session ``cur`` answered (``p``'s is a twin) or not
        (``p``'s replaces it)."""
        try:
            procs = {a.incarnation: a for a in answers if a.member == p.answer.member}
            if cur.incarnation in procs:
                new = procs.get(p.answer.incarnation)
                self._twin(p.answer.member, procs[cur.incarnation].describe(), p.answer.incarnation,
                           new.describe() if new is not None else f"process {p.answer.incarnation.hex()}")  # fmt: skip
                self._ack(q, p, taken=False)
            else:
                self._install(p.answer.member, p.answer.incarnation, p.key, p.sid)
                self._ack(q, p, taken=True)
        finally:
            q.drop()

    def _ack(self, q: Any, p: _Pending, taken: bool) -> None:
        rk = hello_key(self.scope, member_key(self.member))
        q.reply(rk, self._frame(p.key, p.sid, CONFIRM_CONTEXT, rk, ACK.pack(4 + taken)))

    def _twin(self, member: int, kept: str, incarnation: bytes, other: str) -> None:
        """Note a second process of ``member``'s key (its frames are refused as ``twin`` from now on)."""
        if self._note_twin(member, incarnation, other, "twins"):
            log.warning("%s: two processes hold the key of %s: %s, kept, and %s, refused (its frames are counted "
                        "auth_twin)", member_name(self.member), member_name(member), kept, other)  # fmt: skip

    def _twin_of_self(self, incarnation: bytes, other: str) -> None:
        """Note another process holding this process's own key (its frames are refused as ``twin``)."""
        if self._note_twin(self.member, incarnation, other, "twins_of_self"):
            log.warning("%s: another process holds this member's key: %s (this one is process %s)",
                        member_name(self.member), other, self.incarnation.hex())  # fmt: skip

    def _note_twin(self, member: int, incarnation: bytes, other: str, counter: str) -> bool:
        """Remember ``member``'s process ``incarnation`` as a twin (the latest ``MAX_TWINS``); whether it is new."""
        with self._cv:
            twins = self._twins.setdefault(member, OrderedDict())
            new = incarnation not in twins
            twins[incarnation] = other
            if len(twins) > MAX_TWINS:
                twins.popitem(last=False)
            self.counts[counter] += new
        return new

    def close(self) -> None:
        """Stop answering hellos and asking (the sessions stay: late frames still open)."""
        undeclare_all([self._decl])  # None when nothing was declared, or the session closed: passed over
        self._decl = None
        self.zs = None


def attach(auth: Auth | None, session: Any, scope: str, hello: bool = True) -> Pairing | None:
    """Attach ``auth``'s process to its Zenoh ``session`` under team scope ``scope``: answer the handshake, and (with
    ``hello``) make a session with every member that answers now. Idempotent for one session; None without
    ``auth`` (an unauthenticated team)."""
    if auth is None:
        return None
    p = auth.sessions
    if p is None or p.zs is not session:
        p = Pairing(auth, scope, session)
    if hello:
        p.hello_all()
    return p
