"""The belief server of the book chapter: it stores every robot's Gaussian and answers queries about them.

:class:`BeliefServer` is the store (no I/O, usable in-process): per robot a bounded history of
:class:`~swarmloc.net.schema.Belief` messages by stamp, the newest revision of each kept. It answers a
:class:`~swarmloc.messages.BeliefQuery` for robot ``j`` at stamp ``t`` with ``j``'s stored belief at the latest
stamp ``<= t`` no older than ``max_age`` s, **as stored** (the server has no odometry, so it does not predict; the
answer's ``reason`` says which stamp it is and ``seq`` is -1, so a real answer from ``j`` replaces it). A node
asks it when a neighbour does not answer in time, and a restarted node asks it for its own latest belief.

:class:`ServerProcess` puts it behind Zenoh: it subscribes to every robot's ``belief`` key and declares the
queryable ``swarmloc/<team>/server/query`` (a ``BeliefQuery`` in the payload; or the selector parameter
``latest=<robot>``, answered with that robot's newest stored :class:`~swarmloc.net.schema.Belief`). With ``auth``
(:mod:`swarmloc.net.auth`) it stores only beliefs signed by the robot they are of, answers only queries signed by
the robot that asks, and signs its replies as the server; refusals are counted ``auth_<category>`` and logged, and
its counters are logged when it stops.

With ``hosted`` (a :class:`~swarmloc.net.central.Fusion`: ``swarmloc server --estimator cekf|iekf|fej``) it also
runs the team's centralized estimator on the raw measurements the robots forward on ``robot/<id>/raw`` (each
forward accepted only if signed by robot ``id``, refusals counted as above), asks a robot again for forwards
missing from its numbers (``server/ack``), stores its final beliefs, publishes them on ``server/belief`` and, once
every robot's stream has ended, its report on ``server/report`` (again every second while it runs, for a robot or
collector that missed it).
**Line map** (the chapter's line fusion on the server). :class:`MapStore` keeps every robot's world-frame wall
lines (:class:`~swarmloc.net.schema.Lines`, published on ``robot/<id>/lines`` by a node with a range finder; with
``auth`` only those signed by the robot whose key they are on) and fuses them into one
:class:`~swarmloc.mapping.LineMap` in a fixed order, ``(stamp, robot, line index)``, whatever order they arrive in
(a message that arrives behind one already fused makes the map be rebuilt at the next query), so the server's map
is the in-process fusion of the same lines. A query ``swarmloc/<team>/server/query?map`` is answered with the fused
map (:class:`~swarmloc.net.schema.MapAnswer`, signed by the server; like ``latest=`` it needs no signature: the map
is no secret). With ``map_out`` the map is saved as GeoJSON when the server stops.
"""

from __future__ import annotations

import bisect
import logging
import math
import os
import queue
import threading
import time
from collections import Counter
from collections.abc import Iterable
from typing import Any

import msgspec
import numpy as np

from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.mapping import LineMap, LineObservation
from swarmloc.messages import BeliefAnswer, BeliefQuery, flat
from swarmloc.net.auth import Refusals, open_envelope, seal
from swarmloc.net.intake import SERVER_BUDGET, Intake, vouch_for
from swarmloc.net.schema import (
    MAX_MAP_LINES,
    SERVER,
    Belief,
    FusedLine,
    Lines,
    MapAnswer,
    Raw,
    Rejected,
    encode,
    group_tag,
)
from swarmloc.net.teamlink import Presence, TeamLink
from swarmloc.net.transport import block, robot_key, server_key

__all__ = ["BeliefServer", "MapStore", "ServerProcess", "linemap_of", "observations_of", "wire_line"]

log = logging.getLogger(__name__)


