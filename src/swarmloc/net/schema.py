"""The wire schema: every Zenoh payload is one MessagePack-encoded :class:`Envelope` (msgspec), versioned.

An envelope names the schema version ``v``, the team, the sending robot (``from_robot``: ``-1`` for the belief
server or the team launcher), a per-sender sequence number ``seq`` (increasing over the sender's life), and a
``body``: one of the neighbour-exchange messages of :mod:`swarmloc.messages` (queries, answers, pairwise
updates: robot ids, key stamp and sub-key, revision, mean and covariance or the estimator's payload) or one of
the runtime messages below (a published :class:`Belief`, lockstep :class:`Progress`, a final :class:`Report`, and a
team estimator's :class:`Broadcast` with its :class:`BroadcastHead` and :class:`BroadcastRepair`, a robot's
world-frame wall :class:`Lines` for the belief server's map and the server's :class:`MapAnswer`).

:func:`decode` checks a received payload before anything reaches a node and says what is wrong: not MessagePack
or not the schema (with msgspec's path to the bad field), another schema version or team, a sender outside the
team's roster or impersonating another robot, a body addressed to somebody else or from a robot to itself,
non-finite numbers, a mean outside SE(2), a covariance that is not symmetric positive definite, a revision outside
``[-2, 2^31)``. Sizes are bounded while decoding, before a field is built: at most
:data:`~swarmloc.messages.MAX_FLOATS` numbers a field, :data:`~swarmloc.messages.MAX_TEXT` characters a text, 64 a
team's name, :data:`MAX_RAW_ITEMS` measurements a forward, :data:`MAX_COUNTERS` counters a report. Stale and
duplicate messages are caught where the state is: the node's history (``stale or duplicate answer``,
``duplicate update``) and the signed frame's replay window (:class:`swarmloc.net.auth.ReplayWindow`).

Who sent a payload is established before it is decoded, by its Ed25519 signature against the team's roster
(:mod:`swarmloc.net.auth`: the frame around the envelope); ``from_robot`` must name the signer.

Conventions: stamps in seconds of the source's (data) clock; SE(2) means as row-major 3x3 matrices and
covariances of the right-perturbation exponential coordinates (as in :mod:`swarmloc.messages`).
"""

from __future__ import annotations

import math
from collections.abc import Container, Sequence
from typing import Annotated

import msgspec

from swarmloc.events import Kind
from swarmloc.messages import (
    SCHEMA_VERSION,
    AnyMessage,
    BeliefAnswer,
    Floats,
    RdlState,
    RdlUpdate,
    TeamUpdate,
    Text,
    message_problem,
)

SERVER = -1
"""``from_robot`` of the belief server and the team launcher."""
MAX_REVISION = 1 << 31
"""Bound on a revision number (an answer's ``seq``, an update's ``based_on``, a belief's ``rev``): a node revises an
answer once per replay that changes it, far fewer times than this."""
MAX_COUNTERS = 4096
"""The most counters (and reasons) one :class:`Report` carries."""
Counts = Annotated[dict[Text, int], msgspec.Meta(max_length=MAX_COUNTERS)]


class Belief(msgspec.Struct, frozen=True, kw_only=True, tag="belief"):
    """A robot's belief at ``stamp`` [s]: ``final`` once no input the node may still receive can change it
    (its history has moved a horizon past ``stamp``); ``rev`` counts its revisions (a final one may follow a
    provisional one with different numbers)."""

    robot: int
    stamp: float
    rev: int = 0
    final: bool = False
    mean: Floats = ()
    cov: Floats = ()
    group: Text = "SE2"


def group_tag(b: object) -> str:
    """The wire name of a belief's group (``"SE2"`` or ``"SE3"``) for :class:`Belief`."""
    return "SE3" if b.group.dim == 6 else "SE2"  # type: ignore[attr-defined]


