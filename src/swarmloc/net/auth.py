"""Authenticated senders: every payload signed with its sender's Ed25519 key and verified against the team's roster.

Before, the sender of a message was whatever its envelope said (``from_robot``): any process that could reach the
team's network could speak as any robot, the belief server or the collector, and a robot holding a valid TLS
certificate could still speak in another robot's name. Now every member (each robot, the belief server
``SERVER = -1``, the collector of ``swarmloc team`` ``COLLECTOR = -2``) holds its own key pair; the **roster** (a
JSON file, :class:`Roster`) maps member ids to public keys and is given to every process. What a member sends is
sealed (:meth:`Signer.seal`): the schema's envelope (:mod:`swarmloc.net.schema`) wrapped in a signed frame.
A receiver opens the frame (:meth:`Verifier.open`) before it decodes anything else, and refuses it (raising
:class:`AuthRejected`, a :class:`~swarmloc.net.schema.Rejected` with a ``category``) unless it verifies against
the roster's key of the member it claims to come from. See ``docs/network.md`` for the threat model.

**Signed frame** (big-endian; ``n`` = length of the schema envelope)::

    offset  size  field
    0       4     magic  b"SLS2"  (swarmloc signed, version 2)
    4       4     sender  int32: robot id >= 0, -1 the belief server, -2 the collector
    8       8     seq     uint64, strictly increasing per sender; starts at the sender's wall clock in ns, so it
                          keeps increasing across a restart of the sender's process
    16      8     stamp   int64, the sender's wall clock when it signed, ns since the Unix epoch
    24      8     key id  the first 8 bytes of SHA-256(sender's raw 32-byte public key)
    32      8     incarnation  8 random bytes of the sending process (one per process: its run)
    40      n     the schema envelope (MessagePack, :func:`swarmloc.net.schema.encode`)
    40 + n  64    Ed25519 signature of  b"swarmloc-signed-v1\\0" + key expression (UTF-8) + b"\\0" + bytes 0 .. 40 + n

(Version 1, ``SLS1``, had no incarnation: a 32-byte header. It is still read, as a frame that names no run.)
(A robot's live inputs, :mod:`swarmloc.live.zenoh_input`, are signed frames too, with the context
``b"swarmloc-input-v1\\0"`` in place of ``b"swarmloc-signed-v1\\0"``: :data:`INPUT_CONTEXT`.)
The key expression is the one the message is sent on (a put's key, a get's selector key, a reply's key), so a
message cannot be moved to another key (another robot's inbox) without breaking its signature; the team's name is
part of it. The frame is bounded (``MAX_SIGNED`` bytes) before anything is parsed.

**Runs and sessions.** A process whose :class:`Auth` is attached to its Zenoh session
(:func:`swarmloc.net.pairing.attach`) makes a session with each member it meets by a signed handshake: it then
sends the frames addressed to one member (queries, answers, pushes) MACed under their pair's session key, and it
accepts a signed frame (a publication: belief, progress, broadcast...) only from the incarnation of its sender
that the handshake vouched for. A frame of another run (a process of before, replayed) is refused
(``other_run``), and so is one of a second process holding a member's key (``twin``). See
:mod:`swarmloc.net.pairing`.

**Refusal categories** (counted as ``auth_<category>`` by nodes, ``collector_auth_<category>`` by the collector,
``auth_<category>`` by the belief server; each logged with its reason): ``oversize``, ``unsigned`` (no signed
frame: too short or no magic), ``unknown_sender`` (not a roster member), ``key_mismatch`` (the frame's key id is not
the claimed sender's key: signed with another member's key, or an unknown one; a MACed frame under the session of
another pair than its sender's), ``bad_signature`` (the signature, or the MAC, does not verify), ``stale`` (stamp
more than ``max_age`` s old), ``future`` (stamp more than ``max_age`` s ahead), ``replay`` (a sequence number
already accepted from that sender's process, or older than the replay window), ``not_owner`` (a publication, belief,
progress or report, or a live input, on another member's key: ``robot/<id>/belief`` and ``input/<id>/odom`` only
from robot ``id``), ``other_run`` (signed by a process of the sender that is not the one of this run, MACed under a
session this receiver does not hold, or a frame that names no run), ``no_session`` (from a member this process
has no session with yet, and could not make one at once), ``twin`` (signed by a second process holding the sender's
key, which the handshake found beside the first), ``sender_mismatch`` (the schema envelope inside names another
sender than the signed frame).
"""

