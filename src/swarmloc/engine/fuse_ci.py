"""Covariance intersection's fusion of one level (``"ci"``): :class:`~swarmloc.estimators.ExpCI`'s update, batched
over the observers of the level.

A neighbour's answer is fused by covariance intersection (the robot's belief scaled by ``1 / w``, the neighbour's
by ``1 / (1 - w)``); absolute fixes are independent information, fused as the thesis estimator does. The weight
``w`` follows the estimator's rule, :attr:`ExpCI.ci_weight <swarmloc.estimators.ExpCI.ci_weight>`
(:data:`CI_WEIGHTS`): ``"closed_form"`` from the fusion linearized at the prior
(:func:`~swarmloc.kernels.ci.pose_weight`, :func:`~swarmloc.kernels.ci.point_weight`, then one fusion) or
``"search"``, the weight minimizing the fused covariance's determinant over fusions at many weights
(:func:`~swarmloc.kernels.ci.ci_search`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from swarmloc.engine.codes import ABSOLUTE, MODEL, POSE, POSE3, R_DEGENERATE, R_NUMERICAL, REJECTED
from swarmloc.engine.fuse_exp import pseudo
from swarmloc.engine.stamp import Sequential, Stamp
from swarmloc.events import Kind
from swarmloc.kernels import ci as KCI
from swarmloc.kernels import group as K
from swarmloc.lie import SE2, SE3
from swarmloc.node.update import Gate
from swarmloc.sensors.models import MeasurementModel
from swarmloc.sensors.models3 import pose3_matrix

CI_WEIGHTS = ("closed_form", "search")
"""The rules for covariance intersection's weight an estimator may declare (``ci_weight``)."""


class CiFusion(Sequential):
    """:class:`~swarmloc.estimators.ExpCI` on a level, with the weight rule ``weight`` (one of :data:`CI_WEIGHTS`)."""

    def __init__(self, gate: Gate, weight: str = "closed_form", **options: Any) -> None:
        if weight not in CI_WEIGHTS:
            raise ValueError(f"unknown CI weight rule {weight!r}; choose from {list(CI_WEIGHTS)}")
        super().__init__(gate, **options)
        self.weight = weight

    def update(self, st: Stamp, rows: np.ndarray, code: int) -> None:
        if code == ABSOLUTE:
            self._independent(st, rows)
            return
        if code == POSE3:
            self._pose3(st, rows)
            return
        model = MODEL[code]
        m = model.size
        lo = st.lo[rows]
        z, R = st.det.z[rows, :m], st.det.R[rows, :m, :m]
        pair = KCI.Pair(st.cur[0][lo], st.cur[1][lo], SE2.from_xytheta(z) if code == POSE else z, R, *st.target(rows))
        if self.gate.p is not None:
            keep = self._gate(st, rows, model, pair)
            rows, pair = rows[keep], KCI.Pair(*(a[keep] for a in pair))
        if rows.size == 0:
            return
        why = R_NUMERICAL if code == POSE else R_DEGENERATE
        order, its, point_its = self.order, self.iterations, self.point_iterations
        if self.weight == "search":
            at = (
                KCI.pose_fusion_at(pair, order, its)
                if code == POSE
                else KCI.point_fusion_at(model.kind, pair, point_its, order)
            )
            m2, c2, _ = KCI.ci_search(at, (rows.size,))
            st.accept(rows, m2, c2, why)
        elif code == POSE:
            st.accept(rows, *KCI.pose_fusion(SE2, pair, order, its), why)
        else:
            m2, c2, ok = KCI.point_fusion(model.kind, pair, point_its, order)
            st.mark(rows[~ok], REJECTED, R_DEGENERATE)
            st.accept(rows[ok], m2[ok], c2[ok], why)

    def _pose3(self, st: Stamp, rows: np.ndarray) -> None:
        """SE(3) relative poses (``"pose3"``): gated as an independent pseudo-observation, the weight in closed form
        (:func:`~swarmloc.kernels.ci.pose_weight` on SE(3)), one fusion; the node
        (:meth:`~swarmloc.estimators.ci.CovarianceIntersection.ci`) takes the closed form whatever ``ci_weight``
        says."""
        lo = st.lo[rows]
        mean, cov = st.cur[0][lo], st.cur[1][lo]
        nb_mean, nb_cov = st.target(rows)
        meas, R = pose3_matrix(st.det.z[rows, :6]), st.det.R[rows, :6, :6]
        order = self.order
        if self.gate.p is not None:
            nu, W = K.relative_to_pseudo(SE3, nb_mean, nb_cov, meas, R, order)
            keep = st.gate(rows, K.pseudo_nis(SE3, mean, cov, nu, W), self.gate, 6)
            rows, mean, cov, nb_mean, nb_cov, meas, R = (a[keep] for a in (rows, mean, cov, nb_mean, nb_cov, meas, R))
        if rows.size == 0:
            return
        m2, c2 = KCI.pose_fusion(SE3, KCI.Pair(mean, cov, meas, R, nb_mean, nb_cov), order, self.iterations)
        st.accept(rows, m2, c2, R_NUMERICAL)

    def _independent(self, st: Stamp, rows: np.ndarray) -> None:
        """Absolute fixes: the thesis estimator's update, gated against the prior."""
        lo = st.lo[rows]
        mean, cov = st.cur[0][lo], st.cur[1][lo]
        nu, W = pseudo(st, rows, ABSOLUTE, self.order)
        if self.gate.p is not None:
            keep = st.gate(rows, K.pseudo_nis(SE2, mean, cov, nu, W), self.gate, 3)
            rows, mean, cov, nu, W = (a[keep] for a in (rows, mean, cov, nu, W))
        if rows.size:
            m2, c2 = K.fuse_pseudo(SE2, mean, cov, nu[:, None], W[:, None], self.order, self.iterations)
            st.accept(rows, m2, c2, R_NUMERICAL)

    def _gate(self, st: Stamp, rows: np.ndarray, model: MeasurementModel, pair: KCI.Pair) -> np.ndarray:
        """The gate on the fusion with the neighbour's belief as independent (relative poses: as a pseudo-observation;
        range/bearing: the point update's innovation, non-finite where the geometry is degenerate)."""
        mean, cov, meas, R, nb_mean, nb_cov = pair
        if model.kind == Kind.POSE:
            nu, W = K.relative_to_pseudo(SE2, nb_mean, nb_cov, meas, R, self.order)
            return st.gate(rows, K.pseudo_nis(SE2, mean, cov, nu, W), self.gate, 3)
        nis = K.point_nis(mean, cov, K.PointMeasurement(model.kind, meas, R, nb_mean, nb_cov, True))
        return st.gate(rows, nis, self.gate, model.size, nonfinite=R_DEGENERATE)
