"""The distributed EKF's fusion of one level (``"dekf"``): :class:`~swarmloc.estimators.DistributedEKF`'s update,
batched over the observers of the level.

Each detection is linearized by its shared measurement model (:data:`swarmloc.sensors.models.MODELS`: prediction
with Jacobians, residual, noise, degenerate geometry; the neighbour's covariance added to the noise), fused by the
Joseph-form Kalman update (:func:`swarmloc.kernels.cartesian.kalman_update`), gated by the nodes'
:class:`~swarmloc.node.update.Gate` and checked finite and positive definite: the steps of
:func:`swarmloc.node.update.gated_kalman`, batched. The fast path (relative poses and absolute fixes) runs the same
update as the structure-of-arrays formulas of :mod:`swarmloc.engine.soa` on an array backend
(:mod:`swarmloc.engine.backends`).

On SE(3) (``group=SE3``) the rows are ``"pose3"`` detections and the state the pose ``(4, 4)`` with the covariance of
``(dp, dtheta)``: the neighbour's answer travels as its group belief (:func:`~swarmloc.engine.se3.to_group`, then back
to the error form, as the node receives it), the residual, Jacobian and noise are the node's
(:class:`swarmloc.sensors.models3.Model3`'s, on the stack; the neighbour's covariance seen through its Jacobian
added, the sum symmetrized), the correction ``K r`` is applied on the group (:func:`~swarmloc.engine.se3.correct`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from swarmloc.engine import se3 as E3
from swarmloc.engine.codes import ABSOLUTE, MODEL, NO_LANDMARK, POSE, R_DEGENERATE, R_NUMERICAL, REJECTED
from swarmloc.engine.stamp import Sequential, Stamp, usable
from swarmloc.events import Kind
from swarmloc.gaussian import symmetric
from swarmloc.kernels import cartesian as C
from swarmloc.lie import SE2, SE3
from swarmloc.node.update import Gate
from swarmloc.sensors.models import KIND_ORDER, MeasurementModel
from swarmloc.sensors.models3 import MODELS3

SOA_MIN_ROWS = 2048
"""On numpy, batches smaller than this take the stacked-matrix kernels even on the fast path: the
structure-of-arrays forms make ~1400 array calls per update, a cost that only large batches amortize."""

FAST_KINDS = (ABSOLUTE, POSE)
"""Kinds the fast path fuses between robots (and absolute fixes)."""
RANGE_BEARING = KIND_ORDER[Kind.RANGE_BEARING]
"""The kind the fast path fuses with :func:`swarmloc.engine.soa.landmark_update`: a map landmark's range-bearing,
and a robot's as a landmark's at the neighbour's position and covariance (the node's ``R + Hk Pk Hk^T``; range and
bearing of a position do not depend on its heading). The range-only and bearing-only kinds take the
stacked-matrix kernels."""

POSE3_MODEL = MODELS3[Kind.POSE3]
"""The ``"pose3"`` model, batched here over the stacked detections of an SE(3) team."""


def kalman_rows(
    x: np.ndarray, P: np.ndarray, r: np.ndarray, H: np.ndarray, R: np.ndarray, angles: tuple[int, ...] = (2,)
) -> tuple[np.ndarray, ...]:
    """:func:`swarmloc.kernels.cartesian.kalman_update` batched, row by row where a singular innovation covariance
    makes the batched inverse fail (the kernel then answers that row alone)."""
    xn, Pn, nis, ok = C.kalman_update(x, P, r, H, R, angles=angles)
    if not np.isnan(nis).all() or x.shape[0] <= 1:
        return xn, Pn, nis, ok
    rows = [C.kalman_update(x[i], P[i], r[i], H[i], R[i], angles=angles) for i in range(x.shape[0])]
    return tuple(np.array([row[k] for row in rows]) for k in range(4))


def linearize(
    model: MeasurementModel, x: np.ndarray, z: np.ndarray, Rz: np.ndarray, xk: np.ndarray | None, Pk: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(r, H, R_eff)`` of detections ``z`` (noise ``Rz``) at observer states ``x``, batched: residual, Jacobian
    w.r.t. the observer, the model's noise plus the target's covariance ``Pk`` seen through its Jacobian (none for
    an absolute fix: ``xk`` None), as the node's :func:`swarmloc.estimators.dekf.linearize`."""
    h, H, Hk = model.predict(x, xk)
    R = model.noise(z, Rz)
    if Hk is not None:
        R = R + Hk @ Pk @ np.swapaxes(Hk, -1, -2)
    return model.residual(z, h), H, R