from __future__ import annotations

import base64
import hashlib
import heapq
import json
import logging
import os
import struct
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Container, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from swarmloc.net.schema import SERVER, Envelope, Rejected, decode
from swarmloc.net.transport import robot_of
from swarmloc.node.accounting import reason_key

log = logging.getLogger(__name__)

COLLECTOR = -2
"""Member id of the collector of ``swarmloc team`` (it receives beliefs, progress and reports; it sends nothing)."""
MAGIC = b"SLS2"
HEADER = struct.Struct(">4siQq8s8s")  # magic, sender, seq, stamp [ns], key id, incarnation
MAGIC_V1 = b"SLS1"
HEADER_V1 = struct.Struct(">4siQq8s")  # version 1: no incarnation (read as a frame that names no run)
SIG_SIZE = 64
INCARNATION_SIZE = 8
MAX_SIGNED = 1 << 20
"""[bytes] the largest signed frame a receiver parses. A message is a few hundred bytes, a node's report a few KiB
(tens under a flood of distinct refusals, each reason counted): the bound keeps a flood of large frames from costing
more than a hash of 1 MiB each."""
MAX_AGE = 30.0
"""[s] default bound on a stamp's age (and lead): the members' clocks must agree to well within it."""
REPLAY_WINDOW = 4096
"""Accepted sequence numbers remembered per sender (the newest); a number not above the newest one forgotten is
refused, so a message overtaken by more than this many later ones of its sender is refused as a replay."""
INCARNATIONS = 4
"""Processes (incarnations) per sender whose replay windows a :class:`Verifier` keeps (the latest ones heard)."""
CONTEXT = b"swarmloc-signed-v1\0"
"""Signing context of the team's frames (beliefs, queries, answers, progress...)."""
INPUT_CONTEXT = b"swarmloc-input-v1\0"
"""Signing context of a robot's live inputs (:mod:`swarmloc.live.zenoh_input`): a frame signed in one context never
verifies in the other, and each is opened by a :class:`Verifier` of its own (its own replay windows)."""
ROSTER_FORMAT = 1
MAX_ROSTER_BYTES = 1 << 20
NAMES = {SERVER: "server", COLLECTOR: "collector"}

CATEGORIES = {
    "oversize": f"signed frame larger than {MAX_SIGNED} bytes",
    "unsigned": "not a signed frame",
    "unknown_sender": "sender not in the roster",
    "key_mismatch": "signed with a key that is not the claimed sender's",
    "bad_signature": "signature does not verify with the claimed sender's key",
    "stale": "stamp too old",
    "future": "stamp too far ahead",
    "replay": "sequence number already accepted from that sender (replayed)",
    "not_owner": "published on another member's key",
    "other_run": "not from the sender's process of this run (another run's, replayed, or another pair's session)",
    "no_session": "from a member this process has no session with",
    "twin": "from a second process holding the sender's key",
    "sender_mismatch": "the envelope names another sender than the signed frame",
}
"""Refusal category -> the reason counted (``auth: <reason>``) and logged."""


class AuthRejected(Rejected):
    """A frame refused by :meth:`Verifier.open`: ``category`` (a key of :data:`CATEGORIES`), ``reason`` (counted:
    ``auth: <meaning>``, a fixed set) and ``detail`` (logged: the claimed sender, the key expression...)."""

    def __init__(self, category: str, detail: str = "") -> None:
        super().__init__(f"auth: {CATEGORIES[category]}")
        self.category = category
        self.detail = detail


def member_name(member: int) -> str:
    """``robot 3``, ``server``, ``collector``."""
    return NAMES.get(member, f"robot {member}")


def member_id(name: str) -> int:
    """A roster member's id from its name in the file: ``"3"``, ``"server"``, ``"collector"``."""
    ids = {v: k for k, v in NAMES.items()}
    if name in ids:
        return ids[name]
    if not (name.isascii() and name.isdigit()) or len(name) > 9:
        raise ValueError(f"roster: member {name!r} is neither a robot id (0, 1, ...) nor 'server' nor 'collector'")
    return int(name)


