"""``diekf`` in clusters on the engine: each cluster's joint state replayed in one compiled loop (numba).

With ``cluster = K`` the :class:`~swarmloc.estimators.DistributedInvariantEKF` nodes are cut into clusters of ``K``
robots in id order (module docstring of :mod:`swarmloc.estimators.diekf`, "Clusters"): the replicas of a cluster's
robots together are the invariant EKF's joint state of that cluster, and no cluster's state is correlated with
another's. This loop keeps exactly that: one ``3K x 3K`` world-frame covariance per cluster (``(n / K, 3K, 3K)``,
the last cluster possibly smaller), so memory is ``O(n K)`` and each update costs ``O(K^2)`` (the Cholesky check
``O(K^3)``) whatever the team's size.

* A detection inside a cluster (of a cluster mate, a landmark, an absolute fix) is :func:`swarmloc.engine.joint.
  replay_joint`'s ``diekf`` step (:func:`swarmloc.engine.joint.steps`) run on the cluster's views of the state.
* A detection of a robot outside the observer's cluster is the node's covariance-intersection update
  (:meth:`TeamProtocol.outsider <swarmloc.estimators.team_protocol.TeamProtocol.outsider>`): the
  outsider's belief at the stamp (predicted, not stored: its node answers a ``BeliefQuery``), ``A = H_i P_ii
  H_i^T``, ``B = H_j P_jj H_j^T``, the weight ``w`` minimizing the cluster's posterior log det
  (:func:`joint_weight`, :func:`swarmloc.kernels.ci.joint_weight` compiled), then the Kalman update of the cluster's
  covariance divided by ``w`` with the noise ``R + B / (1 - w)`` on the observer's columns. The outsider is not
  updated.

Results equal the nodes' to rounding (tests/test_engine_clusters.py). Units: metres, radians, seconds.
"""

from __future__ import annotations

from functools import cache
from typing import Any, Unpack

import numpy as np
from numba import njit

from swarmloc.arrays import BoolArray, FloatArray
from swarmloc.engine.codes import R_DEGENERATE, REJECTED
from swarmloc.engine.detections import Timeline
from swarmloc.engine.joint import flush, run, stamp_loop, steps
from swarmloc.engine.joint_math import F, commit, degenerate, kalman, measure, rows3, to_world
from swarmloc.engine.replay_io import Noise, Replayed, Switches, constants, joint_start, noise_tuple
from swarmloc.kernels.ci import WEIGHT_GRID
from swarmloc.motion import UnicycleNoise


@njit(error_model="numpy")
def joint_weight(A: np.ndarray, B: np.ndarray, R: np.ndarray, dof: int) -> float:
    """:func:`swarmloc.kernels.ci.joint_weight` compiled: the CI weight in ``W_BOUNDS`` minimizing ``-dof log w -
    log det(S_w + A / w) + log det S_w``, ``S_w = R + B / (1 - w)``, on the same grid of ``WEIGHT_GRID`` points,
    then the vertex of the parabola through the best point and its neighbours (:func:`swarmloc.engine.formulas.
    ci_cost`, ``ci_grid``, ``ci_vertex``; a 1- or 2-row measurement padded as there)."""
    a, b, r = rows3(A), rows3(B), rows3(R, 1.0)
    g = WEIGHT_GRID
    c = np.empty(g)
    for k in range(g):
        c[k] = F.ci_cost(F.ci_grid(k), a, b, r, dof)
    j = int(np.argmin(c))
    w: float = F.ci_vertex(j, c[max(j - 1, 0)], c[j], c[min(j + 1, g - 1)])
    return w


