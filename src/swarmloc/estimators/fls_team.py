"""A fixed-lag smoother on the exact distributed invariant EKF's exchange (``"flsx"``).

The node is a :class:`~swarmloc.estimators.diekf.DistributedInvariantEKF` (its pose ``x_i``, world-frame covariance
``P_ii`` and replica of the team's cross-covariances, its ``RdlStateQuery`` exchange and its ``TeamUpdate``
broadcasts, unchanged) whose **own landmark and absolute detections go through a window** of its recent poses, as
:class:`~swarmloc.estimators.fls.FixedLagSmoother`'s: odometry ``BetweenFactorPose2`` between the poses at its
detection instants, one nonlinear factor per landmark detection, poses older than ``lag`` marginalized into a
prior. At a detection group the window is solved (Gauss-Newton, relinearizing the landmark and odometry factors of
the last ``lag`` seconds) and its newest pose's marginal ``(x+, P+)`` replaces the filter's ``(x, P)``, as one
linear update of the team filter with ``H_i = I``:

``S^-1 = P^-1 D P^-1`` with ``D = P - P+`` (its negative eigenvalues clipped to 0), ``nu = P^-1 delta`` with
``exp(delta) x = x+``: the filter moves to ``x+`` and ``P - D``, every cross-covariance ``Sigma_il`` to
``(P - D) P^-1 Sigma_il``, what a private measurement of that information does. It is broadcast as ``diekf``'s
landmark updates are (one ``TeamUpdate`` per group, under the first fused landmark detection's key, empty ones
under the others), so every replica applies it exactly as ``diekf`` would.

Every other change of the filter's own pose (its updates as observer of a robot, and the teammates' broadcasts,
which move it through the cross-covariances) enters the window as a **pseudo-factor**: the Gaussian in the
world-frame error that turns the filter's ``(x, P)`` before into the one after (information ``P+^-1 - P^-1``,
clipped at 0), linear in the Cartesian pose, on the pose at the detection's instant (the observer's updates) or on
the window's newest pose (received broadcasts: a world-frame correction commutes with the odometry, as ``diekf``
uses; attaching it before the odometry since then only adds variance). So the window's newest marginal follows the
filter, and the next solve's ``D`` is the new landmark information plus what relinearization changed.

Everything else (answers, queries, broadcasts, replay, the networked driver) is ``diekf``'s: the node needs the
whole team's all-to-all channel, as ``diekf`` does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from swarmloc.estimators.dekf import DEGENERATE, linearize
from swarmloc.estimators.diekf import DistributedInvariantEKF
from swarmloc.estimators.fls import _TINY, Factor, Window, WindowSolver, _gtsam
from swarmloc.gaussian import GroupGaussian
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import invariant as I
from swarmloc.lie import SE2
from swarmloc.messages import Message, TeamUpdate, flat
from swarmloc.node import FUSED, NUMERICAL, Group, Outcome, usable_covariance
from swarmloc.sensors.models import model

__all__ = ["TeamFixedLagSmoother", "TeamFlsState"]

_ZERO3 = np.zeros(3)
_ZERO33 = np.zeros((3, 3))
_EYE = flat(np.eye(3))
_ZEROS = flat(np.zeros((3, 3)))


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


def world_delta(x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
    """The world-frame correction ``delta`` with ``exp(hat(delta)) g(x0) = g(x1)``."""
    return SE2.log(SE2.from_xytheta(x1) @ SE2.inverse(SE2.from_xytheta(x0), validate=False))


def _psd(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (negative ones set to 0) and eigenvectors of the symmetric part of ``M``."""
    lam, V = np.linalg.eigh(0.5 * (M + M.T))
    return np.maximum(lam, 0.0), V


def _sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + M.T)