def key_id(public: bytes) -> bytes:
    return hashlib.sha256(public).digest()[:8]


def _public_raw(private: Any) -> bytes:
    return private.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


# ------------------------------------------------------------------------------------------------ keys and rosters
def new_key(path: str | os.PathLike[str]) -> bytes:
    """Make a key pair: the private key at ``path`` (PKCS#8 PEM, mode 0600, never overwritten), the public key (raw
    32 bytes, base64) at ``<path>.pub``; returns the raw public key."""
    private = Ed25519PrivateKey.generate()
    pem = private.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    public = _public_raw(private)
    Path(f"{os.fspath(path)}.pub").write_text(base64.b64encode(public).decode() + "\n")
    return public


def load_private(path: str | os.PathLike[str]) -> Any:
    """An Ed25519 private key from a PEM file that only its owner may read (as ssh insists)."""
    p = Path(path)
    if os.name == "posix" and p.stat().st_mode & 0o077:
        raise ValueError(f"key file {p} may be read by others: chmod 600 {p}")
    if p.stat().st_size > 16384:
        raise ValueError(f"key file {p} is not a key (over 16 KiB)")
    key = serialization.load_pem_private_key(p.read_bytes(), password=None)
    if not isinstance(key, Ed25519PrivateKey):
        raise ValueError(f"key file {p} does not hold an Ed25519 private key")
    return key


def public_key(text: str) -> bytes:
    """A raw public key from ``text``: base64 of 32 bytes, or a file holding that (``.pub``) or a private key."""
    p = Path(text)
    if p.is_file():
        if p.read_bytes()[:11] == b"-----BEGIN ":
            return _public_raw(load_private(p))
        text = p.read_text()
    try:
        raw = base64.b64decode(text.strip(), validate=True)
    except ValueError:
        raw = b""
    if len(raw) != 32:
        raise ValueError(f"{text.strip()[:60]!r} is not an Ed25519 public key (base64 of 32 bytes) nor a key file")
    return raw


@dataclass(frozen=True)
class Roster:
    """The team's members and their public keys (``keys``: member id -> raw 32-byte Ed25519 public key;
    ``max_age`` [s]: a signed stamp older, or further ahead, is refused)."""

    keys: Mapping[int, bytes]
    max_age: float = MAX_AGE

    def __post_init__(self) -> None:
        for m, k in self.keys.items():
            if not isinstance(m, int) or m < COLLECTOR or len(k) != 32:
                raise ValueError(f"roster: member {m!r} needs an id >= -2 and a 32-byte public key")
        if len(set(self.keys.values())) != len(self.keys):
            raise ValueError("roster: two members share a key (each needs its own: one could speak as the other)")
        if not 0 < self.max_age < 86400:
            raise ValueError(f"roster: max_age_s must be in (0, 86400) s, got {self.max_age}")

    @property
    def robots(self) -> list[int]:
        return sorted(m for m in self.keys if m >= 0)

    def to_json(self) -> str:
        members = {NAMES.get(m, str(m)): base64.b64encode(k).decode() for m, k in sorted(self.keys.items())}
        return json.dumps({"swarmloc_roster": ROSTER_FORMAT, "max_age_s": self.max_age, "members": members}, indent=2)

    def save(self, path: str | os.PathLike[str]) -> None:
        Path(path).write_text(self.to_json() + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Roster:
        p = Path(path)
        if p.stat().st_size > MAX_ROSTER_BYTES:
            raise ValueError(f"roster {p}: larger than {MAX_ROSTER_BYTES} bytes")
        try:
            d = json.loads(p.read_text())
        except (ValueError, UnicodeDecodeError) as exc:
            raise ValueError(f"roster {p}: not JSON: {exc}") from None
        members = d.get("members") if isinstance(d, dict) else None
        if not isinstance(members, dict) or d.get("swarmloc_roster") != ROSTER_FORMAT:
            raise ValueError(f"roster {p}: expected {{'swarmloc_roster': 1, 'members': {{id: base64 key}}}}")
        keys = {member_id(str(name)): public_key(str(k)) for name, k in members.items()}
        return cls(keys, float(d.get("max_age_s", MAX_AGE)))


def make_team_keys(
    folder: str | os.PathLike[str], robots: Iterable[int], max_age: float = MAX_AGE
) -> tuple[Path, dict[int, Path]]:
    """Key pairs for ``robots``, the belief server and the collector in ``folder`` (``robot<id>.key``,
    ``server.key``, ``collector.key``, each with its ``.pub``) and their roster ``roster.json``; returns the roster's
    path and each member's private key file."""
    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True, mode=0o700)
    files = key_files(d, robots)
    roster = Roster({m: new_key(f) for m, f in files.items()}, max_age)
    roster.save(d / "roster.json")
    return d / "roster.json", files


