"""The centralized EKFs (``cekf``, ``iekf``) and ``diekf`` replayed with JAX: :mod:`swarmloc.engine.joint`'s loop
as one compiled scan (``run_engine(source, "cekf" | "iekf" | "diekf", backend="jax")``, :func:`replay_joint_jax`),
and many runs of one team size at once (:func:`replay_joint_batch`, ``jax.vmap``: Monte Carlo sweeps).

The scan, the events and the measurement models are :mod:`swarmloc.engine.jax_replay`'s; here the kernels of the
joint state ``X (n, 3)``, ``P (3n, 3n)`` (Cartesian, or world-frame errors with ``invariant``) as
:func:`swarmloc.engine.joint.replay_joint` runs them, on the same formulas: the scalar prediction of
:mod:`swarmloc.engine.soa`; the screening of the centralized nodes (or of ``diekf``'s, whose robots start at their
own first input), every measurement kind (a 1- or 2-row measurement padded to 3 rows that are zero in ``H`` and the
residual and one in the noise: they change nothing), the gate's rules, the invariant filters' noise and correction
on the group, all of :mod:`swarmloc.engine.formulas`; a prediction's shear of ``P``'s rows and columns, a record's
block and its Cartesian form, the world-frame Jacobian, the 3x3 inverse and the degenerate geometry, all of
:mod:`swarmloc.engine.blocks`. Written apart still: the Joseph update on the two robots' columns and the
positive-definite check, as matrix products here and as loops in :mod:`swarmloc.engine.joint_math` (numba's loops
are faster than its matrix products on these sizes, and JAX has no loop that writes in place). One difference in
arithmetic only: a prediction is applied to ``P`` at once, where the numba loop keeps it pending until an update reads
``P`` (the same products rounded in another order: equal to 1e-12 on simulated teams). Units: m, rad, s.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache
from typing import Any, Unpack

import numpy as np

from swarmloc.engine import soa
from swarmloc.engine.codes import ABSOLUTE, FUSED, NO_LANDMARK, R_DEGENERATE, REJECTED
from swarmloc.engine.detections import Timeline
from swarmloc.engine.jax_replay import (
    blocks,
    cartesian,
    compiled,
    formulas,
    inverse,
    measure,
    run_batch,
    sym,
    verdict,
    wrap,
)
from swarmloc.engine.replay_io import Events, Replayed, Switches, Traced, constants, joint_start
from swarmloc.motion import UnicycleNoise


# ------------------------------------------------------------------------------------------------ the pieces
def predict_step(jnp: Any, noise: UnicycleNoise, invariant: bool, x: Any, v: Any, w: Any, dt: Any) -> Traced:
    """One robot's (or a batch's) prediction over ``dt``: the new pose, its shear ``(a, b)`` and process noise
    (upper triangle; world-frame with ``invariant``, and no shear); ``dt <= 0`` changes nothing."""
    z = jnp.zeros_like(x[..., 0])
    xs, q = soa.predict(jnp, (x[..., 0], x[..., 1], x[..., 2]), (z,) * 6, v, w, dt, noise)
    if invariant:
        return jnp.stack(xs, -1), z, z, formulas().world_noise(xs[0], xs[1], q)
    return jnp.stack(xs, -1), *blocks().moved(x[..., 0], x[..., 1], xs[0], xs[1]), q


def _advance(jnp: Any, lax: Any, noise: UnicycleNoise, invariant: bool, state: Traced, k: Any, t: Any) -> Traced:
    """Robot ``k`` moved to ``t`` (not before its clock): ``X``, its rows and columns of ``P`` sheared and its block
    given the process noise (the numba loop's pending prediction, applied at once)."""
    X, P, tc, v, w = state
    N = P.shape[0]
    xn, a, b, q = predict_step(jnp, noise, invariant, X[k], v[k], w[k], t - tc[k])
    i = 3 * k
    if not invariant:
        shear = blocks().shear
        rows = lax.dynamic_slice(P, (i, 0), (3, N))
        P = lax.dynamic_update_slice(P, jnp.stack([*shear(rows[0], rows[1], rows[2], a, b), rows[2]]), (i, 0))
        cols = lax.dynamic_slice(P, (0, i), (N, 3))
        cols = jnp.stack([*shear(cols[:, 0], cols[:, 1], cols[:, 2], a, b), cols[:, 2]], 1)
        P = lax.dynamic_update_slice(P, cols, (0, i))
    block = lax.dynamic_slice(P, (i, i), (3, 3)) + sym(jnp, q)
    P = lax.dynamic_update_slice(P, block, (i, i))
    return X.at[k].set(xn), P, tc.at[k].set(jnp.maximum(tc[k], t)), v, w


def _marginals(jnp: Any, noise: UnicycleNoise, invariant: bool, state: Traced, t: Any) -> Traced:
    """Every robot's Cartesian marginal predicted to ``t`` (not stored): ``x (n, 3)``, ``P (n, 3, 3)``."""
    X, P, tc, v, w = state
    n = X.shape[0]
    xn, a, b, q = predict_step(jnp, noise, invariant, X, v, w, t - tc)
    idx = jnp.arange(n)
    return xn, cartesian(jnp, invariant, xn, P.reshape(n, 3, n, 3)[idx, :, idx, :], a, b, q)


def kalman_columns(
    jnp: Any, lax: Any, invariant: bool, X: Any, P: Any, r: Any, H: Any, Rm: Any, i: Any, jj: Any
) -> Traced:
    """:func:`swarmloc.engine.joint_math.kalman` on the columns of robots ``i`` and ``jj``: ``(X+, P+, nis, ok)``."""
    N = P.shape[0]
    Pc = jnp.concatenate([lax.dynamic_slice(P, (0, 3 * i), (N, 3)), lax.dynamic_slice(P, (0, 3 * jj), (N, 3))], 1)
    U = Pc @ H.T
    Uc = jnp.concatenate([lax.dynamic_slice(U, (3 * i, 0), (3, 3)), lax.dynamic_slice(U, (3 * jj, 0), (3, 3))])
    S = H @ Uc + Rm
    S_inv, regular = inverse(jnp, S)
    nis = jnp.where(regular, r @ S_inv @ r, jnp.nan)
    K = U @ S_inv
    W = U - K @ S
    step = (K @ r).reshape(-1, 3)
    if invariant:
        xn = jnp.stack(formulas().left_correct(X[:, 0], X[:, 1], X[:, 2], step[:, 0], step[:, 1], step[:, 2]), -1)
    else:
        xn = (X + step).at[:, 2].set(wrap(jnp, X[:, 2] + step[:, 2]))
    A = P - K @ U.T - W @ K.T
    Pn = 0.5 * (A + A.T)
    ok = regular & jnp.isfinite(nis) & jnp.isfinite(xn).all() & jnp.isfinite(Pn).all()
    return xn, Pn, nis, ok


# ------------------------------------------------------------------------------------------------ the events
def detection(jnp: Any, lax: Any, form: Traced, state: Traced, ev: Events, const: Traced) -> Traced:
    """A detection: the observer moved to its stamp, the screening, the target (a robot: moved to the stamp too;
    ``diekf``: only if it takes the update), the measurement, the update and its outcome."""
    noise, invariant, distributed = form
    t0, thr, gate_on, relative, lm_on, lxy, lcov = const
    i, j, kind, t = ev["a"], ev["b"], ev["kind"], ev["t"]
    state = _advance(jnp, lax, noise, invariant, state, i, t)
    F = formulas()
    if distributed:
        st0, why0 = F.screen_started(kind, i, j, t, t0, relative, lm_on)
    else:
        st0, why0 = F.screen_central(kind, i, j, relative, lm_on)
    robot = j >= 0
    jr = jnp.where(robot, j, i)
    moved = _advance(jnp, lax, noise, invariant, state, jr, t)
    s1 = tuple(jnp.where(robot, a, b) for a, b in zip(moved, state, strict=True))
    X, P = s1[0], s1[1]
    lk = jnp.clip(NO_LANDMARK - 1 - j, 0, lxy.shape[0] - 1)
    xk = jnp.where(robot, X[jr], jnp.concatenate([lxy[lk], jnp.zeros(1)]))
    B = blocks()
    degenerate = B.degenerate(kind, X[i, 0], X[i, 1], xk[0], xk[1])
    r, H, Rm = measure(jnp, kind, X[i], xk, ev["z"], ev["R"])
    Hk = H[:, 3:5]
    Rm = jnp.where(~robot & (kind != ABSOLUTE), Rm + Hk @ lcov[lk] @ Hk.T, Rm)  # a map landmark's covariance
    H = jnp.where(robot, H, H.at[:, 3:].set(0.0))
    if invariant:  # world-frame error columns: H N
        H = H.at[:, 5].set(jnp.where(robot, B.to_world(H[:, 3], H[:, 4], H[:, 5], xk[0], xk[1]), H[:, 5]))
        H = H.at[:, 2].set(B.to_world(H[:, 0], H[:, 1], H[:, 2], X[i, 0], X[i, 1]))
    xn, Pn, nis, ok = kalman_columns(jnp, lax, invariant, X, P, r, H, Rm, i, jr)
    d = F.rule((st0, why0, st0 != 0), degenerate, REJECTED, R_DEGENERATE)
    st, why = verdict(jnp, d, gate_on, nis, thr[kind], ok, Pn)
    fused = st == FUSED
    keep = state if distributed else tuple(jnp.where(st0 != 0, a, b) for a, b in zip(state, s1, strict=True))
    out = (xn, Pn, *s1[2:])
    return tuple(jnp.where(fused, a, b) for a, b in zip(out, keep, strict=True)), st, why


@cache
def _kernels(noise: UnicycleNoise, invariant: bool, distributed: bool) -> Any:
    """``make(jnp, lax, t0, const)`` of :func:`swarmloc.engine.jax_replay.compiled` for this form."""

    def make(jnp: Any, lax: Any, t0: Any, const: Any) -> Any:
        form = (noise, invariant, distributed)
        return (
            lambda s, k, t: _advance(jnp, lax, noise, invariant, s, k, t),
            lambda s, ev: detection(jnp, lax, form, s, ev, (t0, *const)),
            lambda s, t: _marginals(jnp, noise, invariant, s, t),
        )

    return make


def replay_joint_jax(
    tl: Timeline,
    x: np.ndarray,
    P: np.ndarray,
    t0: float | np.ndarray,
    noise: UnicycleNoise,
    *,
    invariant: bool = False,
    **switches: Unpack[Switches],
) -> Replayed:
    """:func:`swarmloc.engine.joint.replay_joint` (the same arguments and results) as one JAX call."""
    return replay_joint_batch([tl], x[None], P[None], [t0], noise, invariant=invariant, _single=True, **switches)[0]


def replay_joint_batch(
    tls: Sequence[Timeline],
    x: np.ndarray,
    P: np.ndarray,
    t0: Sequence[Any],
    noise: UnicycleNoise,
    *,
    invariant: bool = False,
    _single: bool = False,
    **switches: Unpack[Switches],
) -> list[Replayed]:
    """Runs of one team of ``n`` robots (``x (B, n, 3)``, ``P (B, n, 3, 3)``, each run its own timeline and start
    ``t0[b]``, every other argument shared) in one call vectorized over the runs (``jax.vmap``): a Monte Carlo
    sweep. Each run's result is :func:`replay_joint_jax`'s. The runs' events are padded to one bucket."""
    if len(tls) != x.shape[0] or len(t0) != x.shape[0]:
        raise ValueError(f"replay_joint_batch: {len(tls)} timelines, {x.shape[0]} initial states, {len(t0)} starts")
    distributed = np.ndim(t0[0]) == 1
    if distributed and not invariant:
        raise ValueError("replay_joint: per-robot starts are diekf's (invariant=True); cekf starts at one t0")
    starts = [joint_start(x[b], P[b], t0[b], invariant) for b in range(len(tls))]
    key = ("joint", noise, bool(invariant), bool(distributed))
    fn = compiled(key, _kernels(*key[1:]), not _single)
    n = x.shape[1]
    states = [(X, J[0], clock, np.zeros(n), np.zeros(n)) for X, J, clock, _ in starts]
    return run_batch(fn, tls, states, [s[3] for s in starts], constants(**switches), _single)
