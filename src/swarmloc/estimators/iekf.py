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

Both keep the joint ``3n x 3n`` covariance like ``cekf`` (their forms are its
:class:`~swarmloc.estimators.cekf.TeamForm` with their own linearization point and error coordinates) and only touch the
rows and columns a detection involves (one rank-``m`` correction, :func:`~swarmloc.estimators.cekf.fuse_linearized`).
Which one to use: see the consistency tables of docs/estimators.md (the invariant EKF is the default recommendation
there, on the evidence of the Monte Carlo runs and MRCLAM).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from swarmloc.estimators.cekf import (
    TeamForm,
    TeamState,
    clock_and_pending,
    compose_pending,
    flush_pending,
    increment,
    log_shear,
    team_state,
)
from swarmloc.estimators.world_form import FORMS as WORLD_FORMS
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import invariant as I
from swarmloc.lie import SE2
from swarmloc.node import TeamNode

__all__ = ["FirstEstimatesEKF", "FirstEstimatesForm", "InvariantEKF", "InvariantForm"]


class InvariantForm(TeamForm):
    """The joint state in world-frame errors (:class:`InvariantEKF`): ``cekf``'s
    :class:`~swarmloc.estimators.cekf.TeamForm` on SE(2) whose ``P`` is of the errors ``(xi_1, ..., xi_n)``, ``pend``
    holding each robot's world-frame process noise (no shear: the error transition of a prediction is the identity),
    corrected on the group."""

    def initial(self, node: TeamNode, t0: float) -> TeamState:
        """Every robot's pose and world-frame covariance as ``diekf``'s form starts them."""
        return team_state(node, t0, SE2, WORLD_FORMS[SE2].initial)

    def advance(self, node: TeamNode, s: TeamState, robot: int, t: float) -> TeamState:
        step = increment(node, s, robot, t)
        if step is None:
            return s
        k, _, (x0, y0, _, _, _, q00, q01, q02, q11, q12, q22), X = step
        # world-frame process noise: N^-1 Q_c N^-T with N^-1 = [[1, 0, y], [0, 1, -x], [0, 0, 1]]
        a02, a12 = q02 + y0 * q22, q12 - x0 * q22
        qw = (
            q00 + 2 * y0 * q02 + y0 * y0 * q22, q01 - x0 * q02 + y0 * a12, a02,
            q11 - 2 * x0 * q12 + x0 * x0 * q22, a12, q22,
        )  # fmt: skip
        old = s.pend[k]
        pend_k = (0.0, 0.0, *qw) if old is None else (0.0, 0.0, *(u + w_ for u, w_ in zip(old[2:], qw, strict=True)))
        return TeamState(X, s.P, *clock_and_pending(s, k, t, pend_k))

    def belief(self, s: TeamState, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The robot's marginal converted to the body-frame convention, ``Sigma = Ad(g^-1) P_ii Ad(g^-1)^T``."""
        P = s.P[i : i + 3, i : i + 3]
        pd = s.pend[i // 3]
        if pd is not None:
            P = P + C.sym3(pd[2:])
        g = SE2.from_xytheta(s.X[i : i + 3])
        return g, I.world_to_body(g, P)

    def world_cross(self, s: TeamState, i: int, ks: Sequence[int]) -> np.ndarray:
        """:meth:`~swarmloc.node.team.WorldCross.world_cross`: ``N_i P_ik N_k^T`` (:func:`I.world_basis`)."""
        P = flush_pending(s).P
        Ni = I.world_basis(s.X[i : i + 3])
        return np.array([Ni @ P[i : i + 3, k : k + 3] @ I.world_basis(s.X[k : k + 3]).T for k in ks]).reshape(-1, 3, 3)

    def to_error(self, H: np.ndarray, x: np.ndarray) -> np.ndarray:
        return H @ I.world_basis(x)

    def correct(self, s: TeamState, delta: np.ndarray, P: np.ndarray) -> TeamState:
        X = I.left_correct(s.X.reshape(-1, 3), delta.reshape(-1, 3)).reshape(-1)
        return TeamState(X, P, s.t, s.cmd, s.pend)


def world_to_cartesian(X: np.ndarray, Pw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cartesian ``(x, P)`` of a team's poses ``X (3n,)`` and world-frame errors' covariance ``Pw (3n, 3n)``, mapped by
    ``N(x_i)`` block by block."""
    N = np.zeros_like(Pw)
    for k in range(0, X.size, 3):
        N[k : k + 3, k : k + 3] = I.world_basis(X[k : k + 3])
    return X, N @ Pw @ N.T


class InvariantEKF(TeamNode):
    """Centralized invariant EKF on SE(2)^n with world-frame errors (module docstring): :class:`InvariantForm`.

    The joint covariance (``joint_at``) is of the world-frame errors ``(xi_1, ..., xi_n)``; a robot's belief is
    converted to the thesis' body-frame convention, ``Sigma = Ad(g^-1) P_ii Ad(g^-1)^T``.
    """

    name = "iekf"
    lazy_odometry = True
    forms = {SE2: InvariantForm()}
    error_frame: ClassVar[str] = "world"

    def _joint(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Cartesian ``(x, P)`` (:func:`world_to_cartesian`)."""
        return world_to_cartesian(*self.joint_at(t))


class FirstEstimatesForm(TeamForm):
    """The Cartesian joint state of ``cekf`` (:class:`~swarmloc.estimators.cekf.TeamForm` on SE(2)) with
    first-estimates Jacobians (:class:`FirstEstimatesEKF`): the state keeps each robot's first estimate at its clock
    (:attr:`~swarmloc.estimators.cekf.TeamState.L`), where every Jacobian is evaluated."""

    first_estimates = True

    def initial(self, node: TeamNode, t0: float) -> TeamState:
        s = team_state(node, t0)
        return s._replace(L=s.X.copy())

    def advance(self, node: TeamNode, s: TeamState, robot: int, t: float) -> TeamState:
        step = increment(node, s, robot, t)
        if step is None:
            return s
        k, i, (x0, y0, _, _, _, *q), X = step
        L = self.first(s).copy()
        dx, dy = x0 - L[i], y0 - L[i + 1]  # first-estimates displacement: new prediction - previous first estimate
        L[i : i + 3] = X[i : i + 3]
        log_shear(node, t, robot, dx, dy)
        return TeamState(X, s.P, *clock_and_pending(s, k, t, compose_pending(s.pend[k], dx, dy, q)), L)

    @staticmethod
    def first(s: TeamState) -> np.ndarray:
        """The first estimates ``L (3n,)`` of a state of this form."""
        if s.L is None:
            raise ValueError("a first-estimates state without its first estimates")
        return s.L

    def lin_point(self, s: TeamState, k: int) -> np.ndarray:
        return self.first(s)[k : k + 3]


class FirstEstimatesEKF(TeamNode):
    """Centralized CL-EKF with first-estimates Jacobians (FEJ-EKF, module docstring): :class:`FirstEstimatesForm`."""

    name = "fej"
    lazy_odometry = True
    forms = {SE2: FirstEstimatesForm()}
    error_frame: ClassVar[str] = "cartesian"