def key_files(folder: Path, robots: Iterable[int]) -> dict[int, Path]:
    """Each member's private key file in a team's ``folder``: ``robot<id>.key``, ``server.key``, ``collector.key``."""
    return {m: folder / f"{NAMES.get(m, f'robot{m}')}.key" for m in [*robots, SERVER, COLLECTOR]}


# ------------------------------------------------------------------------------------------------ sealing and opening
def _signed_bytes(context: bytes, key_expr: str, frame: bytes | memoryview) -> bytes:
    return b"".join((context, key_expr.encode(), b"\0", frame))


class Signer:
    """Seals what ``member`` sends with its ``private`` key (thread-safe: one sequence for the whole process) in
    signing ``context`` (:data:`CONTEXT`: the team's frames; :data:`INPUT_CONTEXT`: a robot's live inputs).
    ``incarnation``: the 8 bytes that name this process in every frame (default: random)."""

    def __init__(
        self,
        member: int,
        private: Any,
        clock: Callable[[], int] = time.time_ns,
        context: bytes = CONTEXT,
        incarnation: bytes | None = None,
    ) -> None:
        self.member = member
        self._key = private
        self.public = _public_raw(private)
        self.key_id = key_id(self.public)
        self.context = context
        self.incarnation = os.urandom(INCARNATION_SIZE) if incarnation is None else bytes(incarnation)
        if len(self.incarnation) != INCARNATION_SIZE:
            raise ValueError(f"Signer: incarnation must be {INCARNATION_SIZE} bytes")
        self.clock = clock
        self._seq = clock()
        self._lock = threading.Lock()

    def for_context(self, context: bytes) -> Signer:
        """A signer with the same member, key and incarnation in another signing ``context``, with a sequence of its
        own."""
        return Signer(self.member, self._key, self.clock, context, self.incarnation)

    def next_seq(self) -> int:
        """The next number of this signer's sequence (also numbers the MACed frames of :mod:`.pairing`)."""
        with self._lock:
            self._seq += 1
            return self._seq

    def seal(self, key_expr: str, payload: bytes) -> bytes:
        """``payload`` (a schema envelope) in a signed frame for ``key_expr``."""
        head = HEADER.pack(MAGIC, self.member, self.next_seq(), self.clock(), self.key_id, self.incarnation)
        frame = head + payload
        return frame + self._key.sign(_signed_bytes(self.context, key_expr, frame))


class ReplayWindow:
    """The sequence numbers accepted from one sender: those above ``floor``, at most ``size`` of them."""

    def __init__(self, size: int) -> None:
        self.size, self.floor = size, -1
        self.seen: set[int] = set()
        self.heap: list[int] = []

    def fresh(self, seq: int) -> bool:
        return seq > self.floor and seq not in self.seen

    def accept(self, seq: int) -> None:
        self.seen.add(seq)
        heapq.heappush(self.heap, seq)
        while len(self.heap) > self.size:
            self.floor = heapq.heappop(self.heap)
            self.seen.discard(self.floor)


class Opened(NamedTuple):
    """A frame opened by :meth:`Verifier.open_frame`: its sender, the sender's incarnation (b"" for a version 1
    frame) and the schema envelope it carries."""

    sender: int
    incarnation: bytes
    payload: bytes


