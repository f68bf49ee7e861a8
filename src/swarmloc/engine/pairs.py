"""Recursive decentralized localization (``rdl``) on the engine: every robot's filter and its pairwise exchanges
replayed in one compiled loop (numba).

Each robot ``k`` keeps what its :class:`~swarmloc.estimators.RecursiveDecentralized` node keeps: Cartesian ``x``,
``P``, and for every robot ``l`` it has exchanged with (``met[k, l]``) a factor ``sigma_kl`` of the
cross-covariance ``Sigma_kl = sigma_kl sigma_lk^T``, with the shear its predictions since its last update owe the
factors (``sa``, ``sb``: :class:`~swarmloc.estimators.rdl.RdlFilter`). :func:`replay_rdl` does, over a whole
:class:`~swarmloc.engine.detections.Timeline`, what the nodes do when every exchange completes (the in-process
runner, no faults), in the order of their history keys:

* at a stamp, the detection groups in observer order (Gauss-Seidel: a teammate with a smaller id answers after its
  own group at the stamp), each detection in the group's canonical order, then the commands;
* a robot's detection of teammate ``j``: ``j``'s answer is its state predicted to the stamp (not stored); the pair's
  joint prior with the tracked cross-covariance, or bounded by covariance intersection when the correlation is not
  tracked or not positive definite; the joint Joseph update, its gate and check; the observer keeps
  its part (``sigma_ij <- P_ij+``, its other factors rescaled by ``P_ii+ P_ii-^-1``); when both take it the target
  moves to the stamp and takes its part (``sigma_ji <- I``, its factors rescaled), else the observer drops its
  factor for the target and the target is untouched ("no update");
* absolute fixes and map landmarks: private updates of the observer, its factors rescaled.

The pair math (the factors' shear, their rescaling, the joint prior) is the nodes' own, :mod:`swarmloc.kernels.pairs`
compiled by numba (:data:`K`). Results equal the nodes' to rounding (tests/test_engine_rdl.py). Units: metres,
radians, seconds.
"""

from __future__ import annotations

from functools import cache
from typing import Any, Unpack

import numpy as np
from numba import njit

from swarmloc.arrays import BoolArray, FloatArray
from swarmloc.engine import blocks as B
from swarmloc.engine.codes import ABSOLUTE, FUSED, GATED, NO_LANDMARK, R_CORRELATION, R_DEGENERATE, REJECTED
from swarmloc.engine.detections import Timeline
from swarmloc.engine.joint import predict_kernel, run, stamp_loop
from swarmloc.engine.joint_math import (
    F,
    degenerate,
    measure,
    verdict,
)
from swarmloc.engine.replay_io import Noise, Replayed, Switches, constants, noise_tuple
from swarmloc.kernels import cartesian as C
from swarmloc.kernels.pairs import build
from swarmloc.motion import UnicycleNoise


def _compile(fn: Any) -> Any:
    return njit(error_model="numpy")(fn)


K = build(_compile)
"""``rdl``'s pair math (:mod:`swarmloc.kernels.pairs`: the nodes' functions) compiled by numba."""


_kalman = _compile(C.kalman_one)
"""The Kalman (Joseph) update of one state, the nodes' own (:func:`swarmloc.kernels.cartesian.kalman_one`) compiled:
``(x+, P+, nis, ok)``, the headings (components ``angles``) wrapped."""


@njit(error_model="numpy")
def _factor(sig: np.ndarray, met: np.ndarray, sa: float, sb: float, k: int, l: int) -> np.ndarray:
    """``sigma_kl`` with robot ``k``'s pending shear ``(sa, sb)`` applied (zero for a robot never met)."""
    if met[k, l]:
        f: np.ndarray = K.sheared(sig[k, l], sa, sb)
        return f
    return np.zeros((3, 3))


@njit(error_model="numpy")
def _rescale(sig: np.ndarray, sa: np.ndarray, sb: np.ndarray, k: int, P_new: np.ndarray, P_old: np.ndarray) -> None:
    """Robot ``k``'s factors rescaled after its update from ``P_old`` to ``P_new`` (:mod:`swarmloc.kernels.pairs`'
    ``rescaled``; a robot not met has a zero factor), its pending shear cleared."""
    sig[k] = K.rescaled(P_new, P_old, sig[k], sa[k], sb[k])
    sa[k] = 0.0
    sb[k] = 0.0