class BeliefServer:
    """Latest Gaussians of every robot, ``history`` stamps per robot (oldest dropped first)."""

    def __init__(self, roster: Iterable[int] | None = None, history: int = 2000, max_age: float = 1.0) -> None:
        if history < 1:
            raise ValueError("BeliefServer: history must be >= 1")
        self.roster = None if roster is None else frozenset(roster)
        self.history = history
        self.max_age = max_age
        self._stamps: dict[int, list[float]] = {}
        self._beliefs: dict[int, dict[float, Belief]] = {}
        self.counts: Counter[str] = Counter()

    def store(self, b: Belief) -> bool:
        """Keep ``b`` unless it is of a robot outside the roster or not newer than the revision stored."""
        if self.roster is not None and b.robot not in self.roster:
            self.counts["rejected_unknown_robot"] += 1
            return False
        stamps = self._stamps.setdefault(b.robot, [])
        beliefs = self._beliefs.setdefault(b.robot, {})
        old = beliefs.get(b.stamp)
        if old is not None and (old.rev > b.rev or (old.rev == b.rev and (old.final or not b.final))):
            self.counts["stale"] += 1
            return False
        if old is None:
            bisect.insort(stamps, b.stamp)
        beliefs[b.stamp] = b
        self.counts["stored"] += 1
        while len(stamps) > self.history:
            del beliefs[stamps.pop(0)]
        return True

    def put(self, robot: int, t: float, belief: GroupGaussian, final: bool = True) -> bool:
        """Store an SE(2) belief of ``robot`` at ``t`` [s] (in-process use)."""
        b = Belief(robot=robot, stamp=float(t), final=final, mean=flat(belief.mean), cov=flat(belief.cov),
                   group=group_tag(belief))  # fmt: skip
        return self.store(b)

    def robots(self) -> list[int]:
        return sorted(r for r, s in self._stamps.items() if s)

    def latest(self, robot: int) -> Belief | None:
        s = self._stamps.get(robot)
        return self._beliefs[robot][s[-1]] if s else None

    def at(self, robot: int, t: float) -> Belief | None:
        """The stored belief of ``robot`` at the latest stamp ``<= t`` (None if none, or older than ``max_age``)."""
        s = self._stamps.get(robot)
        if not s:
            return None
        i = bisect.bisect_right(s, t)
        if i == 0 or t - s[i - 1] > self.max_age:
            return None
        return self._beliefs[robot][s[i - 1]]

    def gaussian(self, robot: int, t: float) -> GroupGaussian | None:
        b = self.at(robot, t)
        if b is None:
            return None
        return GroupGaussian(SE2, np.reshape(b.mean, (3, 3)), np.reshape(b.cov, (3, 3)), validate=False)

    def answer(self, q: BeliefQuery) -> BeliefAnswer:
        """Answer for robot ``q.receiver`` at ``q.stamp`` (revision -1; ``found=False`` with the reason if none)."""
        self.counts["queries"] += 1
        b = self.at(q.receiver, q.stamp)
        common: dict[str, Any] = dict(sender=q.receiver, receiver=q.sender, stamp=q.stamp, sub=q.sub, seq=-1)
        if b is None:
            self.counts["not_found"] += 1
            why = f"belief server: no belief of robot {q.receiver} within {self.max_age:g} s"
            return BeliefAnswer(found=False, reason=why, **common)
        self.counts["answered"] += 1
        return BeliefAnswer(
            mean=b.mean, cov=b.cov, reason=f"belief server: stored belief at {b.stamp:.3f} s (not predicted)", **common
        )


def observations_of(msg: Lines) -> list[LineObservation]:
    """The :class:`~swarmloc.mapping.LineObservation` of each line of ``msg``, in order."""
    out = []
    for x in msg.lines:
        cov = np.array([[x[2], x[3]], [x[3], x[4]]])
        end: dict[str, Any] = {} if len(x) < 13 else {"end_var": (x[9], x[10]), "closed": (x[11] == 1.0, x[12] == 1.0)}
        out.append(LineObservation(x[0], x[1], cov, np.reshape(x[5:9], (2, 2)), msg.robot, msg.stamp, **end))
    return out