class Progress(msgspec.Struct, frozen=True, kw_only=True, tag="progress"):
    """``robot`` has read every source event keyed before ``(t, prio)`` (its next input: a detection group has
    priority 1, odometry 2; ``t = inf``: its source is exhausted); ``done``: it has also settled (no answer
    outstanding) and published its final beliefs. ``moved``: how many times the progress of a teammate it waits
    for advanced while behind its next input (modulo :data:`MAX_MOVED`): a node that waits repeats an unchanged
    progress, and while ``moved`` changes what it waits on moves, so it is not stalled
    (:meth:`~swarmloc.net.lockstep.Lockstep.check_lost`)."""

    robot: int
    t: float
    prio: int = 1
    done: bool = False
    moved: int = 0


class Report(msgspec.Struct, frozen=True, kw_only=True, tag="report"):
    """A node's counters when it stops (node counters and network counters, and the reasons behind them)."""

    robot: int
    stats: Counts = {}
    reasons: Counts = {}
    net: Counts = {}
    net_reasons: Counts = {}
    wall_s: float = 0.0
    cpu_s: float = 0.0


MAX_BROADCAST_N = 1 << 62
"""Bound on a broadcast number (numbers count a sender's broadcasts over its life, from 0)."""
MAX_MOVED = 1 << 62
"""Bound on :class:`Progress`'s ``moved`` (a count over the sender's life, from 0)."""
MAX_REPAIR = 256
"""The most broadcast numbers one :class:`BroadcastRepair` asks for."""
ALL = -1
"""``Broadcast.to`` of a broadcast published to the whole team (a repair names its one receiver)."""


class Broadcast(msgspec.Struct, frozen=True, kw_only=True, tag="broadcast"):
    """One update of a team estimator (``diekf``) for every teammate: ``robot``'s broadcast number ``n`` (0, 1, 2, ...
    over its life, one per broadcast: a receiver that sees a gap asks for the missing ones), published on
    ``robot/<robot>/broadcast`` (``to = -1``) or sent again to one teammate's inbox (``to``: a repair). ``update``:
    the :class:`~swarmloc.messages.TeamUpdate` with ``receiver = -1`` (each receiver reads it as addressed to
    itself); None in a repair: the sender no longer keeps broadcast ``n`` (it is beyond its buffer)."""

    robot: int
    n: int
    to: int = ALL
    update: TeamUpdate | None = None


class BroadcastHead(msgspec.Struct, frozen=True, kw_only=True, tag="broadcast_head"):
    """``robot`` has published broadcasts ``0 .. n - 1``, and every update it will broadcast for an exchange keyed
    before ``(t, prio, robot)`` is among them (announced on its broadcast key whenever that changes: a teammate
    waits for them before it fuses or answers anything keyed later, and sees the last ones missing if they were
    lost)."""

    robot: int
    n: int
    t: float = math.inf
    prio: int = 0


class BroadcastRepair(msgspec.Struct, frozen=True, kw_only=True, tag="broadcast_repair"):
    """``sender`` asks ``receiver`` (on its inbox) for its broadcasts ``first .. last`` again (at most
    :data:`MAX_REPAIR`); with ``head``, also for its :class:`BroadcastHead` (announced again on its broadcast key:
    ``sender`` has none of it), and the interval may be empty (``last = first - 1``)."""

    sender: int
    receiver: int
    first: int
    last: int
    head: bool = False


MAX_RAW_ITEMS = 512
"""The most measurements one :class:`Raw` forward carries."""


class RawOdometry(msgspec.Struct, frozen=True, array_like=True, tag="o"):
    """A forwarded odometry command of the forwarding robot: ``(v [m/s], w [rad/s])`` over ``[t0, t1]`` [s]."""

    t0: float
    t1: float
    v: float
    w: float


class RawDetection(msgspec.Struct, frozen=True, array_like=True, tag="d"):
    """A forwarded detection of the forwarding robot (:class:`~swarmloc.events.Detection` without its scoring-only
    truth): stamp [s], kind, ``z`` and its noise covariance ``cov`` (row-major), target id (None: anonymous). A kind
    is encoded as its name; a name that is no :class:`~swarmloc.events.Kind` is refused on decoding."""

    t: float
    kind: Kind
    z: Floats
    cov: Floats
    target: int | None = None
    target_is_robot: bool = True


