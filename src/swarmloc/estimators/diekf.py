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
the estimates equal the centralized invariant EKF's (tested to 1e-9). Nothing is approximated: no correlation is
left untracked, which is what makes the filter consistent without landmarks, where ``rdl``'s pairwise
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
(:func:`~swarmloc.estimators.state_exchange.anonymous_sub`), as ``rdl`` does; the detection given a robot is
broadcast under that key, so where the identity is right the broadcast is the tagged run's. Every other teammate's
exchange is settled by an empty broadcast under its key (:meth:`TeamProtocol.settle`), as a gated
detection's: an answerer over the network waits for the broadcast keyed by the query it answered before it goes on.

**SE(3).** With an SE(3) initial belief the same node runs with 6-dof poses
(:class:`~swarmloc.estimators.world_form.WorldForm3`; the group picks the node's
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
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, ClassVar, Literal, Protocol

import numpy as np

from swarmloc.estimators.adaptive_noise import Innovation, MedianScale, NoiseScale, innovation_terms
from swarmloc.estimators.cluster_reform import Boundary, Reforming, Schedule, seen_schedule, stacked_bound
from swarmloc.estimators.dekf import DEGENERATE, FilterState
from swarmloc.estimators.odometry_fault import FaultMonitor, broadcast_evidence, observer_evidence
from swarmloc.estimators.state_exchange import StateQueries
from swarmloc.estimators.world_form import FORMS, TeamState, robot_pair, world_step
from swarmloc.gaussian import GroupGaussian, symmetric
from swarmloc.kernels.ci import W_BOUNDS, joint_weight
from swarmloc.lie import SE2, SE3
from swarmloc.messages import (
    Answer,
    BeliefAnswer,
    BeliefQuery,
    ClusterPiece,
    Message,
    RdlState,
    RdlStateQuery,
    TeamUpdate,
    flat,
)
from swarmloc.motion.odocal import OdometryCalibration
from swarmloc.node import (
    FUSED,
    NUMERICAL,
    P_GROUP,
    Gate,
    Group,
    Outcome,
    RobotNode,
    belief_of,
    broadcast_nis,
    fits,
    positive_definite,
    usable_covariance,
)
from swarmloc.node.base import Reach
from swarmloc.node.keys import SubKey

log = logging.getLogger("swarmloc.node")

__all__ = [
    "FORMS", "DistributedInvariantEKF", "Numbers", "Replica", "TeamProtocol", "TeamState",
]  # fmt: skip


class Replica(FilterState, Protocol):
    """What the team protocol reads of a node's state (:class:`TeamState`; ``flsd``'s holds more): a filter state
    and the replica ``Sigma`` of the team's cross-covariances."""

    @property
    def Sigma(self) -> np.ndarray: ...


Numbers = tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]
"""A broadcast's numbers ``(target j, H_i, H_j, S^-1, nu, P_ii, P_jj, w)`` (module docstring, step 2)."""


