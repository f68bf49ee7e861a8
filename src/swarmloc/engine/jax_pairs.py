"""``rdl`` replayed with JAX: :mod:`swarmloc.engine.pairs`' loop as one compiled scan (``run_engine(source, "rdl",
backend="jax")``, :func:`replay_rdl_jax`), and many runs of one team size at once (:func:`replay_rdl_batch`).

The scan and the measurement models are :mod:`swarmloc.engine.jax_replay`'s, the screening and the gate's rules
:mod:`swarmloc.engine.formulas`', the prediction's shear, its effect on the factors, the 3x3 inverse and the
degenerate geometry :mod:`swarmloc.engine.blocks`' (numba's too); here the kernels of ``rdl``'s state as
:func:`swarmloc.engine.pairs.replay_rdl` runs them (its pair prior, rescaling and Joseph update still written apart,
as matrix products here and as loops or BLAS calls there): each robot's Cartesian ``x``, ``P``, the pending
shear ``(sa, sb)`` its predictions owe its factors, and for every pair that has exchanged (``met[k, l]``) the factor
``sigma_kl`` of their cross-covariance. A detection of a teammate builds the pair's joint prior (the tracked
cross-covariance, or covariance intersection over :data:`~swarmloc.estimators.rdl.CI_WEIGHTS` when it is not known
or not positive definite), applies the Joseph update, its gate and check, and hands each robot its part; absolute
fixes and map landmarks are private updates. Results equal numba's to rounding (tests/test_engine_jax_joint.py).
Units: m, rad, s.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache
from typing import Any, Unpack

import numpy as np

from swarmloc.engine import soa
from swarmloc.engine.codes import (
    ABSOLUTE,
    FUSED,
    GATED,
    NO_LANDMARK,
    R_CORRELATION,
    R_DEGENERATE,
    REJECTED,
)
from swarmloc.engine.detections import Timeline
from swarmloc.engine.jax_replay import blocks, compiled, formulas, inverse, measure, run_batch, sym, usable, verdict
from swarmloc.engine.replay_io import Events, Replayed, Switches, Traced, constants
from swarmloc.estimators.rdl import CI_WEIGHTS
from swarmloc.motion import UnicycleNoise

_UP = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _predicted(jnp: Any, noise: UnicycleNoise, x: Any, P: Any, v: Any, w: Any, dt: Any) -> Traced:
    """A robot's (or a batch's) ``(x, P, a, b)`` predicted over ``dt`` (unchanged for ``dt <= 0``), ``(a, b)`` the
    prediction's shear (:func:`swarmloc.engine.blocks.moved`)."""
    xs, ps = soa.predict(jnp, (x[..., 0], x[..., 1], x[..., 2]), tuple(P[..., a, b] for a, b in _UP), v, w, dt, noise)
    xn = jnp.stack(xs, -1)
    return xn, sym(jnp, ps), *blocks().moved(x[..., 0], x[..., 1], xn[..., 0], xn[..., 1])


def _advance(jnp: Any, noise: UnicycleNoise, st: Traced, k: Any, t: Any) -> Traced:
    """Robot ``k`` predicted to ``t`` and stored, its pending shear grown."""
    x, P, tc, v, w, sa, sb, met, sig = st
    xn, Pn, a, b = _predicted(jnp, noise, x[k], P[k], v[k], w[k], t - tc[k])
    return (x.at[k].set(xn), P.at[k].set(Pn), tc.at[k].set(jnp.maximum(tc[k], t)), v, w, sa.at[k].add(a),
            sb.at[k].add(b), met, sig)  # fmt: skip


def _factors(jnp: Any, st: Traced, k: Any, a: Any, b: Any) -> Any:
    """Robot ``k``'s factors ``sigma_kl (n, 3, 3)`` with the pending shear ``(a, b)`` applied (zero where not met)."""
    sig, met = st[8][k], st[7][k]
    f = jnp.stack([*blocks().shear(sig[:, 0], sig[:, 1], sig[:, 2], a, b), sig[:, 2]], 1)
    return jnp.where(met[:, None, None], f, 0.0)


