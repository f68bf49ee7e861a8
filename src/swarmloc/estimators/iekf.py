"""Observability-preserving centralized EKFs: the invariant EKF (``"iekf"``) and first-estimates Jacobians (``"fej"``).

Without absolute information (no landmarks, no fixes) the team's global pose is unobservable: 3 directions on
SE(2), a rigid motion of the whole team. The standard centralized EKF (:mod:`swarmloc.estimators.cekf`) evaluates
its Jacobians at estimates that move at every update, so the unobservable subspace of its linearized system loses
a dimension (the global rotation) and the filter gains information it does not have (Huang, Mourikis &
Roumeliotis, "Observability-based consistent EKF estimators for multi-robot cooperative localization", Autonomous
Robots 2011). :mod:`swarmloc.evaluation.observability` measures that information; both filters here gain none.

* :class:`InvariantEKF` (``"iekf"``): the error of robot ``i`` is world-frame, ``g_i = exp(hat(xi_i)) g^_i``
  (:mod:`swarmloc.kernels.invariant`). A rigid motion of the team moves every ``xi_i`` by the same vector, so
  the unobservable directions are the constant ``[I; ...; I]`` for *any* estimate; the error transition of the
  odometry step is the identity (process noise ``Q_w = N^-1 Q_c N^-T`` is added to the robot's block only),
  and every relative measurement's Jacobian satisfies ``H_i + H_j = 0`` exactly. The structure is preserved by
  construction (Barrau & Bonnabel 2017). The update corrects on the group: ``g^ <- exp(hat(K r)) g^``.
* :class:`FirstEstimatesEKF` (``"fej"``): the Cartesian EKF of ``cekf`` with every Jacobian evaluated at a
  robot's *first* estimate at that time (its prediction before any update): the propagation Jacobian's
  displacement is ``x+ - x_first`` and measurement Jacobians use the first estimates. Then the product of the
  propagation Jacobians maps the initial unobservable basis to the one at the first estimates, which the
  measurement Jacobians annihilate (Huang et al. 2011, FEJ-EKF). Residuals use the current estimate.

Both keep the joint ``3n x 3n`` covariance like ``cekf`` and only touch the rows and columns a detection involves
(one rank-``m`` correction). Which one to use: see the consistency tables of docs/estimators.md (the invariant EKF
is the default recommendation there, on the evidence of the Monte Carlo runs and MRCLAM).
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import numpy as np

from swarmloc.estimators.cekf import CentralizedEKF, TeamState, clock_and_pending, compose_pending, flush_pending
from swarmloc.estimators.dekf import DEGENERATE
from swarmloc.events import Detection, Kind
from swarmloc.gaussian import GroupGaussian
from swarmloc.kernels import invariant as I
from swarmloc.lie import SE2, wrap_angle
from swarmloc.messages import Message
from swarmloc.node import FUSED, Group, Node, Outcome, belief_of, gated_kalman
from swarmloc.sensors.models import model

__all__ = ["FirstEstimatesEKF", "InvariantEKF", "joint_correction"]


def joint_correction(
    P: np.ndarray, starts: list[int], blocks: list[np.ndarray], r: np.ndarray, R: np.ndarray, gate: Any
) -> tuple[np.ndarray, np.ndarray] | Outcome:
    """The gated Kalman update (:func:`~swarmloc.node.update.gated_kalman`, Joseph form) of a joint covariance
    ``P (n, n)`` by a measurement whose Jacobian is nonzero only in the 3-column blocks starting at ``starts``
    (``blocks[k]`` of shape ``(m, 3)``): the correction ``K r (n,)`` and ``P+``, or the outcome that stops it.
    Cost ``O(n^2 m)``."""
    cols = np.concatenate([np.arange(i, i + 3) for i in starts])
    return gated_kalman(np.zeros(P.shape[0]), P, r, np.hstack(blocks), R, gate, cols=cols, angles=())


class _LoggedCentral(CentralizedEKF):
    """Shared detection loop of the two filters; subclasses say where Jacobians are evaluated and how the mean is
    corrected. ``lin_log``: set to a list to record every applied linearization (see
    :mod:`swarmloc.evaluation.observability`)."""

    error_frame: ClassVar[str] = "cartesian"
    groups: ClassVar[tuple[type, ...]] = (SE2,)
    first_estimates: ClassVar[bool] = False
    lin_log: list | None = None
    _advance_commands = Node._advance_commands  # each filter predicts its own way: no Cartesian run

    def _lin_point(self, s: Any, k: int) -> np.ndarray:
        """Where the Jacobians of the robot whose block starts at ``k`` are evaluated."""
        return s.X[k : k + 3]

    def _to_error(self, H: np.ndarray, x: np.ndarray) -> np.ndarray:
        """A Cartesian Jacobian block at ``x`` in the filter's error coordinates."""
        return H

    def _correct(self, s: Any, delta: np.ndarray, P: np.ndarray) -> Any:
        raise NotImplementedError

    def _log_update(self, t: float, starts: list[int], blocks: list[np.ndarray], R: np.ndarray) -> None:
        if self.lin_log is not None:
            robots = {k: r for r, k in self._idx.items()}
            self.lin_log.append(("update", t, {robots[k]: H for k, H in zip(starts, blocks, strict=True)}, R))

    def _fuse_group(self, s: Any, g: Group) -> tuple[Any, list[Outcome], list[Message]]:
        s, outcomes = self._fuse_each(s, g, lambda s, d, target: self._fuse_one(s, g, d, target))
        return s, outcomes, []

    def _fuse_one(self, s: Any, g: Group, d: Detection, target: tuple[str, Any]) -> tuple[Any, Outcome]:
        """One classified detection of group ``g`` fused into the joint state ``s``: the new state and its outcome
        (the state as it was, the detected robot predicted to the stamp, when the detection is not fused)."""
        i = self._idx[g.observer]
        m = model(d.kind)
        R = m.noise(d.z, d.cov)
        xi, li = s.X[i : i + 3], self._lin_point(s, i)
        if target[0] == Kind.ABSOLUTE:
            starts, blocks = [i], [self._to_error(np.eye(3), li)]
            r = m.residual(d.z, xi)
        else:
            if target[0] == "robot":
                s = self._adv(s, target[1], g.t)  # the detected robot at the detection's stamp
                k = self._idx[target[1]]
                xk, lk, Ck = s.X[k : k + 3], self._lin_point(s, k), None
            else:
                xk, Ck = target[1]
                lk = xk
            if m.degenerate(xi, xk) or m.degenerate(li, lk):
                return s, ("rejected", DEGENERATE)
            h, Hi, Hk = m.predict(xi, xk)
            if self.first_estimates:
                _, Hi, Hk = m.predict(li, lk)
            r = m.residual(d.z, h)
            if Ck is None:
                starts, blocks = [i, k], [self._to_error(Hi, li), self._to_error(Hk, lk)]
            else:
                starts, blocks = [i], [self._to_error(Hi, li)]
                R = R + Hk @ Ck @ Hk.T
        sf = self._flushed(s)
        res = joint_correction(sf.P, starts, blocks, r, R, self.gate)
        if isinstance(res[0], str):
            return s, res
        s = self._correct(sf, *res)
        self._log_update(g.t, starts, blocks, R)
        return s, FUSED

    def _flushed(self, s: Any) -> Any:
        return flush_pending(s)