def wire_line(
    rho: float,
    alpha: float,
    cov: np.ndarray,
    ends: np.ndarray,
    end_var: tuple[float, float] | None = None,
    closed: tuple[bool, bool] = (False, False),
) -> tuple[float, ...]:
    """A line as :data:`~swarmloc.net.schema.LINE_FIELDS` numbers (``rho, alpha, c_rr, c_ra, c_aa, x0, y0, x1, y1``),
    with ``end_var``: four more (``v0, v1, k0, k1``: the ends' variances and closed flags)."""
    x = (float(rho), float(alpha), float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1]), *map(float, np.ravel(ends)))
    if end_var is None:
        return x
    return (*x, float(end_var[0]), float(end_var[1]), float(bool(closed[0])), float(bool(closed[1])))


def linemap_of(answer: MapAnswer) -> LineMap:
    """A :class:`LineMap` holding the lines of a server's ``answer`` (to save or draw it)."""
    from swarmloc.mapping import MapLine

    lm = LineMap()
    for fl in answer.lines:
        x = fl.line
        cov = np.array([[x[2], x[3]], [x[3], x[4]]])
        ln = MapLine(x[0], x[1], cov, 0.0, 0.0, set(fl.robots), fl.n_obs)
        s = ln.project(np.reshape(x[5:9], (2, 2)))
        ln.s0, ln.s1 = float(s.min()), float(s.max())
        lm.lines.append(ln)
    return lm


class MapStore:
    """The server's line map: every robot's :class:`Lines` (one message per robot and stamp; at most ``max_obs``
    line observations), fused in ``(stamp, robot, index)`` order into a :class:`LineMap` (``map_kw``)."""

    def __init__(self, roster: Iterable[int] | None = None, max_obs: int = 200_000, **map_kw: Any) -> None:
        self.roster = None if roster is None else frozenset(roster)
        self.max_obs = max_obs
        self.map_kw = map_kw
        self.map = LineMap(**map_kw)
        self._obs: list[tuple[tuple[float, int, int], LineObservation]] = []
        self._fused = 0  # observations (a prefix of ``_obs``) already in ``map``
        self._seen: set[tuple[int, float]] = set()
        self.messages = 0
        self.counts: Counter[str] = Counter()

    def store(self, msg: Lines) -> bool:
        """Keep ``msg``'s lines unless its robot is outside the roster, it repeats a (robot, stamp) already stored,
        a line is unusable (the whole message is refused) or the store is full; counted either way."""
        if self.roster is not None and msg.robot not in self.roster:
            self.counts["lines_unknown_robot"] += 1
            return False
        if (msg.robot, msg.stamp) in self._seen:
            self.counts["lines_duplicate"] += 1
            return False
        if not msg.lines:  # a node publishes none for a scan without lines: remembered, it would cost without bound
            self.counts["lines_empty"] += 1
            return False
        if len(self._obs) + len(msg.lines) > self.max_obs:
            self.counts["lines_full"] += 1
            return False
        obs = observations_of(msg)
        try:
            for o in obs:
                o.check()
        except ValueError:
            self.counts["lines_unusable"] += 1
            return False
        self._seen.add((msg.robot, msg.stamp))
        for i, o in enumerate(obs):
            key = (msg.stamp, msg.robot, i)
            at = bisect.bisect_left(self._obs, key, key=lambda e: e[0])
            if at < self._fused:
                self._fused = -1  # arrived behind the fused prefix: rebuild at the next query
                self.counts["lines_out_of_order"] += 1
            self._obs.insert(at, (key, o))
        self.messages += 1
        self.counts["lines_stored"] += len(obs)
        return True

    def current(self) -> LineMap:
        """The map of every line stored, fused in order (incrementally, or rebuilt after an out-of-order one)."""
        if self._fused < 0:
            self.map, self._fused = LineMap(**self.map_kw), 0
            self.counts["map_rebuilt"] += 1
        for _, o in self._obs[self._fused :]:
            self.map.offer(o)
        self._fused = len(self._obs)
        return self.map

    def answer(self) -> MapAnswer:
        """The current map as a :class:`MapAnswer` (its first :data:`MAX_MAP_LINES` lines)."""
        lm = self.current()
        lines = tuple(
            FusedLine(line=wire_line(ln.rho, ln.alpha, ln.cov, ln.endpoints()), robots=tuple(sorted(ln.robots)),
                      n_obs=ln.n_obs)
            for ln in lm.lines[:MAX_MAP_LINES]
        )  # fmt: skip
        return MapAnswer(lines=lines, observations=len(self._obs), messages=self.messages)