def _rescale(jnp: Any, st: Traced, k: Any, P_new: Any, P_old: Any) -> Traced:
    """Robot ``k``'s factors ``sigma_kl <- P_new P_old^-1 sigma_kl`` (met pairs), its pending shear cleared."""
    x, P, tc, v, w, sa, sb, met, sig = st
    inv, regular = inverse(jnp, P_old)
    M = P_new @ jnp.where(regular, inv, P_old)  # numba's inverse hands back the matrix itself when singular
    new = jnp.where(met[k][:, None, None], M @ _factors(jnp, st, k, sa[k], sb[k]), sig[k])
    return x, P, tc, v, w, sa.at[k].set(0.0), sb.at[k].set(0.0), met, sig.at[k].set(new)


def _kalman(jnp: Any, x: Any, P: Any, r: Any, H: Any, R: Any) -> Traced:
    """:func:`swarmloc.engine.pairs._kalman`: the Joseph form, headings wrapped: ``(x+, P+, nis, ok)``."""
    N = P.shape[0]
    PHt = P @ H.T
    S_inv, regular = inverse(jnp, H @ PHt + R)
    Sr = S_inv @ r
    nis = jnp.where(regular, r @ Sr, jnp.nan)
    K = PHt @ S_inv
    xn = x + PHt @ Sr
    head = jnp.arange(N) % 3 == 2
    xn = jnp.where(head & jnp.isfinite(xn), soa.wrap(jnp, xn), xn)
    IKH = jnp.eye(N) - K @ H
    A = IKH @ P @ IKH.T + K @ R @ K.T
    Pn = 0.5 * (A + A.T)
    return xn, Pn, nis, regular & jnp.isfinite(nis) & jnp.isfinite(xn).all() & jnp.isfinite(Pn).all()


def _prior(jnp: Any, Pi: Any, Pj: Any, fi: Any, fj: Any, met: Any, H: Any, R: Any) -> Traced:
    """:func:`swarmloc.engine.pairs._joint_prior`: ``(P (6, 6), 1)`` with the tracked cross-covariance (known and
    positive definite), else covariance intersection's prior with ``1`` (both gain), ``0`` (the observer only) or
    ``-1`` (neither)."""
    known = jnp.where(met, (fi != 0).any() & (fj != 0).any(), ~(fj != 0).any())
    Pij = fi @ fj.T
    tracked = jnp.block([[Pi, Pij], [Pij.T, Pj]])
    w = jnp.asarray(CI_WEIGHTS)[:, None, None]
    z = jnp.zeros((w.shape[0], 3, 3))
    Ps = jnp.concatenate([jnp.concatenate([Pi / w, z], 2), jnp.concatenate([z, Pj / (1.0 - w)], 2)], 1)
    PHt = Ps @ H.T
    S = H @ PHt + R
    inv, regular = inverse(jnp, S)
    S_inv = jnp.where(regular[:, None, None], inv, S)  # numba's inverse hands back the matrix itself when singular
    Pn = Ps - PHt @ S_inv @ jnp.swapaxes(PHt, -1, -2)
    gi = jnp.linalg.slogdet(Pi)[1] - jnp.linalg.slogdet(Pn[:, :3, :3])[1]
    gj = jnp.linalg.slogdet(Pj)[1] - jnp.linalg.slogdet(Pn[:, 3:, 3:])[1]
    both = jnp.where(jnp.isfinite(gi) & jnp.isfinite(gj), jnp.minimum(gi, gj), -jnp.inf)
    kb = jnp.argmax(both)
    gi = jnp.where(jnp.isfinite(gi), gi, -jnp.inf)
    ki = jnp.argmax(gi)
    ci = jnp.where(both[kb] >= 0.0, 1, jnp.where(gi[ki] > 0.0, 0, -1))
    ci_P = Ps[jnp.where(both[kb] >= 0.0, kb, ki)]
    use = known & usable(jnp, tracked)
    return jnp.where(use, tracked, ci_P), jnp.where(use, 1, ci)