@cache
def _kernels() -> Any:
    """Compile the replay loop (:func:`swarmloc.engine.joint.stamp_loop`) (once per process; the noise model is an
    argument, ``qn``) over the state ``(x (n, 3), (met, sig), P (n, 3, 3), (sa, sb), tc, v, w)``: in the
    joint form's slots, the correlations where its joint covariance is, each robot's own covariance and shear (what a
    prediction moves) where its pending prediction is."""
    predict = predict_kernel()

    @njit(error_model="numpy")
    def predicted(x: FloatArray, P: FloatArray, tc: FloatArray, v: FloatArray, w: FloatArray, qn: Noise, k: int,
                  t: float) -> tuple[FloatArray, FloatArray, float, float]:  # fmt: skip
        """Robot ``k``'s ``(x, P, a, b)`` predicted to ``t``, ``(a, b)`` the prediction's shear
        (:func:`swarmloc.engine.blocks.moved`; zero: already there)."""
        dt = t - tc[k]
        xk, Pk = x[k].copy(), P[k].copy()
        if not dt > 0:
            return xk, Pk, 0.0, 0.0
        r = predict(xk[0], xk[1], xk[2], Pk[0, 0], Pk[0, 1], Pk[0, 2], Pk[1, 1], Pk[1, 2], Pk[2, 2], v[k], w[k], dt, qn)
        out = np.array([[r[3], r[4], r[5]], [r[4], r[6], r[7]], [r[5], r[7], r[8]]])
        return (np.array([r[0], r[1], r[2]]), out, *B.moved(xk[0], xk[1], r[0], r[1]))

    @njit(error_model="numpy")
    def advance(x: FloatArray, P: FloatArray, shear: tuple[FloatArray, FloatArray], tc: FloatArray, v: FloatArray,
                w: FloatArray, qn: Noise, k: int, t: float) -> None:  # fmt: skip
        """Robot ``k`` predicted to ``t`` in place (as :func:`predicted`, no arrays made: once per command)."""
        dt = t - tc[k]
        if not dt > 0:
            return
        sa, sb = shear
        xk, Pk = x[k], P[k]
        r = predict(xk[0], xk[1], xk[2], Pk[0, 0], Pk[0, 1], Pk[0, 2], Pk[1, 1], Pk[1, 2], Pk[2, 2], v[k], w[k], dt, qn)
        a, b = B.moved(xk[0], xk[1], r[0], r[1])
        sa[k] += a
        sb[k] += b
        xk[0], xk[1], xk[2] = r[0], r[1], r[2]
        Pk[0, 0], Pk[0, 1], Pk[0, 2], Pk[1, 1], Pk[1, 2], Pk[2, 2] = r[3], r[4], r[5], r[6], r[7], r[8]
        Pk[1, 0], Pk[2, 0], Pk[2, 1] = r[4], r[5], r[7]
        tc[k] = t

    @njit(error_model="numpy")
    def record(x: FloatArray, corr: tuple[BoolArray, FloatArray], P: FloatArray, shear: tuple[FloatArray, FloatArray],
               tc: FloatArray, v: FloatArray, w: FloatArray, qn: Noise, k: int, t: float, out_x: FloatArray,
               out_P: FloatArray, o: int) -> None:  # noqa: ARG001  # fmt: skip
        out_x[o], out_P[o], _, _ = predicted(x, P, tc, v, w, qn, k, t)

    return stamp_loop(advance, _detect(predicted, advance), record)


