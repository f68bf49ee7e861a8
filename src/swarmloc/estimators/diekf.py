"""The exact distributed invariant EKF (``"diekf"``): the centralized :class:`~swarmloc.estimators.iekf.InvariantEKF`,
computed by the robots themselves, with one broadcast per update.

Each robot keeps its own pose estimate ``x_i`` and world-frame error covariance ``P_ii``
(:mod:`swarmloc.kernels.invariant`) and a replica of every cross-covariance of the team ``Sigma_ab`` (``a != b``).
This is Kia, Rounds & Martinez's decoupled cooperative localization ("Cooperative localization for mobile agents",
IEEE Control Systems Magazine 2016) in world-frame errors, where it simplifies: the odometry step's error transition
is the identity, so a prediction only adds process noise to the robot's own ``P_ii`` and no cross-covariance
changes between updates (the Cartesian version must carry each robot's accumulated transition matrix).

An update of observer ``i`` detecting ``j`` (or a landmark: ``j = i``, ``H_j = 0``):

1. ``i`` asks ``j`` for ``(x_j, P_jj)`` at the detection's stamp (:class:`~swarmloc.messages.RdlStateQuery`, the
   same exchange as ``rdl``);
2. ``i`` forms ``S = H P H^T + R`` with ``Sigma_ij`` from its replica, gates, and broadcasts ``(H_i, H_j, S^-1,
   S^-1 r, P_ii, P_jj)`` (:class:`~swarmloc.messages.TeamUpdate`) to every teammate;
3. every robot ``a`` (``i`` included) computes ``Gamma_b = Sigma_bi H_i^T + Sigma_bj H_j^T`` for every ``b`` from
   its replica and the broadcast, corrects its own pose ``x_a <- exp(hat(Gamma_a S^-1 r)) x_a`` and covariance
   ``P_aa <- P_aa - Gamma_a S^-1 Gamma_a^T``, and its replica ``Sigma_ab <- Sigma_ab - Gamma_a S^-1 Gamma_b^T``
   (then symmetrized, ``Sigma_ba = Sigma_ab^T`` to the bit: apart, rounding parted the two blocks and clusters'
   covariance-intersection divisions inflated the part, docs/benchmarks.md).

Every robot applies the broadcasts in key order (the node's history replays a late one), so all replicas agree and
the estimates equal the centralized invariant EKF's (tested to 1e-9) with the same process noise. Where landmarks
are fused, each robot by default scales its own process noise online from its innovations (``adaptive="median"``,
:class:`~swarmloc.estimators.adaptive_noise.MedianScale`; a prediction only adds to ``P_ii``, so a scaled one changes
no cross-covariance and no replica); ``adaptive=False`` keeps the noise as given. Nothing is approximated: no
correlation is left untracked, which is what makes the filter consistent without landmarks, where ``rdl``'s pairwise
approximation of third-party correlations fails. The price is communication and memory: one broadcast of
``O(m^2)`` numbers to all ``n - 1`` teammates per fused detection, ``O(n^2)`` memory and flops per robot per
update, and a connected all-to-all channel (a lost broadcast leaves replicas different). Gated detections are
broadcast as empty updates, so that every teammate knows the exchange is settled and a replay that gates a
detection retracts what it sent before. Over the network each update is one broadcast to the team, numbered per
sender, lost ones repaired (:mod:`swarmloc.net.broadcast`).

**A lying teammate** (:mod:`swarmloc.node.trust`). A broadcast is applied only when its own normalized innovation
``nu^T S nu`` is within the gate (as the sender's gate held it) and, when scaled, it is a cluster's
covariance-intersection update of its sender alone; else it is refused (``updates_refused``, ``suspect_<sender>``;
three in a row quarantine the sender). One that would leave this robot's covariance not positive definite is not
applied (``updates_unusable``). A broadcast that passes moves a robot by at most ``sqrt(gamma_m)`` of its own standard
deviations. The check reads the broadcast alone, so every teammate refuses the same ones and the honest replicas stay
equal; a broadcast that one robot cannot apply leaves its replica apart from the others'.

**Clusters** (``cluster = K``, ``[filter] diekf_cluster``). The team is cut into clusters of ``K`` robots in id
order; each robot keeps the replica of its own cluster only and broadcasts to it, so memory is ``O(K^2)`` and the
work per detection ``O(K^2)`` per robot whatever the team's size. Inside a cluster the filter is exact; a robot
outside it is asked a ``BeliefQuery`` and its detection fused by covariance intersection
(:meth:`TeamProtocol.outsider`): consistent whatever the two clusters' correlation, one-sided (the
outsider is not updated), and conservative. Over the network a node subscribes to its cluster's broadcasts only
and its lockstep waits for theirs only (:mod:`swarmloc.net.broadcast`). ``K >= n`` is the exact filter. The
engine replays the clusters in one compiled loop (``run_engine(source, "diekf", backend="numba", cluster=K)``,
:mod:`swarmloc.engine.joint_clusters`). The accuracy cost and the cost per robot against team size:
``benchmarks/diekf_cluster.py``.

**Clusters that re-form** (``reform = period`` [s], ``[filter] diekf_reform``; with ``cluster = K``). As the robots
move, a robot may come to see another cluster's robots more than its own's. Every ``period`` s the team is cut again by
whom the robots saw (:mod:`swarmloc.estimators.cluster_reform`): a schedule computed from the recording, the same in
every node (:meth:`DistributedInvariantEKF.plan`, which the in-process runner calls; a live source has no schedule and
its clusters stay fixed). At a boundary ``T`` each node predicts its robot to ``T`` and starts its new cluster's replica
from the covariance-intersection bound of the pieces (the robots of one old cluster in it): ``blockdiag(Sigma_1 / w_1,
..., Sigma_m / w_m)``, each piece's exact correlations kept, none across pieces, its own ``P_ii / w``. A piece's
cross-covariances are in the replica of each of its robots; each sends its share to its new mates outside the piece
(:class:`~swarmloc.messages.ClusterPiece`, each pair once, by its lower id), and a receiver re-applies the boundary with
it (:class:`~swarmloc.estimators.cluster_reform.Reforming`: the boundary is a history entry keyed before every input
stamped ``T``). The nodes equal the centralized prototype ``benchmarks/diekf_reform.py`` (tests/test_cluster_reform.py).
Over the network (:mod:`swarmloc.net.lockstep`) a node reaches a boundary once nothing before it can still come, its
groups after it wait for the pieces, a piece made before a late input is sent again revised, and the node hears the
broadcasts of its clusters of the current period and the next only (an old mate until it settled what is keyed before
the boundary: :mod:`swarmloc.net.hearing`; a next period's mate's are dropped, counted ``broadcasts_other_cluster``):
the run equals the in-process one (tests/test_net_progress.py).

Anonymous detections (``association`` ``nearest`` or ``joint``): every teammate is asked with the
``RdlStateQuery`` keyed as the detection would be were it of that teammate
(:func:`~swarmloc.estimators.state_exchange.anonymous_sub`), and its belief before the scan with a ``BeliefQuery``,
from which the identity is chosen, as ``rdl`` does; the detection given a robot is
broadcast under that key, so where the identity is right the broadcast is the tagged run's. Every other teammate's
exchange is settled by an empty broadcast under its key (:meth:`TeamProtocol.settle`), as a gated
detection's: an answerer over the network waits for the broadcast keyed by the query it answered before it goes on.

**SE(3).** With an SE(3) initial belief the same node runs with 6-dof poses (the group picks the node's
:class:`~swarmloc.estimators.world_form.WorldForm` once, :data:`FORMS`). Body-twist odometry ``g+ = g Delta exp(w^)`` is
group-affine, so the world-frame error ``xi`` (``g = exp(xi^) g^``) still has the identity transition: a prediction adds
``Ad(g^+) Sigma_inc Ad(g^+)^T`` to ``P_ii`` and changes no cross-covariance. A relative pose ``"pose3"`` is autonomous
in this error: exactly ``g^_i z g^_j^-1 = exp(-xi_i^) exp(xi_j^) exp((Ad(g^_j) n)^)``, so the innovation ``r = log(g^_i
z g^_j^-1)`` has the constant Jacobians ``H_i = -I``, ``H_j = I`` and the noise ``Ad(g^_j) R_z Ad(g^_j)^T``
(:func:`~swarmloc.kernels.cartesian3.relative_pose3_world`); the team's unobservable rigid motion ``[I; I; ...]`` is
annihilated whatever the estimate (the body-frame error's are not, Huang et al. 2011). Point detections (``"rbe3"``,
``"bearing3"`` of a teammate or a known 3-D landmark) take the Cartesian Jacobians of
:class:`~swarmloc.sensors.models3.Model3` times :func:`~swarmloc.kernels.cartesian3.world_basis3`; a rigid motion of the
whole team moves no body-frame point of a teammate, so they too gain nothing along it. A broadcast carries ``n = 6``;
the correction is ``g <- exp(delta^) g``. On planar motion (poses in ``z = 0``, yaw only, planar twists and
block-diagonal noises) the planar part of the error follows the SE(2) filter (tests/test_se3_diekf.py). Clusters are
SE(2) only (the covariance-intersection weight is SE(2)'s)."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence
from typing import Any, ClassVar, Literal

import numpy as np

from swarmloc.estimators.adaptive_noise import scale_for
from swarmloc.estimators.cluster_reform import Boundary, Reforming, seen_schedule
from swarmloc.estimators.odometry_fault import FaultMonitor, broadcast_evidence, observer_evidence
from swarmloc.estimators.team_protocol import TeamProtocol
from swarmloc.estimators.world_form import FORMS, TeamState, world_step
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, SE3
from swarmloc.messages import (
    ClusterPiece,
    Message,
    TeamUpdate,
)
from swarmloc.motion.odocal import OdometryCalibration
from swarmloc.node import (
    FUSED,
    Group,
    Outcome,
    RobotNode,
)
from swarmloc.node.base import Reach
from swarmloc.node.keys import SubKey

log = logging.getLogger("swarmloc.node")

__all__ = ["FORMS", "DistributedInvariantEKF", "TeamState"]


class DistributedInvariantEKF(RobotNode):
    """Exact distributed invariant EKF (module docstring): the node's filter over its :class:`TeamProtocol`
    (:attr:`protocol`, which speaks the exchange: :class:`~swarmloc.node.robot.RobotNode` hands it the exchange's
    hooks). ``team``: every robot id of the team (``make_team`` passes it). ``cluster``: 0 (default)
    for the exact filter over the whole team, or ``K >= 1`` robots per cluster (module docstring, "Clusters"):
    replica and broadcasts over the robot's cluster only, covariance intersection with robots outside it. The
    exchange's queries are :class:`~swarmloc.estimators.state_exchange.StateQueries`' (``rdl``'s). ``adaptive``: the
    process noise scaled online from this robot's own innovations (:class:`~swarmloc.estimators.adaptive_noise.
    NoiseScale`, or ``"median"``, the default: :class:`~swarmloc.estimators.adaptive_noise.MedianScale`, only where
    landmarks are fused; :attr:`noise_scale`; ``[filter] diekf_adaptive``; False: the noise as given).
    ``odocal``: this robot's odometry scale and yaw-rate bias calibrated online from its own posteriors
    (:class:`~swarmloc.motion.odocal.OdometryCalibration`,
    :attr:`odometry`; SE(2) only; ``[filter] diekf_odocal``). ``fault``: an odometry fault of this robot detected
    from the mutual detections it takes part in, its covariance inflated
    (:class:`~swarmloc.estimators.odometry_fault.FaultMonitor`, :attr:`faults`; ``[filter] diekf_fault``)."""

    name = "diekf"
    lazy_odometry = True
    error_frame: ClassVar[str] = "world"
    update_types = (TeamUpdate,)
    lin_log: list[Any] | None = None
    groups: ClassVar[tuple[type, ...]] = (SE2, SE3)
    protocol: TeamProtocol

    def __init__(self, robot: int, initial: GroupGaussian, *, team: Sequence[int] = (), cluster: int = 0,
                 reform: float = 0.0, adaptive: bool | Literal["median"] = "median", odocal: bool = False,
                 fault: bool = False, **kw: Any) -> None:  # fmt: skip
        self.faults = FaultMonitor() if fault else None
        self.noise_scale = scale_for(adaptive, kw.get("landmarks"), kw.get("use_landmarks", True))
        self.odometry = OdometryCalibration() if odocal else None
        self.protocol = TeamProtocol(type(self).__name__, self.name, robot, initial, team, cluster, clusters=True,
                                     association=kw.get("association", "tags"), gated_broadcasts=True)  # fmt: skip
        self.protocol.innovations = self.noise_scale is not None
        if odocal and self.protocol.form.group is not SE2:
            raise ValueError("diekf: 'odocal' calibrates planar odometry: SE(2) only")
        if isinstance(reform, bool) or not isinstance(reform, int | float) or not (0 <= reform < math.inf):
            raise ValueError(f"diekf: 'reform' must be a period >= 0 s (0: fixed clusters), got {reform!r}")
        if reform and not cluster:
            raise ValueError("diekf: re-forming clusters ('reform' > 0) needs clusters ('cluster' > 0)")
        self.reform = float(reform)
        """[s] The period of the clusters' re-forming (0: fixed clusters; module docstring, :meth:`plan`)."""
        self.reforming: Reforming | None = None
        """The re-forming's part, once :meth:`plan` gave the schedule (None: fixed clusters)."""
        super().__init__(robot, initial, team=self.protocol.team, **kw)

    def plan(self, events: Iterable[Any]) -> None:
        """With ``reform > 0``: the clusters' schedule from the recording's ``events`` (the whole team's,
        :func:`~swarmloc.estimators.cluster_reform.seen_schedule`), before the first input (module docstring)."""
        if not self.reform:
            return
        if self.history_size:
            raise RuntimeError("diekf.plan: the node has filed inputs; plan it before the first input")
        p = self.protocol
        sched = seen_schedule(events, p.everyone, p.cluster, self.reform)
        p.follow(sched)
        self.reforming = Reforming(p, sched, self._history, self._file, self._filing.replay, self.accounting)
        self.team = tuple(sorted({r for k in range(len(sched.cuts)) for r in sched.cluster(self.robot, k)}))
        """Every robot this one shares a cluster with at some time (a network driver hears each while it is a mate
        of this period or the next: :mod:`swarmloc.net.hearing`)."""

    def boundary(self) -> float | None:
        """The next boundary of the clusters' schedule not reached yet (None: none, or fixed clusters)."""
        return None if self.reforming is None else self.reforming.boundary()

    def awaits(self, t: float) -> str | None:
        """The pieces still owed to this robot for the boundaries up to ``t`` [s] (None: none)."""
        return None if self.reforming is None else self.reforming.awaits(t)

    def step(self, item: Any) -> list[Message]:
        """:meth:`Node.step`; with a schedule, the boundaries up to the item's stamp are reached first
        (:meth:`~swarmloc.estimators.cluster_reform.Reforming.reach`), a
        :class:`~swarmloc.messages.ClusterPiece` is taken by the re-forming, and the pieces a late input changed are
        sent again."""
        if self.reforming is None or not self.started:
            if self.reform and self.started and not self.counts["unplanned"]:  # no plan: said once
                self.counts["unplanned"] = 1
                log.warning("diekf robot %s: no recording to plan from: its clusters stay fixed", self.robot)
            return super().step(item)
        first = item[0] if isinstance(item, list | tuple) and item else item
        stamp = getattr(first, "stamp", None)
        out = self.reforming.reach(stamp) if isinstance(stamp, float | int) and math.isfinite(stamp) else []
        if isinstance(item, ClusterPiece):
            return out + self.reforming.take(item)
        if isinstance(item, TeamUpdate) and item.sender in self.team and item.receiver == self.robot:
            self.protocol.use(item.stamp)
            if item.sender not in self.protocol.pos:  # a mate of another time (a network driver hears them all)
                self.counts["broadcasts_other_cluster"] += 1
                return out
        return out if isinstance(item, Reach) else out + super().step(item) + self.reforming.revise()

    @property
    def dim(self) -> int:
        """Dimension of a robot's error (3: SE(2); 6: SE(3))."""
        return self.protocol.form.dim

    # ------------------------------------------------------------------------------------------------ filter
    def _initial_state(self, t0: float) -> TeamState:
        return self.protocol.initial(self.initial.mean, self.initial.cov, t0)

    def _advance(self, s: TeamState, robot: int, t: float) -> TeamState:
        dt = t - s.t
        if dt <= 0:
            return s
        x, P = self.protocol.form.predict(s.x, s.P, s.v, s.w, dt, self.noise)
        if self.noise_scale is not None:
            P = self.noise_scale.inflate(s.P, P, t)
        return TeamState(t, s.v, s.w, x, P, s.Sigma)

    def _set_command(self, s: TeamState, robot: int, v: Any, w: Any) -> TeamState:
        if self.odometry is not None:
            self.odometry.record_command(s.t, v, w)
            v, w = self.odometry.apply(s.t, v, w)
        return TeamState(s.t, v, w, s.x, s.P, s.Sigma)

    def _advance_commands(self, s: Any, cmds: Any) -> Any:
        """A run of odometry: :meth:`_advance` and :meth:`_set_command` one by one (predicting in world-frame errors,
        not rdl's Cartesian run), the pose kept in floats between steps (the same numbers)."""
        own_model = self.noise_scale is not None or self.odometry is not None
        if self.measure_time or not self.protocol.form.runs or own_model:
            return super()._advance_commands(s, cmds)  # timed, SE(3), adaptive or calibrated
        t0, v, w, P = s.t, s.v, s.w, s.P
        x0, y0, th = s.x.tolist()
        for t, _, vk, wk in cmds:
            dt = t - t0
            if dt > 0:
                x0, y0, th, P = world_step(x0, y0, th, P, v, w, dt, self.noise)
                t0 = t
            v, w = vk, wk
        x = s.x if P is s.P else np.array([x0, y0, th])
        return TeamState(t0, v, w, x, P, s.Sigma)

    def _belief(self, s: TeamState, robot: int) -> GroupGaussian:
        return self.protocol.belief(s.x, s.P)

    # ------------------------------------------------------------------------------------------------ update
    def _fuse_group(self, s: TeamState, g: Group) -> tuple[TeamState, list[Outcome], list[Message]]:
        self.protocol.use(g.t)
        outcomes: list[Outcome] = []
        msgs: list[Message] = []
        for d, sub in zip(g.detections, g.keys, strict=True):
            s, outcome, sent = self._fuse_one(s, g, d, sub)
            outcomes.append(outcome)
            msgs += sent
        if self.odometry is not None and FUSED in outcomes:
            self.odometry.record_pose(g.t, s.x, self._belief(s, self.robot).cov)
        return s, outcomes, msgs

    def _fuse_one(self, s: TeamState, g: Group, d: Any, sub: SubKey) -> tuple[TeamState, Outcome, list[Message]]:
        """One detection of ``g`` (key ``sub``) fused and broadcast (:meth:`TeamProtocol.fuse`), or its outcome."""
        target = self._classify(g, d, sub)
        if self.faults is not None:  # a landmark's, or one not fused: none (a replay drops what it filed before)
            ev = observer_evidence(self.protocol, s, d, target[1]) if target[0] == "robot" else None
            s = self._inflated(s, self.faults.record(g.t, ("o", sub), ev))
        if target[0] in ("rejected", "unknown"):
            return s, target, []
        self.protocol.last_innovation = None
        out = self.protocol.fuse(s, d, target, sub, self.gate, self.lin_log, g.t)
        if self.noise_scale is not None and self.protocol.last_innovation is not None:
            self.noise_scale.record(g.t, sub, self.protocol.last_innovation)
        return out

    # ------------------------------------------------------------------------------------------------ exchange
    def _robot_target(self, g: Group, d: Any, sub: SubKey) -> tuple[str, Any]:
        if self.protocol.cluster and d.target not in self.protocol.pos:
            sub = ()  # the BeliefQuery's answer (TeamProtocol.requests)
        return super()._robot_target(g, d, sub)

    def _apply_update(self, s: TeamState, u: Message) -> tuple[TeamState, bool]:
        # The detected robot is predicted to the stamp; a third party is not: a world-frame correction commutes
        # with the odometry (exp(d) g Delta), so it applies at the robot's own clock. This is what the
        # centralized filter does with its blocks (the same process-noise linearization points, same numbers).
        if isinstance(u, Boundary):  # the clusters re-formed: this robot predicted to the boundary
            return self.protocol.reform(self._adv(s, self.robot, u.t), u.k, u.pieces), True
        if isinstance(u, TeamUpdate) and u.target == self.robot:
            s = self._adv(s, self.robot, u.stamp)
        s, applied = self.protocol.apply(s, u, self.counts)
        if self.faults is not None and isinstance(u, TeamUpdate):
            key = ("t", u.sender, tuple(u.sub))
            s = self._inflated(s, self.faults.record(float(u.stamp), key, broadcast_evidence(u, self.robot)))
        return s, applied

    @staticmethod
    def _inflated(s: TeamState, D: np.ndarray | None) -> TeamState:
        """``s`` with its covariance inflated by ``D`` (an odometry fault's, :attr:`faults`; None: as it is)."""
        return s if D is None else s._replace(P=s.P + D)
