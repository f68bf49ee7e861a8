"""The Zenoh side of a :class:`~swarmloc.net.process.NetNode`: what it declares on its session, and undeclares.

Everything received is put on the node's one queue (``inbound.intake``, within its budgets:
:mod:`swarmloc.net.intake`) as ``(kind, sample)`` and handled on the node's thread (:mod:`swarmloc.net.inbound`):
queries on ``robot/<id>/query``, pushed messages on ``robot/<id>/inbox``, the ``progress`` of the teammates its
lockstep waits for (:func:`~swarmloc.net.lockstep.watched`), and
liveliness changes under ``alive``. It publishes its ``belief`` and
``progress`` (a smoother's ``delayed`` output too; and, with ``ros_domain``, a ROS 2 pose topic in rmw_zenoh's
layout, with the node's and the publisher's rmw_zenoh liveliness tokens: :mod:`swarmloc.net.rosgraph`), and holds
its liveliness token. With ``auth`` it first answers the per-pair handshake, and makes a session with every member
up before it declares its token (:mod:`swarmloc.net.pairing`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

from swarmloc.net.auth import Auth
from swarmloc.net.teamlink import Presence
from swarmloc.net.transport import alive_key, block, robot_key, undeclare_all

PUBLISHED = ("belief", "progress", "delayed", "lines")
"""The robot's own keys it publishes on (each declared once opened; ``delayed``, ``lines`` only where it has them)."""


