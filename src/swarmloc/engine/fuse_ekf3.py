"""The distributed EKF's fusion of one level on SE(3) (``"dekf"`` for a 3-D team):
:class:`~swarmloc.estimators.dekf.DistributedEKF`'s SE(3) update, batched over the observers of the level.

One ``"pose3"`` detection of each group at a time (:class:`~swarmloc.engine.stamp.Sequential`): the neighbour's
answer travels as its group belief (:func:`~swarmloc.engine.se3.to_group`, then back to the error form, as the
node receives it), the residual, Jacobian and noise are :func:`~swarmloc.engine.se3.pose3_linearize`, the update
the Joseph-form Kalman update of the correction ``K r`` (:func:`swarmloc.kernels.cartesian.kalman_update`),
gated by the nodes' :class:`~swarmloc.node.update.Gate`, checked finite and positive definite and applied on the
group (:func:`~swarmloc.engine.se3.correct`): the steps of :func:`swarmloc.node.update.gated_kalman`, batched.
"""

from __future__ import annotations

import numpy as np

from swarmloc.engine import se3 as E3
from swarmloc.engine.codes import R_NUMERICAL, REJECTED
from swarmloc.engine.stamp import Sequential, Stamp, usable
from swarmloc.kernels import cartesian as C


class Ekf3Fusion(Sequential):
    """:class:`~swarmloc.estimators.dekf.DistributedEKF` (SE(3)) on a level (the rows are ``"pose3"`` detections)."""

    def update(self, st: Stamp, rows: np.ndarray, code: int) -> None:
        lo = st.lo[rows]
        g, P = st.cur[0][lo], st.cur[1][lo]
        gk, Pk = E3.to_error(*E3.to_group(*st.target(rows)))  # the answer travels as a group belief
        r, H, Rn = E3.pose3_linearize(g, gk, Pk, st.det.z[rows, :6], st.det.R[rows, :6, :6])
        dx, Pn, nis, ok = C.kalman_update(np.zeros((rows.size, 6)), P, r, H, Rn, angles=())
        if np.isnan(nis).all() and rows.size > 1:  # a singular innovation covariance failed the batch: row by row
            each = [C.kalman_update(np.zeros(6), P[i], r[i], H[i], Rn[i], angles=()) for i in range(rows.size)]
            dx, Pn, nis, ok = (np.array([e[k] for e in each]) for k in range(4))
        ok = ok & usable(Pn)
        keep = st.gate(rows, nis, self.gate, 6)
        st.mark(rows[keep & ~ok], REJECTED, R_NUMERICAL)
        good = keep & ok
        st.store(rows[good], E3.correct(g[good], dx[good]), Pn[good])
