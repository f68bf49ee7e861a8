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
from swarmloc.engine.fuse_exp import fuse_pseudo
from swarmloc.engine.stamp import Sequential, Stamp
from swarmloc.kernels import ci as KCI
from swarmloc.kernels import group as K
from swarmloc.lie import SE2, SE3
from swarmloc.node.update import Gate
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
        """A level's detections of kind ``code``: relative poses and range/bearing of robots by covariance
        intersection (``"pose3"`` on SE(3) at the closed-form weight whatever ``ci_weight`` says, as the node:
        :meth:`swarmloc.estimators.ci.CovarianceIntersection.ci`), absolute fixes as independent information."""
        if code == ABSOLUTE:  # the thesis estimator's update, gated against the prior
            fuse_pseudo(st, rows, SE2, self.gate, self.order, self.iterations)
            return
        G = SE3 if code == POSE3 else SE2
        m = G.dim if code in (POSE, POSE3) else MODEL[code].size
        lo = st.lo[rows]
        z, R = st.det.z[rows, :m], st.det.R[rows, :m, :m]
        meas = pose3_matrix(z) if code == POSE3 else SE2.from_xytheta(z) if code == POSE else z
        pair = KCI.Pair(st.cur[0][lo], st.cur[1][lo], meas, R, *st.target(rows))
        if self.gate.p is not None:
            keep = self._gate(st, rows, code, pair)
            rows, pair = rows[keep], KCI.Pair(*(a[keep] for a in pair))
        if rows.size == 0:
            return
        why = R_NUMERICAL if code in (POSE, POSE3) else R_DEGENERATE
        order, its, point_its = self.order, self.iterations, self.point_iterations
        if self.weight == "search" and code != POSE3:
            at = (
                KCI.pose_fusion_at(pair, order, its)
                if code == POSE
                else KCI.point_fusion_at(MODEL[code].kind, pair, point_its, order)
            )
            m2, c2, _ = KCI.ci_search(at, (rows.size,))
            st.accept(rows, m2, c2, why)
        elif code in (POSE, POSE3):
            st.accept(rows, *KCI.pose_fusion(G, pair, order, its), why)
        else:
            m2, c2, ok = KCI.point_fusion(MODEL[code].kind, pair, point_its, order)
            st.mark(rows[~ok], REJECTED, R_DEGENERATE)
            st.accept(rows[ok], m2[ok], c2[ok], why)

    def _gate(self, st: Stamp, rows: np.ndarray, code: int, pair: KCI.Pair) -> np.ndarray:
        """The gate on the fusion with the neighbour's belief as independent (relative poses: as a pseudo-observation;
        range/bearing: the point update's innovation, non-finite where the geometry is degenerate)."""
        mean, cov, meas, R, nb_mean, nb_cov = pair
        if code in (POSE, POSE3):
            G = SE3 if code == POSE3 else SE2
            nu, W = K.relative_to_pseudo(G, nb_mean, nb_cov, meas, R, self.order)
            return st.gate(rows, K.pseudo_nis(G, mean, cov, nu, W), self.gate, G.dim)
        model = MODEL[code]
        nis = K.point_nis(mean, cov, K.PointMeasurement(model.kind, meas, R, nb_mean, nb_cov, True))
        return st.gate(rows, nis, self.gate, model.size, nonfinite=R_DEGENERATE)