class TeamProtocol:
    """``diekf``'s team protocol (module docstring), a part of the nodes that run it (:class:`DistributedInvariantEKF`,
    and ``flsd``'s :class:`~swarmloc.estimators.fls_team.TeamFixedLagSmoother`): the team (this robot's cluster) and
    each robot's place in the replica, the group's world-frame form, the exchange's queries, one detection's gated
    update and its broadcast, a teammate's broadcast checked and applied.

    ``where``, ``name``: the owner's class and estimator names (messages); ``clusters``: whether the owner takes
    ``cluster > 0``; ``update``: the owner's team update (default step 3, :meth:`team_update`; ``flsd``'s also files
    the change in its window); ``gated_broadcasts``: whether a teammate's broadcast passed its sender's gate as
    it is (:meth:`update_lie`)."""

    def __init__(self, where: str, name: str, robot: int, initial: Any, team: Sequence[int], cluster: int, *,
                 clusters: bool, association: str, gated_broadcasts: bool,
                 update: Callable[..., Any] | None = None) -> None:  # fmt: skip
        self.form = FORMS.get(getattr(initial, "group", SE2), FORMS[SE2])  # a wrong belief: RobotNode says so
        everyone = tuple(sorted({int(r) for r in team} | {int(robot)}))
        if isinstance(cluster, bool) or not isinstance(cluster, int) or cluster < 0:
            raise ValueError(f"{where}: 'cluster' must be an integer >= 0 (0: the whole team), got {cluster!r}")
        if cluster and not (clusters and self.form.clusters):
            on = f" on {self.form.group.name}" if clusters else ""
            raise ValueError(f"{where} ({name}) has no clusters{on}: 'cluster' must be 0")
        if cluster and association != "tags":
            raise ValueError(f"{name}: clusters need tagged detections (association 'tags')")
        self.robot = int(robot)
        self.cluster = cluster
        self.everyone = everyone
        """The whole team; :attr:`team` is this robot's cluster (all of it without clusters)."""
        k = everyone.index(self.robot) // cluster if cluster else 0
        self.team = everyone[k * cluster : (k + 1) * cluster] if cluster else everyone
        self.mates = [r for r in self.team if r != self.robot]
        self.pos = {r: k for k, r in enumerate(self.team)}
        self.schedule: Schedule | None = None
        """The clusters' re-forming (:meth:`follow`; None: fixed clusters)."""
        self._period = 0  # the schedule's cut that team, mates and pos are of (:meth:`use`)
        self.update = self.team_update if update is None else update
        self.gated_broadcasts = gated_broadcasts
        self.queries = StateQueries(self.robot)
        self._unusable: set[tuple[Any, ...]] = set()
        self.innovations = False
        """Whether :meth:`one` keeps :attr:`last_innovation` (an owner that adapts its noise sets it)."""
        self.last_innovation: Innovation | None = None
        """The last detection's innovation terms (:func:`~swarmloc.estimators.adaptive_noise.innovation_terms`)."""

    # ------------------------------------------------------------------------------------------------ re-forming
    def follow(self, schedule: Schedule) -> None:
        """Re-form the clusters by ``schedule`` (module docstring, "Clusters that re-form"), whose first cut holds this
        robot's cluster as it is."""
        if not self.cluster:
            raise ValueError("diekf: re-forming clusters needs clusters ('cluster' > 0)")
        if schedule.cluster(self.robot, 0) != self.team:
            raise ValueError(f"diekf: the schedule's first cut does not hold this robot's cluster {list(self.team)}")
        self.schedule, self._period = schedule, 0

    def use(self, t: float | None) -> None:
        """:attr:`team`, :attr:`mates` and :attr:`pos`: this robot's cluster at stamp ``t`` [s] (with a schedule;
        else, or ``t`` None, they stay)."""
        if self.schedule is None or t is None or (k := self.schedule.period(t)) == self._period:
            return
        self._period = k
        self.team = self.schedule.cluster(self.robot, k)
        self.mates = [r for r in self.team if r != self.robot]
        self.pos = {r: q for q, r in enumerate(self.team)}

    def _cuts(self, k: int) -> tuple[tuple[int, ...], tuple[int, ...], dict[int, int]]:
        """This robot's cluster before boundary ``k`` and after it, and each robot's old cluster (index in cut
        ``k - 1``)."""
        assert self.schedule is not None  # noqa: S101  (a boundary: a schedule's)
        old = {r: c for c, g in enumerate(self.schedule.cuts[k - 1]) for r in g}
        return self.schedule.cluster(self.robot, k - 1), self.schedule.cluster(self.robot, k), old

    def pieces(self, s: Replica, k: int, t: float) -> list[Message]:
        """This robot's share of its piece (:class:`~swarmloc.messages.ClusterPiece`) for each new mate outside it at
        boundary ``k`` (stamp ``t``), from the state ``s`` before it: the old replica's cross-covariances with the
        piece's robots after this one (each pair is sent once, by its lower id)."""
        was, now, _ = self._cuts(k)
        later = [b for b in now if b in was and b > self.robot]
        outside = [r for r in now if r not in was]
        if not later or not outside:
            return []
        pos = {r: q for q, r in enumerate(was)}
        sigma = flat(np.stack([s.Sigma[pos[self.robot], pos[b]] for b in later]))
        return [ClusterPiece(sender=self.robot, receiver=m, stamp=t, robots=tuple(later), sigma=sigma)
                for m in outside]  # fmt: skip

    def owed(self, k: int) -> set[int]:
        """The new mates that owe this robot a piece at boundary ``k``: those of another old cluster with a later robot
        of their piece."""
        was, now, old = self._cuts(k)
        return {a for a in now if a not in was and any(old[b] == old[a] and b > a for b in now)}

    def piece_problem(self, m: ClusterPiece) -> str | None:
        """Why a teammate's piece is not the one it owes this robot at a boundary of the schedule, or None."""
        k = 0 if self.schedule is None else self.schedule.period(m.stamp)
        if self.schedule is None or k == 0 or self.schedule.times[k - 1] != m.stamp or m.receiver != self.robot:
            return "cluster piece at no re-forming of this robot's clusters"
        was, now, old = self._cuts(k)
        if m.sender not in now or m.sender in was:
            return f"cluster piece from robot {m.sender}, not a new mate from another cluster"
        if list(m.robots) != [b for b in now if old.get(b) == old[m.sender] and b > m.sender]:
            return f"cluster piece of robot {m.sender} names other robots than its piece's"
        return None

    def reform(self, s: Replica, k: int, pieces: Mapping[int, ClusterPiece]) -> TeamState:
        """The state at boundary ``k`` from ``s`` before it (this robot predicted to the boundary): the replica of the
        new cluster from the covariance-intersection bound of its pieces
        (:func:`~swarmloc.estimators.cluster_reform.stacked_bound`), this robot's piece from its own replica, the
        others' from the ``pieces`` its new mates sent (a piece not received yet: zero, until it comes)."""
        was, now, old = self._cuts(k)
        me, at = self.robot, {r: q for q, r in enumerate(was)}
        got = {(a, b): S for a, m in pieces.items() for b, S in m.blocks().items()}
        zero = np.zeros((self.form.dim, self.form.dim))

        def block(a: int, b: int) -> np.ndarray:
            if a == b:
                return s.P if a == me else zero  # a teammate's own covariance: not in the replica
            if a in at and b in at:
                return np.asarray(s.Sigma[at[a], at[b]])
            return got[a, b] if (a, b) in got else got[b, a].T if (b, a) in got else zero

        Sigma = stacked_bound(now, old, block, self.form.dim)
        q = now.index(me)
        return TeamState(s.t, s.v, s.w, s.x, Sigma[q, q].copy(), Sigma)

    def initial(self, mean: np.ndarray, cov: np.ndarray, t0: float) -> TeamState:
        x, P = self.form.initial(mean, cov)
        n, d = len(self.team), self.form.dim
        return TeamState(t0, 0.0, 0.0, x, P, np.zeros((n, n, d, d)))

    def belief(self, x: Any, P: np.ndarray) -> GroupGaussian:
        return belief_of(*self.form.belief(x, P))

    def answer(self, s: Replica, q: Message) -> Answer | None:
        """The answer to an :class:`~swarmloc.messages.RdlStateQuery` (None: another query)."""
        if not isinstance(q, RdlStateQuery):
            return None
        return RdlState(sender=q.receiver, receiver=q.sender, stamp=q.stamp, sub=q.sub, x=flat(s.x), P=flat(s.P),
                        sigma=self.form.eye)  # fmt: skip

    def team_update(
        self, s: Replica, i: int, j: int, Hi: np.ndarray, Hj: np.ndarray, Sinv: np.ndarray, nu: np.ndarray,
        Pii: np.ndarray, Pjj: np.ndarray, w: float = 1.0,
    ) -> TeamState:  # fmt: skip
        """Step 3 of the module docstring on this robot's state (``w < 1``: a covariance-intersection update, every
        covariance of the cluster divided by ``w`` first)."""
        P0, Sigma0 = s.P, s.Sigma
        if w != 1.0:
            P0, Sigma0 = P0 / w, Sigma0 / w
            Pii, Pjj = Pii / w, Pjj / w
        pi, pj, me = self.pos[i], self.pos[j], self.pos[self.robot]
        Ci = Sigma0[:, pi].copy()
        Ci[pi] = Pii
        if pj == pi:
            Cj = Ci
        else:
            Cj = Sigma0[:, pj].copy()
            Cj[pj] = Pjj
        if me not in (pi, pj):
            Ci[me], Cj[me] = Sigma0[me, pi], Sigma0[me, pj]
        Gam = Ci @ Hi.T + Cj @ Hj.T  # (n, 3, m)
        G = Gam @ Sinv
        Sigma = Sigma0 - np.einsum("aim,bjm->abij", G, Gam)
        Sigma = 0.5 * (Sigma + Sigma.transpose(1, 0, 3, 2))  # Sigma_ba = Sigma_ab^T, as P's symmetrization below
        P = P0 - G[me] @ Gam[me].T
        P = symmetric(P)
        return TeamState(s.t, s.v, s.w, self.form.correct(s.x, Gam[me] @ nu), P, Sigma)

    # ------------------------------------------------------------------------------------------------ update
    def one(self, s: Replica, d: Any, target: tuple[str, Any], gate: Gate, lin_log: list[Any] | None,
            t: float | None) -> Any:  # fmt: skip
        """One detection (of the group stamped ``t``): the new state and the broadcast's :data:`Numbers`, or an
        outcome; with ``lin_log``, its linearization is appended there."""
        self.use(t)
        i, form = self.robot, self.form
        why = form.unsupported(d, target)
        if why is not None:
            return ("rejected", why)
        if target[0] == "robot":
            a: RdlState = target[1]
            j = d.target
            if j not in self.pos:
                if self.cluster and j in self.everyone:
                    return self.outsider(s, i, d, a, gate)
                return ("unknown", f"robot {j} is not in this node's team {list(self.team)}")
            xj, Pjj, _ = a.arrays()
            if xj.shape != s.x.shape:
                return ("rejected", f"the neighbour's answer is not an {form.group.name} state")
            lin = form.robot(d, s, xj, Pjj, s.Sigma[self.pos[i], self.pos[j]])
            if isinstance(lin, str):
                return ("rejected", lin)
            r, Hi, Hj, S, R = lin
        else:
            lin = form.landmark(d, s, target)
            if isinstance(lin, str):
                return ("rejected", lin)
            r, Hi, S, R = lin
            j, Pjj, Hj = i, s.P, np.zeros_like(Hi)
        out = self.gated_update(s, i, j, Hi, Hj, S, r, Pjj, gate)
        if self.innovations:
            self.last_innovation = innovation_terms(r, S, R, landmark=target[0] != "robot")
        if lin_log is not None and not isinstance(out[0], str):
            lin_log.append(("update", t, {i: Hi, j: Hj} if j != i else {i: Hi}, R))
        return out

    def outsider(self, s: Replica, i: int, d: Any, a: Any, gate: Gate) -> Any:
        """A detection of robot ``d.target`` outside this robot's cluster, by covariance intersection: for a weight
        ``w`` in (0, 1), ``blockdiag(Sigma_cluster / w, P_jj / (1 - w))`` bounds the joint covariance of the cluster
        and the outsider whatever their correlation; the update is the cluster's exact one with the outsider's
        uncertainty in the noise, ``S = H_i P_ii H_i^T / w + H_j P_jj H_j^T / (1 - w) + R``, broadcast to the cluster
        as a team update of ``i`` alone with ``scale = w``. ``w`` minimizes the log det of the *cluster's* posterior
        (:func:`~swarmloc.kernels.ci.joint_weight`): chosen for ``i`` alone it inflated every cluster mate at each
        of ``i``'s outside detections, and clusters of 2 diverged (2.1 m on ``sim:random``, 6 robots). The outsider
        is not updated."""
        if not isinstance(a, BeliefAnswer):
            return ("rejected", f"the answer of robot {d.target}, outside the cluster, is not a belief")
        gj, bj = a.belief_arrays()  # checked as a message: an SE(2) element, a covariance
        Ad = SE2.Ad(gj, validate=False)
        xj, Pjj = SE2.to_xytheta(gj), Ad @ bj @ Ad.T  # I.body_to_world, without checking gj again
        lin = robot_pair(d, s.x, xj)
        if lin is None:
            return ("rejected", DEGENERATE)
        r, Hi, Hj, R = lin
        A, B = Hi @ s.P @ Hi.T, Hj @ Pjj @ Hj.T
        w = joint_weight(A, B, R, self.form.dim * len(self.team))
        S = A / w + B / (1.0 - w) + R
        return self.gated_update(s, i, i, Hi, np.zeros_like(Hi), S, r, s.P, gate, w)

    def gated_update(
        self, s: Replica, i: int, j: int, Hi: np.ndarray, Hj: np.ndarray, S: np.ndarray, r: np.ndarray,
        Pjj: np.ndarray, gate: Gate, w: float = 1.0,
    ) -> Any:  # fmt: skip
        """The gated team update of one detection with innovation ``r``, its covariance ``S`` and Jacobians
        ``Hi``, ``Hj`` (the SE(2) and SE(3) forms share it; ``w < 1``: a covariance-intersection one,
        :meth:`outsider`): ``(new state, the broadcast's numbers)``, or an outcome (gated, or rejected when ``S``
        is singular or the result not finite)."""
        try:
            Sinv = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            return ("rejected", NUMERICAL)
        Sinv = symmetric(Sinv)
        nu = Sinv @ r
        verdict = gate.verdict(float(r @ nu), len(r))
        if verdict is not None:
            return verdict
        new = self.update(s, i, j, Hi, Hj, Sinv, nu, s.P, Pjj, w)
        if not (np.isfinite(new.x).all() and usable_covariance(new.P) and np.isfinite(new.Sigma).all()):
            return ("rejected", NUMERICAL)
        return new, (j, Hi, Hj, Sinv, nu, s.P, Pjj, w)

    def fuse(self, s: Replica, d: Any, target: tuple[str, Any], sub: SubKey, gate: Gate, lin_log: list[Any] | None,
             t: float) -> tuple[Any, Outcome, list[Message]]:  # fmt: skip
        """One detection of the group stamped ``t`` (key ``sub``): the new state, ``fused`` and the update's broadcast
        (:meth:`one`), or the state, the outcome and an empty broadcast (the exchange settled)."""
        res = self.one(s, d, target, gate, lin_log, t)
        if isinstance(res[0], str):
            return s, res, self.broadcast(t, sub)
        new, numbers = res
        return new, FUSED, self.broadcast(t, sub, numbers)

    # ------------------------------------------------------------------------------------------------ exchange
    def requests(self, g: Group, needs_answer: Callable[[Group, Any], bool], mates: Sequence[int]) -> list[Message]:
        """``rdl``'s queries; with clusters, a robot outside the cluster is asked a ``BeliefQuery`` instead (its
        belief is all :meth:`outsider` needs, and an answerer outside the cluster waits for no broadcast)."""
        self.use(g.t)
        out = self.queries.requests(g, needs_answer, mates)
        if not self.cluster:
            return out
        kept: dict[tuple[Any, ...], Message] = {}
        for q in out:
            if q.receiver in self.pos:
                kept[(q.receiver, tuple(q.sub))] = q
            else:
                kept.setdefault((q.receiver, ()), BeliefQuery(sender=self.robot, receiver=q.receiver, stamp=q.stamp))
        return list(kept.values())

    def candidates(self, g: Group, mates: Sequence[int]) -> dict[int, GroupGaussian]:
        return self.queries.candidates(g, mates, lambda t, x, P, robot: self.belief(x, P))

    def broadcast(self, t: float, sub: SubKey, numbers: Numbers | None = None) -> list[Message]:
        """One exchange's broadcast to every teammate: an update's :data:`Numbers`, or none (an empty update: the
        exchange is settled, its detection not fused)."""
        self.use(t)
        if numbers is None:
            return [TeamUpdate(sender=self.robot, receiver=r, stamp=t, sub=sub) for r in self.mates]
        j, Hi, Hj, Sinv, nu, Pii, Pjj, w = numbers
        body: dict[str, Any] = dict(
            target=j, m=len(nu), n=self.form.dim, Hi=flat(Hi), Hj=flat(Hj), Sinv=flat(Sinv), nu=flat(nu),
            Pii=flat(Pii), Pjj=flat(Pjj), **({} if w == 1.0 else {"scale": w}),
        )  # fmt: skip
        return [TeamUpdate(sender=self.robot, receiver=r, stamp=t, sub=sub, **body) for r in self.mates]

    def settle(self, g: Group) -> list[Message]:
        """An empty broadcast under the key of every found answer that no detection used
        (:meth:`~swarmloc.estimators.state_exchange.StateQueries.unused`): the answerer knows the exchange is settled
        (each teammate counts it ``no_update``)."""
        return [m for _, k, a in self.queries.unused(g) if a.found for m in self.broadcast(g.t, k)]

    def update_problem(self, u: Message) -> str | None:
        if not isinstance(u, TeamUpdate):
            return f"{type(u).__name__} is not a team update"
        self.use(u.stamp)
        if u.sender not in self.pos or (not u.empty and u.target not in self.pos):
            return f"team update from or about a robot outside the team {list(self.team)}"
        if not u.empty and u.n != self.form.dim:
            return f"team update of a {u.n}-dof error; this node's error has {self.form.dim} dof"
        return None

    def update_lie(self, u: Message, gate: Gate) -> str | None:
        """A broadcast must be what a teammate with this node's gate sent: its own normalized innovation ``nu^T S nu
        <= gamma_m`` (the sender's gate held it), and scaled only as a cluster's covariance-intersection update of
        its sender alone, ``w`` within the bounds the sender chooses it in (:mod:`~swarmloc.node.trust`)."""
        if gate.p is None or not isinstance(u, TeamUpdate) or u.empty:
            return None
        if u.scale != 1.0 and not (self.cluster and u.target == u.sender and u.scale >= W_BOUNDS[0]):
            return f"broadcast of robot {u.sender} scaled as no robot of this team scales one"
        m = u.m
        if not self.gated_broadcasts or fits(gate, broadcast_nis(np.reshape(u.Sinv, (m, m)), np.array(u.nu)), m):
            return None
        return f"broadcast of robot {u.sender} beyond the gate"

    def apply(self, s: Replica, u: Message, counts: Counter[str]) -> tuple[Any, bool]:
        """A teammate's broadcast applied to ``s`` (this robot at its clock; the detected robot predicted to the
        stamp by the owner); not when it would leave this robot's covariance not positive definite."""
        if not isinstance(u, TeamUpdate):
            return s, False
        self.use(u.stamp)
        m, n = u.m, u.n
        A = np.array  # np.array(t).reshape: what np.reshape(t) makes of a tuple, without its dispatch
        Hi, Hj = A(u.Hi).reshape(m, n), A(u.Hj).reshape(m, n)
        Sinv, nu = A(u.Sinv).reshape(m, m), A(u.nu)
        Pii, Pjj = A(u.Pii).reshape(n, n), A(u.Pjj).reshape(n, n)
        new = self.update(s, u.sender, u.target, Hi, Hj, Sinv, nu, Pii, Pjj, float(u.scale))
        usable = positive_definite(new.P)
        self._count_unusable(counts, (float(u.stamp), P_GROUP, u.sender, tuple(u.sub)), not usable)
        return (new if usable else s), True

    def _count_unusable(self, counts: Counter[str], key: tuple[Any, ...], unusable: bool) -> None:
        """Keep ``updates_unusable`` the number of broadcasts whose last application left this robot's covariance not
        positive definite (not applied: no honest broadcast does that, :mod:`~swarmloc.node.trust`)."""
        if unusable and key not in self._unusable:
            self._unusable.add(key)
            counts["updates_unusable"] += 1
        elif not unusable and key in self._unusable:
            self._unusable.discard(key)
            counts["updates_unusable"] -= 1

    def prune(self, cutoff: float) -> None:
        """Forget the unusable broadcasts stamped before ``cutoff`` (their count stands)."""
        self._unusable = {k for k in self._unusable if k[0] >= cutoff}