def pseudo_factor(pose: int, x0: np.ndarray, P0: np.ndarray, x1: np.ndarray, P1: np.ndarray,
                  at: np.ndarray) -> Factor | None:  # fmt: skip
    """The linear factor on ``pose`` that turns the Gaussian ``(x0, P0)`` (world-frame error) into ``(x1, P1)``:
    information ``L = P1^-1 - P0^-1`` (clipped at 0) about the world-frame error, centred so that the mean moves to
    ``x1``, written in the Cartesian pose around ``at`` (the pose's estimate that ``x0`` corresponds to). None when
    it carries nothing."""
    P1i = np.linalg.inv(P1)
    lam, V = _psd(P1i - np.linalg.inv(P0))
    lam = np.where(lam > 1e-12 * lam.max(), lam, 0.0)
    if not (lam > 0).any():
        return None
    rhs = V.T @ (P1i @ world_delta(x0, x1))  # L c = P1^-1 delta, in L's eigenbasis
    sq = np.sqrt(lam)
    b = np.where(lam > 0, rhs / np.where(sq > 0, sq, 1.0), 0.0)
    A = (sq[:, None] * V.T) @ I.world_basis_inv(at)
    return Factor("pseudo", pose, -1, "", np.asarray(at, dtype=float), A, b, 1.0)


