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
(:meth:`DistributedInvariantEKF._outsider`): consistent whatever the two clusters' correlation, one-sided (the
outsider is not updated), and conservative. Over the network a node subscribes to its cluster's broadcasts only
and its lockstep waits for theirs only (:mod:`swarmloc.net.broadcast`). ``K >= n`` is the exact filter. The
engine replays the clusters in one compiled loop (``run_engine(source, "diekf", backend="numba", cluster=K)``,
:mod:`swarmloc.engine.joint_clusters`; ``backend="jax"``: :mod:`swarmloc.engine.jax_clusters`). The accuracy cost
and the cost per robot against team size: ``benchmarks/diekf_cluster.py``.

Anonymous detections (``association`` ``nearest`` or ``joint``): every teammate is asked with the
``RdlStateQuery`` keyed as the detection would be were it of that teammate
(:func:`~swarmloc.estimators.state_exchange.anonymous_sub`), as ``rdl`` does; the detection given a robot is
broadcast under that key, so where the identity is right the broadcast is the tagged run's. Every other teammate's
exchange is settled by an empty broadcast under its key (:meth:`DistributedInvariantEKF._settle`), as a gated
detection's: an answerer over the network waits for the broadcast keyed by the query it answered before it goes on.

**SE(3).** With an SE(3) initial belief the same node runs with 6-dof poses (:class:`WorldForm3`; the group picks
the node's :class:`WorldForm` once, :data:`FORMS`). Body-twist odometry ``g+ = g Delta exp(w^)`` is group-affine,
so the world-frame error ``xi`` (``g = exp(xi^) g^``) still has the identity transition: a prediction adds
``Ad(g^+) Sigma_inc Ad(g^+)^T`` to ``P_ii`` and changes no cross-covariance. A relative pose ``"pose3"`` is
autonomous in this error: exactly ``g^_i z g^_j^-1 = exp(-xi_i^) exp(xi_j^) exp((Ad(g^_j) n)^)``, so the innovation
``r = log(g^_i z g^_j^-1)`` has the constant Jacobians ``H_i = -I``, ``H_j = I`` and the noise ``Ad(g^_j) R_z
Ad(g^_j)^T`` (:func:`~swarmloc.kernels.cartesian3.relative_pose3_world`); the team's unobservable rigid motion
``[I; I; ...]`` is annihilated whatever the estimate (the body-frame error's are not, Huang et al. 2011). Point
detections (``"rbe3"``, ``"bearing3"`` of a teammate or a known 3-D landmark) take the Cartesian Jacobians of
:class:`~swarmloc.sensors.models3.Model3` times :func:`~swarmloc.kernels.cartesian3.world_basis3`; a rigid motion of
the whole team moves no body-frame point of a teammate, so they too gain nothing along it. A broadcast carries
``n = 6``; the correction is ``g <- exp(delta^) g``. On planar motion (poses in ``z = 0``, yaw only, planar twists and
block-diagonal noises) the planar part of the error follows the SE(2) filter (tests/test_se3_diekf.py). Clusters
are SE(2) only (the covariance-intersection weight is SE(2)'s).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar, NamedTuple

import numpy as np

from swarmloc.estimators.dekf import DEGENERATE, linearize
from swarmloc.estimators.state_exchange import StateQueries
from swarmloc.events import Kind
from swarmloc.gaussian import GroupGaussian
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import cartesian3 as C3
from swarmloc.kernels import invariant as I
from swarmloc.kernels.ci import W_BOUNDS, joint_weight
from swarmloc.lie import SE2, SE3
from swarmloc.messages import (
    Answer,
    BeliefAnswer,
    BeliefQuery,
    Message,
    RdlState,
    RdlStateQuery,
    TeamUpdate,
    flat,
)
from swarmloc.motion.twist3 import as_twist, twist_increment
from swarmloc.node import (
    FUSED,
    NUMERICAL,
    P_GROUP,
    Group,
    Node,
    Outcome,
    RobotNode,
    belief_of,
    broadcast_nis,
    fits,
    positive_definite,
    usable_covariance,
)
from swarmloc.sensors.models import model

__all__ = ["FORMS", "DistributedInvariantEKF", "TeamState", "WorldForm", "WorldForm3"]

_EYE = flat(np.eye(3))
_NO_SIGMA = np.zeros((0, 0, 3, 3))
_NO_SIGMA.setflags(write=False)


class TeamState(NamedTuple):
    """A robot's filter state: time [s], command (SE(2): ``(v, w)``; SE(3): the body twist's linear and angular
    velocity), pose (SE(2): ``x (3,)``; SE(3): ``(4, 4)``), world-frame covariance ``P (d, d)`` and the replica
    ``Sigma (n, n, d, d)`` of the team's cross-covariances (robots in ``team`` order; diagonal blocks unused)."""

    t: float
    v: Any
    w: Any
    x: np.ndarray
    P: np.ndarray
    Sigma: np.ndarray


def _pair(d: Any, xi: np.ndarray, xj: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """A robot detection ``d`` linearized at the two poses in world-frame errors: ``(r, H_i, H_j, R)`` (innovation,
    Jacobians, noise), or None for a degenerate geometry."""
    mm = model(d.kind)
    if mm.degenerate(xi, xj):
        return None
    h, Hi_c, Hj_c = mm.predict(xi, xj)
    return mm.residual(d.z, h), Hi_c @ I.world_basis(xi), Hj_c @ I.world_basis(xj), mm.noise(d.z, d.cov)


def world_step(x0: float, y0: float, th0: float, P: np.ndarray, v: float, w: float, dt: float,
               noise: Any) -> tuple[float, float, float, np.ndarray]:  # fmt: skip
    """One SE(2) prediction over ``dt`` [s] > 0: the new pose (floats) and world-frame covariance ``P + N^-1 Q N^-T``
    (:func:`swarmloc.kernels.invariant.cartesian_to_world_cov` at the new pose, its products inlined)."""
    x0, y0, th, _, _, q00, q01, q02, q11, q12, q22 = C.increment_terms_xy(x0, y0, th0, v, w, dt, noise)
    Qc = np.array([[q00, q01, q02], [q01, q11, q12], [q02, q12, q22]])
    Ni = np.array([[1.0, 0.0, y0], [0.0, 1.0, -x0], [0.0, 0.0, 1.0]])  # I.world_basis_inv
    return x0, y0, th, P + Ni @ Qc @ Ni.T


class WorldForm:
    """The world-frame error on SE(2): pose ``(x, y, theta)``, the planar models' Jacobians times
    :func:`~swarmloc.kernels.invariant.world_basis` (:mod:`swarmloc.kernels.invariant`)."""

    group: type = SE2
    dim = 3
    runs = True
    """Whether a run of odometry has a float loop (:meth:`DistributedInvariantEKF._advance_commands`)."""
    clusters = True
    """Whether the covariance-intersection weight of an outsider is defined (SE(2)'s)."""
    eye = _EYE

    def initial(self, mean: np.ndarray, cov: np.ndarray) -> tuple[Any, np.ndarray]:
        """Pose and world-frame covariance of a right-perturbation belief."""
        x, _ = C.from_group(mean, cov)
        return x, I.body_to_world(mean, cov)

    def predict(self, x: Any, P: np.ndarray, v: Any, w: Any, dt: float, noise: Any) -> tuple[Any, np.ndarray]:
        """Pose and covariance after the command held over ``dt > 0`` [s] (:func:`world_step`)."""
        x0, y0, th, P = world_step(*x.tolist(), P, v, w, dt, noise)
        return np.array([x0, y0, th]), P

    def belief(self, x: Any, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The right-perturbation belief of pose ``x`` with world-frame covariance ``P``."""
        g = SE2.from_xytheta(x)
        return g, I.world_to_body(g, P)

    def correct(self, x: Any, delta: np.ndarray) -> Any:
        """The pose ``x`` corrected by the world-frame ``delta``: ``exp(hat(delta)) g(x)``."""
        return I.left_correct(x, delta)

    def unsupported(self, d: Any, target: tuple[str, Any]) -> str | None:
        """Why ``d`` of ``target`` cannot be fused on this group (None: it can)."""
        return None

    def robot(self, d: Any, s: Any, xj: Any, Pjj: np.ndarray, Sij: np.ndarray) -> tuple | str:
        """``(r, H_i, H_j, S, R)`` of robot detection ``d`` of pose ``xj`` (covariance ``Pjj``, cross-covariance
        ``Sij`` with the observer), or the reason it cannot be fused."""
        lin = _pair(d, s.x, xj)
        if lin is None:
            return DEGENERATE
        r, Hi, Hj, R = lin
        return r, Hi, Hj, Hi @ s.P @ Hi.T + Hi @ Sij @ Hj.T + Hj @ Sij.T @ Hi.T + Hj @ Pjj @ Hj.T + R, R

    def landmark(self, d: Any, s: Any, target: tuple[str, Any]) -> tuple | str:
        """``(r, H_i, S, R)`` of a landmark detection (the map's uncertainty in ``R``), or the reason."""
        lin = linearize(d, s.x, target)
        if lin is None:
            return DEGENERATE
        r, Hi_c, R, _ = lin
        Hi = Hi_c @ I.world_basis(s.x)
        return r, Hi, Hi @ s.P @ Hi.T + R, R


class WorldForm3(WorldForm):
    """The world-frame error on SE(3): pose ``(4, 4)``, ``"pose3"`` with constant Jacobians
    (:func:`~swarmloc.kernels.cartesian3.relative_pose3_world`), the point kinds' Cartesian Jacobians times
    :func:`~swarmloc.kernels.cartesian3.world_basis3` (module docstring)."""

    group = SE3
    dim = 6
    runs = False
    clusters = False
    eye = flat(np.eye(6))

    def initial(self, mean: np.ndarray, cov: np.ndarray) -> tuple[Any, np.ndarray]:
        g = np.asarray(mean, dtype=float)
        A = SE3.Ad(g, validate=False)
        P = A @ np.asarray(cov, dtype=float) @ A.T
        return g.copy(), 0.5 * (P + P.T)

    def predict(self, x: Any, P: np.ndarray, v: Any, w: Any, dt: float, noise: Any) -> tuple[Any, np.ndarray]:
        inc, S = twist_increment(as_twist(v, w), dt, noise)
        g = x @ inc
        A = SE3.Ad(g, validate=False)
        P = P + A @ S @ A.T
        return g, 0.5 * (P + P.T)

    def belief(self, x: Any, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        A = SE3.Ad(SE3.inverse(x, validate=False), validate=False)
        return x, A @ P @ A.T

    def correct(self, x: Any, delta: np.ndarray) -> Any:
        return SE3.normalize(SE3.exp(delta, validate=False) @ x)

    def unsupported(self, d: Any, target: tuple[str, Any]) -> str | None:
        return C3.unsupported(d, target)

    def robot(self, d: Any, s: Any, xj: Any, Pjj: np.ndarray, Sij: np.ndarray) -> tuple | str:
        if d.kind == Kind.POSE3:
            r, Hi, Hj, R = C3.relative_pose3_world(s.x, xj, d.z, d.cov)
            S = s.P - Sij - Sij.T + Pjj + R  # H P H^T with H_i = -I, H_j = I
        else:
            lin = C3.linearize(d, s.x, xj)
            if isinstance(lin, str):
                return lin
            r, Hi_c, Hj_c, R = lin
            Hi, Hj = Hi_c @ C3.world_basis3(s.x), Hj_c @ C3.world_basis3(xj)
            S = Hi @ s.P @ Hi.T + Hi @ Sij @ Hj.T + Hj @ Sij.T @ Hi.T + Hj @ Pjj @ Hj.T + R
        return r, Hi, Hj, 0.5 * (S + S.T), R

    def landmark(self, d: Any, s: Any, target: tuple[str, Any]) -> tuple | str:
        pl, Cl = target[1]
        lin = C3.linearize(d, s.x, pl)
        if isinstance(lin, str):
            return lin
        r, Hi_c, Hl, R = lin
        Hi = Hi_c @ C3.world_basis3(s.x)
        S = Hi @ s.P @ Hi.T + R + Hl @ Cl @ Hl.T
        return r, Hi, 0.5 * (S + S.T), R


FORMS: dict[type, WorldForm] = {SE2: WorldForm(), SE3: WorldForm3()}
"""The world-frame error form of each group."""


class DistributedInvariantEKF(RobotNode):
    """Exact distributed invariant EKF (module docstring). ``team``: every robot id of the team (``make_team``
    passes it). ``cluster``: 0 (default) for the exact filter over the whole team, or ``K >= 1`` robots per
    cluster (module docstring, "Clusters"): replica and broadcasts over the robot's cluster only, covariance
    intersection with robots outside it. The exchange's queries are
    :class:`~swarmloc.estimators.state_exchange.StateQueries`' (``rdl``'s)."""

    name = "diekf"
    lazy_odometry = True
    error_frame: ClassVar[str] = "world"
    update_types = (TeamUpdate,)
    lin_log: list | None = None
    groups: ClassVar[tuple[type, ...]] = (SE2, SE3)
    _state: ClassVar[type] = TeamState
    """The state :meth:`_team_update` returns (``flsd`` keeps its own fields from it)."""

    gated_broadcasts: ClassVar[bool] = True
    """Whether a teammate's broadcast passed its sender's gate as it is (its normalized innovation is checked against
    this node's gate: :meth:`_update_lie`)."""
    clusters: ClassVar[bool] = True
    """Whether the class takes ``cluster > 0`` (``flsd`` does not, nor does an SE(3) team)."""

    def __init__(self, robot: int, initial: GroupGaussian, *, team: Sequence[int] = (), cluster: int = 0,
                 **kw: Any) -> None:  # fmt: skip
        self._form = FORMS.get(getattr(initial, "group", SE2), FORMS[SE2])  # a wrong belief: RobotNode says so
        everyone = tuple(sorted({int(r) for r in team} | {int(robot)}))
        if isinstance(cluster, bool) or not isinstance(cluster, int) or cluster < 0:
            raise ValueError(f"{type(self).__name__}: 'cluster' must be an integer >= 0 (0: the whole team), "
                             f"got {cluster!r}")  # fmt: skip
        if cluster and not (self.clusters and self._form.clusters):
            on = f" on {self._form.group.name}" if self.clusters else ""
            raise ValueError(f"{type(self).__name__} ({self.name}) has no clusters{on}: 'cluster' must be 0")
        if cluster and kw.get("association", "tags") != "tags":
            raise ValueError(f"{self.name}: clusters need tagged detections (association 'tags')")
        self.cluster = cluster
        self.everyone = everyone
        """The whole team; :attr:`team` is this robot's cluster (all of it without clusters)."""
        k = everyone.index(int(robot)) // cluster if cluster else 0
        self.team = everyone[k * cluster : (k + 1) * cluster] if cluster else everyone
        self._pos = {r: k for k, r in enumerate(self.team)}
        self._unusable: set[tuple] = set()
        super().__init__(robot, initial, team=self.team, **kw)
        self._queries = StateQueries(self.robot)

    @property
    def dim(self) -> int:
        """Dimension of a robot's error (3: SE(2); 6: SE(3))."""
        return self._form.dim

    # ------------------------------------------------------------------------------------------------ filter
    def _initial_state(self, t0: float) -> TeamState:
        x, P = self._form.initial(self.initial.mean, self.initial.cov)
        n, d = len(self.team), self._form.dim
        return TeamState(t0, 0.0, 0.0, x, P, np.zeros((n, n, d, d)))

    def _advance(self, s: TeamState, robot: int, t: float) -> TeamState:
        dt = t - s.t
        if dt <= 0:
            return s
        x, P = self._form.predict(s.x, s.P, s.v, s.w, dt, self.noise)
        return TeamState(t, s.v, s.w, x, P, s.Sigma)

    def _set_command(self, s: TeamState, robot: int, v: Any, w: Any) -> TeamState:
        return TeamState(s.t, v, w, s.x, s.P, s.Sigma)

    def _advance_commands(self, s: Any, cmds: Any) -> Any:
        """A run of odometry: :meth:`_advance` and :meth:`_set_command` one by one (predicting in world-frame errors,
        not rdl's Cartesian run), the pose kept in floats between steps (the same numbers)."""
        if self.measure_time or not self._form.runs or type(self)._advance is not DistributedInvariantEKF._advance:
            return Node._advance_commands(self, s, cmds)  # timed, SE(3), or a subclass with more state (flsd)
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
        return belief_of(*self._form.belief(s.x, s.P))

    def _answer(self, s: TeamState, q: Message) -> Answer | None:
        if isinstance(q, RdlStateQuery):
            return RdlState(
                sender=q.receiver,
                receiver=q.sender,
                stamp=q.stamp,
                sub=q.sub,
                x=flat(s.x),
                P=flat(s.P),
                sigma=self._form.eye,
            )
        if isinstance(q, BeliefQuery):
            return super()._answer(s, q)
        return None

    def _team_update(
        self, s: TeamState, i: int, j: int, Hi: np.ndarray, Hj: np.ndarray, Sinv: np.ndarray, nu: np.ndarray,
        Pii: np.ndarray, Pjj: np.ndarray, w: float = 1.0,
    ) -> TeamState:  # fmt: skip
        """Step 3 of the module docstring on this robot's state (``w < 1``: a covariance-intersection update, every
        covariance of the cluster divided by ``w`` first)."""
        if w != 1.0:
            s = s._replace(P=s.P / w, Sigma=s.Sigma / w)
            Pii, Pjj = Pii / w, Pjj / w
        pi, pj, me = self._pos[i], self._pos[j], self._pos[self.robot]
        Ci = s.Sigma[:, pi].copy()
        Ci[pi] = Pii
        if pj == pi:
            Cj = Ci
        else:
            Cj = s.Sigma[:, pj].copy()
            Cj[pj] = Pjj
        if me not in (pi, pj):
            Ci[me], Cj[me] = s.Sigma[me, pi], s.Sigma[me, pj]
        Gam = Ci @ Hi.T + Cj @ Hj.T  # (n, 3, m)
        G = Gam @ Sinv
        Sigma = s.Sigma - np.einsum("aim,bjm->abij", G, Gam)
        Sigma = 0.5 * (Sigma + Sigma.transpose(1, 0, 3, 2))  # Sigma_ba = Sigma_ab^T, as P's symmetrization below
        P = s.P - G[me] @ Gam[me].T
        P = 0.5 * (P + P.T)
        return self._state(s.t, s.v, s.w, self._correct(s.x, Gam[me] @ nu), P, Sigma)

    def _correct(self, x: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """The pose ``x`` corrected by the world-frame ``delta`` (:meth:`WorldForm.correct`)."""
        return self._form.correct(x, delta)

    # ------------------------------------------------------------------------------------------------ update
    def _fuse_group(self, s: TeamState, g: Group) -> tuple[TeamState, list[Outcome], list[Message]]:
        outcomes: list[Outcome] = []
        msgs: list[Message] = []
        mates = [r for r in self.team if r != self.robot]
        for d, sub in zip(g.detections, g.keys, strict=True):
            target = self._classify(g, d, sub)
            if target[0] in ("rejected", "unknown"):
                outcomes.append(target)
                continue
            res = self._one(s, g, d, target)
            if isinstance(res[0], str):
                outcomes.append(res)
                msgs += [TeamUpdate(sender=self.robot, receiver=r, stamp=g.t, sub=sub) for r in mates]  # settled
                continue
            s, (j, Hi, Hj, Sinv, nu, Pii, Pjj, w) = res
            body = dict(
                target=j, m=len(nu), n=self.dim, Hi=flat(Hi), Hj=flat(Hj), Sinv=flat(Sinv), nu=flat(nu), Pii=flat(Pii),
                Pjj=flat(Pjj), **({} if w == 1.0 else {"scale": w}),
            )  # fmt: skip
            msgs += [TeamUpdate(sender=self.robot, receiver=r, stamp=g.t, sub=sub, **body) for r in mates]
            outcomes.append(FUSED)
        return s, outcomes, msgs

    def _one(self, s: TeamState, g: Group, d: Any, target: tuple[str, Any]) -> Any:
        """One detection: the new state and the broadcast's numbers, or an outcome."""
        i, form = self.robot, self._form
        why = form.unsupported(d, target)
        if why is not None:
            return ("rejected", why)
        if target[0] == "robot":
            a: RdlState = target[1]
            j = d.target
            if j not in self._pos:
                if self.cluster and j in self.everyone:
                    return self._outsider(s, i, d, a)
                return ("unknown", f"robot {j} is not in this node's team {list(self.team)}")
            xj, Pjj, _ = a.arrays()
            if xj.shape != s.x.shape:
                return ("rejected", f"the neighbour's answer is not an {form.group.name} state")
            lin = form.robot(d, s, xj, Pjj, s.Sigma[self._pos[i], self._pos[j]])
            if isinstance(lin, str):
                return ("rejected", lin)
            r, Hi, Hj, S, R = lin
        else:
            lin = form.landmark(d, s, target)
            if isinstance(lin, str):
                return ("rejected", lin)
            r, Hi, S, R = lin
            j, Pjj, Hj = i, s.P, np.zeros_like(Hi)
        out = self._gated_update(s, i, j, Hi, Hj, S, r, Pjj)
        if self.lin_log is not None and not isinstance(out[0], str):
            self.lin_log.append(("update", g.t, {i: Hi, j: Hj} if j != i else {i: Hi}, R))
        return out

    def _requests(self, g: Group) -> list[Message]:
        """``rdl``'s queries; with clusters, a robot outside the cluster is asked a ``BeliefQuery`` instead (its
        belief is all :meth:`_outsider` needs, and an answerer outside the cluster waits for no broadcast)."""
        out = self._queries.requests(g, self._needs_answer, self._teammates(g))
        if not self.cluster:
            return out
        kept: dict[tuple, Message] = {}
        for q in out:
            if q.receiver in self._pos:
                kept[(q.receiver, tuple(q.sub))] = q
            else:
                kept.setdefault((q.receiver, ()), BeliefQuery(sender=self.robot, receiver=q.receiver, stamp=q.stamp))
        return list(kept.values())

    def _candidates(self, g: Group, mates: Sequence[int]) -> dict[int, GroupGaussian]:
        return self._queries.candidates(g, mates, self._answered_belief)

    def _answered_belief(self, t: float, x: np.ndarray, P: np.ndarray, robot: int) -> GroupGaussian:
        return self._belief(TeamState(t, 0.0, 0.0, x, P, _NO_SIGMA), robot)

    def _robot_target(self, g: Group, d: Any, sub: tuple) -> tuple[str, Any]:
        if self.cluster and d.target not in self._pos:
            sub = ()  # the BeliefQuery's answer (:meth:`_requests`)
        return super()._robot_target(g, d, sub)

    def _outsider(self, s: TeamState, i: int, d: Any, a: Any) -> Any:
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
        lin = _pair(d, s.x, xj)
        if lin is None:
            return ("rejected", DEGENERATE)
        r, Hi, Hj, R = lin
        A, B = Hi @ s.P @ Hi.T, Hj @ Pjj @ Hj.T
        w = joint_weight(A, B, R, self.dim * len(self.team))
        S = A / w + B / (1.0 - w) + R
        return self._gated_update(s, i, i, Hi, np.zeros_like(Hi), S, r, s.P, w)

    def _gated_update(
        self, s: Any, i: int, j: int, Hi: np.ndarray, Hj: np.ndarray, S: np.ndarray, r: np.ndarray, Pjj: np.ndarray,
        w: float = 1.0,
    ) -> Any:  # fmt: skip
        """The gated team update of one detection with innovation ``r``, its covariance ``S`` and Jacobians
        ``Hi``, ``Hj`` (the SE(2) and SE(3) forms share it; ``w < 1``: a covariance-intersection one,
        :meth:`_outsider`): ``(new state, the broadcast's numbers)``, or an outcome (gated, or rejected when ``S``
        is singular or the result not finite)."""
        try:
            Sinv = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            return ("rejected", NUMERICAL)
        Sinv = 0.5 * (Sinv + Sinv.T)
        nu = Sinv @ r
        verdict = self._gated(float(r @ nu), len(r))
        if verdict is not None:
            return verdict
        new = self._team_update(s, i, j, Hi, Hj, Sinv, nu, s.P, Pjj, w)
        if not (np.isfinite(new.x).all() and usable_covariance(new.P) and np.isfinite(new.Sigma).all()):
            return ("rejected", NUMERICAL)
        return new, (j, Hi, Hj, Sinv, nu, s.P, Pjj, w)

    # ------------------------------------------------------------------------------------------------ broadcasts
    def _settle(self, g: Group) -> list[Message]:
        """An empty broadcast under the key of every found answer that no detection used
        (:meth:`~swarmloc.estimators.state_exchange.StateQueries.unused`): the answerer knows the exchange is settled
        (each teammate counts it ``no_update``)."""
        mates = [r for r in self.team if r != self.robot]
        return [
            TeamUpdate(sender=self.robot, receiver=m, stamp=g.t, sub=k)
            for _, k, a in self._queries.unused(g)
            if a.found
            for m in mates
        ]

    def _update_problem(self, u: Message) -> str | None:
        if u.sender not in self._pos or (not u.empty and u.target not in self._pos):
            return f"team update from or about a robot outside the team {list(self.team)}"
        if not u.empty and u.n != self.dim:
            return f"team update of a {u.n}-dof error; this node's error has {self.dim} dof"
        return None

    def _apply_update(self, s: TeamState, u: TeamUpdate) -> tuple[TeamState, bool]:
        # The detected robot is predicted to the stamp; a third party is not: a world-frame correction commutes
        # with the odometry (exp(d) g Delta), so it applies at the robot's own clock. This is what the
        # centralized filter does with its blocks (the same process-noise linearization points, same numbers).
        if u.target == self.robot:
            s = self._adv(s, self.robot, u.stamp)
        m, n = u.m, u.n
        A = np.array  # np.array(t).reshape: what np.reshape(t) makes of a tuple, without its dispatch
        Hi, Hj = A(u.Hi).reshape(m, n), A(u.Hj).reshape(m, n)
        Sinv, nu = A(u.Sinv).reshape(m, m), A(u.nu)
        Pii, Pjj = A(u.Pii).reshape(n, n), A(u.Pjj).reshape(n, n)
        new = self._team_update(s, u.sender, u.target, Hi, Hj, Sinv, nu, Pii, Pjj, float(u.scale))
        usable = positive_definite(new.P)
        self._count_unusable((float(u.stamp), P_GROUP, u.sender, tuple(u.sub)), not usable)
        return (new if usable else s), True

    def _count_unusable(self, key: tuple, unusable: bool) -> None:
        """Keep ``updates_unusable`` the number of broadcasts whose last application left this robot's covariance not
        positive definite (not applied: no honest broadcast does that, :mod:`~swarmloc.node.trust`)."""
        if unusable and key not in self._unusable:
            self._unusable.add(key)
            self.counts["updates_unusable"] += 1
        elif not unusable and key in self._unusable:
            self._unusable.discard(key)
            self.counts["updates_unusable"] -= 1

    def _prune(self) -> None:
        super()._prune()
        cutoff = self._clock.present - self.horizon
        self._unusable = {k for k in self._unusable if k[0] >= cutoff}  # (their count stands)

    def _update_lie(self, u: Message) -> str | None:
        """A broadcast must be what a teammate with this node's gate sent: its own normalized innovation ``nu^T S nu
        <= gamma_m`` (the sender's gate held it), and scaled only as a cluster's covariance-intersection update of
        its sender alone, ``w`` within the bounds the sender chooses it in (:mod:`~swarmloc.node.trust`)."""
        if self.gate.p is None or not isinstance(u, TeamUpdate) or u.empty:
            return None
        if u.scale != 1.0 and not (self.cluster and u.target == u.sender and u.scale >= W_BOUNDS[0]):
            return f"broadcast of robot {u.sender} scaled as no robot of this team scales one"
        m = u.m
        if not self.gated_broadcasts or fits(self.gate, broadcast_nis(np.reshape(u.Sinv, (m, m)), np.array(u.nu)), m):
            return None
        return f"broadcast of robot {u.sender} beyond the gate"
