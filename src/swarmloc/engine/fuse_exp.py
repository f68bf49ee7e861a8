"""The thesis estimator's fusion of one level (``"expfusion"``): :class:`~swarmloc.estimators.ExpFusion`'s update on
SE(2) or SE(3) (``group``), batched over the observers of the level through :mod:`swarmloc.kernels.group`.

A group's pose pseudo-observations (absolute fixes, relative poses) are fused at once, gated against the prior;
then its range/bearing detections one at a time, gated and updated by the iterated point update.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from swarmloc.engine.codes import ABSOLUTE, FUSED, MODEL, PENDING, POSE, POSE3, R_DEGENERATE, R_NUMERICAL, REJECTED
from swarmloc.engine.stamp import Fusion, Stamp, runs, usable
from swarmloc.kernels import group as K
from swarmloc.lie import SE2, SE3
from swarmloc.lie.base import SEGroup
from swarmloc.node.update import Gate
from swarmloc.sensors.models3 import pose3_matrix

PSEUDO_KINDS = (ABSOLUTE, POSE, POSE3)
"""Kinds fused as pseudo-observations of the observer's own pose (``"pose3"``: an SE(3) team's)."""


def pseudo(st: Stamp, rows: np.ndarray, code: int, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Pseudo-observations ``(nu, W)`` of the observers' own poses (absolute fixes, relative poses)."""
    det = st.det
    if code == ABSOLUTE:
        return K.absolute_to_pseudo(det.z[rows], det.R[rows])
    tm, tc = st.target(rows)
    if code == POSE3:
        return K.relative_to_pseudo(SE3, tm, tc, pose3_matrix(det.z[rows]), det.R[rows], order)
    return K.relative_to_pseudo(SE2, tm, tc, SE2.from_xytheta(det.z[rows]), det.R[rows], order)


def fuse_pseudo(st: Stamp, rows: np.ndarray, G: type[SEGroup], gate: Gate, order: int, iterations: int) -> None:
    """All pose pseudo-observations ``rows`` of each group at once on the group ``G``, gated one by one against the
    prior (the thesis estimator's; covariance intersection fuses its absolute fixes so, one per group at a time)."""
    det = st.det
    nu = np.empty((rows.size, G.n + 1, G.n + 1))
    W = np.empty((rows.size, G.dim, G.dim))
    for code in PSEUDO_KINDS:
        sel = det.kind[rows] == code
        if sel.any():
            nu[sel], W[sel] = pseudo(st, rows[sel], code, order)
    if gate.p is not None:
        lo = st.lo[rows]
        keep = st.gate(rows, K.pseudo_nis(G, st.cur[0][lo], st.cur[1][lo], nu, W), gate, G.dim)
        rows, nu, W = rows[keep], nu[keep], W[keep]
    if rows.size == 0:
        return
    starts, _ = runs(det.observer[rows])
    count = np.diff(np.r_[starts, rows.size])
    for c in np.unique(count):
        first = starts[count == c]
        idx = first[:, None] + np.arange(c)  # (B, c): each observer's pseudo-observations in order
        lo = st.lo[rows[first]]
        m2, c2 = K.fuse_pseudo(G, st.cur[0][lo], st.cur[1][lo], nu[idx], W[idx], order, iterations)
        ok = np.isfinite(m2).all(axis=(-1, -2)) & usable(c2)
        st.cur[0][lo[ok]] = m2[ok]
        st.cur[1][lo[ok]] = c2[ok]
        st.status[rows[idx[ok]].ravel()] = FUSED  # all of the group's pseudo-observations
        st.mark(rows[idx[~ok]].ravel(), REJECTED, R_NUMERICAL)


class ExpFusionLevel(Fusion):
    """:class:`~swarmloc.estimators.ExpFusion` on a level; ``group``: the team's, SE(2) or SE(3) (whose groups hold
    ``"pose3"`` detections only: the engine rejects the other kinds before fusion, as the nodes do)."""

    def __init__(self, gate: Gate, group: type[SEGroup] = SE2, **options: Any) -> None:
        super().__init__(gate, **options)
        self.group = group

    def fuse_level(self, st: Stamp, rows: np.ndarray) -> None:
        det = st.det
        rows = rows[st.status[rows] == PENDING]
        kinds = det.kind[rows]
        poses = np.isin(kinds, PSEUDO_KINDS)
        if poses.any():
            fuse_pseudo(st, rows[poses], self.group, self.gate, self.order, self.iterations)
        points = rows[~poses]
        if points.size:
            _, rank = runs(det.observer[points])
            for k in range(int(rank.max()) + 1):
                at = points[rank == k]
                at = at[st.status[at] == PENDING]
                for code in np.unique(det.kind[at]):
                    self.point(st, at[det.kind[at] == code], int(code))

    def point(self, st: Stamp, rows: np.ndarray, code: int) -> None:
        """Range/bearing of robots: gate, then the iterated update on the group."""
        model = MODEL[code]
        name, m = model.kind, model.size
        lo = st.lo[rows]
        mean, cov = st.cur[0][lo], st.cur[1][lo]
        z, R = st.det.z[rows, :m], st.det.R[rows, :m, :m]
        tm, tc = st.target(rows)
        if self.gate.p is not None:
            nis = K.point_nis(mean, cov, K.PointMeasurement(name, z, R, tm, tc, True))
            keep = st.gate(rows, nis, self.gate, m, nonfinite=R_DEGENERATE)
            rows, mean, cov, z, R, tm, tc = (a[keep] for a in (rows, mean, cov, z, R, tm, tc))
        if rows.size == 0:
            return
        meas = K.PointMeasurement(name, z, R, tm, tc, True)
        m2, c2, ok = K.point_update(mean, cov, meas, self.point_iterations, self.order)
        st.mark(rows[~ok], REJECTED, R_DEGENERATE)
        st.accept(rows[ok], m2[ok], c2[ok], R_NUMERICAL)
