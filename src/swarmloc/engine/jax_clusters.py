"""``diekf`` in clusters replayed with JAX: :mod:`swarmloc.engine.joint_clusters`' loop as one compiled scan
(``run_engine(source, "diekf", backend="jax", cluster=K)``, :func:`replay_clusters_jax`), and many runs of one team
size at once (:func:`replay_clusters_batch`, ``jax.vmap``: Monte Carlo sweeps).

The state is one ``3K x 3K`` world-frame covariance per cluster, ``(ceil(n / K), 3K, 3K)``; the team is padded to a
whole number of clusters with robots that never start (identity covariance, no correlation, never a target, never
recorded), so every cluster's view has one shape and is taken with ``lax.dynamic_slice``. Per detection, in the
numba loop's order:

* inside the observer's cluster (a cluster mate, a landmark, an absolute fix): :mod:`swarmloc.engine.jax_joint`'s
  ``diekf`` detection on the cluster's view (the cluster's poses, covariance, clocks and commands; its robots'
  starts), written back;
* a robot of another cluster: the node's covariance-intersection update
  (:meth:`TeamProtocol.outsider <swarmloc.estimators.diekf.TeamProtocol.outsider>`): the
  outsider's world-frame belief predicted to the stamp (not stored), ``A = H_i P_ii H_i^T``, ``B = H_j P_jj
  H_j^T``, the weight minimizing the cluster's posterior log det (:func:`_weight`, the grid and parabola of
  :func:`swarmloc.kernels.ci.joint_weight`; ``dof`` the cluster's real size), the cluster's covariance divided by
  it (not the blocks of mates not started yet, nor the padding), and the Kalman update on the observer's columns
  with noise ``R + B / (1 - w)``.

A 1- or 2-row measurement is padded to 3 rows that are zero in ``H`` and one in the noise
(:func:`swarmloc.engine.jax_replay.measure`): they add ``log 1 = 0`` to the weight's cost, so the weight is the
numba loop's. Results equal the numba loop's to rounding (``tests/test_engine_jax_clusters.py``). Units: m, rad, s.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache
from typing import Any, Unpack

import numpy as np

from swarmloc.engine.checks import cluster_size
from swarmloc.engine.codes import FUSED, R_DEGENERATE, REJECTED
from swarmloc.engine.detections import Timeline
from swarmloc.engine.jax_joint import detection, kalman_columns, predict_step
from swarmloc.engine.jax_replay import blocks, cartesian, compiled, formulas, measure, run_batch, sym, verdict
from swarmloc.engine.replay_io import Events, Replayed, Switches, Traced, constants, joint_start
from swarmloc.kernels.ci import WEIGHT_GRID
from swarmloc.motion import UnicycleNoise

__all__ = ["replay_clusters_batch", "replay_clusters_jax"]


# ------------------------------------------------------------------------------------------------ the pieces
def _weight(jnp: Any, A: Any, B: Any, R: Any, dof: Any) -> Any:
    """:func:`swarmloc.engine.joint_clusters.joint_weight` traced: the cost of :func:`swarmloc.engine.formulas.
    ci_cost` on the whole grid at once, its best point and the vertex of the parabola through it and its
    neighbours."""
    F = formulas()
    g = WEIGHT_GRID
    c = F.ci_cost(F.ci_grid(jnp.arange(g)), *(tuple(tuple(M[a, b] for b in range(3)) for a in range(3))
                                             for M in (A, B, R)), dof)  # fmt: skip
    j = jnp.argmin(c)
    return F.ci_vertex(j, c[jnp.maximum(j - 1, 0)], c[j], c[jnp.minimum(j + 1, g - 1)])


def _view(lax: Any, state: Traced, lo: Any, b: Any, K: int) -> Traced:
    """The cluster ``b`` (its first robot ``lo``) as a joint state of ``K`` robots: ``(X, P, clocks, v, w)``."""
    X, PC, tc, v, w = state
    rows = [lax.dynamic_slice(a, (lo,), (K,)) for a in (tc, v, w)]
    return (lax.dynamic_slice(X, (lo, 0), (K, 3)), lax.dynamic_index_in_dim(PC, b, keepdims=False), *rows)


def _put(lax: Any, state: Traced, view: Traced, lo: Any, b: Any) -> Traced:
    """``state`` with the cluster ``b`` (first robot ``lo``) replaced by ``view``."""
    X, PC, tc, v, w = state
    Xv, Pv, tv, vv, wv = view
    return (lax.dynamic_update_slice(X, Xv, (lo, 0)), lax.dynamic_update_slice(PC, Pv[None], (b, 0, 0)),
            lax.dynamic_update_slice(tc, tv, (lo,)), lax.dynamic_update_slice(v, vv, (lo,)),
            lax.dynamic_update_slice(w, wv, (lo,)))  # fmt: skip


def _advance(jnp: Any, lax: Any, noise: UnicycleNoise, K: int, state: Traced, k: Any, t: Any) -> Traced:
    """Robot ``k`` moved to ``t`` (not before its clock): its pose, and its block of its cluster's covariance given
    the world-frame process noise."""
    X, PC, tc, v, w = state
    xn, _, _, q = predict_step(jnp, noise, True, X[k], v[k], w[k], t - tc[k])
    at = (k // K, 3 * (k % K), 3 * (k % K))
    block = lax.dynamic_slice(PC, at, (1, 3, 3)) + sym(jnp, q)[None]
    return X.at[k].set(xn), lax.dynamic_update_slice(PC, block, at), tc.at[k].set(jnp.maximum(tc[k], t)), v, w


def _marginals(jnp: Any, noise: UnicycleNoise, state: Traced, t: Any) -> Traced:
    """Every robot's Cartesian marginal predicted to ``t`` (not stored): ``x (N, 3)``, ``P (N, 3, 3)``."""
    X, PC, tc, v, w = state
    N, K = X.shape[0], PC.shape[1] // 3
    xn, a, b, q = predict_step(jnp, noise, True, X, v, w, t - tc)
    M = jnp.moveaxis(jnp.diagonal(PC.reshape(-1, K, 3, K, 3), axis1=1, axis2=3), -1, 1).reshape(N, 3, 3)
    return xn, cartesian(jnp, True, xn, M, a, b, q)


