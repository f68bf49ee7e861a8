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

from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from swarmloc.estimators.cekf import joint_correction
from swarmloc.estimators.rdl import RdlFilter, RdlNode
from swarmloc.estimators.world_form import FORMS
from swarmloc.kernels import invariant as I
from swarmloc.lie import SE2
from swarmloc.node import Gate, Outcome

__all__ = ["InvariantRDL", "WorldPairs"]


class WorldPairs:
    """World-frame errors (:mod:`swarmloc.kernels.invariant`): the :class:`~swarmloc.estimators.rdl.PairForm` of
    ``irdl`` (module docstring)."""

    initial = FORMS[SE2].initial  # the pose and the world-frame covariance, as diekf's
    belief = FORMS[SE2].belief  # converted to the body-frame convention, Sigma = Ad(g^-1) P Ad(g^-1)^T

    def advance(self, node: RdlNode, s: RdlFilter, t: float) -> RdlFilter:
        """``P`` gains the world-frame process noise; the factors stay (the error transition is the identity)."""
        x, P = FORMS[SE2].predict(s.x, s.P, s.v, s.w, t - s.t, node.noise)
        return RdlFilter(t, s.v, s.w, x, P, s.ids, s.sigma)

    def advance_commands(
        self, node: RdlNode, s: RdlFilter, cmds: Sequence[tuple[float, int, float, float]]
    ) -> RdlFilter | None:
        """None: no float loop in world-frame errors."""
        return None

    def correction(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        """The world-frame correction that takes the pose ``x0`` to ``x1``."""
        return I.world_delta(x0, x1)

    def to_error(self, H: np.ndarray, x: np.ndarray) -> np.ndarray:
        return H @ I.world_basis(x)

    def update(
        self, x: np.ndarray, P: np.ndarray, r: np.ndarray, H: np.ndarray, R: np.ndarray, gate: Gate
    ) -> tuple[np.ndarray, np.ndarray] | Outcome:
        """The correction (:func:`~swarmloc.estimators.cekf.joint_correction`) applied on the group."""
        res = joint_correction(P, list(range(0, x.size, 3)), [H], r, R, gate)
        if isinstance(res[0], str):
            return res
        delta, Pn = res
        return I.left_correct(x, delta.reshape(x.shape)), Pn


class InvariantRDL(RdlNode):
    """Recursive decentralized localization in world-frame errors (module docstring): :class:`WorldPairs`."""

    name = "irdl"
    form = WorldPairs()
    error_frame: ClassVar[str] = "world"