def check_stamp(age_ns: int, max_age_ns: int, who: str) -> None:
    """Refuse a frame stamped more than ``max_age_ns`` ago (``stale``) or ahead (``future``)."""
    if age_ns > max_age_ns:
        raise AuthRejected("stale", f"{who}: stamped {age_ns / 1e9:.1f} s ago")
    if -age_ns > max_age_ns:
        raise AuthRejected("future", f"{who}: stamped {-age_ns / 1e9:.1f} s ahead")


class Verifier:
    """Opens frames signed in ``context`` against ``roster``, remembering the accepted sequence numbers of each
    sender's process (one per receiver; thread-safe). ``runs``: once set (:mod:`.pairing`), called as
    ``runs(sender, incarnation)`` for every frame that verifies, returns a refusal category when the frame's
    process is not its sender's of this run (None: it is)."""

    def __init__(
        self,
        roster: Roster,
        clock: Callable[[], int] = time.time_ns,
        window: int = REPLAY_WINDOW,
        context: bytes = CONTEXT,
    ) -> None:
        self.roster = roster
        self.context = context
        self._pub = {m: Ed25519PublicKey.from_public_bytes(k) for m, k in roster.keys.items()}
        self._kid = {m: key_id(k) for m, k in roster.keys.items()}
        self._owner_of = {kid: m for m, kid in self._kid.items()}
        self.clock = clock
        self.max_age_ns = int(roster.max_age * 1e9)
        self._size = window
        self._windows: dict[int, OrderedDict[bytes, ReplayWindow]] = {m: OrderedDict() for m in roster.keys}
        self._lock = threading.Lock()
        self.runs: Callable[[int, bytes], str | None] | None = None

    def open(self, key_expr: str, data: bytes, publication: bool = False) -> tuple[int, bytes]:
        """``(sender, schema envelope)`` of a frame received on ``key_expr``, or :class:`AuthRejected`.
        ``publication``: ``key_expr`` is a member's own (``robot/<id>/belief``...): only ``id`` may send on it."""
        opened = self.open_frame(key_expr, data, publication)
        return opened.sender, opened.payload

    def open_frame(self, key_expr: str, data: bytes, publication: bool = False) -> Opened:
        """:meth:`open`, with the sender's incarnation."""
        if len(data) > MAX_SIGNED:
            raise AuthRejected("oversize", f"{len(data)} bytes on {key_expr}")
        head = HEADER if data[:4] == MAGIC else HEADER_V1 if data[:4] == MAGIC_V1 else None
        if head is None or len(data) < head.size + SIG_SIZE:
            raise AuthRejected("unsigned", f"{len(data)} bytes on {key_expr}")
        fields = head.unpack_from(data)
        sender, seq, stamp, kid = fields[1:5]
        incarnation = fields[5] if head is HEADER else b""
        who = f"claimed sender {member_name(sender)} on {key_expr}"
        if sender not in self._pub:
            raise AuthRejected("unknown_sender", who)
        frame = memoryview(data)[: len(data) - SIG_SIZE]
        if kid != self._kid[sender]:
            raise AuthRejected("key_mismatch", f"{who}: {self._signed_by(kid, key_expr, data, frame)}")
        try:
            self._pub[sender].verify(data[-SIG_SIZE:], _signed_bytes(self.context, key_expr, frame))
        except InvalidSignature:
            raise AuthRejected("bad_signature", who) from None
        check_stamp(self.clock() - stamp, self.max_age_ns, who)
        if publication and robot_of(key_expr) != sender:
            raise AuthRejected("not_owner", who)
        refusal = None if self.runs is None else self.runs(sender, incarnation)
        if refusal is not None:
            raise AuthRejected(refusal, f"{who}: its process {incarnation.hex() or '(none named)'}")
        with self._lock:
            win = self._window(sender, incarnation)
            if not win.fresh(seq):
                raise AuthRejected("replay", f"{who}: sequence number {seq}")
            win.accept(seq)
        return Opened(sender, incarnation, bytes(frame[head.size :]))

    def _window(self, sender: int, incarnation: bytes) -> ReplayWindow:
        """The replay window of ``sender``'s process ``incarnation`` (the latest ``INCARNATIONS`` of a sender)."""
        wins = self._windows[sender]
        win = wins.get(incarnation)
        if win is None:
            win = wins[incarnation] = ReplayWindow(self._size)
            if len(wins) > INCARNATIONS:
                wins.popitem(last=False)
        wins.move_to_end(incarnation)
        return win

    def _signed_by(self, kid: bytes, key_expr: str, data: bytes, frame: memoryview) -> str:
        """Who signed a frame whose key id is not its claimed sender's: a member (verified), or nobody known."""
        m = self._owner_of.get(kid)
        if m is None:
            return "signed with a key outside the roster"
        try:
            self._pub[m].verify(data[-SIG_SIZE:], _signed_bytes(self.context, key_expr, frame))
        except InvalidSignature:
            return f"key id of {member_name(m)}, signature invalid"
        return f"signed with the key of {member_name(m)} (verified)"


