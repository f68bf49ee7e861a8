"""Covariance intersection in exponential coordinates (``"ci"``): the thesis' state, consistent fusion.

Each node keeps what the thesis estimator keeps (one Gaussian on SE(2)) and fuses a neighbour's information with
*covariance intersection*: for any unknown correlation between the robot's belief ``Sigma_i`` and the neighbour's
``Sigma_k``, ``blockdiag(Sigma_i / w, Sigma_k / (1 - w))`` bounds their joint covariance (Julier & Uhlmann 1997),
while the measurement noise, independent of both, is fused as usual ("CI with independent measurement noise",
Carrillo-Arce et al., IROS 2013). ``w`` minimizes the determinant of the posterior linearized at the prior, in
closed form (:func:`swarmloc.kernels.ci.point_weight`, :func:`~swarmloc.kernels.ci.pose_weight`; any ``w`` gives a
valid CI, so this only trades a little tightness, where the update is strongly nonlinear, for one fusion instead
of a search over many). Consistent by construction, but conservative: it never gains as much as a
filter that knows the correlations. Landmarks and absolute fixes are independent information and are fused
normally, one at a time.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from swarmloc.estimators.expfusion import DEGENERATE, NUMERICAL, ExpFusion, ExpState
from swarmloc.kernels import group as K
from swarmloc.kernels.ci import point_weight, pose_weight
from swarmloc.lie import SE2
from swarmloc.messages import Message
from swarmloc.node import FUSED, Group, Outcome, usable_covariance


class ExpCI(ExpFusion):
    """Thesis-style exponential-coordinate estimator with covariance-intersection fusion of neighbours."""

    name = "ci"

    def _fuse_group(self, s: ExpState, g: Group) -> tuple[ExpState, list[Outcome], list[Message]]:
        mean, cov = s.mean, s.cov
        outcomes: list[Outcome] = []
        for d in g.detections:
            target = self._classify(g, d)
            if target[0] in ("rejected", "unknown"):
                outcomes.append(target)
                continue
            res = self._ci(mean, cov, d, target) if target[0] == "robot" else self._independent(mean, cov, d, target)
            if isinstance(res[0], str):
                outcomes.append(res)
            else:
                mean, cov = res
                outcomes.append(FUSED)
        return ExpState(s.t, s.v, s.w, mean, cov), outcomes, []

    def _independent(self, mean: np.ndarray, cov: np.ndarray, d: Any, target: tuple[str, Any]) -> Any:
        """Absolute fixes and landmarks: the usual (thesis / point) update."""
        pseudo = self._pseudo(d, target)
        if pseudo is None:
            return self._point(mean, cov, d, target)
        if self.gate.p is not None:
            verdict = self._gated(float(K.pseudo_nis(SE2, mean, cov, *pseudo)), 3)
            if verdict is not None:
                return verdict
        m2, c2 = K.fuse_pseudo(SE2, mean, cov, pseudo[0][None], pseudo[1][None], self.order, self.iterations)
        if not (np.isfinite(m2).all() and usable_covariance(c2)):
            return ("rejected", NUMERICAL)
        return m2, c2

    def _ci(self, mean: np.ndarray, cov: np.ndarray, d: Any, target: tuple[str, Any]) -> Any:
        """Covariance intersection with a neighbour's answer: the weight in closed form from the linearized fusion
        (:func:`swarmloc.kernels.ci.point_weight`, :func:`~swarmloc.kernels.ci.pose_weight`), then one fusion."""
        nb_mean, nb_cov = target[1].belief_arrays()
        R = np.asarray(d.cov, dtype=float)
        order, its = self.order, self.iterations
        if d.kind == "pose":
            m = SE2.from_xytheta(d.z)
            if self.gate.p is not None:
                nu, W = K.relative_to_pseudo(SE2, nb_mean, nb_cov, m, R, order)
                verdict = self._gated(float(K.pseudo_nis(SE2, mean, cov, nu, W)), 3)
                if verdict is not None:
                    return verdict
            w = float(pose_weight(mean, cov, m, R, nb_mean, nb_cov, order))
            nu, W = K.relative_to_pseudo(SE2, nb_mean, nb_cov / (1 - w), m, R, order)
            m2, c2 = K.fuse_pseudo(SE2, mean, cov / w, nu[None], W[None], order, its)
        else:
            verdict = self._point_gate(mean, cov, d, nb_mean, nb_cov, True)
            if verdict is not None:
                return verdict
            w = float(point_weight(mean, cov, d.kind, d.z, R, nb_mean, nb_cov))
            m2, c2, ok = K.point_update(
                mean, cov / w, d.kind, d.z, R, nb_mean, nb_cov / (1 - w), True, self.point_iterations, order
            )
            if not bool(ok):
                return ("rejected", DEGENERATE)
        if not (np.isfinite(m2).all() and usable_covariance(c2)):
            return ("rejected", DEGENERATE if d.kind != "pose" else NUMERICAL)
        return m2, c2
