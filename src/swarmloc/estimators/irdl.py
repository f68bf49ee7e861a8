"""Recursive decentralized localization with world-frame errors (``"irdl"``): ``rdl`` made consistent without
landmarks.

The exchange is :mod:`swarmloc.estimators.rdl`'s (Luft, Schubert, Roumeliotis & Burgard 2018): robot ``i`` asks the
detected robot ``j`` for ``(x_j, P_jj, sigma_ji)``, performs the joint update of the pair, keeps its part and sends
``j`` its new ``(x_j, P_jj)``; cross-covariances are factored, ``Sigma_il = sigma_il sigma_li^T``, and those with
third robots are rescaled, ``sigma_il <- P_ii+ P_ii-^-1 sigma_il``. What changes is the error convention, that of
:class:`~swarmloc.estimators.iekf.InvariantEKF`: every covariance and factor is of the world-frame error
``g = exp(hat(xi)) g^`` (:mod:`swarmloc.kernels.invariant`). Consequences:

* the odometry step's error transition is the identity: a prediction adds ``Q_w = N^-1 Q_c N^-T`` to ``P_ii`` and
  leaves every factor alone (``rdl`` multiplies them by ``Phi_i``);
* a relative measurement's Jacobians satisfy ``H_i + H_j = 0`` at any estimate, so no update gains information
  along the team's unobservable global motion (:mod:`swarmloc.evaluation.observability`);
* a third robot ``l``'s correlation with ``i`` after ``i``'s update is approximated by the rescaling above. With
  world-frame errors the unobservable part of every robot's error is the *same* vector for all robots, so that
  shared part, which the rescaling carries over exactly, is what dominates the third-party correlations without
  absolute information; with Cartesian errors the shared part is state dependent and ``rdl`` loses it.

Nodes of one team must all run ``irdl`` (answers carry world-frame covariances). Beliefs are converted to the
thesis' body-frame convention, ``Sigma = Ad(g^-1) P Ad(g^-1)^T``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from swarmloc.estimators.dekf import DEGENERATE, linearize
from swarmloc.estimators.iekf import joint_correction
from swarmloc.estimators.rdl import (
    UNKNOWN_CORRELATION,
    RdlFilter,
    RecursiveDecentralized,
    joint_prior,
    rescale_factors,
)
from swarmloc.gaussian import GroupGaussian
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import invariant as I
from swarmloc.lie import SE2
from swarmloc.messages import RdlState
from swarmloc.node import Group, Node, belief_of
from swarmloc.sensors.models import model

__all__ = ["InvariantRDL"]


class InvariantRDL(RecursiveDecentralized):
    """Recursive decentralized localization in world-frame errors (module docstring)."""

    name = "irdl"
    error_frame: ClassVar[str] = "world"
    lin_log: list | None = None

    def _initial_state(self, t0: float) -> RdlFilter:
        s = super()._initial_state(t0)
        return RdlFilter(s.t, s.v, s.w, s.x, I.body_to_world(self.initial.mean, self.initial.cov), s.ids, s.sigma)

    def _advance(self, s: RdlFilter, robot: int, t: float) -> RdlFilter:
        dt = t - s.t
        if dt <= 0:
            return s
        x0, y0, th, _, _, q00, q01, q02, q11, q12, q22 = C.increment_terms(s.x, s.v, s.w, dt, self.noise)
        Qc = np.array([[q00, q01, q02], [q01, q11, q12], [q02, q12, q22]])
        x = np.array([x0, y0, th])
        P = s.P + I.cartesian_to_world_cov(x, Qc)
        return RdlFilter(t, s.v, s.w, x, P, s.ids, s.sigma)

    _advance_commands = Node._advance_commands  # predicts in world-frame errors, not rdl's Cartesian run

    def _belief(self, s: RdlFilter, robot: int) -> GroupGaussian:
        g = SE2.from_xytheta(s.x)
        return belief_of(g, I.world_to_body(g, s.P))

    def _correction(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        """The world-frame correction that takes the pose ``x0`` to ``x1`` (what an update's check measures)."""
        return I.world_delta(x0, x1)

    def _log_update(self, t: float, blocks: dict[int, np.ndarray], R: np.ndarray) -> None:
        if self.lin_log is not None:
            self.lin_log.append(("update", t, blocks, R))

    def _private(self, s: RdlFilter, d: Any, target: tuple[str, Any]) -> Any:
        """Absolute fix or landmark: a private update in world-frame errors, then every factor rescaled."""
        lin = linearize(d, s.x, target)
        if lin is None:
            return ("rejected", DEGENERATE)
        r, Hi, R_eff, _ = lin
        Hw = Hi @ I.world_basis(s.x)
        res = joint_correction(s.P, [0], [Hw], r, R_eff, self.gate)
        if isinstance(res[0], str):
            return res
        delta, P = res
        self._log_update(d.t, {self.robot: Hw}, R_eff)
        return RdlFilter(s.t, s.v, s.w, I.left_correct(s.x, delta), P, s.ids, rescale_factors(s, P)), None

    def _pair(self, s: RdlFilter, g: Group, d: Any, sub: tuple, a: RdlState) -> Any:
        """The joint update of observer ``i`` and target ``j`` (world-frame errors) from ``j``'s answer ``a``."""
        j = d.target
        m = model(d.kind)
        xj, Pjj, sig_ji = a.arrays()
        if m.degenerate(s.x, xj):
            return ("rejected", DEGENERATE)
        fi = s.factor(j)
        h, Hi, Hj = m.predict(s.x, xj)
        blocks = [Hi @ I.world_basis(s.x), Hj @ I.world_basis(xj)]
        R = m.noise(d.z, d.cov)
        prior = joint_prior(s.P, Pjj, fi, sig_ji, np.hstack(blocks), R, j in s.ids)  # CI: correlation unknown
        if prior is None:
            return ("gated", UNKNOWN_CORRELATION)
        res = joint_correction(prior[0], [0, 3], blocks, m.residual(d.z, h), R, self.gate)
        if isinstance(res[0], str):
            return res
        delta, Pn = res
        self._log_update(g.t, {self.robot: blocks[0], j: blocks[1]}, R)
        xi_new, xj_new = I.left_correct(np.stack([s.x, xj]), delta.reshape(2, 3))
        return self._pair_result(s, g, sub, a, xi_new, xj_new, Pn, prior[1])