@cache
def _kernels() -> Any:
    """Compile the cluster loop (:func:`swarmloc.engine.joint.stamp_loop`) around :func:`swarmloc.engine.joint.steps`
    (``diekf``'s, once per process; the noise model is an argument, ``qn``), each robot's steps run on its cluster's
    views of the state."""
    advance, marginal, fuse, belief = steps(True, True)

    @njit(error_model="numpy")
    def outsider(X: FloatArray, P: FloatArray, pend: FloatArray, has: BoolArray, i: int, xj: FloatArray, Pj: FloatArray,
                 kind: int, z: FloatArray, R: FloatArray, thr: FloatArray, gate: bool, asleep: BoolArray
                 ) -> tuple[int, int]:  # fmt: skip
        """Observer ``i`` of the cluster ``(X, P, ...)`` (views) detects a robot of another cluster at ``(xj, Pj)``:
        the covariance-intersection update of the module docstring; ``(outcome, reason)``. ``asleep``: the cluster
        mates not started yet, whose nodes take no broadcast (their covariance is not divided by ``w``; uncorrelated
        with the cluster, the update leaves them as they are)."""
        a = 3 * i
        if degenerate(kind, X, a, xj):
            return REJECTED, R_DEGENERATE
        r, H, Rm = measure(kind, X, a, xj, z, R)
        to_world(H, 3, xj[0], xj[1])
        to_world(H, 0, X[a], X[a + 1])
        Hi, Hj = H[:, :3].copy(), H[:, 3:].copy()
        flush(P, pend, has)
        A = Hi @ P[a : a + 3, a : a + 3].copy() @ Hi.T
        B = Hj @ Pj @ Hj.T
        wt = joint_weight(A, B, Rm, P.shape[0])
        Pw = P / wt
        for k in range(asleep.shape[0]):
            if asleep[k]:
                Pw[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = P[3 * k : 3 * k + 3, 3 * k : 3 * k + 3]
        xn, Pn, nis, ok = kalman(X, Pw, r, Hi, np.arange(a, a + 3), Rm + B / (1 - wt), True)
        return commit(X, P, xn, Pn, nis, ok, thr[kind], gate)

    @njit(error_model="numpy", inline="always")  # no call between the loop and its step
    def detect(X: FloatArray, P: FloatArray, pend: FloatArray, has: BoolArray, tc: FloatArray, v: FloatArray,
               w: FloatArray, qn: Noise, t0: FloatArray, t: float, q: int, i: int, j: int, kind: int, z: FloatArray,
               R: FloatArray, thr: FloatArray, gate: bool, relative: bool, lm_on: bool, lxy: FloatArray,
               lcov: FloatArray) -> tuple[int, int]:  # fmt: skip
        """Detection ``q`` of observer ``i``, target ``j``, on its cluster's views of the state (``P (clusters, 3K,
        3K)``): :func:`swarmloc.engine.joint.steps`' ``fuse``, or :func:`outsider` for a robot of another cluster."""
        st, why = F.screen_started(kind, i, j, t, t0, relative, lm_on)
        if st != 0:
            return st, why
        n, K = tc.shape[0], P.shape[1] // 3
        b, lo, hi = _span(i, K, n)
        m = 3 * (hi - lo)
        Xc, Pc, pc, hc = X[3 * lo : 3 * hi], P[b, :m, :m], pend[lo:hi], has[lo:hi]
        if j >= 0 and j // K != b:  # a robot of another cluster
            bj, lj, hj = _span(j, K, n)
            mj = 3 * (hj - lj)
            xj, Pj = belief(X[3 * lj : 3 * hj], P[bj, :mj, :mj], pend[lj:hj], has[lj:hj], tc[lj:hj], v[lj:hj],
                            w[lj:hj], qn, j - lj, t)  # fmt: skip
            return outsider(Xc, Pc, pc, hc, i - lo, xj, Pj, kind, z[q], R[q], thr, gate, ~(t >= t0[lo:hi]))
        st, why = fuse(Xc, Pc, pc, hc, tc[lo:hi], v[lo:hi], w[lo:hi], qn, t, q, i - lo, j - lo if j >= 0 else j, kind,
                       z, R, lxy, lcov, thr, gate)  # fmt: skip
        return st, why

    @njit(error_model="numpy")
    def record(X: FloatArray, P: FloatArray, pend: FloatArray, has: BoolArray, tc: FloatArray, v: FloatArray,
               w: FloatArray, qn: Noise, k: int, t: float, out_x: FloatArray, out_P: FloatArray, o: int
               ) -> None:  # fmt: skip
        """Robot ``k``'s record (:func:`swarmloc.engine.joint.steps`' ``marginal``) on its cluster's views."""
        b, lo, hi = _span(k, P.shape[1] // 3, tc.shape[0])
        m = 3 * (hi - lo)
        marginal(X[3 * lo : 3 * hi], P[b, :m, :m], pend[lo:hi], has[lo:hi], tc[lo:hi], v[lo:hi], w[lo:hi], qn, k - lo,
                 t, out_x, out_P, o)  # fmt: skip

    return stamp_loop(advance, detect, record)


@njit(error_model="numpy")
def _span(k: int, K: int, n: int) -> tuple[int, int, int]:
    """Robot row ``k``'s cluster of ``K`` in a team of ``n``: ``(its index, first row, one past its last row)``."""
    b = k // K
    return b, b * K, min(b * K + K, n)


def _cluster_size(cluster: Any, n: int, t0: Any) -> int:
    """The robots per cluster for a team of ``n``: ``cluster`` (an integer >= 1) capped at ``n``; ``t0`` must be
    each robot's start ``(n,)``. ValueError naming the argument otherwise."""
    if isinstance(cluster, bool) or not isinstance(cluster, int | np.integer) or cluster < 1:
        raise ValueError(f"replay_clusters: 'cluster' must be an integer >= 1, got {cluster!r}")
    if np.ndim(t0) != 1:
        raise ValueError("replay_clusters: t0 must be each robot's start (n,), as diekf's nodes start")
    return min(int(cluster), max(n, 1))


def replay_clusters(tl: Timeline, x: np.ndarray, P: np.ndarray, t0: np.ndarray, noise: UnicycleNoise, cluster: int,
                    **switches: Unpack[Switches]) -> Replayed:  # fmt: skip
    """``diekf``'s nodes in clusters of ``cluster`` robots (rows in id order) over ``tl``, from Cartesian beliefs
    ``x (n, 3)``, ``P (n, 3, 3)`` and each robot's start ``t0 (n,)`` (``inf``: never starts); the rest as
    :func:`swarmloc.engine.joint.replay_joint` (``invariant=True``), which it equals for ``cluster >= n``. Returns
    ``(status, reason, records)`` as that does."""
    n = x.shape[0]
    K = _cluster_size(cluster, n, t0)
    X, J, clock, starts = joint_start(x, P, t0, True, K)
    st = (X.reshape(3 * n), J, np.zeros((n, 8)), np.zeros(n, dtype=np.bool_), clock, np.zeros(n), np.zeros(n))
    return run(_kernels(), st, st[5:], tl, starts, constants(noise_tuple(noise), **switches))
