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
unobservable) the approximation of the third-party correlations breaks down (README, MRCLAM table).
"""

from __future__ import annotations

from bisect import bisect_left
from typing import Any, NamedTuple

import numpy as np

from swarmloc.estimators.dekf import DEGENERATE, CartState, DistributedEKF, linearize
from swarmloc.kernels import cartesian as C
from swarmloc.messages import BeliefQuery, Message, RdlState, RdlStateQuery, RdlUpdate, flat
from swarmloc.node import FUSED, Group, Outcome, gated_kalman, same
from swarmloc.sensors.models import model

_ZERO = np.zeros((3, 3))
_ZERO.setflags(write=False)


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
        out = self.sigma.copy()
        out[:, 0, :] += self.sa * self.sigma[:, 2, :]
        out[:, 1, :] += self.sb * self.sigma[:, 2, :]
        return out

    def factor(self, robot: int) -> np.ndarray:
        """``sigma_i,robot`` (zero for a robot never met)."""
        i = bisect_left(self.ids, robot)
        if not (i < len(self.ids) and self.ids[i] == robot):
            return _ZERO
        f = self.sigma[i]
        if not self.sa and not self.sb:
            return f
        return np.array([f[0] + self.sa * f[2], f[1] + self.sb * f[2], f[2]])

    def with_factor(self, robot: int, value: np.ndarray, sigma: np.ndarray) -> tuple[tuple, np.ndarray]:
        """``(ids, sigma)`` with ``robot``'s factor set to ``value`` (added when new) in ``sigma`` (factors with no
        pending shear, e.g. from :func:`rescale_factors`)."""
        i = bisect_left(self.ids, robot)
        if i < len(self.ids) and self.ids[i] == robot:
            sigma = sigma.copy()
            sigma[i] = value
            return self.ids, sigma
        return (*self.ids[:i], robot, *self.ids[i:]), np.insert(sigma, i, value, axis=0)


def rescale_factors(s: RdlFilter, P_new: np.ndarray) -> np.ndarray:
    """``sigma_il <- P_new P_old^-1 sigma_il`` for every robot ``l`` (Luft et al.'s approximation); the result has no
    pending shear."""
    if not s.ids:
        return s.sigma
    return (P_new @ np.linalg.inv(s.P)) @ s.factors()


class RecursiveDecentralized(DistributedEKF):
    """Recursive decentralized localization: pairwise exact updates, tracked correlations (module docstring)."""

    name = "rdl"
    update_types = (RdlUpdate,)

    def _initial_state(self, t0: float) -> RdlFilter:
        s = super()._initial_state(t0)
        return RdlFilter(s.t, s.v, s.w, s.x, s.P, (), np.zeros((0, 3, 3)))

    def _advance(self, s: RdlFilter, robot: int, t: float) -> RdlFilter:
        dt = t - s.t
        if dt <= 0:
            return s
        x, P, dx, dy = C.predict_one(s.x, s.P, s.v, s.w, dt, self.noise)
        return RdlFilter(t, s.v, s.w, x, P, s.ids, s.sigma, s.sa - dy, s.sb + dx)  # sigma <- Phi sigma, deferred

    def _set_command(self, s: RdlFilter, robot: int, v: float, w: float) -> RdlFilter:
        return RdlFilter(s.t, v, w, s.x, s.P, s.ids, s.sigma, s.sa, s.sb)

    def _advance_commands(self, s: Any, cmds: Any) -> Any:
        """A run of odometry in one float loop, the factors' deferred shear accumulated as :meth:`_advance` does
        (the same bits as one :meth:`_advance` per command)."""
        if self.measure_time:
            return super(DistributedEKF, self)._advance_commands(s, cmds)
        x, P, t, (v, w), (sa, sb) = self._predict_run(s, (s.sa, s.sb), cmds)
        return RdlFilter(t, v, w, x, P, s.ids, s.sigma, sa, sb)

    def _belief(self, s: RdlFilter, robot: int) -> Any:
        return super()._belief(CartState(s.t, s.v, s.w, s.x, s.P), robot)

    # ------------------------------------------------------------------------------------------------ exchange
    def _requests(self, g: Group) -> list[Message]:
        return [
            RdlStateQuery(sender=self.robot, receiver=d.target, stamp=g.t, sub=k)
            for d, k in zip(g.detections, g.keys, strict=True)
            if self._needs_answer(g, d)
        ]

    def _answer(self, s: RdlFilter, q: Message) -> Message | None:
        if isinstance(q, RdlStateQuery):
            return RdlState(
                sender=q.receiver, receiver=q.sender, stamp=q.stamp, sub=q.sub,
                x=flat(s.x), P=flat(s.P), sigma=flat(s.factor(q.sender)),
            )  # fmt: skip
        if isinstance(q, BeliefQuery):
            return super()._answer(s, q)
        return None

    def _update_problem(self, u: Message) -> str | None:
        """An update must answer a state this node sent, in its latest revision."""
        served = self._served.get(((float(u.stamp), 1, u.sender, tuple(u.sub)), u.sender, "RdlStateQuery"))
        if served is None:
            return "update for a state this node never sent"
        if u.based_on != served.seq:
            return "update computed from an outdated state (stale)"
        return None

    def _apply_update(self, s: RdlFilter, u: RdlUpdate) -> tuple[RdlFilter, bool]:
        """A neighbour's joint update, while the state it was computed from is still the state before its key: new
        ``(x, P)``, ``sigma_ji <- I``, the other factors rescaled."""
        s = self._adv(s, u.receiver, u.stamp)
        key = (float(u.stamp), 1, u.sender, tuple(u.sub))
        served = self._served.get((key, u.sender, "RdlStateQuery"))
        q = RdlStateQuery(sender=u.sender, receiver=u.receiver, stamp=u.stamp, sub=u.sub)
        if served is None or served.seq != u.based_on or not same(served, self._answer(s, q)):
            return s, False
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
                continue
            res = self._pair(s, g, d, sub, target[1]) if target[0] == "robot" else self._private(s, d, target)
            if isinstance(res[0], str):
                outcomes.append(res)
                if target[0] == "robot":  # tell the target that no update follows its answer
                    a = target[1]
                    msgs.append(RdlUpdate(sender=self.robot, receiver=d.target, stamp=g.t, sub=sub, based_on=a.seq))
                continue
            s = res[0]
            if res[1] is not None:
                msgs.append(res[1])
            outcomes.append(FUSED)
        return s, outcomes, msgs

    def _private(self, s: RdlFilter, d: Any, target: tuple[str, Any]) -> Any:
        """Absolute fix or landmark: a private EKF update, then every factor rescaled."""
        lin = linearize(d, s.x, target)
        if lin is None:
            return ("rejected", DEGENERATE)
        r, Hi, R_eff, _ = lin
        res = gated_kalman(s.x, s.P, r, Hi, R_eff, self.gate)
        if isinstance(res[0], str):
            return res
        x, P = res
        return RdlFilter(s.t, s.v, s.w, x, P, s.ids, rescale_factors(s, P)), None

    def _pair(self, s: RdlFilter, g: Group, d: Any, sub: tuple, a: RdlState) -> Any:
        """The joint update of observer ``i`` and target ``j`` from ``j``'s answer ``a``."""
        j = d.target
        m = model(d.kind)
        xj, Pjj, sig_ji = a.arrays()
        if m.degenerate(s.x, xj):
            return ("rejected", DEGENERATE)
        Pij = s.factor(j) @ sig_ji.T
        h, Hi, Hj = m.predict(s.x, xj)
        X = np.concatenate([s.x, xj])
        P = np.block([[s.P, Pij], [Pij.T, Pjj]])
        H = np.hstack([Hi, Hj])
        res = gated_kalman(X, P, m.residual(d.z, h), H, m.noise(d.z, d.cov), self.gate, angles=(2, 5))
        if isinstance(res[0], str):
            return res
        Xn, Pn = res
        Pi = Pn[:3, :3]
        ids, sigma = s.with_factor(j, Pn[:3, 3:], rescale_factors(s, Pi))
        new = RdlFilter(s.t, s.v, s.w, Xn[:3], Pi, ids, sigma)
        update = RdlUpdate(
            sender=self.robot, receiver=j, stamp=g.t, sub=sub, based_on=a.seq, x=flat(Xn[3:]), P=flat(Pn[3:, 3:])
        )
        return new, update
