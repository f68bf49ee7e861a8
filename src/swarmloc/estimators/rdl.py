"""Recursive decentralized localization (``"rdl"``; Luft, Schubert, Roumeliotis & Burgard, IJRR 2018).

Each node keeps its robot's Cartesian state ``x_i``, covariance ``P_ii`` and, for every robot ``l`` it has
exchanged with, a factor ``sigma_il`` such that the cross-covariance is ``Sigma_il = sigma_il sigma_li^T``
(robots start independent: a robot not yet met has ``sigma = 0``). Prediction updates only the node's own
factors (``sigma_il <- Phi_i sigma_il``). A relative measurement of ``j`` by ``i`` needs only the two robots:
``i`` asks ``j`` for ``(x_j, P_jj, sigma_ji)`` (:class:`~swarmloc.messages.RdlStateQuery`), performs the joint
EKF update exactly, keeps its part (``sigma_ij <- P_ij+``) and sends ``j`` its new ``(x_j, P_jj)``
(:class:`~swarmloc.messages.RdlUpdate`, which names the revision of ``j``'s answer it was computed from; ``j``
sets ``sigma_ji <- I``). The cross-covariances with all other robots are updated approximately by
``Sigma_il+ = P_ii+ P_ii-^-1 Sigma_il-`` (only ``i``'s factor changes). Absolute fixes and landmarks are private
updates with the same rescaling.

It reaches close to the centralized EKF's accuracy while staying (approximately) consistent, with pairwise
communication only; with two robots it equals the centralized EKF. Without landmarks (the team's pose
unobservable) the approximation of the third-party correlations breaks down (docs/mrclam.md, MRCLAM table).

The exchange is :class:`RdlNode`'s, whatever the errors' coordinates: those are its :class:`PairForm`, Cartesian here
(:class:`CartesianPairs`), world-frame in ``irdl`` (:mod:`swarmloc.estimators.irdl`).

**An exchange that does not complete** (the update lost, late past the horizon, refused as computed from an
outdated answer; the answer or the query lost) leaves the pair's bookkeeping unknown: the observer may have applied
the joint update (keeping ``sigma_ij <- P_ij+``) while the target did not (``sigma_ji`` not reset). The target
cannot tell which, so it refuses the correlation rather than guess: answering an ``RdlStateQuery`` files an
:class:`Unconfirmed` placeholder at the exchange's key, which drops ``sigma_ji`` until the observer's update
replaces it, or its "no update" (or its notice that no answer reached it: an empty update with ``based_on < 0``)
removes it (the robot stays in ``ids``, its factor zero: met, no longer tracked). A pair of which a side has
dropped its factor, or whose target tracks a correlation the observer never had (a restart), or whose tracked joint
covariance is not positive definite, fuses as if the correlation were unknown: the joint prior is bounded by
covariance intersection, ``blockdiag(P_ii / w, P_jj / (1 - w))``, valid whatever the true cross-covariance (the pair
math, written once for the nodes and the engine's compiled replay, is :mod:`swarmloc.kernels.pairs`'). When both
robots gain from that update, both take it and the factors restart from it (observer ``sigma_ij <- P_ij+``,
target ``sigma_ji <- I``); else the observer alone takes its part, drops its own factor, and the target gets "no
update" (the pair stays untracked); a measurement that helps neither is not fused (``gated``). A restarted node (no
factors) is fused the same way. An update computed from a revision of the answer that differs from the latest by
less than :func:`near` still applies (most revisions under delay are that small). Without faults every placeholder
is replaced by its update before anything reads it, so the result is
unchanged (``tests/test_net.py``: networked = in-process; ``tests/test_rdl_faults.py``).

**A lying teammate** (:mod:`swarmloc.node.trust`). An update must move this robot from the state it answered by a
correction within the gate, ``delta^T P^-1 delta <= gamma_3`` (which every honest joint update of a tracked or
independent pair meets); one beyond is refused before it is filed (``updates_refused``, ``suspect_<sender>``), which
leaves the exchange as a lost update leaves it (its placeholder stands: the pair's correlation is dropped), and
three in a row quarantine the sender.

**Anonymous detections** (``association`` ``nearest`` or ``joint``, :mod:`swarmloc.node.associate`): the pair's
exchange needs the target before the question, so for each anonymous detection ``d`` the observer asks **every
teammate** ``r`` with an ``RdlStateQuery`` keyed :func:`~swarmloc.estimators.state_exchange.anonymous_sub` ``(d, r)``,
the key ``d`` would have were it of ``r``, and with a ``BeliefQuery`` for its belief before the scan, from which the
identity is chosen (:meth:`~swarmloc.node.robot.RobotNode._candidates`; why not from the first answers:
:mod:`~swarmloc.estimators.state_exchange`); the detection given
``r`` is fused under that key from ``r``'s answer, so the true target's exchange is the tagged run's, and every
other teammate gets "no update" (:meth:`RecursiveDecentralized._settle`), which removes the
:class:`Unconfirmed` placeholder its answer filed. A replay that changes the identity changes which teammate gets
the update and which "no update" (the one retracts, the other files). Cost: ``n - 1`` queries, answers and updates
per anonymous detection, and ``n - 1`` belief queries and answers per scan; with two or more in one scan, a
teammate's answer to the second is computed while the first one's placeholder stands (its factor for the observer
dropped) and is revised once that "no update" arrives, so the update computed from it is refused as stale and sent
again (``tests/test_association_node.py``: where every identity
is right the beliefs equal the tagged run's bit for bit, in process and over Zenoh).
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Sequence
from typing import Any, ClassVar, NamedTuple, Protocol

import numpy as np

from swarmloc.estimators.dekf import linearize, predict_run
from swarmloc.estimators.state_exchange import StateQueries
from swarmloc.events import Detection
from swarmloc.gaussian import GroupGaussian
from swarmloc.kernels import cartesian as C
from swarmloc.kernels.pairs import PAIRS
from swarmloc.lie import wrap_angle
from swarmloc.messages import Answer, BeliefQuery, Message, RdlState, RdlStateQuery, RdlUpdate, flat
from swarmloc.node import (
    FUSED,
    P_GROUP,
    Entry,
    Gate,
    Group,
    Key,
    Outcome,
    RobotNode,
    belief_of,
    correction_nis,
    fits,
    gated_kalman,
    same,
)
from swarmloc.node.keys import SubKey
from swarmloc.sensors.models import DEGENERATE, model

_ZERO = np.zeros((3, 3))
_ZERO.setflags(write=False)
_NO_FACTORS = np.zeros((0, 3, 3))
_NO_FACTORS.setflags(write=False)
UNKNOWN_CORRELATION = "the pair's correlation is unknown and the measurement too weak to bound it"
NEAR_MAHALANOBIS = 1e-4
"""[squared Mahalanobis] Largest change of an answer's mean for which an update computed before it still applies."""
NEAR_RELATIVE = 1e-3
"""Largest relative change of an answer's covariance and factor for which an update computed before it applies."""