def _pick(jnp: Any, cond: Any, a: Traced, b: Traced) -> Traced:
    return tuple(jnp.where(cond, u, v) for u, v in zip(a, b, strict=True))


def _pair(jnp: Any, noise: UnicycleNoise, st: Traced, i: Any, j: Any, ev: Events, const: Traced) -> Traced:
    """Robot ``i``'s detection of teammate ``j``: the pair's update, each taking its part (or only the observer,
    its factor for ``j`` dropped, when only it gains): ``(state, outcome, reason)``."""
    thr, gate_on = const[1], const[2]
    x, P, tc, v, w, sa, sb, met, sig = st
    kind, t = ev["kind"], ev["t"]
    xj, Pj, a, b = _predicted(jnp, noise, x[j], P[j], v[j], w[j], t - tc[j])  # the answer (not stored)
    degenerate = blocks().degenerate(kind, x[i, 0], x[i, 1], xj[0], xj[1])
    fj = _factors(jnp, st, j, sa[j] + a, sb[j] + b)[i]
    fi = _factors(jnp, st, i, sa[i], sb[i])[j]
    r, H, Rm = measure(jnp, kind, x[i], xj, ev["z"], ev["R"])
    prior, both = _prior(jnp, P[i], Pj, fi, fj, met[i, j], H, Rm)
    Xn, Pn, nis, ok = _kalman(jnp, jnp.concatenate([x[i], xj]), prior, r, H, Rm)
    d = formulas().rule((REJECTED, R_DEGENERATE, degenerate), both < 0, GATED, R_CORRELATION)
    code = verdict(jnp, d, gate_on, nis, thr[kind], ok, Pn)
    s = (x.at[i].set(Xn[:3]), P.at[i].set(Pn[:3, :3]), *st[2:])
    s = _rescale(jnp, s, i, Pn[:3, :3], P[i])
    alone = (*s[:8], s[8].at[i, j].set(0.0))  # only the observer gains: its correlation with j is unknown now
    s = (*s[:7], s[7].at[i, j].set(True), s[8].at[i, j].set(Pn[:3, 3:]))
    s = _advance(jnp, noise, s, j, t)  # the target takes its part at the stamp
    Pj_old = s[1][j]
    s = (s[0].at[j].set(Xn[3:]), s[1].at[j].set(Pn[3:, 3:]), *s[2:])
    s = _rescale(jnp, s, j, Pn[3:, 3:], Pj_old)
    s = (*s[:7], s[7].at[j, i].set(True), s[8].at[j, i].set(jnp.eye(3)))
    return _pick(jnp, code[0] == FUSED, _pick(jnp, both == 0, alone, s), st), *code


def _private(jnp: Any, st: Any, i: Any, j: Any, ev: Events, const: Traced) -> Traced:
    """An absolute fix or a map landmark's detection by robot ``i``: a private update, its factors rescaled."""
    thr, gate_on, lxy, lcov = const[1], const[2], const[5], const[6]
    x, P = st[0], st[1]
    kind = ev["kind"]
    lk = jnp.clip(NO_LANDMARK - 1 - j, 0, lxy.shape[0] - 1)
    xk = jnp.concatenate([lxy[lk], jnp.zeros(1)])
    degenerate = blocks().degenerate(kind, x[i, 0], x[i, 1], xk[0], xk[1])
    r, H, Rm = measure(jnp, kind, x[i], xk, ev["z"], ev["R"])
    Hk = H[:, 3:5]
    Rm = jnp.where(kind != ABSOLUTE, Rm + Hk @ lcov[lk] @ Hk.T, Rm)  # a map landmark's covariance
    xn, Pn, nis, ok = _kalman(jnp, x[i], P[i], r, H[:, :3], Rm)
    code = verdict(jnp, (REJECTED, R_DEGENERATE, degenerate), gate_on, nis, thr[kind], ok, Pn)
    s = _rescale(jnp, (x.at[i].set(xn), P.at[i].set(Pn), *st[2:]), i, Pn, P[i])
    return _pick(jnp, code[0] == FUSED, s, st), *code