class Raw(msgspec.Struct, frozen=True, kw_only=True, tag="raw"):
    """``robot``'s forward number ``n`` (0, 1, 2, ... over its run) to the server-hosted centralized estimator
    (:mod:`swarmloc.net.central`), on ``robot/<robot>/raw``: its next measurements in stamp order (``items``), and
    where its stream then stands: every measurement it will forward later is keyed at or after ``(upto, prio)``
    (``upto = inf``: it has forwarded everything); ``first`` [s]: its stream's first stamp; ``odometry`` and
    ``detections``: how many it has forwarded in forwards ``0 .. n`` (so that the server counts exactly what a
    lost forward carried). A forward with no items repeats where the stream stands (its end, until the server has
    reported)."""

    robot: int
    n: int
    first: float
    upto: float
    prio: int = 1
    odometry: int = 0
    detections: int = 0
    items: Annotated[tuple[RawOdometry | RawDetection, ...], msgspec.Meta(max_length=MAX_RAW_ITEMS)] = ()


class RawAck(msgspec.Struct, frozen=True, kw_only=True, tag="raw_ack"):
    """The server to ``robot`` (on ``server/ack``): it has every forward of ``robot`` below ``next`` and asks for
    ``missing`` again (at most :data:`MAX_REPAIR` numbers, each below the highest it has)."""

    robot: int
    next: int
    missing: Annotated[tuple[int, ...], msgspec.Meta(max_length=MAX_REPAIR)] = ()


MAX_LINES = 64
"""The most lines one :class:`Lines` message carries (a scan yields a handful; the bound is checked on decoding)."""
MAX_MAP_LINES = 4096
"""The most lines a :class:`MapAnswer` carries."""
LINE_FIELDS = 9
"""A line on the wire: ``rho, alpha, c_rr, c_ra, c_aa, x0, y0, x1, y1`` (world frame, [m] and [rad])."""
LINE_END_FIELDS = 4
"""Optional after them: ``v0, v1, k0, k1``: each end's variance along the line [m^2] and whether it is closed (1.0,
the wall ends there) or open (0.0); a line without them has open ends (:class:`swarmloc.mapping.LineMap`)."""
WireLine = Annotated[tuple[float, ...], msgspec.Meta(min_length=LINE_FIELDS, max_length=LINE_FIELDS + LINE_END_FIELDS)]


class Lines(msgspec.Struct, frozen=True, kw_only=True, tag="lines"):
    """Wall lines ``robot`` extracted from its range scan at ``stamp`` [s] and carried into the world frame with its
    final belief there (:func:`swarmloc.mapping.scan_observations`), in extraction order; each line is
    :data:`LINE_FIELDS` numbers: ``(rho, alpha)`` [m, rad], the covariance's ``c_rr, c_ra, c_aa``, the segment's end
    points. At most :data:`MAX_LINES`; published on ``robot/<robot>/lines`` for the belief server."""

    robot: int
    stamp: float
    lines: Annotated[tuple[WireLine, ...], msgspec.Meta(max_length=MAX_LINES)] = ()


class FusedLine(msgspec.Struct, frozen=True, kw_only=True):
    """One line of the server's map: ``line`` as in :class:`Lines`, the ``robots`` that saw it, ``n_obs``."""

    line: WireLine
    robots: Annotated[tuple[int, ...], msgspec.Meta(max_length=MAX_COUNTERS)] = ()
    n_obs: int = 1


class MapAnswer(msgspec.Struct, frozen=True, kw_only=True, tag="map"):
    """The belief server's fused line map (its reply to a map query): ``lines``, and ``observations``: how many
    line observations it has fused (from ``messages`` :class:`Lines` messages)."""

    lines: Annotated[tuple[FusedLine, ...], msgspec.Meta(max_length=MAX_MAP_LINES)] = ()
    observations: int = 0
    messages: int = 0