class Unconfirmed(NamedTuple):
    """History placeholder of a pairwise exchange this node answered (as the target) whose update has not come: until
    the observer's update replaces it or its "no update" removes it, the node forgets its factor for ``observer``."""

    observer: int


class RdlFilter(NamedTuple):
    """A node's filter state: time [s], command ``(v, w)``, ``x (3,)``, ``P (3, 3)``, the ids of the robots it has
    exchanged with (sorted), their factors as stored ``sigma (len(ids), 3, 3)``, and the shear ``(sa, sb)`` that the
    predictions since the last update owe them.

    A prediction multiplies every factor by ``Phi = [[1, 0, -dy], [0, 1, dx], [0, 0, 1]]``; such matrices compose by
    adding their two entries, so predictions only add to ``(sa, sb)`` and the factors are
    ``S(sa, sb) @ sigma`` (:meth:`factors`), applied when an update needs them.
    """

    t: float
    v: float
    w: float
    x: np.ndarray
    P: np.ndarray
    ids: tuple[int, ...]
    sigma: np.ndarray
    sa: float = 0.0
    sb: float = 0.0

    def factors(self) -> np.ndarray:
        """Every factor ``sigma_il`` with the pending shear applied, ``(len(ids), 3, 3)``."""
        if not self.sa and not self.sb:
            return self.sigma
        out: np.ndarray = PAIRS.sheared(self.sigma, self.sa, self.sb)
        return out

    def factor(self, robot: int) -> np.ndarray:
        """``sigma_i,robot`` (zero for a robot never met)."""
        i = bisect_left(self.ids, robot)
        if not (i < len(self.ids) and self.ids[i] == robot):
            return _ZERO
        f: np.ndarray = self.sigma[i]
        if not self.sa and not self.sb:
            return f
        out: np.ndarray = PAIRS.sheared(f, self.sa, self.sb)
        return out

    def without_factor(self, robot: int) -> RdlFilter:
        """The same filter with the factor for ``robot`` zero while ``robot`` stays in ``ids``: a robot met whose
        correlation is no longer tracked (a robot never met is not in ``ids``)."""
        i = bisect_left(self.ids, robot)
        if not (i < len(self.ids) and self.ids[i] == robot):
            return self
        sigma = self.sigma.copy()
        sigma[i] = 0.0
        return self._replace(sigma=sigma)

    def with_factor(self, robot: int, value: np.ndarray, sigma: np.ndarray) -> tuple[tuple[int, ...], np.ndarray]:
        """``(ids, sigma)`` with ``robot``'s factor set to ``value`` (added when new) in ``sigma`` (factors with no
        pending shear, e.g. from :func:`rescale_factors`)."""
        i = bisect_left(self.ids, robot)
        if i < len(self.ids) and self.ids[i] == robot:
            sigma = sigma.copy()
            sigma[i] = value
            return self.ids, sigma
        return (*self.ids[:i], robot, *self.ids[i:]), np.insert(sigma, i, value, axis=0)