class DistributedInvariantEKF(RobotNode):
    """Exact distributed invariant EKF (module docstring): the node's filter over its :class:`TeamProtocol`
    (:attr:`protocol`, which speaks the exchange: :class:`~swarmloc.node.robot.RobotNode` hands it the exchange's
    hooks). ``team``: every robot id of the team (``make_team`` passes it). ``cluster``: 0 (default)
    for the exact filter over the whole team, or ``K >= 1`` robots per cluster (module docstring, "Clusters"):
    replica and broadcasts over the robot's cluster only, covariance intersection with robots outside it. The
    exchange's queries are :class:`~swarmloc.estimators.state_exchange.StateQueries`' (``rdl``'s). ``adaptive``: the
    process noise scaled online from this robot's own innovations (:class:`~swarmloc.estimators.adaptive_noise.
    NoiseScale`, or ``"median"``: :class:`~swarmloc.estimators.adaptive_noise.MedianScale`; :attr:`noise_scale`;
    ``[filter] diekf_adaptive``). ``odocal``: this robot's odometry scale and yaw-rate
    bias calibrated online from its own posteriors (:class:`~swarmloc.motion.odocal.OdometryCalibration`,
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
                 reform: float = 0.0, adaptive: bool | Literal["median"] = False, odocal: bool = False,
                 fault: bool = False, **kw: Any) -> None:  # fmt: skip
        self.faults = FaultMonitor() if fault else None
        self.noise_scale = MedianScale() if adaptive == "median" else NoiseScale() if adaptive else None
        self.odometry = OdometryCalibration() if odocal else None
        self.protocol = TeamProtocol(type(self).__name__, self.name, robot, initial, team, cluster, clusters=True,
                                     association=kw.get("association", "tags"), gated_broadcasts=True)  # fmt: skip
        self.protocol.innovations = bool(adaptive)
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

    def _one(self, s: TeamState, g: Group | None, d: Any, target: tuple[str, Any]) -> Any:
        """One detection: the new state and the broadcast's numbers, or an outcome (:meth:`TeamProtocol.one`)."""
        return self.protocol.one(s, d, target, self.gate, self.lin_log, None if g is None else g.t)

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