def line_problem(x: tuple[float, ...]) -> str | None:
    """Why one wire line is unusable (non-finite, covariance not SPD, end points equal), or None."""
    if not (_finite(x, LINE_FIELDS) or _finite(x, LINE_FIELDS + LINE_END_FIELDS)):
        return f"a line must be {LINE_FIELDS} or {LINE_FIELDS + LINE_END_FIELDS} finite numbers"
    if len(x) > LINE_FIELDS and not (min(x[9:11]) >= 0 and set(x[11:13]) <= {0.0, 1.0}):
        return "a line's end variances must be >= 0 and its end flags 0 or 1"
    c_rr, c_ra, c_aa = x[2:5]
    if not (c_rr > 0 and c_aa > 0 and c_rr * c_aa - c_ra * c_ra > 0):
        return "a line's covariance is not positive definite"
    if x[5] == x[7] and x[6] == x[8]:
        return "a line's end points are equal"
    return None


Body = (
    AnyMessage
    | Belief
    | Progress
    | Report
    | Broadcast
    | BroadcastHead
    | BroadcastRepair
    | Raw
    | RawAck
    | Lines
    | MapAnswer
)


class Envelope(msgspec.Struct, frozen=True, kw_only=True):
    v: int
    team: Annotated[str, msgspec.Meta(max_length=64)]
    from_robot: int
    seq: int
    body: Body


_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder(Envelope)


def encode(team: str, from_robot: int, seq: int, body: Body) -> bytes:
    return _encoder.encode(Envelope(v=SCHEMA_VERSION, team=team, from_robot=from_robot, seq=seq, body=body))