def near(a: RdlState, b: RdlState) -> bool:
    """Whether two revisions of one answer differ so little that an update computed from one applies to the other:
    the means by less than :data:`NEAR_MAHALANOBIS` (squared, in ``b``'s covariance), the covariances and the factors
    by less than :data:`NEAR_RELATIVE` (relative). Most revisions under link faults are that small (late news of a
    third robot); refusing their updates would leave most exchanges unconfirmed."""
    if same(a, b):
        return True
    xa, Pa, sa = a.arrays()
    xb, Pb, sb = b.arrays()
    d = xa - xb
    d[2] = wrap_angle(d[2])
    try:
        if d @ np.linalg.solve(Pb, d) > NEAR_MAHALANOBIS:
            return False
        if np.abs(np.linalg.solve(Pb, Pa) - np.eye(3)).max() > NEAR_RELATIVE:
            return False
    except np.linalg.LinAlgError:
        return False
    scale = max(float(np.abs(sb).max()), float(np.abs(sa).max()))
    return bool(scale == 0.0 or np.abs(sa - sb).max() <= NEAR_RELATIVE * scale)


def rescale_factors(s: RdlFilter, P_new: np.ndarray) -> np.ndarray:
    """``sigma_il <- P_new P_old^-1 sigma_il`` for every robot ``l`` (Luft et al.'s approximation;
    :mod:`swarmloc.kernels.pairs`' ``rescaled``); the result has no pending shear."""
    out: np.ndarray = PAIRS.rescaled(P_new, s.P, s.sigma, s.sa, s.sb)
    return out