class Wiring:
    """Part of :class:`~swarmloc.net.process.NetNode`: opening and closing its Zenoh declarations on ``session``
    for robot ``robot`` of team ``team`` (keys under ``scope``), and publishing on its own keys.

    ``offer``: takes ``(kind, sample)`` of everything received, within the node's budgets (its
    :class:`~swarmloc.net.intake.Intake`); ``env``: ``env(body, key)``, the signed envelope of a message
    (:meth:`~.outbound.Envelopes.seal`); ``auth``: the per-pair sessions to attach (None: unauthenticated);
    ``mates``: the teammates whose broadcasts it hears (``["*"]``: all; None: a node without broadcasts);
    ``watched``: the teammates whose progress it hears (``["*"]``: all); both as opened (then :meth:`hear`);
    ``delayed``, ``lines``: whether it publishes a smoother's delayed output and scans' lines; ``ros_domain``: the
    ROS domain its beliefs are published in too (None: not)."""

    def __init__(
        self,
        session: Any,
        scope: str,
        team: str,
        robot: int,
        offer: Callable[[tuple[str, Any]], Any],
        env: Callable[[Any, str], bytes],
        *,
        auth: Auth | None = None,
        mates: Sequence[str] | None = None,
        watched: Sequence[str] = ("*",),
        delayed: bool = False,
        lines: bool = False,
        ros_domain: int | None = None,
    ) -> None:
        self.session, self.scope, self.team, self.robot = session, scope, team, robot
        self.offer, self.env, self.mates, self.watched = offer, env, mates, watched
        self.delayed, self.lines, self.ros_domain = delayed, lines, ros_domain
        self.presence = Presence(session, scope, auth)
        """Its joining and leaving the team; what it declares (:attr:`~.teamlink.Presence.decl`) is undeclared by
        :meth:`close`."""
        self.block: Any = None
        """``zenoh.CongestionControl.BLOCK`` once opened (zenoh is imported lazily): what it sends is never dropped."""
        self.pub: dict[str, Any] = dict.fromkeys(PUBLISHED)
        """The publisher of each of the robot's own keys (:data:`PUBLISHED`), once opened."""
        self._ros_pub: Any = None
        self._ros_graph: Any = None
        self._ros_gid = b""
        self._ros_seq = 0
        self._subs: dict[tuple[str, str], Any] = {}  # (kind, robot): the subscriber of a teammate's key (:meth:`hear`)

    def open(self) -> None:
        """Declare the node's queryable, subscribers, publishers and liveliness token on its session."""
        self.block = block()  # never drop a belief, a progress announcement or a push

        s, team, r = self.session, self.scope, self.robot  # keys: the team's scope (its name, and the run's id)
        p = self.presence
        p.join()  # the per-pair handshake answered before anything else is declared
        put = self.offer  # within the budgets of what a node takes in (:mod:`.intake`)
        p.decl.append(s.declare_queryable(robot_key(team, r, "query"), handler=lambda q: put(("query", q))))
        p.decl.append(s.declare_subscriber(robot_key(team, r, "inbox"), handler=lambda x: put(("inbox", x))))
        # the teammates' progress (lockstep's: :func:`~swarmloc.net.lockstep.watched`) and broadcasts (a team
        # estimator: :mod:`swarmloc.net.broadcast`; diekf in clusters: its cluster's only, each a key of its own, so
        # that what a node takes in is flat in the team's size)
        self.hear("progress", self.watched)
        self.hear("broadcast", self.mates or ())
        p.decl.append(
            s.liveliness().declare_subscriber(alive_key(team), history=True, handler=lambda x: put(("alive", x)))
        )
        for kind in ("belief", "progress", *(["delayed"] if self.delayed else []), *(["lines"] if self.lines else [])):
            self.pub[kind] = s.declare_publisher(robot_key(team, r, kind), congestion_control=self.block)
        if self.ros_domain is not None:
            self._open_ros(self.ros_domain)
        p.announce(r)

    def hear(self, kind: str, robots: Sequence[str]) -> None:
        """Subscribe to the ``kind`` key (``progress``, ``broadcast``) of each of ``robots`` (``"*"``: all) not
        subscribed yet, and undeclare those of the others; not this session's own: verified for nothing."""
        import zenoh

        want = set(robots)
        for k, m in [k for k in self._subs if k[0] == kind and k[1] not in want]:
            undeclare_all([self._subs.pop((k, m))])
        for m in robots:
            if (kind, m) not in self._subs:
                self._subs[kind, m] = self.session.declare_subscriber(
                    robot_key(self.scope, m, kind),
                    handler=lambda x, kind=kind: self.offer((kind, x)),
                    allowed_origin=zenoh.Locality.REMOTE,
                )  # fmt: skip

    def heard(self, kind: str) -> list[str]:
        """The teammates whose ``kind`` key it subscribes to now (:meth:`hear`)."""
        return sorted(m for k, m in self._subs if k == kind)

    def _open_ros(self, domain: int) -> None:
        """The ROS 2 pose publisher (rmw_zenoh's key layout) and the node's and publisher's graph tokens."""
        import hashlib

        from swarmloc.net import ros
        from swarmloc.net.rosgraph import RosGraph  # in the ROS graph: ros2 node list / topic list see it

        # the ROS topic names the team, not the run: a run id may start with a digit, which ROS names refuse
        self.ros_topic = f"/swarmloc/{self.team.replace('-', '_')}/robot{self.robot}/pose"
        key = ros.ros_key(self.ros_topic, domain)
        self._ros_pub = self.session.declare_publisher(key, congestion_control=self.block)
        self._ros_gid = hashlib.blake2b(key.encode(), digest_size=16).digest()
        self._ros_seq = 0
        self._ros_graph = RosGraph(
            self.session, domain, f"/swarmloc/{self.team.replace('-', '_')}", f"robot{self.robot}"
        )
        self._ros_graph.publisher(self.ros_topic, ros.DDS_TYPE_NAME, ros.type_hash())

    def key(self, kind: str) -> str:
        """This robot's ``kind`` key (``belief``, ``progress``, ``broadcast``...)."""
        return robot_key(self.scope, self.robot, kind)

    def put(self, kind: str, body: Any) -> None:
        """Sign ``body`` and publish it on this robot's ``kind`` key (one of :data:`PUBLISHED`)."""
        self.pub[kind].put(self.env(body, self.key(kind)))

    def publisher(self, kind: str) -> Any:
        """The publisher of this robot's ``kind`` key: one of :data:`PUBLISHED` once opened, another (a team
        estimator's ``broadcast``) declared on first use."""
        if self.pub.get(kind) is None:
            self.pub[kind] = self.session.declare_publisher(self.key(kind), congestion_control=self.block)
            self.presence.decl.append(self.pub[kind])
        return self.pub[kind]

    def put_ros(self, t: Any, b: Any) -> None:
        """Publish belief ``b`` (a group Gaussian) at time ``t`` on the ROS pose topic, if there is one."""
        if self._ros_pub is None:
            return
        from swarmloc.net import ros

        self._ros_seq += 1  # rmw_zenoh drops samples without its attachment (sequence, source time, gid)
        att = ros.ros_attachment(self._ros_seq, time.time_ns(), self._ros_gid)
        self._ros_pub.put(ros.to_cdr(ros.pose_message(t, b.mean, b.cov)), attachment=att)

    def close(self, last: Callable[[], Any] | None = None) -> None:
        """Undeclare everything :meth:`open` declared (the session itself belongs to the caller), once ``last()``
        has sent the node's last messages (:meth:`~.teamlink.Presence.leave`)."""
        self.presence.decl += self._subs.values()  # undeclared with the rest, once the last messages are sent
        self._subs.clear()
        self.presence.leave(last, f"robot {self.robot}")
        if self._ros_graph is not None:
            self._ros_graph.close()