class InvariantEKF(_LoggedCentral):
    """Centralized invariant EKF on SE(2)^n with world-frame errors (module docstring).

    The joint covariance (``joint_at``) is of the world-frame errors ``(xi_1, ..., xi_n)``; a robot's belief is
    converted to the thesis' body-frame convention, ``Sigma = Ad(g^-1) P_ii Ad(g^-1)^T``.
    """

    name = "iekf"
    error_frame: ClassVar[str] = "world"

    def _initial_state(self, t0: float) -> TeamState:
        s = super()._initial_state(t0)
        P = s.P.copy()
        for r, b in self.initial.items():
            k = self._idx[r]
            P[k : k + 3, k : k + 3] = I.body_to_world(b.mean, b.cov)
        return TeamState(s.X, P, s.t, s.cmd, s.pend)

    def _advance(self, s: TeamState, robot: int, t: float) -> TeamState:
        step = self._increment(s, robot, t)
        if step is None:
            return s
        k, i, (x0, y0, th, _, _, q00, q01, q02, q11, q12, q22) = step
        X = s.X.copy()
        X[i], X[i + 1], X[i + 2] = x0, y0, th
        # world-frame process noise: N^-1 Q_c N^-T with N^-1 = [[1, 0, y], [0, 1, -x], [0, 0, 1]]
        a02, a12 = q02 + y0 * q22, q12 - x0 * q22
        qw = (
            q00 + 2 * y0 * q02 + y0 * y0 * q22, q01 - x0 * q02 + y0 * a12, a02,
            q11 - 2 * x0 * q12 + x0 * x0 * q22, a12, q22,
        )  # fmt: skip
        old = s.pend[k]
        pend_k = (0.0, 0.0, *qw) if old is None else (0.0, 0.0, *(u + w_ for u, w_ in zip(old[2:], qw, strict=True)))
        return TeamState(X, s.P, *clock_and_pending(s, k, t, pend_k))

    def _belief(self, s: TeamState, robot: int) -> GroupGaussian:
        i = self._idx[robot]
        P = s.P[i : i + 3, i : i + 3]
        pd = s.pend[i // 3]
        if pd is not None:
            q00, q01, q02, q11, q12, q22 = pd[2:]
            P = P + np.array([[q00, q01, q02], [q01, q11, q12], [q02, q12, q22]])
        g = SE2.from_xytheta(s.X[i : i + 3])
        return belief_of(g, I.world_to_body(g, P))

    def _to_error(self, H: np.ndarray, x: np.ndarray) -> np.ndarray:
        return H @ I.world_basis(x)

    def _joint(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Cartesian ``(x, P)``: the world-frame errors' covariance mapped by ``N(x_i)`` block by block."""
        X, Pw = self.joint_at(t)
        N = np.zeros_like(Pw)
        for k in range(0, X.size, 3):
            N[k : k + 3, k : k + 3] = I.world_basis(X[k : k + 3])
        return X, N @ Pw @ N.T

    def _correct(self, s: TeamState, delta: np.ndarray, P: np.ndarray) -> TeamState:
        X = I.left_correct(s.X.reshape(-1, 3), delta.reshape(-1, 3)).reshape(-1)
        return TeamState(X, P, s.t, s.cmd, s.pend)


class FejState(NamedTuple):
    """:class:`~swarmloc.estimators.cekf.TeamState` plus ``L (3n,)``: each robot's first estimate at its clock."""

    X: np.ndarray
    P: np.ndarray
    t: tuple[float, ...]
    cmd: tuple[tuple[float, float], ...]
    pend: tuple[tuple[float, ...] | None, ...]
    L: np.ndarray


class FirstEstimatesEKF(_LoggedCentral):
    """Centralized CL-EKF with first-estimates Jacobians (FEJ-EKF, module docstring)."""

    name = "fej"
    first_estimates: ClassVar[bool] = True

    def _initial_state(self, t0: float) -> FejState:
        s: TeamState = super()._initial_state(t0)
        return FejState(*s, s.X.copy())

    def _lin_point(self, s: FejState, k: int) -> np.ndarray:
        return s.L[k : k + 3]

    def _advance(self, s: FejState, robot: int, t: float) -> FejState:
        step = self._increment(s, robot, t)
        if step is None:
            return s
        k, i, (x0, y0, th, _, _, *q) = step
        dx, dy = x0 - s.L[i], y0 - s.L[i + 1]  # first-estimates displacement: new prediction - previous first estimate
        X, L = s.X.copy(), s.L.copy()
        X[i], X[i + 1], X[i + 2] = x0, y0, th
        L[i : i + 3] = X[i : i + 3]
        self._log_shear(t, robot, dx, dy)
        return FejState(X, s.P, *clock_and_pending(s, k, t, compose_pending(s.pend[k], dx, dy, q)), L)

    def _set_command(self, s: FejState, robot: int, v: float, w: float) -> FejState:
        cmd = list(s.cmd)
        cmd[self._idx[robot] // 3] = (v, w)
        return FejState(s.X, s.P, s.t, tuple(cmd), s.pend, s.L)

    def _flushed(self, s: FejState) -> FejState:
        f = flush_pending(s)
        return FejState(f.X, f.P, f.t, f.cmd, f.pend, s.L)

    def _correct(self, s: FejState, delta: np.ndarray, P: np.ndarray) -> FejState:
        X = s.X + delta
        X[2::3] = wrap_angle(X[2::3])
        return FejState(X, P, s.t, s.cmd, s.pend, s.L)
