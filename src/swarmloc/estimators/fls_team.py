"""A fixed-lag smoother on the exact distributed invariant EKF's exchange (``"flsd"``).

The node is a :class:`~swarmloc.estimators.diekf.DistributedInvariantEKF` (its pose ``x_i``, world-frame covariance
``P_ii`` and replica of the team's cross-covariances, its ``RdlStateQuery`` exchange and its ``TeamUpdate``
broadcasts, unchanged) that also keeps a **window** of its robot's recent poses, as
:class:`~swarmloc.estimators.fls.FixedLagSmoother` does: odometry ``BetweenFactorPose2`` between consecutive poses,
one nonlinear factor per own landmark (or absolute) detection, poses older than ``lag`` marginalized into a prior.

* **Own landmarks.** At a detection group the window, with the group's landmark factors added, is solved (Gauss-Newton,
  relinearizing the factors of the last ``lag`` seconds). Each detection is then applied to the filter as a
  ``diekf`` landmark update linearized at the *smoothed* pose ``x_w`` instead of the filter's (the iterated EKF's
  step: ``H = H(x_w)``, ``r = z - h(x_w) - H xi`` with ``exp(xi) x_w = x``) and broadcast as ``diekf`` broadcasts
  it, so every replica applies it exactly.
* **Everything else that moves the robot's pose** (its updates as the observer of a robot, and every teammate's
  broadcast, which reaches it through the cross-covariances) enters the window as a **pseudo-factor** on the pose at
  the update's stamp (:func:`pseudo_factor`): the update ``xi <- xi + G nu``, ``P <- P - G S^-1 G^T`` is the Kalman
  update of the measurement ``G^T P^-1 xi = S nu`` with noise ``S - G^T P^-1 G`` (the innovation's covariance
  given the pose), linear in the pose. So the window's newest marginal follows the filter's and the window's
  solve weighs its landmark factors as the filter would. (Differences of information matrices instead, clipped to
  positive semi-definite, made a near-null direction come and go with rounding: replayed input then differed by
  1e-6.)

The estimates and covariances answered and recorded are the filter's; what the window adds is the
linearization point of the landmark updates. The process noise is scaled online as ``diekf``'s
(:mod:`swarmloc.estimators.adaptive_noise`, by default where landmarks are fused): the filter's prediction and the
window's odometry increments by the same scale, read from the innovations the filter fuses one after another.
Everything else (answers, queries, broadcasts, replay, the networked driver) is ``diekf``'s: the node needs the
whole team's all-to-all channel, as ``diekf`` does.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar, Literal, NamedTuple

import numpy as np

from swarmloc.estimators.adaptive_noise import innovation_terms, scale_for, scaled
from swarmloc.estimators.dekf import linearize
from swarmloc.estimators.fls import Factor, OfSolver, Window, WindowSolver
from swarmloc.estimators.iekf import world_to_cartesian
from swarmloc.estimators.team_protocol import TeamProtocol
from swarmloc.gaussian import GroupGaussian, symmetric
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import invariant as I
from swarmloc.lie import SE2
from swarmloc.messages import Message, TeamUpdate
from swarmloc.node import FUSED, NUMERICAL, Group, Outcome, RobotNode, usable_covariance
from swarmloc.node.keys import SubKey
from swarmloc.sensors.models import model

__all__ = ["TeamFixedLagSmoother", "TeamFlsState"]

_ZERO3 = np.zeros(3)
_ZERO33 = np.zeros((3, 3))


class TeamFlsState(NamedTuple):
    """A node's state: ``diekf``'s (time [s], command ``(v, w)``, pose ``x (3,)``, world-frame ``P (3, 3)``,
    replica ``Sigma (n, n, 3, 3)``), the Cartesian increment since the window's newest pose (``rel (3,)`` in its
    frame, covariance ``Q (3, 3)``) and the window."""

    t: float
    v: float
    w: float
    x: np.ndarray
    P: np.ndarray
    Sigma: np.ndarray
    rel: np.ndarray
    Q: np.ndarray
    win: Window


def pseudo_factor(pose: int, P0: np.ndarray, G: np.ndarray, Sinv: np.ndarray, nu: np.ndarray,
                  at: np.ndarray) -> Factor | None:  # fmt: skip
    """The linear factor on ``pose`` equivalent to a team update's effect on this robot's pose: the update moved
    the world-frame error of the estimate ``at`` (covariance ``P0``) by ``G nu`` and its covariance by ``-G Sinv
    G^T`` (``G = Gamma_me (3, m)``, :mod:`swarmloc.estimators.diekf`). That is the Kalman update of the measurement
    ``J xi = r + noise(R')`` with ``J = G^T P0^-1``, ``r = S nu``, ``R' = S - G^T P0^-1 G`` (the innovation's
    covariance given this pose; positive definite), written whitened in the Cartesian pose around ``at``. None
    when the update does not reach this pose (``G = 0``) or ``Sinv`` is singular (no update of ours sends one)."""
    if not G.any():
        return None
    try:
        S = np.linalg.inv(Sinv)
    except np.linalg.LinAlgError:  # a teammate's malformed update: the filter takes it as diekf does, not the window
        return None
    J = G.T @ np.linalg.inv(P0)
    Rp = S - J @ G
    Rp = symmetric(Rp)
    try:
        C_ = np.linalg.cholesky(Rp)
    except np.linalg.LinAlgError:  # rounding: R' is a conditional covariance, at least the sensor's noise
        lam, V = np.linalg.eigh(Rp)
        if not lam.max() > 0:  # not a covariance at all: a malformed update
            return None
        C_ = V * np.sqrt(np.maximum(lam, 1e-12 * float(lam.max())))
    W = np.linalg.inv(C_)  # W^T W = R'^-1 (up to an orthogonal factor)
    A = W @ J @ I.world_basis_inv(at)
    return Factor("pseudo", pose, -1, "", np.asarray(at, dtype=float), A, W @ (S @ nu), 1.0)


class TeamFixedLagSmoother(RobotNode):
    """``diekf`` whose own landmark updates come from a fixed-lag smoother of its recent poses (module
    docstring): the node's wiring of ``diekf``'s :class:`~swarmloc.estimators.team_protocol.TeamProtocol`
    (:attr:`protocol`) and a :class:`~swarmloc.estimators.fls.WindowSolver` (:attr:`solver`). ``lag`` [s],
    ``max_iterations`` and ``delayed`` as :class:`~swarmloc.estimators.fls.FixedLagSmoother`'s; ``team`` and
    ``adaptive`` as ``diekf``'s (by default the process noise scaled online where landmarks are fused, in the filter
    and in the window's odometry factors alike: :attr:`noise_scale`); ``cluster`` must be 0 (its pseudo-factors are
    the exact update's)."""

    name = "flsd"
    lazy_odometry = True
    error_frame: ClassVar[str] = "world"
    update_types = (TeamUpdate,)
    lin_log: list[Any] | None = None
    groups: ClassVar[tuple[type, ...]] = (SE2,)  # its smoother is planar
    protocol: TeamProtocol
    lag = OfSolver()
    lagged_log = OfSolver()
    lagged_when = OfSolver()
    lagged_fresh = OfSolver()
    lagged_scale = OfSolver()
    lagged_causal = OfSolver()

    def __init__(self, robot: int, initial: GroupGaussian, *, team: Sequence[int] = (), cluster: int = 0,
                 lag: float = 2.0, max_iterations: int = 3, delayed: bool = False,
                 adaptive: bool | Literal["median"] = "median", **kw: Any) -> None:  # fmt: skip
        self.solver = WindowSolver(type(self).__name__, lag, max_iterations, delayed)
        self.noise_scale = scale_for(adaptive, kw.get("landmarks"), kw.get("use_landmarks", True))
        if self.noise_scale is not None:
            self.solver.scale_at = self.noise_scale.scale
        # no gate on a teammate's broadcast: a landmark's is linearized at the smoothed pose, where the filter's gate
        # does not bound its normalized innovation (8 of MRCLAM dataset 6's went past it): only the covariance it
        # leaves is checked
        self.protocol = TeamProtocol(type(self).__name__, self.name, robot, initial, team, cluster, clusters=False,
                                     association=kw.get("association", "tags"), update=self._team_update,
                                     gated_broadcasts=False)  # fmt: skip
        self.protocol.innovations = self.noise_scale is not None
        super().__init__(robot, initial, team=self.protocol.team, **kw)

    # ------------------------------------------------------------------------------------------------ filter
    def _initial_state(self, t0: float) -> TeamFlsState:
        s = self.protocol.initial(self.initial.mean, self.initial.cov, t0)
        win = Window((0,), (t0,), {0: s.x}, (s.x, np.array(self.initial.cov, dtype=float), 1.0), (), 1)
        return self._with_causal(TeamFlsState(s.t, s.v, s.w, s.x, s.P, s.Sigma, _ZERO3, _ZERO33, win))

    def _advance(self, s: TeamFlsState, robot: int, t: float) -> TeamFlsState:
        dt = t - s.t
        if dt <= 0:
            return s
        x, P = self.protocol.form.predict(s.x, s.P, s.v, s.w, dt, self.noise)  # diekf's world-frame step
        rel, Q, _, _ = C.predict_one(s.rel, s.Q, s.v, s.w, dt, self.noise)
        lam = 1.0 if self.noise_scale is None else self.noise_scale.scale(t)
        if lam != 1.0:  # diekf's scaled step; the window's increment Phi Q Phi^T + lam Q_step likewise
            P = scaled(s.P, P, lam)
            Q = scaled(Q - C.predict_one(s.rel, _ZERO33, s.v, s.w, dt, self.noise)[1], Q, lam)
        return s._replace(t=t, x=x, P=P, rel=rel, Q=Q)

    def _set_command(self, s: TeamFlsState, robot: int, v: float, w: float) -> TeamFlsState:
        return s._replace(v=v, w=w)

    def _belief(self, s: TeamFlsState, robot: int) -> GroupGaussian:
        return self.protocol.belief(s.x, s.P)

    def _team_update(
        self, s: TeamFlsState, i: int, j: int, Hi: np.ndarray, Hj: np.ndarray, Sinv: np.ndarray, nu: np.ndarray,
        Pii: np.ndarray, Pjj: np.ndarray, w: float = 1.0,
    ) -> TeamFlsState:  # fmt: skip
        """``diekf``'s update (:meth:`~swarmloc.estimators.team_protocol.TeamProtocol.team_update`); the change of this
        robot's pose is also filed in the window (:func:`pseudo_factor`) unless the update is the node's own landmark
        update (``i == j == robot``: the window holds its factors). No clusters here (``w`` is always 1)."""
        new = self.protocol.team_update(s, i, j, Hi, Hj, Sinv, nu, Pii, Pjj)
        out = s._replace(x=new.x, P=new.P, Sigma=new.Sigma)
        me, pos = self.robot, self.protocol.pos
        if i == j == me:
            return out
        Ci = Pii if me == i else s.Sigma[pos[me], pos[i]]
        Cj = Ci if j == i else (Pjj if me == j else s.Sigma[pos[me], pos[j]])
        G = Ci @ Hi.T + Cj @ Hj.T
        s = self._posed(s)  # the pose at the update's instant: its change is about it
        f = pseudo_factor(s.win.poses[-1], s.P, G, Sinv, nu, s.x)
        win = s.win if f is None else s.win._replace(factors=(*s.win.factors, f))
        return out._replace(rel=s.rel, Q=s.Q, win=win)

    def _posed(self, s: TeamFlsState) -> TeamFlsState:
        """``s`` with a window pose at its time ``s.t`` (added with its odometry factor when the newest is older)."""
        win = s.win
        if win.stamps[-1] >= s.t:
            return s
        pid = win.next_id
        odo = Factor.odometry(win.poses[-1], pid, s.rel, s.Q)
        win = Window((*win.poses, pid), (*win.stamps, s.t), {**win.est, pid: s.x}, win.prior,
                     (*win.factors, odo), pid + 1, win.causal)  # fmt: skip
        if win.stamps[0] < s.t - 2 * self.solver.lag:  # no landmark solve for a while: marginalize the old poses
            solved = self.solver.solve(win, pid, s.t)
            if solved is not None:
                win = solved[0]
        return s._replace(rel=_ZERO3, Q=_ZERO33, win=win)

    def _record(self, t: float, sub: SubKey, inn: Any) -> None:
        """File an innovation with the noise scale (none: nothing to file)."""
        if self.noise_scale is not None and inn is not None:
            self.noise_scale.record(t, sub, inn)

    def _apply_update(self, s: TeamFlsState, u: Message) -> tuple[TeamFlsState, bool]:
        s = self._adv(s, self.robot, u.stamp)  # the pose at the update's stamp: a function of the inputs only
        new, applied = self.protocol.apply(s, u, self.counts)
        return self._with_causal(new), applied

    def _with_causal(self, s: TeamFlsState) -> TeamFlsState:
        """``s`` with its belief kept in the window as the causal belief at the newest pose when that pose is at
        ``s``'s time (the last input at a stamp leaves the belief after every input stamped then), so that the
        delayed output is never less sure than the filter was there (:mod:`swarmloc.estimators.fls`); nothing
        without the delayed output."""
        win = s.win
        if self.solver.lagged_log is None or win.stamps[-1] != s.t:
            return s
        kept = world_to_cartesian(s.x, s.P)  # the world-frame covariance as a Cartesian one, as the window files
        return s._replace(win=win._replace(causal={**win.causal, win.poses[-1]: kept}))

    # ------------------------------------------------------------------------------------------------ update
    def _smoothed_landmarks(
        self, s: TeamFlsState, factors: list[Factor], xw: np.ndarray
    ) -> tuple[TeamFlsState, list[tuple[np.ndarray, ...]]] | None:
        """Each landmark factor linearized at the smoothed pose ``xw`` and applied to the filter in turn, with the
        ``(Hw, Sinv, nu, Pii)`` of each update to broadcast and its innovation ``(r, S)``; None when an innovation
        covariance is singular or the result is not a usable state."""
        new = s
        updates: list[tuple[np.ndarray, ...]] = []
        for f in factors:
            m = model(f.meas)
            h, Hc, _ = m.predict(xw, f.target) if f.target is not None else m.predict(xw)
            Hw = np.asarray(Hc, dtype=float) @ I.world_basis(xw)
            r = m.residual(f.z, h) - Hw @ I.world_delta(xw, new.x)
            S = Hw @ new.P @ Hw.T + f.R
            try:
                Sinv = symmetric(np.linalg.inv(S))
            except np.linalg.LinAlgError:
                return None
            nu = Sinv @ r
            updates.append((Hw, Sinv, nu, new.P, r, S))
            new = self._team_update(new, self.robot, self.robot, Hw, np.zeros_like(Hw), Sinv, nu, new.P, new.P)
        if not (np.isfinite(new.x).all() and usable_covariance(new.P) and np.isfinite(new.Sigma).all()):
            return None
        return new, updates

    def _fuse_group(self, s: TeamFlsState, g: Group) -> tuple[TeamFlsState, list[Outcome], list[Message]]:
        outcomes: list[Outcome | None] = []
        msgs: list[Message] = []
        landmarks: list[tuple[int, SubKey, Factor]] = []  # (outcome slot, key, factor)
        broadcast = self.protocol.broadcast
        for d, sub in zip(g.detections, g.keys, strict=True):
            target = self._classify(g, d, sub)
            if target[0] in ("rejected", "unknown"):
                outcomes.append(target)
                continue
            if target[0] == "robot":
                self.protocol.last_innovation = None
                s, outcome, sent = self.protocol.fuse(s, d, target, sub, self.gate, self.lin_log, g.t)
                self._record(g.t, sub, self.protocol.last_innovation)
                outcomes.append(outcome)
                msgs += sent
                continue
            lin = linearize(d, s.x, target)
            if isinstance(lin, str):
                outcomes.append(("rejected", lin))
                continue
            r, Hi_c, R, _ = lin
            Hw = Hi_c @ I.world_basis(s.x)
            S = Hw @ s.P @ Hw.T + R
            try:
                nis = float(r @ np.linalg.solve(S, r))
            except np.linalg.LinAlgError:
                outcomes.append(("rejected", NUMERICAL))
                continue
            verdict = self._gated(nis, len(r))
            if verdict is not None:
                if self.noise_scale is not None:
                    self._record(g.t, sub, innovation_terms(r, S, R, landmark=True))
                outcomes.append(verdict)
                msgs += broadcast(g.t, sub)
                continue
            landmarks.append((len(outcomes), sub, Factor.unary(d, target, R)))
            outcomes.append(None)
        if not landmarks:
            return self._with_causal(s), [o for o in outcomes if o is not None], msgs
        s = self._posed(s)  # the pose at this group's instant (its robot detections made it already)
        pid = s.win.poses[-1]
        win = s.win._replace(est={**s.win.est, pid: s.x})
        solved = self.solver.solve(win._replace(factors=(*win.factors, *(f._replace(a=pid) for _, _, f in landmarks))),
                                   pid, g.t)  # fmt: skip
        applied = None if solved is None else self._smoothed_landmarks(s, [f for _, _, f in landmarks], solved[1])
        if solved is not None and applied is not None:
            new, updates = applied
            for (k, sub, f), (Hw, Sinv, nu, Pii, r, S) in zip(landmarks, updates, strict=True):
                outcomes[k] = FUSED
                if self.noise_scale is not None:  # the innovation the filter fused, one after another as diekf's
                    self._record(g.t, sub, innovation_terms(r, S, f.R, landmark=True))
                msgs += broadcast(g.t, sub, (self.robot, Hw, np.zeros_like(Hw), Sinv, nu, Pii, Pii, 1.0))
            return self._with_causal(new._replace(win=solved[0])), [o for o in outcomes if o is not None], msgs
        for k, sub, _ in landmarks:
            outcomes[k] = ("rejected", NUMERICAL)
            msgs += broadcast(g.t, sub)
        return self._with_causal(s._replace(win=win)), [o for o in outcomes if o is not None], msgs