class Auth:
    """One process's side of it: its ``signer`` (None: it sends nothing) and a :class:`Verifier` of its own."""

    def __init__(self, roster: Roster, signer: Signer | None = None) -> None:
        if signer is not None and roster.keys.get(signer.member) != signer.public:
            raise ValueError(f"the key given is not the roster's key of {member_name(signer.member)}")
        self.roster = roster
        self.signer = signer
        self.verifier = Verifier(roster)
        self.sessions: Any = None
        """The process's per-pair sessions once attached to its Zenoh session (a
        :class:`~swarmloc.net.pairing.Pairing`, :func:`~swarmloc.net.pairing.attach`): frames to a member it has a
        session with are MACed, and a frame is accepted only from its sender's process of this run. None: frames
        are signed, and opened whatever process of the sender signed them."""

    @classmethod
    def load(cls, key_file: str | os.PathLike[str], roster_file: str | os.PathLike[str], member: int) -> Auth:
        """``member``'s key and the team's roster from their files (ValueError naming what is wrong)."""
        roster = Roster.load(roster_file)
        if member not in roster.keys:
            raise ValueError(f"{member_name(member)} is not in the roster {roster_file}")
        return cls(roster, Signer(member, load_private(key_file)))

    def seal(self, key_expr: str, payload: bytes, to: int | None = None) -> bytes:
        """``payload`` framed for ``key_expr``: MACed for member ``to`` (default: the member whose inbox or query
        key it is) when this process has a session with it, else signed."""
        if self.signer is None:
            raise RuntimeError("this process has no key: it cannot send")
        if self.sessions is not None:
            return self.sessions.seal(key_expr, payload, to)
        return self.signer.seal(key_expr, payload)

    def open(self, key_expr: str, data: bytes, publication: bool = False) -> tuple[int, bytes]:
        return (self.verifier if self.sessions is None else self.sessions).open(key_expr, data, publication)

    def session_counts(self) -> dict[str, int]:
        """The per-pair sessions' counters (handshakes, renewals, twins...; empty when not attached)."""
        return {} if self.sessions is None else self.sessions.snapshot()


def signs_as(auth: Auth | None, member: int, who: str) -> None:
    """Check that ``auth`` holds ``member``'s own key, the one ``who`` signs what it sends with (None: an
    unauthenticated team, nothing to check): ValueError naming the key needed and the one held otherwise."""
    if auth is None or (auth.signer is not None and auth.signer.member == member):
        return
    held = "no key" if auth.signer is None else f"{member_name(auth.signer.member)}'s"
    raise ValueError(f"{who}: auth must hold {member_name(member)}'s own key to sign what it sends (it holds {held})")


def seal(auth: Auth | None, key_expr: str, payload: bytes, to: int | None = None) -> bytes:
    """``payload`` sealed for ``key_expr`` (and member ``to``: :meth:`Auth.seal`); as it is without ``auth``: an
    unauthenticated team."""
    return payload if auth is None else auth.seal(key_expr, payload, to)