def _detection(jnp: Any, noise: UnicycleNoise, st: Traced, ev: Events, const: Traced) -> Traced:
    """A detection: the observer moved to its stamp, the screening of ``rdl``'s nodes, then a private or a pair's
    update."""
    t0, relative, lm_on = const[0], const[3], const[4]
    i, j, kind, t = ev["a"], ev["b"], ev["kind"], ev["t"]
    st = _advance(jnp, noise, st, i, t)
    s0, w0 = formulas().screen_started(kind, i, j, t, t0, relative, lm_on)
    private = (kind == ABSOLUTE) | (j <= NO_LANDMARK)
    sp, cp, wp = _private(jnp, st, i, j, ev, const)
    sq, cq, wq = _pair(jnp, noise, st, i, jnp.where(j >= 0, j, i), ev, const)
    done = _pick(jnp, private, sp, sq)
    code, why = jnp.where(private, cp, cq), jnp.where(private, wp, wq)
    return _pick(jnp, s0 != 0, st, done), jnp.where(s0 != 0, s0, code), jnp.where(s0 != 0, w0, why)


@cache
def _kernels(noise: UnicycleNoise) -> Any:
    """``make(jnp, lax, t0, const)`` of :func:`swarmloc.engine.jax_replay.compiled` for ``rdl``."""

    def make(jnp: Any, lax: Any, t0: Any, const: Any) -> Any:  # noqa: ARG001
        return (
            lambda s, k, t: _advance(jnp, noise, s, k, t),
            lambda s, ev: _detection(jnp, noise, s, ev, (t0, *const)),
            lambda s, t: _predicted(jnp, noise, s[0], s[1], s[3], s[4], t - s[2])[:2],
        )

    return make


def replay_rdl_jax(tl: Timeline, x: np.ndarray, P: np.ndarray, t0: np.ndarray, noise: UnicycleNoise,
                   **switches: Unpack[Switches]) -> Replayed:  # fmt: skip
    """:func:`swarmloc.engine.pairs.replay_rdl` (the same arguments and results) as one JAX call."""
    return replay_rdl_batch([tl], x[None], P[None], [t0], noise, _single=True, **switches)[0]


def replay_rdl_batch(
    tls: Sequence[Timeline],
    x: np.ndarray,
    P: np.ndarray,
    t0: Sequence[np.ndarray],
    noise: UnicycleNoise,
    *,
    _single: bool = False,
    **switches: Unpack[Switches],
) -> list[Replayed]:
    """Runs of one team of ``n`` robots (``x (B, n, 3)``, ``P (B, n, 3, 3)``, each run its own timeline and
    robots' starts ``t0[b] (n,)``) in one call vectorized over the runs (``jax.vmap``); each run's result is
    :func:`replay_rdl_jax`'s."""
    if len(tls) != x.shape[0] or len(t0) != x.shape[0]:
        raise ValueError(f"replay_rdl_batch: {len(tls)} timelines, {x.shape[0]} initial states, {len(t0)} starts")
    n = x.shape[1]
    starts = [np.asarray(s, dtype=float) for s in t0]
    states = [(np.array(x[b], dtype=float), np.array(P[b], dtype=float), np.where(np.isfinite(s), s, 0.0),
               np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros((n, n), dtype=bool),
               np.zeros((n, n, 3, 3))) for b, s in enumerate(starts)]  # fmt: skip
    fn = compiled(("rdl", noise), _kernels(noise), not _single)
    return run_batch(fn, tls, states, starts, constants(**switches), _single)