class TeamFixedLagSmoother(WindowSolver, DistributedInvariantEKF):
    """``diekf`` whose own landmark updates come from a fixed-lag smoother of its recent poses (module
    docstring). ``lag`` [s] and ``max_iterations`` as :class:`~swarmloc.estimators.fls.FixedLagSmoother`'s."""

    name = "flsx"

    def __init__(self, robot: int, initial: GroupGaussian, *, team: Sequence[int] = (), lag: float = 2.0,
                 max_iterations: int = 3, **kw: Any) -> None:  # fmt: skip
        if not (isinstance(lag, int | float) and math.isfinite(lag) and lag > 0):
            raise ValueError(f"{type(self).__name__}: 'lag' must be a positive number of seconds, got {lag!r}")
        if not (isinstance(max_iterations, int) and max_iterations >= 1):
            raise ValueError(f"{type(self).__name__}: 'max_iterations' must be an integer >= 1, got {max_iterations!r}")
        self.lag = float(lag)
        self.max_iterations = max_iterations
        self._g = _gtsam()
        super().__init__(robot, initial, team=team, **kw)

    # ------------------------------------------------------------------------------------------------ filter
    def _initial_state(self, t0: float) -> TeamFlsState:
        s = super()._initial_state(t0)
        win = Window((0,), (t0,), {0: s.x}, (s.x, np.array(self.initial.cov, dtype=float), 1.0), (), 1)
        return TeamFlsState(s.t, s.v, s.w, s.x, s.P, s.Sigma, _ZERO3, _ZERO33, win)

    def _advance(self, s: TeamFlsState, robot: int, t: float) -> TeamFlsState:
        dt = t - s.t
        if dt <= 0:
            return s
        x0, y0, th, _, _, q00, q01, q02, q11, q12, q22 = C.increment_terms(s.x, s.v, s.w, dt, self.noise)
        x = np.array([x0, y0, th])
        Qc = np.array([[q00, q01, q02], [q01, q11, q12], [q02, q12, q22]])
        rel, Q, _, _ = C.predict_one(s.rel, s.Q, s.v, s.w, dt, self.noise)
        return s._replace(t=t, x=x, P=s.P + I.cartesian_to_world_cov(x, Qc), rel=rel, Q=Q)

    def _set_command(self, s: TeamFlsState, robot: int, v: float, w: float) -> TeamFlsState:
        return s._replace(v=v, w=w)

    def _team_update(self, s: TeamFlsState, *args: Any) -> TeamFlsState:  # type: ignore[override]
        new = super()._team_update(s, *args)
        return s._replace(x=new.x, P=new.P, Sigma=new.Sigma)

    def _newest_anchor(self, s: TeamFlsState) -> np.ndarray:
        """The window's newest pose as the filter's present pose implies it (``x`` less the increment ``rel``)."""
        g = SE2.from_xytheta(s.x) @ SE2.inverse(SE2.from_xytheta(s.rel), validate=False)
        return np.array([g[0, 2], g[1, 2], math.atan2(g[1, 0], g[0, 0])])

    def _posed(self, s: TeamFlsState) -> TeamFlsState:
        """``s`` with a window pose at its time ``s.t`` (added with its odometry factor when the newest is older)."""
        win = s.win
        if win.stamps[-1] >= s.t:
            return s
        pid = win.next_id
        _, Qg = C.to_group(s.rel, s.Q)
        odo = Factor("odometry", win.poses[-1], pid, "", s.rel, Qg + _TINY * np.eye(3), None, 1.0)
        win = Window((*win.poses, pid), (*win.stamps, s.t), {**win.est, pid: s.x}, win.prior,
                     (*win.factors, odo), pid + 1)  # fmt: skip
        if win.stamps[0] < s.t - 2 * self.lag:  # no landmark solve for a while: marginalize the old poses
            solved = self._solve(win, pid, s.t)
            if solved is not None:
                win = solved[0]
        return s._replace(rel=_ZERO3, Q=_ZERO33, win=win)

    def _fold(self, before: TeamFlsState, after: TeamFlsState) -> TeamFlsState:
        """``after`` with the change of the filter's own pose since ``before`` filed in the window as a
        pseudo-factor on its newest pose."""
        if np.array_equal(before.x, after.x) and np.array_equal(before.P, after.P):
            return after
        win = after.win
        f = pseudo_factor(win.poses[-1], before.x, before.P, after.x, after.P, self._newest_anchor(before))
        if f is None:
            return after
        return after._replace(win=win._replace(factors=(*win.factors, f)))

    def _apply_update(self, s: TeamFlsState, u: TeamUpdate) -> tuple[TeamFlsState, bool]:
        if u.target == self.robot:
            s = self._adv(s, self.robot, u.stamp)
        new, ok = super()._apply_update(s, u)
        if np.array_equal(s.x, new.x) and np.array_equal(s.P, new.P):
            return new, ok
        s = self._posed(s)
        new = new._replace(rel=s.rel, Q=s.Q, win=s.win)
        return self._fold(s, new), ok

    # ------------------------------------------------------------------------------------------------ update
    def _fuse_group(self, s: TeamFlsState, g: Group) -> tuple[TeamFlsState, list[Outcome], list[Message]]:
        i = self.robot
        mates = [r for r in self.team if r != i]
        outcomes: list[Outcome | None] = []
        msgs: list[Message] = []
        pseudo: list[tuple[TeamFlsState, TeamFlsState]] = []
        landmarks: list[tuple[int, tuple, Factor]] = []  # (outcome slot, key, factor)
        for d, sub in zip(g.detections, g.keys, strict=True):
            target = self._classify(g, d, sub)
            if target[0] in ("rejected", "unknown"):
                outcomes.append(target)
                continue
            if target[0] == "robot":
                res = self._one(s, g, d, target)
                if isinstance(res[0], str):
                    outcomes.append(res)
                    msgs += [TeamUpdate(sender=i, receiver=r, stamp=g.t, sub=sub) for r in mates]
                    continue
                new, (j, Hi, Hj, Sinv, nu, Pii, Pjj) = res
                pseudo.append((s, new))
                s = new
                body = dict(
                    target=j, m=len(nu), Hi=flat(Hi), Hj=flat(Hj), Sinv=flat(Sinv), nu=flat(nu), Pii=flat(Pii),
                    Pjj=flat(Pjj),
                )  # fmt: skip
                msgs += [TeamUpdate(sender=i, receiver=r, stamp=g.t, sub=sub, **body) for r in mates]
                outcomes.append(FUSED)
                continue
            lin = linearize(d, s.x, target)
            if lin is None:
                outcomes.append(("rejected", DEGENERATE))
                continue
            r, Hi_c, R, _ = lin
            Hw = Hi_c @ I.world_basis(s.x)
            try:
                nis = float(r @ np.linalg.solve(Hw @ s.P @ Hw.T + R, r))
            except np.linalg.LinAlgError:
                outcomes.append(("rejected", NUMERICAL))
                continue
            verdict = self._gated(nis, len(r))
            if verdict is not None:
                outcomes.append(verdict)
                msgs += [TeamUpdate(sender=i, receiver=rr, stamp=g.t, sub=sub) for rr in mates]
                continue
            lm = None if target[0] == "absolute" else np.asarray(target[1][0], dtype=float)
            z = np.asarray(d.z, dtype=float)
            landmarks.append((len(outcomes), sub, Factor("unary", -1, -1, d.kind, z, R, lm, 1.0)))
            outcomes.append(None)
        if not pseudo and not landmarks:
            return s, list(outcomes), msgs  # type: ignore[arg-type]
        # the pose at this group's instant, the observer's updates on it
        s = self._posed(s)
        win = s.win
        pid = win.poses[-1]
        factors = list(win.factors)
        for before, after in pseudo:
            f = pseudo_factor(pid, before.x, before.P, after.x, after.P, before.x)
            if f is not None:
                factors.append(f)
        win = win._replace(est={**win.est, pid: s.x}, factors=tuple(factors))
        if not landmarks:
            return s._replace(win=win), list(outcomes), msgs  # type: ignore[arg-type]
        win2 = win._replace(factors=(*win.factors, *(f._replace(a=pid) for _, _, f in landmarks)))
        solved = self._solve(win2, pid, g.t)
        if solved is None:
            for k, sub, _ in landmarks:
                outcomes[k] = ("rejected", NUMERICAL)
                msgs += [TeamUpdate(sender=i, receiver=r, stamp=g.t, sub=sub) for r in mates]
            return s._replace(win=win), list(outcomes), msgs  # type: ignore[arg-type]
        win3, xw, Pc = solved
        Lam = np.zeros((3, 3))  # the new factors' information about the newest pose, at its smoothed estimate
        for _, _, f in landmarks:
            m = model(f.meas)
            Hc = (m.predict(xw, f.target) if f.target is not None else m.predict(xw))[1]
            Hw = np.asarray(Hc, dtype=float) @ I.world_basis(xw)
            Lam += Hw.T @ np.linalg.solve(f.R, Hw)
        Pinv = np.linalg.inv(s.P)
        D = s.P - np.linalg.inv(Pinv + Lam)
        Sinv = Pinv @ D @ Pinv
        Sinv = 0.5 * (Sinv + Sinv.T)
        nu = Pinv @ world_delta(s.x, xw)
        Pii = s.P
        eye = np.eye(3)
        new = self._team_update(s, i, i, eye, np.zeros((3, 3)), Sinv, nu, Pii, Pii)
        if not (np.isfinite(new.x).all() and usable_covariance(new.P) and np.isfinite(new.Sigma).all()):
            for k, sub, _ in landmarks:
                outcomes[k] = ("rejected", NUMERICAL)
                msgs += [TeamUpdate(sender=i, receiver=r, stamp=g.t, sub=sub) for r in mates]
            return s._replace(win=win), list(outcomes), msgs  # type: ignore[arg-type]
        body = dict(target=i, m=3, Hi=_EYE, Hj=_ZEROS, Sinv=flat(Sinv), nu=flat(nu), Pii=flat(Pii), Pjj=flat(Pii))
        for n, (k, sub, _) in enumerate(landmarks):
            outcomes[k] = FUSED
            extra = body if n == 0 else {}
            msgs += [TeamUpdate(sender=i, receiver=r, stamp=g.t, sub=sub, **extra) for r in mates]
        return new._replace(win=win3), list(outcomes), msgs  # type: ignore[arg-type]