def _outsider(jnp: Any, lax: Any, noise: UnicycleNoise, K: int, state: Traced, ev: Events, const: Traced) -> Traced:
    """Observer ``ev["a"]`` detects robot ``ev["b"]`` of another cluster: the module docstring's covariance
    intersection; ``(state, outcome, reason)``."""
    t0, n, thr, gate_on = const
    X, PC, tc, v, w = state
    i, j, kind, t = ev["a"], ev["b"], ev["kind"], ev["t"]
    b, lo = i // K, (i // K) * K
    xj, _, _, q = predict_step(jnp, noise, True, X[j], v[j], w[j], t - tc[j])
    Pj = lax.dynamic_slice(PC, (j // K, 3 * (j % K), 3 * (j % K)), (1, 3, 3))[0] + sym(jnp, q)
    view = _view(lax, state, lo, b, K)
    Xv, Pv = view[0], view[1]
    li = i - lo
    xi = X[i]
    B = blocks()
    degenerate = B.degenerate(kind, xi[0], xi[1], xj[0], xj[1])
    r, H, Rm = measure(jnp, kind, xi, xj, ev["z"], ev["R"])
    H = H.at[:, 5].set(B.to_world(H[:, 3], H[:, 4], H[:, 5], xj[0], xj[1]))  # world-frame error columns: H N
    H = H.at[:, 2].set(B.to_world(H[:, 0], H[:, 1], H[:, 2], xi[0], xi[1]))
    Hi, Hj = H[:, :3], H[:, 3:]
    A = Hi @ lax.dynamic_slice(Pv, (3 * li, 3 * li), (3, 3)) @ Hi.T
    B = Hj @ Pj @ Hj.T
    size = jnp.minimum(K, n - lo)  # the cluster's robots, the padding not counted
    wt = _weight(jnp, A, B, Rm, 3 * size)
    rows = jnp.arange(3 * K) // 3
    asleep = ~(t >= lax.dynamic_slice(t0, (lo,), (K,)))  # mates not started yet, and the padding (start inf)
    keep = asleep[rows][:, None] & (rows[:, None] == rows[None, :])
    Pw = jnp.where(keep, Pv, Pv / wt)
    xn, Pn, nis, ok = kalman_columns(jnp, lax, True, Xv, Pw, r, H.at[:, 3:].set(0.0), Rm + B / (1 - wt), li, li)
    st, why = verdict(jnp, (REJECTED, R_DEGENERATE, degenerate), gate_on, nis, thr[kind], ok, Pn)
    new = _put(lax, state, (xn, Pn, *view[2:]), lo, b)
    return tuple(jnp.where(st == FUSED, a, c) for a, c in zip(new, state, strict=True)), st, why


def _detection_c(jnp: Any, lax: Any, noise: UnicycleNoise, K: int, state: Traced, ev: Events, const: Traced) -> Traced:
    """A detection: the screening of ``diekf``'s nodes, then a robot of another cluster by :func:`_outsider`,
    anything else by ``jax_joint``'s ``diekf`` detection on the observer's cluster; the observer moved to its stamp
    whatever the outcome (once: in each branch)."""
    t0, n, thr, gate_on, relative, lm_on, lxy, lcov = const
    i, j, kind, t = ev["a"], ev["b"], ev["kind"], ev["t"]
    st0, why0 = formulas().screen_started(kind, i, j, t, t0, relative, lm_on)  # reads no state
    b = i // K
    lo = b * K

    def outside(state: Any) -> Any:
        return _outsider(jnp, lax, noise, K, _advance(jnp, lax, noise, K, state, i, t), ev, (t0, n, thr, gate_on))

    def inside(state: Any) -> Any:  # the detection moves the observer on the view
        local = {**ev, "a": i - lo, "b": jnp.where(j >= 0, j - lo, j)}
        t0v = lax.dynamic_slice(t0, (lo,), (K,))
        view, st, why = detection(jnp, lax, (noise, True, True), _view(lax, state, lo, b, K), local,
                                   (t0v, thr, gate_on, relative, lm_on, lxy, lcov))  # fmt: skip
        return _put(lax, state, view, lo, b), st, why

    def screened(state: Any) -> Any:
        return _advance(jnp, lax, noise, K, state, i, t), st0, why0

    branch = jnp.where(st0 != 0, 0, jnp.where((j >= 0) & (j // K != b), 1, 2))
    out: Traced = lax.switch(branch, (screened, outside, inside), state)
    return out


@cache
def _kernels(noise: UnicycleNoise, K: int, n: int) -> Any:
    """``make(jnp, lax, t0, const)`` of :func:`swarmloc.engine.jax_replay.compiled` for clusters of ``K`` of a team of
    ``n`` robots."""

    def make(jnp: Any, lax: Any, t0: Any, const: Any) -> Any:
        thr, gate_on, relative, lm_on, lxy, lcov = const
        full = (t0, n, thr, gate_on, relative, lm_on, lxy, lcov)
        return (
            lambda s, k, t: _advance(jnp, lax, noise, K, s, k, t),
            lambda s, ev: _detection_c(jnp, lax, noise, K, s, ev, full),
            lambda s, t: _marginals(jnp, noise, s, t),
        )

    return make


def replay_clusters_jax(
    tl: Timeline,
    x: np.ndarray,
    P: np.ndarray,
    t0: np.ndarray,
    noise: UnicycleNoise,
    cluster: int,
    **switches: Unpack[Switches],
) -> Replayed:
    """:func:`swarmloc.engine.joint_clusters.replay_clusters` (the same arguments and results) as one JAX call."""
    return replay_clusters_batch([tl], x[None], P[None], [t0], noise, cluster, _single=True, **switches)[0]


def replay_clusters_batch(
    tls: Sequence[Timeline],
    x: np.ndarray,
    P: np.ndarray,
    t0: Sequence[np.ndarray],
    noise: UnicycleNoise,
    cluster: int,
    *,
    _single: bool = False,
    **switches: Unpack[Switches],
) -> list[Replayed]:
    """Runs of one team of ``n`` robots in clusters of ``cluster`` (``x (B, n, 3)``, ``P (B, n, 3, 3)``, each run its
    own timeline and starts ``t0[b] (n,)``, every other argument shared) in one call vectorized over the runs
    (``jax.vmap``). Each run's result is :func:`replay_clusters_jax`'s."""
    if len(tls) != x.shape[0] or len(t0) != x.shape[0]:
        raise ValueError(f"replay_clusters_batch: {len(tls)} timelines, {x.shape[0]} initial states, {len(t0)} starts")
    n = x.shape[1]
    K = cluster_size(cluster, n, t0)
    starts = [joint_start(x[b], P[b], t0[b], True, K, pad=True) for b in range(len(tls))]  # (X, PC, clocks, starts)
    states = [(X, PC, clock, np.zeros(len(clock)), np.zeros(len(clock))) for X, PC, clock, _ in starts]
    fn = compiled(("clusters", noise, K, n), _kernels(noise, K, n), not _single)
    return run_batch(fn, tls, states, [s[3] for s in starts], constants(**switches), _single)
