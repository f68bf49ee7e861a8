"""``diekf``'s team protocol (:class:`TeamProtocol`), apart from the estimator that runs it: the exact distributed
invariant EKF (:mod:`swarmloc.estimators.diekf`, whose docstring describes the exchange, the clusters and their
re-forming) and ``flsd``'s fixed-lag smoother (:mod:`swarmloc.estimators.fls_team`) both own one."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

import numpy as np

from swarmloc.estimators.adaptive_noise import Innovation, innovation_terms
from swarmloc.estimators.cluster_reform import Schedule, stacked_bound
from swarmloc.estimators.dekf import FilterState
from swarmloc.estimators.state_exchange import StateQueries
from swarmloc.estimators.world_form import FORMS, TeamState, robot_pair
from swarmloc.gaussian import GroupGaussian, symmetric
from swarmloc.kernels.ci import W_BOUNDS, joint_weight
from swarmloc.lie import SE2
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
from swarmloc.node import (
    FUSED,
    NUMERICAL,
    P_GROUP,
    Gate,
    Group,
    Outcome,
    belief_of,
    broadcast_nis,
    fits,
    positive_definite,
    usable_covariance,
)
from swarmloc.node.keys import SubKey
from swarmloc.sensors.models import DEGENERATE

__all__ = ["Numbers", "Replica", "TeamProtocol"]


class Replica(FilterState, Protocol):
    """What the team protocol reads of a node's state (:class:`TeamState`; ``flsd``'s holds more): a filter state
    and the replica ``Sigma`` of the team's cross-covariances."""

    @property
    def Sigma(self) -> np.ndarray: ...


Numbers = tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]
"""A broadcast's numbers ``(target j, H_i, H_j, S^-1, nu, P_ii, P_jj, w)`` (``diekf``'s docstring, step 2)."""


class TeamProtocol:
    """``diekf``'s team protocol (``diekf``'s docstring), a part of the nodes that run it
    (:class:`~swarmloc.estimators.diekf.DistributedInvariantEKF`,
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
        """Re-form the clusters by ``schedule`` (``diekf``'s docstring, "Clusters that re-form"), whose first cut holds
        this robot's cluster as it is."""
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
        """Step 3 of ``diekf``'s docstring on this robot's state (``w < 1``: a covariance-intersection update, every
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
        xj, Pjj = SE2.to_xytheta(gj), Ad @ bj @ Ad.T  # the world-frame error's covariance
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