def _detect(predicted: Any, advance: Any) -> Any:
    """The detection step of the loop (:func:`swarmloc.engine.joint.stamp_loop`) around the compiled steps of
    :func:`_kernels`: a private update, or the exchange with the target."""

    @njit(error_model="numpy")
    def pair(x: FloatArray, P: FloatArray, sa: FloatArray, sb: FloatArray, met: BoolArray, sig: FloatArray,
             tc: FloatArray, v: FloatArray, w: FloatArray, qn: Noise, i: int, j: int, kind: int, zq: FloatArray,
             Rq: FloatArray, t: float, thr: FloatArray, gate: bool) -> tuple[int, int]:  # fmt: skip
        xj, Pj, a, b = predicted(x, P, tc, v, w, qn, j, t)  # the target's answer (not stored)
        if B.degenerate(kind, x[i, 0], x[i, 1], xj[0], xj[1]):
            return REJECTED, R_DEGENERATE
        fj = _factor(sig, met, sa[j] + a, sb[j] + b, j, i)
        fi = _factor(sig, met, sa[i], sb[i], i, j)
        X = np.concatenate((x[i], xj))
        r, H, Rm = measure(kind, X, 0, xj, zq, Rq)
        prior, both = K.pair_prior(P[i].copy(), Pj, fi, fj, met[i, j], H, Rm)
        if both < 0:
            return GATED, R_CORRELATION
        Xn, Pn, nis, ok = _kalman(X, prior, r, H, Rm, (2, 5))
        out = verdict(nis, ok, Pn, thr[kind], gate)
        if out[0]:
            return out
        Pi_old = P[i].copy()
        x[i], P[i] = Xn[:3], Pn[:3, :3]
        _rescale(sig, sa, sb, i, P[i], Pi_old)
        if both == 0:  # only the observer gains: its correlation with the target is unknown now
            sig[i, j] = 0.0
            return FUSED, 0
        sig[i, j], met[i, j] = Pn[:3, 3:], True
        advance(x, P, (sa, sb), tc, v, w, qn, j, t)  # the target takes its part at the stamp
        Pj_old = P[j].copy()
        x[j], P[j] = Xn[3:], Pn[3:, 3:]
        _rescale(sig, sa, sb, j, P[j], Pj_old)
        sig[j, i], met[j, i] = np.eye(3), True
        return FUSED, 0

    @njit(error_model="numpy", inline="always")  # no call between the loop and its step
    def detect(x: FloatArray, corr: tuple[BoolArray, FloatArray], P: FloatArray, shear: tuple[FloatArray, FloatArray],
               tc: FloatArray, v: FloatArray, w: FloatArray, qn: Noise, t0: FloatArray, t: float, q: int, i: int,
               j: int, kind: int, z: FloatArray, R: FloatArray, thr: FloatArray, gate: bool, relative: bool,
               lm_on: bool, lxy: FloatArray, lcov: FloatArray) -> tuple[int, int]:  # fmt: skip
        res, why = F.screen_started(kind, i, j, t, t0, relative, lm_on)
        if res != 0:
            return res, why
        met, sig = corr
        sa, sb = shear
        if kind == ABSOLUTE or j <= NO_LANDMARK:
            return _private(x, P, sa, sb, met, sig, i, kind, j, z[q], R[q], lxy, lcov, thr, gate)
        return pair(x, P, sa, sb, met, sig, tc, v, w, qn, i, j, kind, z[q], R[q], t, thr, gate)

    return detect


@njit(error_model="numpy")
def _private(x: np.ndarray, P: np.ndarray, sa: np.ndarray, sb: np.ndarray, met: np.ndarray, sig: np.ndarray, i: int,
             kind: int, j: int, zq: np.ndarray, Rq: np.ndarray, lxy: np.ndarray, lcov: np.ndarray, thr: np.ndarray,
             gate: bool) -> tuple[int, int]:  # fmt: skip
    """An absolute fix or a map landmark's detection by robot ``i``: a private update, its factors rescaled."""
    X = x[i].copy()
    lm = NO_LANDMARK - 1 - j
    xk = lxy[lm].copy() if kind != ABSOLUTE else np.zeros(0)
    if degenerate(kind, X, 0, xk):
        return REJECTED, R_DEGENERATE
    r, H, Rm = measure(kind, X, 0, xk, zq, Rq)
    if kind != ABSOLUTE:
        Hk = H[:, 3:5].copy()
        Rm = Rm + Hk @ lcov[lm] @ Hk.T
        H = H[:, :3].copy()
    xn, Pn, nis, ok = _kalman(X, P[i].copy(), r, H, Rm, (2,))
    out = verdict(nis, ok, Pn, thr[kind], gate)
    if out[0]:
        return out
    P_old = P[i].copy()
    x[i], P[i] = xn, Pn
    _rescale(sig, sa, sb, i, Pn, P_old)
    return FUSED, 0


def replay_rdl(tl: Timeline, x: np.ndarray, P: np.ndarray, t0: np.ndarray, noise: UnicycleNoise,
               **switches: Unpack[Switches]) -> Replayed:  # fmt: skip
    """``rdl`` over ``tl`` (robots as rows, the engine's codes) from Cartesian beliefs ``x (n, 3)``, ``P (n, 3, 3)``
    at each robot's start ``t0 (n,)`` [s] (``inf``: never starts), with the nodes' ``switches``
    (:class:`~swarmloc.engine.replay_io.Switches`). Returns ``(status, reason, records)`` as
    :func:`swarmloc.engine.joint.replay_joint`: records of every started robot at every recorded stamp.
    """
    n = x.shape[0]
    t0 = np.asarray(t0, dtype=float)
    corr = (np.zeros((n, n), dtype=np.bool_), np.zeros((n, n, 3, 3)))  # (met, sig)
    st = (np.array(x, dtype=float), corr, np.array(P, dtype=float), (np.zeros(n), np.zeros(n)),
          np.where(np.isfinite(t0), t0, 0.0), np.zeros(n), np.zeros(n))  # fmt: skip
    return run(_kernels(), st, st[5:], tl, t0, constants(noise_tuple(noise), **switches))
