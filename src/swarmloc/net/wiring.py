"""The Zenoh side of a :class:`~swarmloc.net.process.NetNode`: what it declares on its session, and undeclares.

Everything received is put on the node's one queue (``_inq``, within its budgets: :mod:`swarmloc.net.intake`) as
``(kind, sample)`` and handled on the node's thread (:mod:`swarmloc.net.inbound`): queries on
``robot/<id>/query``, pushed messages on ``robot/<id>/inbox``, every teammate's ``progress``, and liveliness
changes under ``alive``. It publishes its ``belief`` and
``progress`` (a smoother's ``delayed`` output too; and, with ``ros_domain``, a ROS 2 pose topic in rmw_zenoh's
layout, with the node's and the publisher's rmw_zenoh liveliness tokens: :mod:`swarmloc.net.rosgraph`), and holds
its liveliness token. With ``auth`` it first answers the per-pair handshake, and makes a session with every member
up before it declares its token (:mod:`swarmloc.net.pairing`).
"""

from __future__ import annotations

import time
from typing import Any

from swarmloc.net.pairing import attach
from swarmloc.net.parts import NodeParts
from swarmloc.net.transport import alive_key, block, robot_key


class Wiring(NodeParts):
    """Part of :class:`~swarmloc.net.process.NetNode`: opening and closing its Zenoh declarations."""

    def _init_wiring(self) -> None:
        self._decl: list[Any] = []
        self._block: Any = None  # zenoh.CongestionControl.BLOCK once opened (zenoh is imported lazily)
        self._ros_pub: Any = None
        self._ros_graph: Any = None
        self._pub_belief: Any = None  # the publishers, once opened
        self._pub_progress: Any = None
        self._pub_delayed: Any = None  # declared for a smoother's delayed output only
        self._pub_lines: Any = None  # declared with scans only

    def _open(self) -> None:
        """Declare the node's queryable, subscribers, publishers and liveliness token on its session."""
        import zenoh

        self._block = block()  # never drop a belief, a progress announcement or a push

        s, team, r = self.session, self.scope, self.robot  # keys: the team's scope (its name, and the run's id)
        # per-pair sessions (:mod:`swarmloc.net.pairing`): answer the handshake before anything else is declared
        attach(self.auth, s, team, hello=False)
        put = self._inq.offer  # within the budgets of what a node takes in (:mod:`.intake`)
        self._decl.append(s.declare_queryable(robot_key(team, r, "query"), handler=lambda q: put(("query", q))))
        self._decl.append(s.declare_subscriber(robot_key(team, r, "inbox"), handler=lambda x: put(("inbox", x))))
        self._decl.append(  # the teammates' progress (not this session's own: it would be verified for nothing)
            s.declare_subscriber(
                robot_key(team, "*", "progress"),
                handler=lambda x: put(("progress", x)),
                allowed_origin=zenoh.Locality.REMOTE,
            )  # fmt: skip
        )
        self._decl.append(
            s.liveliness().declare_subscriber(alive_key(team), history=True, handler=lambda x: put(("alive", x)))
        )
        if self.broadcasts:  # the teammates' broadcasts (a team estimator: :mod:`swarmloc.net.broadcast`)
            # diekf in clusters: its cluster's only (each a key of its own), so that what a node takes in is flat
            # in the team's size; otherwise one subscription to every teammate's
            team_node: Any = self.node  # a team estimator's (diekf): its team, not declared on Node
            mates = [str(m) for m in team_node.team if m != r] if getattr(self.node, "cluster", 0) else ["*"]
            for m in mates:
                self._decl.append(
                    s.declare_subscriber(
                        robot_key(team, m, "broadcast"),
                        handler=lambda x: put(("broadcast", x)),
                        allowed_origin=zenoh.Locality.REMOTE,
                    )  # fmt: skip
                )
        self._pub_belief = s.declare_publisher(robot_key(team, r, "belief"), congestion_control=self._block)
        self._pub_progress = s.declare_publisher(robot_key(team, r, "progress"), congestion_control=self._block)
        if self.publishing.delayed is not None:  # a smoother's delayed output (:mod:`.publishing`)
            self._pub_delayed = s.declare_publisher(robot_key(team, r, "delayed"), congestion_control=self._block)
        if self.publishing.scans is not None:  # each scan's world lines, for the belief server's map
            self._pub_lines = s.declare_publisher(robot_key(team, r, "lines"), congestion_control=self._block)
        if self.settings.ros_domain is not None:
            import hashlib

            from swarmloc.net import ros

            # the ROS topic names the team, not the run: a run id may start with a digit, which ROS names refuse
            self.ros_topic = f"/swarmloc/{self.team.replace('-', '_')}/robot{r}/pose"
            key = ros.ros_key(self.ros_topic, self.settings.ros_domain)
            self._ros_pub = s.declare_publisher(key, congestion_control=self._block)
            self._ros_gid = hashlib.blake2b(key.encode(), digest_size=16).digest()
            self._ros_seq = 0
            from swarmloc.net.rosgraph import RosGraph  # in the ROS graph: ros2 node list / topic list see it

            domain = self.settings.ros_domain
            self._ros_graph = RosGraph(s, domain, f"/swarmloc/{self.team.replace('-', '_')}", f"robot{r}")
            self._ros_graph.publisher(self.ros_topic, ros.DDS_TYPE_NAME, ros.type_hash())
        if self.auth is not None:  # a session with every member up now, before the team hears of this process
            self.auth.sessions.hello_all()
        self._token = s.liveliness().declare_token(alive_key(team, r))

    def _put(self, kind: str, body: Any) -> None:
        """Sign ``body`` and publish it on this robot's ``kind`` key (``belief``, ``progress``, ``delayed``,
        ``lines``: each declared by :meth:`_open`)."""
        pub = {"belief": self._pub_belief, "progress": self._pub_progress, "delayed": self._pub_delayed,
               "lines": self._pub_lines}[kind]  # fmt: skip
        pub.put(self._env(body, robot_key(self.scope, self.robot, kind)))

    def _put_ros(self, t: Any, b: Any) -> None:
        """Publish belief ``b`` (a group Gaussian) at time ``t`` on the ROS pose topic, if there is one."""
        if self._ros_pub is None:
            return
        from swarmloc.net import ros

        self._ros_seq += 1  # rmw_zenoh drops samples without its attachment (sequence, source time, gid)
        att = ros.ros_attachment(self._ros_seq, time.time_ns(), self._ros_gid)
        self._ros_pub.put(ros.to_cdr(ros.pose_message(t, b.mean, b.cov)), attachment=att)

    def _close(self) -> None:
        """Undeclare everything :meth:`_open` declared (the session itself belongs to the caller)."""
        for d in [*self._decl, getattr(self, "_token", None)]:
            if d is not None:
                try:
                    d.undeclare()
                except Exception:  # noqa: BLE001 - closing: nothing left to do about it
                    pass
        self._decl.clear()
        if self.auth is not None and self.auth.sessions is not None:
            self.auth.sessions.close()
        if self._ros_graph is not None:
            self._ros_graph.close()
