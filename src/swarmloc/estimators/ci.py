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

from typing import Any, ClassVar

import numpy as np

from swarmloc.estimators.expfusion import ExpNode, ExpState, point, point_gate, pseudo
from swarmloc.events import Kind
from swarmloc.kernels import ci as KCI
from swarmloc.kernels import group as K
from swarmloc.lie import SE2, SE3
from swarmloc.messages import Message
from swarmloc.node import NUMERICAL, Group, Outcome, applied, usable_covariance
from swarmloc.sensors.models import DEGENERATE
from swarmloc.sensors.models3 import pose3_matrix


class CovarianceIntersection:
    """``ci``'s update (module docstring): a neighbour's detection by covariance intersection (:meth:`ci`), the
    others (absolute fixes, landmarks) as the thesis fuses them, one at a time."""

    def fuse_group(self, node: ExpNode, s: ExpState, g: Group) -> tuple[ExpState, list[Outcome], list[Message]]:
        def fuse(mc: tuple[np.ndarray, np.ndarray], d: Any, target: tuple[str, Any]) -> tuple[Any, Outcome]:
            mean, cov = mc
            step = self.ci if target[0] == "robot" else self.independent
            return applied(mc, step(node, mean, cov, d, target))

        (mean, cov), outcomes = node._fuse_each((s.mean, s.cov), g, fuse)
        return ExpState(s.t, s.v, s.w, mean, cov), outcomes, []

    @staticmethod
    def independent(node: ExpNode, mean: np.ndarray, cov: np.ndarray, d: Any, target: tuple[str, Any]) -> Any:
        """Absolute fixes and landmarks: the usual (thesis / point) update."""
        obs = pseudo(node, d, target)
        G = node.group
        if obs is None:
            if G is SE3:
                return ("rejected", f"kind {d.kind!r} is not supported on {G.name}")
            return point(node, mean, cov, d, target)
        if node.gate.p is not None:
            verdict = node._gated(float(K.pseudo_nis(G, mean, cov, *obs)), G.dim)
            if verdict is not None:
                return verdict
        m2, c2 = K.fuse_pseudo(G, mean, cov, obs[0][None], obs[1][None], node.order, node.iterations)
        if not (np.isfinite(m2).all() and usable_covariance(c2)):
            return ("rejected", NUMERICAL)
        return m2, c2

    @staticmethod
    def ci(node: ExpNode, mean: np.ndarray, cov: np.ndarray, d: Any, target: tuple[str, Any]) -> Any:
        """Covariance intersection with a neighbour's answer: the weight in closed form from the linearized fusion
        (:func:`swarmloc.kernels.ci.point_weight`, :func:`~swarmloc.kernels.ci.pose_weight`, on SE(2) or SE(3)), then
        one fusion."""
        nb_mean, nb_cov = target[1].belief_arrays()
        R = np.asarray(d.cov, dtype=float)
        G, order, its = node.group, node.order, node.iterations
        pose = d.kind in (Kind.POSE, Kind.POSE3)
        if (G is SE3 or d.kind == Kind.POSE3) and not (d.kind == Kind.POSE3 and G is SE3 and nb_mean.shape == (4, 4)):
            return ("rejected", f"kind {d.kind!r} is not supported on {G.name}")
        if pose:  # a relative pose on its group: gated as an independent pseudo-observation
            m = pose3_matrix(d.z) if G is SE3 else SE2.from_xytheta(d.z)
            pair = KCI.Pair(mean, cov, m, R, nb_mean, nb_cov)
            if node.gate.p is not None:
                nu, W = K.relative_to_pseudo(G, nb_mean, nb_cov, m, R, order)
                verdict = node._gated(float(K.pseudo_nis(G, mean, cov, nu, W)), G.dim)
                if verdict is not None:
                    return verdict
            if node.ci_weight == "search" and G is SE2:  # SE(3): the closed form whatever ci_weight says
                m2, c2, _ = KCI.ci_search(KCI.pose_fusion_at(pair, order, its))
            else:
                m2, c2 = KCI.pose_fusion(G, pair, order, its)
        else:
            verdict = point_gate(node, mean, cov, K.PointMeasurement(d.kind, d.z, R, nb_mean, nb_cov, True))
            if verdict is not None:
                return verdict
            pair = KCI.Pair(mean, cov, d.z, R, nb_mean, nb_cov)
            if node.ci_weight == "search":
                m2, c2, _ = KCI.ci_search(KCI.point_fusion_at(d.kind, pair, node.point_iterations, order))
                ok = bool(np.isfinite(c2).all())
            else:
                m2, c2, found = KCI.point_fusion(d.kind, pair, node.point_iterations, order)
                ok = bool(found)
            if not ok:
                return ("rejected", DEGENERATE)
        if not (np.isfinite(m2).all() and usable_covariance(c2)):
            return ("rejected", NUMERICAL if pose else DEGENERATE)
        return m2, c2


class ExpCI(ExpNode):
    """Thesis-style exponential-coordinate estimator with covariance-intersection fusion of neighbours
    (:class:`~swarmloc.estimators.expfusion.ExpNode` with :class:`CovarianceIntersection`)."""

    name = "ci"
    rule = CovarianceIntersection()
    ci_weight: ClassVar[str] = "closed_form"
    """How :meth:`CovarianceIntersection.ci` picks the weight ``w``: ``"closed_form"`` (the minimizer of the
    linearized posterior's determinant) or ``"search"`` (the minimizer of the fused covariance's determinant over
    fusions at many weights, :func:`swarmloc.kernels.ci.ci_search`). The batched engine follows the same attribute."""