class ServerProcess:
    """:class:`BeliefServer` on its team's ``link`` (:class:`~swarmloc.net.teamlink.TeamLink`: the Zenoh session, the
    team's name, run id and robots, and the server's key)."""

    def __init__(
        self,
        link: TeamLink,
        server: BeliefServer | None = None,
        hosted: Any = None,
        map_out: str | os.PathLike[str] | None = None,
    ) -> None:
        link.signing_as(SERVER, "ServerProcess")
        self.session, self.team, self.auth = link.session, link.team, link.auth
        self.scope, self.roster = link.scope, link.roster
        self.server = server if server is not None else BeliefServer(self.roster)
        self.maps = MapStore(self.roster)
        self.map_out = map_out
        self.counts: Counter[str] = Counter()
        self.reasons: Counter[str] = Counter()
        self._reject = Refusals(self.counts, self.reasons, "belief server", log, warn=0)
        """Counts (and logs) a message dropped, for its reason (:class:`~swarmloc.net.auth.Refusals`)."""
        self._q = Intake(self.roster, SERVER_BUDGET, signed=self.auth is not None, team_size=len(self.roster),
                         vouch=None if self.auth is None else vouch_for(self.auth))  # fmt: skip
        """What the server receives, within its budgets (:mod:`swarmloc.net.intake`)."""
        self._stop = threading.Event()
        self.hosted = hosted
        self._reported = -math.inf  # when the hosted estimator's report was last published (monotonic)
        self._cpu0 = self._wall0 = 0.0

    def stop(self) -> None:
        self._stop.set()
        self._q.put(("wake", None))

    def run(self, max_wall: float | None = None) -> None:
        """Serve until :meth:`stop` (or ``max_wall`` s)."""
        s, put = self.session, self._q.offer  # within the server's budgets (:mod:`swarmloc.net.intake`)
        p = Presence(s, self.scope, self.auth)
        p.join()
        p.decl += [
            s.declare_subscriber(robot_key(self.scope, "*", "belief"), handler=lambda x: put(("belief", x))),
            s.declare_subscriber(robot_key(self.scope, "*", "lines"), handler=lambda x: put(("lines", x))),
            s.declare_queryable(server_key(self.scope), handler=lambda q: put(("query", q))),
        ]
        if self.hosted is not None:
            p.decl += [s.declare_subscriber(robot_key(self.scope, "*", w), handler=lambda x, w=w: put((w, x)))
                       for w in ("raw", "progress")]  # fmt: skip
            self._pubs = {w: s.declare_publisher(server_key(self.scope, w), congestion_control=block())
                          for w in ("belief", "report", "ack")}  # fmt: skip
            p.decl += list(self._pubs.values())
        p.announce("server")
        end = None if max_wall is None else time.monotonic() + max_wall
        self._wall0, self._cpu0 = time.perf_counter(), time.process_time()
        try:
            while not self._stop.is_set() and (end is None or time.monotonic() < end):
                try:
                    kind, x = self._q.get(timeout=0.05 if self.hosted is not None else 0.2)
                except queue.Empty:
                    kind = None
                self._q.fold(self.counts, self.reasons)
                try:
                    if kind is not None:
                        self._handle(kind, x)
                    if self.hosted is not None and (kind is None or self._q.empty()):
                        self._host()
                except Exception as exc:  # never die of one message
                    log.exception("belief server: error on %s", kind)
                    self._reject(f"internal error: {type(exc).__name__}")
        finally:
            p.leave(counts=self.counts)
            if self.map_out is not None:
                try:
                    self.maps.current().save_geojson(self.map_out)
                except Exception:  # noqa: BLE001 - stopping: say so, nothing else to do
                    log.exception("belief server: could not save the map to %s", self.map_out)
            level = logging.WARNING if self.counts["rejected"] else logging.INFO
            log.log(level, "belief server: stopped; %s; store %s; map %s; refused %s", dict(self.counts),
                    dict(self.server.counts), dict(self.maps.counts), dict(self.reasons))  # fmt: skip
            if self.hosted is not None:
                log.log(level, "belief server: hosted %s: %s", self.hosted.node.name, dict(self.hosted.counts))

    def _host(self) -> None:
        """Fuse what the forwards allow; store and publish the beliefs that became final; the report at the end."""
        h = self.hosted
        for b in h.pump():
            self.server.store(b)
            self._pubs["belief"].put(self._sealed(server_key(self.scope, "belief"), b))
        for ack in h.wanted():  # forwards missing: asked of their robot again
            self._pubs["ack"].put(self._sealed(server_key(self.scope, "ack"), ack))
        if h.done and time.monotonic() - self._reported >= 1.0:
            if self._reported == -math.inf:  # wall and CPU seconds from the server's start to the estimator's end
                log.info("belief server: hosted %s done: %s", h.node.name, dict(h.counts))
                self._took = (time.perf_counter() - self._wall0, time.process_time() - self._cpu0)
            self._reported = time.monotonic()
            rep = h.report(*self._took)
            rep = msgspec.structs.replace(rep, net={**rep.net, **self.counts},
                                          net_reasons={**rep.net_reasons, **self.reasons})  # fmt: skip
            self._pubs["report"].put(self._sealed(server_key(self.scope, "report"), rep))

    def _handle(self, kind: str, x: Any) -> None:
        if kind == "query":
            try:
                self._query(x)
            finally:
                x.drop()
            return
        if kind not in ("progress", "raw", "belief", "lines"):  # "wake": nothing to read
            return
        try:  # a publication
            env = open_envelope(self.auth, str(x.key_expr), x.payload.to_bytes(), self.team, self.roster,
                                server_ok=False, publication=True)  # fmt: skip
        except Rejected as exc:
            self._reject(exc.reason, "message", exc)
            return
        body = env.body
        if kind == "progress":  # a forwarding robot is alive (hosted estimator)
            self.hosted.hear(env.from_robot)
        elif kind == "raw" and isinstance(body, Raw):
            self.hosted.offer(body)
        elif kind == "belief" and isinstance(body, Belief):
            self.server.store(body)
        elif kind == "lines" and isinstance(body, Lines):
            if not self.maps.store(body):
                self._reject("lines not stored (see the map's counts)")
        else:
            self._reject(f"{type(body).__name__} on a {kind} key")

    def _query(self, q: Any) -> None:
        if q.parameters is not None and "map" in q.parameters:
            self.counts["map_queries"] += 1
            q.reply(q.key_expr, self._sealed(str(q.key_expr), self.maps.answer()))
            return
        latest = q.parameters.get("latest") if q.parameters is not None else None
        if latest is not None:
            try:
                robot = int(latest)
            except ValueError:
                self._reject(f"latest={latest!r} is not a robot id")
                q.reply_err(b"latest=<robot id>")
                return
            b = self.server.latest(robot)
            if b is None:
                q.reply_err(f"no belief of robot {robot}".encode())
            else:
                q.reply(q.key_expr, self._sealed(str(q.key_expr), b))
            return
        try:
            payload = q.payload.to_bytes() if q.payload is not None else b""
            env = open_envelope(self.auth, str(q.key_expr), payload, self.team, self.roster, server_ok=False)
        except Rejected as exc:
            self._reject(exc.reason, "message", exc)
            q.reply_err(exc.reason.encode()[:200])
            return
        if not isinstance(env.body, BeliefQuery):
            self._reject(f"{type(env.body).__name__} is not a belief query")
            q.reply_err(b"only BeliefQuery")
            return
        q.reply(q.key_expr, self._sealed(str(q.key_expr), self.server.answer(env.body), to=env.from_robot))

    def _sealed(self, key: str, body: Any, to: int | None = None) -> bytes:
        """``body`` signed by the server for ``key`` (MACed for robot ``to`` when in session with it)."""
        return seal(self.auth, key, encode(self.team, SERVER, 0, body), to)