class EkfFusion(Sequential):
    """:class:`~swarmloc.estimators.DistributedEKF` on a level: one detection of each group at a time.

    ``ops``: the fast path's kernels (:func:`swarmloc.engine.backends.make_ops`), None: the stacked-matrix kernels
    for every kind; ``backend``: its name (numpy takes the fast path for batches of :data:`SOA_MIN_ROWS` or more).
    :attr:`landmarks`: the map's positions and covariances, ``(xy (L, 2), cov (L, 2, 2))``, or None. ``group``: the
    robots' (SE(3): module docstring).
    """

    def __init__(self, gate: Gate, ops: Any = None, backend: str = "numpy", group: type = SE2, **options: Any) -> None:
        super().__init__(gate, **options)
        self.ops = ops
        self.backend = backend
        self.group = group

    def _map(self) -> tuple[np.ndarray, np.ndarray]:
        """:attr:`landmarks`, which a landmark detection needs (the engine refuses one when there is no map)."""
        if self.landmarks is None:
            raise RuntimeError("EkfFusion: a landmark detection, but no map of landmarks")
        return self.landmarks

    def _fast(self, code: int, rows: int, kinds: tuple[int, ...] = FAST_KINDS) -> bool:
        return self.ops is not None and code in kinds and (self.backend != "numpy" or rows >= SOA_MIN_ROWS)

    def update(self, st: Stamp, rows: np.ndarray, code: int) -> None:
        if self.group is SE3:
            self._update_pose3(st, rows)
            return
        model = MODEL[code]
        m = model.size
        lo = st.lo[rows]
        x, P = st.cur[0][lo], st.cur[1][lo]
        z, Rz = st.det.z[rows, :m], st.det.R[rows, :m, :m]
        if self._fast(code, rows.size):
            if code == ABSOLUTE:
                xn, Pn, nis, ok, pd = self.ops.absolute_update(x, P, z, Rz)
            else:
                xn, Pn, nis, ok, pd = self.ops.pose_update(x, P, *st.target(rows), z, Rz)
            ok = ok & pd
        else:
            xk: np.ndarray | None = None  # the targets' states (None: an absolute fix)
            Pk: np.ndarray | None = None
            landmark = st.det.target[rows] <= NO_LANDMARK
            if landmark.any() and not landmark.all():  # different observers: independent, in either order
                self.update(st, rows[landmark], code)
                self.update(st, rows[~landmark], code)
                return
            if landmark.any():  # the map's position (2,) and covariance (2, 2), as the node's landmark_state
                k = NO_LANDMARK - 1 - st.det.target[rows]
                xy, cov = self._map()
                xk, Pk = xy[k], cov[k]
            elif model.targets != "self":
                xk, Pk = C.from_group(*C.to_group(*st.target(rows)))  # the answer travels as a group belief
            if xk is not None and Pk is not None:  # (set together)
                bad = model.degenerate(x, xk)
                if bad.any():
                    st.mark(rows[bad], REJECTED, R_DEGENERATE)
                    rows, x, P, z, Rz, xk, Pk = (a[~bad] for a in (rows, x, P, z, Rz, xk, Pk))
                    if rows.size == 0:
                        return
            if xk is not None and Pk is not None and self._fast(code, rows.size, (RANGE_BEARING,)):
                # a landmark's, or a robot's at its position
                lk, L = (xk, Pk) if landmark.any() else (xk[:, :2], Pk[:, :2, :2])
                xn, Pn, nis, ok, pd = self.ops.landmark_update(x, P, lk, L, z, Rz)
                ok = ok & pd
            else:
                xn, Pn, nis, ok = kalman_rows(x, P, *linearize(model, x, z, Rz, xk, Pk))
                ok = ok & usable(Pn)
        keep = st.gate(rows, nis, self.gate, m)
        st.mark(rows[keep & ~ok], REJECTED, R_NUMERICAL)
        good = keep & ok
        st.store(rows[good], xn[good], Pn[good])

    def _update_pose3(self, st: Stamp, rows: np.ndarray) -> None:
        """:meth:`update` of an SE(3) team (module docstring)."""
        lo = st.lo[rows]
        g, P = st.cur[0][lo], st.cur[1][lo]
        gk, Pk = E3.to_error(*E3.to_group(*st.target(rows)))  # the answer travels as a group belief
        z, Rz = st.det.z[rows, :6], st.det.R[rows, :6, :6]
        h, H, Hk = POSE3_MODEL.predict(g, gk)
        Rn = symmetric(POSE3_MODEL.noise(z, Rz) + Hk @ Pk @ np.swapaxes(Hk, -1, -2))
        dx, Pn, nis, ok = kalman_rows(np.zeros((rows.size, 6)), P, POSE3_MODEL.residual(z, h), H, Rn, angles=())
        ok = ok & usable(Pn)
        keep = st.gate(rows, nis, self.gate, 6)
        st.mark(rows[keep & ~ok], REJECTED, R_NUMERICAL)
        good = keep & ok
        st.store(rows[good], E3.correct(g[good], dx[good]), Pn[good])