class Rejected(ValueError):
    """A received payload that is dropped; ``reason`` says why (counted and logged by the receiver)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def _finite(xs: tuple, n: int) -> bool:
    return len(xs) == n and all(math.isfinite(x) for x in xs)


def number_problem(b: Body) -> str | None:
    """Why a revision or priority of ``b`` is out of range (revisions in ``[-2, 2^31)``: -2 a node's own "not
    found", -1 the belief server's; priorities in ``[0, 3]``; a progress's ``moved`` in ``[0, 2^62)``), or None."""
    rev = b.seq if isinstance(b, BeliefAnswer | RdlState) else b.based_on if isinstance(b, RdlUpdate) else None
    rev = b.rev if isinstance(b, Belief) else rev
    if rev is not None and not -2 <= rev < MAX_REVISION:
        return f"{type(b).__name__}: revision {rev} outside [-2, 2^31)"
    if isinstance(b, Progress | BroadcastHead) and not 0 <= b.prio <= 3:
        return f"{type(b).__name__}: priority {b.prio} outside [0, 3]"
    if isinstance(b, Progress) and not 0 <= b.moved < MAX_MOVED:
        return f"Progress: moved {b.moved} outside [0, 2^62)"
    return None


def body_problem(b: Body) -> str | None:
    """Why a body's content is unusable (see the module docstring), or None."""
    why = number_problem(b)
    if why:
        return why
    if isinstance(b, Belief):
        if not math.isfinite(b.stamp):
            return "belief: non-finite stamp"
        if b.group == "SE2" and not (_finite(b.mean, 9) and _finite(b.cov, 9)):
            return "belief: mean and cov must be 9 finite numbers each"
        # the same SE(2) / SE(3) / SPD checks as an answer
        return message_problem(
            BeliefAnswer(sender=b.robot, receiver=b.robot, stamp=b.stamp, group=b.group, mean=b.mean, cov=b.cov)
        )
    if isinstance(b, Progress):
        return None if not math.isnan(b.t) else "progress: NaN time"
    if isinstance(b, Lines):
        return "lines: non-finite stamp" if not math.isfinite(b.stamp) else _lines_problem("lines", b.lines)
    if isinstance(b, MapAnswer):
        return _lines_problem("map", [fl.line for fl in b.lines])
    if isinstance(b, Report):
        return None
    if isinstance(b, Raw):
        return raw_problem(b)
    if isinstance(b, RawAck):
        ok = 0 <= b.next < MAX_BROADCAST_N and len(b.missing) <= MAX_REPAIR
        return None if ok and all(b.next <= n < MAX_BROADCAST_N for n in b.missing) else "raw ack: numbers out of range"
    if isinstance(b, Broadcast):
        if not 0 <= b.n < MAX_BROADCAST_N:
            return f"broadcast: number {b.n} outside [0, 2^62)"
        if b.update is None:
            return None if b.to != ALL else "broadcast: no update (only a repair may say a broadcast is gone)"
        u = b.update
        if u.sender != b.robot or u.receiver != ALL:
            return "broadcast: its update must be from the broadcasting robot to the team (receiver -1)"
        return message_problem(u)
    if isinstance(b, BroadcastHead):
        if math.isnan(b.t):
            return "broadcast head: NaN time"
        return None if 0 <= b.n < MAX_BROADCAST_N else f"broadcast head: count {b.n} outside [0, 2^62)"
    if isinstance(b, BroadcastRepair):
        if not 0 <= b.first <= b.last + int(b.head) and b.last < MAX_BROADCAST_N:
            return f"broadcast repair: numbers {b.first}..{b.last} are not an interval in [0, 2^62)"
        if b.last - b.first >= MAX_REPAIR:
            return f"broadcast repair: at most {MAX_REPAIR} numbers at once, asked {b.last - b.first + 1}"
        return None
    return message_problem(b)


def _lines_problem(what: str, lines: Sequence[tuple[float, ...]]) -> str | None:
    """Why the first unusable one of ``lines`` is (:func:`line_problem`), with its index, or None."""
    for i, x in enumerate(lines):
        why = line_problem(x)
        if why:
            return f"{what}: line {i}: {why}"
    return None


def raw_problem(b: Raw) -> str | None:
    """Why a :class:`Raw` forward is unusable: numbers out of range, stamps not finite or not in order, an item
    before where the stream stood, sizes of ``z`` and ``cov`` that do not fit the kind. (What a measurement says is
    the estimator's to judge: a bad one is rejected and counted there.)"""
    from swarmloc.sensors.models import MODELS

    if not 0 <= b.n < MAX_BROADCAST_N or b.odometry < 0 or b.detections < 0:
        return f"raw: number {b.n} or counts ({b.odometry}, {b.detections}) out of range"
    first_ok = math.isfinite(b.first) or (b.first == math.inf and not b.items)  # inf: a robot with nothing at all
    if not (first_ok and not math.isnan(b.upto) and b.prio in (1, 2)):
        return "raw: first stamp not finite, upto NaN, or prio not 1 (detections) or 2 (odometry)"
    if len(b.items) > MAX_RAW_ITEMS:
        return f"raw: {len(b.items)} items, at most {MAX_RAW_ITEMS}"
    last: tuple[float, int] = (-math.inf, 0)
    for it in b.items:
        if isinstance(it, RawOdometry):
            t, p, ok = it.t0, 2, all(math.isfinite(x) for x in (it.t0, it.t1, it.v, it.w)) and it.t1 >= it.t0
        else:
            m = MODELS.get(it.kind)
            d = None if m is None else m.size
            t, p, ok = it.t, 1, d is not None and len(it.z) == d and len(it.cov) == d * d and math.isfinite(it.t)
            ok = ok and all(math.isfinite(x) for x in (*it.z, *it.cov))
        if not ok:
            return f"raw: bad {type(it).__name__} at {t!r} (non-finite numbers, t1 < t0, or sizes that do not fit)"
        if (t, p) < last or t < b.first or (t, p) >= (b.upto, b.prio):
            return f"raw: item stamped {t!r} out of order (first {b.first!r}, upto {b.upto!r})"
        last = (t, p)
    return None


ROBOT_BODIES = Belief | Progress | Report | Broadcast | BroadcastHead | Raw | RawAck | Lines
"""The bodies that speak for the robot they name (``robot``); the others are neighbour messages (``sender`` to
``receiver``) or the server's map."""


def sender_of(b: Body) -> int:
    """The robot a body speaks for (the belief server, :data:`SERVER`, for its map)."""
    if isinstance(b, MapAnswer):
        return SERVER
    return b.robot if isinstance(b, ROBOT_BODIES) else b.sender


MAX_QUOTED = 80
"""The most characters of msgspec's message kept in a reason: it may quote a field of the payload whole (an unknown
kind: ``Invalid enum value '...'``)."""


def malformed(exc: Exception) -> str:
    """The reason for a payload msgspec refuses: its message (cut to :data:`MAX_QUOTED` characters) and the path to
    the field (``- at `$.body...```)."""
    what, at, path = str(exc).rpartition(" - at ")
    if not at:
        what, path = path, ""
    return f"malformed: {what if len(what) <= MAX_QUOTED else what[:MAX_QUOTED] + '...'}{at}{path}"


def decode(
    payload: bytes,
    team: str,
    roster: Container[int],
    to_robot: int | None = None,
    server_ok: bool = True,
) -> Envelope:
    """Decode and validate a payload for a node of ``roster`` (``to_robot``: the receiving robot; a neighbour
    message addressed to another robot, or from the receiving robot to itself, is refused, as the node itself
    refuses them: :func:`swarmloc.node.protocol.refusal`). Raises :class:`Rejected` with the reason."""
    try:
        env = _decoder.decode(payload)
    except (msgspec.DecodeError, msgspec.ValidationError) as exc:
        raise Rejected(malformed(exc)) from None
    if env.v != SCHEMA_VERSION:
        raise Rejected(f"schema version {env.v}, this node speaks {SCHEMA_VERSION}")
    if env.team != team:
        raise Rejected(f"message for team {env.team!r}, this is team {team!r}")
    if env.from_robot not in roster and not (server_ok and env.from_robot == SERVER):
        raise Rejected(f"sender {env.from_robot} is outside the team's roster")
    b = env.body
    if env.from_robot != SERVER and sender_of(b) != env.from_robot:
        raise Rejected(f"robot {env.from_robot} sent a message in the name of robot {sender_of(b)}")
    own = isinstance(b, MapAnswer) or (isinstance(b, Report) and b.robot == SERVER)  # the server's own
    if env.from_robot == SERVER and not own and sender_of(b) not in roster:
        raise Rejected(f"server message about robot {sender_of(b)}, outside the team's roster")
    if to_robot is not None and isinstance(b, Lines | MapAnswer):
        raise Rejected(f"{type(b).__name__} is for the belief server's map, not for robot {to_robot}")
    if to_robot is not None and isinstance(b, Broadcast):
        if b.to not in (ALL, to_robot):
            raise Rejected(f"broadcast repair addressed to robot {b.to}, received by robot {to_robot}")
        if b.robot == to_robot:
            raise Rejected(f"broadcast of robot {b.robot} received by itself")
    elif to_robot is not None and isinstance(b, BroadcastHead) and b.robot == to_robot:
        # its own head played back to it (a replay on its own key): taken, it would ask itself for repairs
        raise Rejected(f"broadcast head of robot {b.robot} received by itself")
    elif to_robot is not None and not isinstance(b, ROBOT_BODIES | MapAnswer):  # a neighbour message
        if b.receiver != to_robot:
            raise Rejected(f"{type(b).__name__} addressed to robot {b.receiver}, received by robot {to_robot}")
        if b.sender == b.receiver:
            raise Rejected(f"{type(b).__name__} addressed from robot {b.sender} to itself")
    why = body_problem(b)
    if why:
        raise Rejected(why)
    return env