class PairForm(Protocol):
    """The error coordinates of a pairwise node's filter (:class:`RdlNode`): its start, prediction, belief,
    Jacobians and correction. A form's steps take the node for its noise and gate."""

    def initial(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(x, P)`` of the robot's initial right-perturbation belief."""

    def advance(self, node: RdlNode, s: RdlFilter, t: float) -> RdlFilter:
        """``s`` predicted to ``t`` [s] (later than ``s.t``)."""

    def advance_commands(
        self, node: RdlNode, s: RdlFilter, cmds: Sequence[tuple[float, int, float, float]]
    ) -> RdlFilter | None:
        """A run of odometry in one float loop (the same bits as one :meth:`advance` per command), or None where the
        form has none (the node then predicts command by command)."""

    def belief(self, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The right-perturbation belief ``(mean, cov)`` of ``(x, P)``."""

    def correction(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        """The correction that takes the state ``x0`` to ``x1`` in the form's error coordinates."""

    def to_error(self, H: np.ndarray, x: np.ndarray) -> np.ndarray:
        """A Cartesian Jacobian block at ``x`` in the form's error coordinates."""

    def update(
        self, x: np.ndarray, P: np.ndarray, r: np.ndarray, H: np.ndarray, R: np.ndarray, gate: Gate
    ) -> tuple[np.ndarray, np.ndarray] | Outcome:
        """The gated update of the poses ``x`` (``(3,)``, or a pair's ``(2, 3)``) with covariance ``P`` by the
        innovation ``r``, Jacobian ``H`` and noise ``R``: the new poses (shaped as ``x``) and covariance, or the outcome
        that stops it."""


class CartesianPairs:
    """Cartesian errors (:mod:`swarmloc.kernels.cartesian`): the :class:`PairForm` of ``rdl``."""

    initial = staticmethod(C.from_group)
    belief = staticmethod(C.to_group)

    def advance(self, node: RdlNode, s: RdlFilter, t: float) -> RdlFilter:
        x, P, dx, dy = C.predict_one(s.x, s.P, s.v, s.w, t - s.t, node.noise)
        return RdlFilter(t, s.v, s.w, x, P, s.ids, s.sigma, s.sa - dy, s.sb + dx)  # sigma <- Phi sigma, deferred

    def advance_commands(
        self, node: RdlNode, s: RdlFilter, cmds: Sequence[tuple[float, int, float, float]]
    ) -> RdlFilter:
        """The factors' deferred shear accumulated as :meth:`advance` does."""
        x, P, t, (v, w), (sa, sb) = predict_run(s, (s.sa, s.sb), cmds, node.noise)
        return RdlFilter(t, v, w, x, P, s.ids, s.sigma, sa, sb)

    def correction(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        """``x1 - x0``, the angle wrapped."""
        d: np.ndarray = x1 - x0
        d[2] = wrap_angle(d[2])
        return d

    def to_error(self, H: np.ndarray, x: np.ndarray) -> np.ndarray:
        return H

    def update(
        self, x: np.ndarray, P: np.ndarray, r: np.ndarray, H: np.ndarray, R: np.ndarray, gate: Gate
    ) -> tuple[np.ndarray, np.ndarray] | Outcome:
        res = gated_kalman(x.reshape(-1), P, r, H, R, gate, angles=tuple(range(2, x.size, 3)))
        if isinstance(res[0], str):
            return res
        return res[0].reshape(x.shape), res[1]


class RdlNode(RobotNode):
    """The node of recursive decentralized localization (module docstring): pairwise exact updates, tracked
    correlations, in the error coordinates of its :attr:`form`."""

    form: ClassVar[PairForm]
    """The estimator's error coordinates."""
    update_types = (RdlUpdate,)
    lazy_odometry = True
    lin_log: list[tuple[Any, ...]] | None = None
    """Set to a list to record every applied update's linearization (:mod:`swarmloc.evaluation.observability`;
    predictions are not recorded, so the record is complete only where their error transition is the identity:
    world-frame errors, ``irdl``)."""

    def _initial_state(self, t0: float) -> RdlFilter:
        x, P = self.form.initial(self.initial.mean, self.initial.cov)
        return RdlFilter(t0, 0.0, 0.0, x, P, (), np.zeros((0, 3, 3)))

    def _advance(self, s: RdlFilter, robot: int, t: float) -> RdlFilter:
        return s if t - s.t <= 0 else self.form.advance(self, s, t)

    def _set_command(self, s: RdlFilter, robot: int, v: float, w: float) -> RdlFilter:
        return RdlFilter(s.t, v, w, s.x, s.P, s.ids, s.sigma, s.sa, s.sb)

    def _advance_commands(self, s: RdlFilter, cmds: Sequence[tuple[float, int, float, float]]) -> RdlFilter:
        """A run of odometry (:meth:`PairForm.advance_commands` where the form has one)."""
        run = None if self.measure_time else self.form.advance_commands(self, s, cmds)
        return super()._advance_commands(s, cmds) if run is None else run

    def _belief(self, s: RdlFilter, robot: int) -> GroupGaussian:
        return belief_of(*self.form.belief(s.x, s.P))

    # ------------------------------------------------------------------------------------------------ exchange
    def _requests(self, g: Group) -> list[Message]:
        """:class:`~swarmloc.estimators.state_exchange.StateQueries`' queries: one ``RdlStateQuery`` per tagged robot
        detection and, with an association policy, one per anonymous detection and teammate."""
        return self._queries.requests(g, self._needs_answer, self._teammates(g))

    def _settle(self, g: Group) -> list[Message]:
        """ "No update" for every unused answer (:meth:`~swarmloc.estimators.state_exchange.StateQueries.unused`): it
        closes its answerer's :class:`Unconfirmed` placeholder; an answer that never came (``seq < 0``) gets the
        no-answer notice, as a tagged exchange."""
        return [
            RdlUpdate(sender=self.robot, receiver=r, stamp=g.t, sub=k, based_on=a.seq if a.found else -1)
            for r, k, a in self._queries.unused(g)
            if a.found or a.seq < 0
        ]

    def _answer(self, s: RdlFilter, q: Message) -> Answer | None:
        if isinstance(q, RdlStateQuery):
            return self._state(s, q)
        if isinstance(q, BeliefQuery):
            return super()._answer(s, q)
        return None

    def _state(self, s: RdlFilter, q: RdlStateQuery) -> RdlState:
        """This node's answer to ``q`` from ``s``: its state and its factor for the asking robot."""
        return RdlState(
            sender=q.receiver, receiver=q.sender, stamp=q.stamp, sub=q.sub,
            x=flat(s.x), P=flat(s.P), sigma=flat(s.factor(q.sender)),
        )  # fmt: skip

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._queries = StateQueries(self.robot)
        self._answered: dict[tuple[Key, int], RdlState] = {}
        """Every revision of the states this node answered with, by ``(exchange key, revision)``: an update computed
        from a revision that differs from the latest by less than :func:`near` still applies."""

    def _revise(self, after: Any) -> list[Message]:
        return self._keep(super()._revise(after))

    def _keep(self, msgs: list[Message]) -> list[Message]:
        for m in msgs:
            if isinstance(m, RdlState) and m.found:
                self._answered[((float(m.stamp), P_GROUP, m.receiver, tuple(m.sub)), m.seq)] = m
        return msgs

    def _prune(self) -> None:
        super()._prune()
        cutoff = self._clock.present - self.horizon
        for k in [k for k in self._answered if k[0][0] < cutoff]:
            del self._answered[k]

    def _on_query(self, q: Message) -> list[Message]:
        """Answer as every node does; an ``RdlStateQuery`` answered with this node's state also files an
        :class:`Unconfirmed` placeholder at the exchange's key (module docstring), unless an update is filed there."""
        out = self._keep(super()._on_query(q))
        if isinstance(q, RdlStateQuery) and len(out) == 1 and isinstance(out[0], RdlState) and out[0].found:
            key = (float(q.stamp), P_GROUP, q.sender, tuple(q.sub))
            if self._history.find(key) is None:
                self.counts["updates_missing"] += 1
                out += self._file([Entry(key, "update", Unconfirmed(q.sender))], accept=False)
        return out

    def _placeholder(self, data: Any) -> bool:
        return isinstance(data, Unconfirmed)

    def _update_problem(self, u: Message) -> str | None:
        """An update (or "no update") must answer a state this node sent, in its latest revision; or be the
        observer's notice that no answer reached it (empty, ``based_on < 0``), which only closes an exchange still
        waiting for its update (its :class:`Unconfirmed` placeholder)."""
        if not isinstance(u, RdlUpdate):
            return f"not an update of {self.name}"
        key = (float(u.stamp), 1, u.sender, tuple(u.sub))
        served = self._exchange.served.get((key, u.sender, "RdlStateQuery"))
        if not isinstance(served, RdlState):
            return "update for a state this node never sent"
        pos = self._history.find(key)
        filed = None if pos is None else self._history.entries[pos].data
        if u.empty and u.based_on < 0:
            if not isinstance(filed, Unconfirmed):
                return "no-answer notice for an exchange that is not open"
            return None
        if u.based_on != served.seq:
            basis = self._answered.get((key, u.based_on))
            newer = isinstance(filed, RdlUpdate) and filed.based_on > u.based_on
            if u.empty or newer or basis is None or not near(basis, served):
                return "update computed from an outdated state (stale)"
        return None

    def _basis(self, u: RdlUpdate) -> RdlState | None:
        """The answer ``u`` was computed from: this node's state of revision ``u.based_on`` sent for its exchange
        (None: not kept)."""
        key = (float(u.stamp), 1, u.sender, tuple(u.sub))
        served = self._exchange.served.get((key, u.sender, "RdlStateQuery"))
        if isinstance(served, RdlState) and served.seq == u.based_on:
            return served
        return self._answered.get((key, u.based_on))

    def _update_lie(self, u: Message) -> str | None:
        """An update must move this robot from the state it was computed from by a correction ``delta`` within the
        gate, ``delta^T P^-1 delta <= gamma_3`` (:mod:`~swarmloc.node.trust`: an honest observer's gated joint update
        passes by construction)."""
        if not isinstance(u, RdlUpdate) or self.gate.p is None:
            return None
        basis = self._basis(u)
        if basis is None:
            return None
        x0, P0, _ = basis.arrays()
        if fits(self.gate, correction_nis(self.form.correction(x0, u.arrays()[0]), P0), 3):
            return None
        return f"update of robot {u.sender} beyond the gate of this robot's own belief"

    def _apply_update(self, s: RdlFilter, u: Message | Unconfirmed) -> tuple[RdlFilter, bool]:
        """A neighbour's joint update, while the state it was computed from is still the state before its key: new
        ``(x, P)``, ``sigma_ji <- I``, the other factors rescaled. A placeholder, or an update that no longer
        applies (the state it was computed from changed: a revised answer went out, a new update may follow), drops
        the factor for the observer and stays filed until that update replaces it."""
        if isinstance(u, Unconfirmed):
            return s.without_factor(u.observer), True
        if not isinstance(u, RdlUpdate):
            raise TypeError(f"{self.name}: {type(u).__name__} is not an update it files")
        s = self._adv(s, u.receiver, u.stamp)
        q = RdlStateQuery(sender=u.sender, receiver=u.receiver, stamp=u.stamp, sub=u.sub)
        basis = self._basis(u)
        if basis is None or not near(basis, self._state(s, q)):
            return s.without_factor(u.sender), True  # a revised answer went out: its update will replace this
        x, P = u.arrays()
        sigma = rescale_factors(s, P)
        ids, sigma = s.with_factor(u.sender, np.eye(3), sigma)
        return RdlFilter(s.t, s.v, s.w, x, P, ids, sigma), True

    # ------------------------------------------------------------------------------------------------ update
    def _fuse_group(self, s: RdlFilter, g: Group) -> tuple[RdlFilter, list[Outcome], list[Message]]:
        outcomes: list[Outcome] = []
        msgs: list[Message] = []
        for d, sub in zip(g.detections, g.keys, strict=True):
            target = self._classify(g, d, sub)
            if target[0] in ("rejected", "unknown"):
                outcomes.append(target)
                a = g.answers.get((d.target, sub)) if d.target_is_robot and d.target is not None else None
                if a is not None and not a.found and a.seq < 0:  # no answer reached this node: tell the target
                    msgs.append(RdlUpdate(sender=self.robot, receiver=a.sender, stamp=g.t, sub=sub, based_on=-1))
                continue
            res = self._pair(s, g, d, sub, target[1]) if target[0] == "robot" else self._private(s, d, target)
            if isinstance(res[0], str):
                outcomes.append(res)
                if target[0] == "robot":  # tell the target that no update follows its answer
                    a = target[1]
                    msgs.append(RdlUpdate(sender=self.robot, receiver=a.sender, stamp=g.t, sub=sub, based_on=a.seq))
                continue
            s = res[0]
            if res[1] is not None:
                msgs.append(res[1])
            outcomes.append(FUSED)
        return s, outcomes, msgs

    def _private(self, s: RdlFilter, d: Any, target: tuple[str, Any]) -> Any:
        """Absolute fix or landmark: a private update, then every factor rescaled."""
        lin = linearize(d, s.x, target)
        if isinstance(lin, str):
            return ("rejected", lin)
        r, Hi, R_eff, _ = lin
        H = self.form.to_error(Hi, s.x)
        res = self.form.update(s.x, s.P, r, H, R_eff, self.gate)
        if isinstance(res[0], str):
            return res
        x, P = res
        self._log_update(d.t, {self.robot: H}, R_eff)
        return RdlFilter(s.t, s.v, s.w, x, P, s.ids, rescale_factors(s, P)), None

    def _pair(self, s: RdlFilter, g: Group, d: Detection, sub: SubKey, a: RdlState) -> Any:
        """The joint update of observer ``i`` and target ``j`` from ``j``'s answer ``a``."""
        j = a.sender
        m = model(d.kind)
        xj, Pjj, sig_ji = a.arrays()
        if m.degenerate(s.x, xj):
            return ("rejected", DEGENERATE)
        h, Hi, Hj = m.predict(s.x, xj)
        assert Hj is not None  # noqa: S101  (a relative model: a Jacobian for the target)
        H = np.hstack([self.form.to_error(Hi, s.x), self.form.to_error(Hj, xj)])
        R = m.noise(d.z, d.cov)
        prior, joint = PAIRS.pair_prior(s.P, Pjj, s.factor(j), sig_ji, j in s.ids, H, R)
        if joint < 0:  # the correlation unknown and the measurement too weak to bound it
            return ("gated", UNKNOWN_CORRELATION)
        res = self.form.update(np.stack([s.x, xj]), prior, m.residual(d.z, h), H, R, self.gate)
        if isinstance(res[0], str):
            return res
        X, Pn = res
        self._log_update(g.t, {self.robot: H[:, :3], j: H[:, 3:]}, R)
        return self._pair_result(s, g, sub, a, X[0], X[1], Pn, joint == 1)

    def _log_update(self, t: float, blocks: dict[int, np.ndarray], R: np.ndarray) -> None:
        if self.lin_log is not None:
            self.lin_log.append(("update", t, blocks, R))

    def _pair_result(
        self,
        s: RdlFilter,
        g: Group,
        sub: SubKey,
        a: RdlState,
        xi: np.ndarray,
        xj: np.ndarray,
        Pn: np.ndarray,
        joint: bool,
    ) -> tuple[RdlFilter, RdlUpdate]:
        """The observer's new filter and the target's update from the joint posterior ``Pn (6, 6)``: both take their
        part (``sigma_ij <- P_ij+``; the target sets ``sigma_ji <- I``), or, with ``joint`` False (a covariance
        intersection that only the observer gains from), the observer alone, its factors rescaled, and the target
        gets "no update" (the pair's correlation stays unknown)."""
        Pi = Pn[:3, :3]
        if not joint:  # the observer's correlation with the target is unknown now: its factor dropped
            new = RdlFilter(s.t, s.v, s.w, xi, Pi, s.ids, rescale_factors(s, Pi)).without_factor(a.sender)
            return new, RdlUpdate(sender=self.robot, receiver=a.sender, stamp=g.t, sub=sub, based_on=a.seq)
        ids, sigma = s.with_factor(a.sender, Pn[:3, 3:], rescale_factors(s, Pi))
        new = RdlFilter(s.t, s.v, s.w, xi, Pi, ids, sigma)
        update = RdlUpdate(
            sender=self.robot, receiver=a.sender, stamp=g.t, sub=sub, based_on=a.seq, x=flat(xj), P=flat(Pn[3:, 3:])
        )
        return new, update


class RecursiveDecentralized(RdlNode):
    """Recursive decentralized localization in Cartesian errors (module docstring): :class:`CartesianPairs`."""

    name = "rdl"
    form = CartesianPairs()