def open_envelope(
    auth: Auth | None,
    key_expr: str,
    payload: bytes,
    team: str,
    roster: Container[int],
    *,
    to_robot: int | None = None,
    server_ok: bool = True,
    publication: bool = False,
) -> Envelope:
    """:func:`~swarmloc.net.schema.decode` a payload received on ``key_expr``, after opening its signed frame with
    ``auth`` (the sender the schema envelope names must be the one that signed). Raises
    :class:`~swarmloc.net.schema.Rejected` (:class:`AuthRejected` for the signature's checks)."""
    if auth is None:
        return decode(payload, team, roster, to_robot=to_robot, server_ok=server_ok)
    sender, inner = auth.open(key_expr, payload, publication)
    env = decode(inner, team, roster, to_robot=to_robot, server_ok=server_ok)
    if env.from_robot != sender:
        raise AuthRejected("sender_mismatch", f"signed by {member_name(sender)}, envelope from {env.from_robot}")
    return env


def note_refusal(counts: Counter[str], exc: Rejected, who: str, where: str, prefix: str = "") -> bool:
    """Count an :class:`AuthRejected` as ``<prefix>auth_<category>`` and log it with its reason (the first 5 of each
    category at WARNING, then every 1000th; the rest at DEBUG). False (nothing done) for another refusal."""
    category = getattr(exc, "category", None)
    if category is None:
        return False
    name = f"{prefix}auth_{category}"
    counts[name] += 1
    n = counts[name]
    level = logging.WARNING if n <= 5 or n % 1000 == 0 else logging.DEBUG
    log.log(level, "%s: refused a %s: %s (%s) [%s: %d]", who, where, exc.reason, getattr(exc, "detail", ""), name, n)
    return True


class Refusals:
    """What a receiver refuses, counted and logged in one way: each refusal as ``<prefix>rejected`` in ``counts`` and
    under its reason in ``reasons`` (at most 256 distinct: :func:`~swarmloc.node.accounting.reason_key`); an
    authentication failure also as ``<prefix>auth_<category>``, logged by :func:`note_refusal`; any other logged to
    ``logger`` as ``"<who>: <verb> a <where>: <reason>"``, the first of each of the first ``warn`` reasons at WARNING,
    the rest at DEBUG."""

    def __init__(self, counts: Counter[str], reasons: Counter[str], who: str, logger: logging.Logger, *,
                 verb: str = "dropped", prefix: str = "", warn: float = 20) -> None:  # fmt: skip
        self.counts, self.reasons, self.who, self.log = counts, reasons, who, logger
        self.verb, self.prefix, self.warn = verb, prefix, warn

    def __call__(self, reason: str, where: str = "message", exc: Rejected | None = None) -> None:
        """Count (and log) one refused ``where`` (a message, a query...) for ``reason``; ``exc``: the refusal raised."""
        self.counts[f"{self.prefix}rejected"] += 1
        key = reason_key(self.reasons, reason)
        self.reasons[key] += 1
        if exc is None or not note_refusal(self.counts, exc, self.who, where, self.prefix):
            level = logging.WARNING if self.reasons[key] == 1 and len(self.reasons) <= self.warn else logging.DEBUG
            self.log.log(level, "%s: %s a %s: %s", self.who, self.verb, where, key)


class TeamKeys:
    """The keys of a team started on one machine (``swarmloc team``): made in ``folder`` unless its ``roster.json``
    exists (then used as they are), or in a temporary folder (mode 0700) removed by :meth:`close`."""

    def __init__(self, robots: Iterable[int], folder: str | os.PathLike[str] | None = None) -> None:
        import tempfile

        self._temp = folder is None
        self.folder = Path(tempfile.mkdtemp(prefix="swarmloc-keys-") if folder is None else folder)
        self.roster_file = self.folder / "roster.json"
        robots = list(robots)
        if not self.roster_file.exists():
            make_team_keys(self.folder, robots)
        self.files = key_files(self.folder, robots)
        self.roster = Roster.load(self.roster_file)

    def args(self, member: int) -> list[str]:
        """``swarmloc node`` / ``swarmloc server`` options for ``member``: ``--key FILE --roster FILE``."""
        return ["--key", str(self.files[member]), "--roster", str(self.roster_file)]

    def auth(self, member: int) -> Auth:
        return Auth.load(self.files[member], self.roster_file, member)

    def close(self) -> None:
        if self._temp:
            import shutil

            shutil.rmtree(self.folder, ignore_errors=True)
