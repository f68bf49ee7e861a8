"""The centralized EKFs (``cekf``, ``iekf``) and ``diekf`` on the engine: the team's joint state replayed in one
compiled loop (numba).

:class:`swarmloc.estimators.CentralizedEKF` keeps the joint Cartesian state ``X = (x_1, y_1, theta_1, ...)`` of
the ``n`` robots and its ``3n x 3n`` covariance; this module does what that node does over a whole
:class:`~swarmloc.engine.detections.Timeline`, in one call compiled by numba (:func:`replay_joint`), so a
recording replays without a Python step per input:

* **Prediction.** Robot ``k`` moves from its clock to a stamp with the command in force (the scalar prediction
  the engine's other kernels share, :func:`swarmloc.engine.scalar.predict_source`); its shear ``Phi`` and process
  covariance are kept pending, composed as the node composes them, and applied to the joint covariance only when
  an update needs it (:func:`swarmloc.estimators.cekf.flush_pending`, the same arithmetic).
* **Order.** At a stamp the detection groups fuse in observer order (each detection in the group's canonical
  order; the observer and a detected robot are predicted to the stamp and stay there, as the node stores them),
  then each robot with a command there moves to the stamp and starts it (after the updates: an update moves
  every correlated robot's heading, so predicting a robot before or after it differs); a record is every robot's
  marginal predicted to the stamp, not stored (:meth:`~swarmloc.node.base.Node.belief_at`).
* **Update.** One detection at a time, the node's Joseph form touching only the observer's and the target's three
  columns (:func:`swarmloc.kernels.cartesian.kalman_update_blocks`), every kind of
  :data:`swarmloc.sensors.models.MODELS` (absolute fixes, relative poses, range-bearing, range, bearing of robots
  and map landmarks), then the gate and the finite, positive-definite check of
  :func:`swarmloc.node.update.gated_kalman`.

**The invariant EKFs** (``invariant=True``). The same loop in world-frame errors
(:mod:`swarmloc.kernels.invariant`): a prediction adds ``N^-1 Q N^-T`` to the robot's block and nothing else (no
shear), Jacobian blocks are ``H_c N(x)``, and the correction moves each robot on the group, ``exp(hat(K r)) g``:
the centralized :class:`~swarmloc.estimators.InvariantEKF` (``iekf``). With each robot's start (``t0 (n,)``) it is
``diekf``'s team (:class:`~swarmloc.estimators.DistributedInvariantEKF`): its nodes' replicas together are this
joint state, so only what the nodes decide apart from the filter differs: a robot starts at its own first input and
is asked only from then on (``screen_started`` of :mod:`swarmloc.engine.formulas`), and a detected robot moves to
the stamp only when it takes the update (a gated or refused detection leaves it where it was).

Results equal the nodes' to rounding (tests/test_engine_cekf.py, tests/test_engine_invariant.py: 1e-10 on
simulated teams, 1e-9 relative on MRCLAM, every outcome count and reason). Units: metres, radians, seconds; angles
wrapped to (-pi, pi].
"""

from __future__ import annotations

import math
from functools import cache
from typing import Any, TypeAlias, Unpack

import numpy as np
from numba import njit

from swarmloc.arrays import BoolArray, FloatArray, IntArray
from swarmloc.engine import blocks as B
from swarmloc.engine.codes import (
    ABSOLUTE,
    FUSED,
    NO_LANDMARK,
    R_DEGENERATE,
    REJECTED,
)
from swarmloc.engine.detections import Timeline
from swarmloc.engine.joint_math import (
    F,
    commit,
    degenerate,
    kalman,
    measure,
    rows3,
    to_world,
    world_noise,
)
from swarmloc.engine.replay_io import Constants, Noise, Replayed, Switches, constants, joint_start, noise_tuple
from swarmloc.engine.scalar import predict_source
from swarmloc.motion import UnicycleNoise

JointState: TypeAlias = tuple[FloatArray, FloatArray, FloatArray, BoolArray, FloatArray, FloatArray, FloatArray]
"""The joint forms' state in the loop (:func:`stamp_loop`): ``(X (3n,), P, pend (n, 8), has (n,), tc, v, w (n,))``,
``P`` the joint covariance ``(3n, 3n)`` or a cluster's blocks ``(clusters, 3K, 3K)``."""
PairState: TypeAlias = tuple[FloatArray, tuple[BoolArray, FloatArray], FloatArray, tuple[FloatArray, FloatArray],
                             FloatArray, FloatArray, FloatArray]  # fmt: skip
"""``rdl``'s state in the same slots (:mod:`swarmloc.engine.pairs`): ``(x (n, 3), (met (n, n), sig (n, n, 3, 3)),
P (n, 3, 3), (sa, sb) (n,), tc, v, w (n,))``."""
State: TypeAlias = JointState | PairState
"""A compiled replay loop's state: ``(.., .., .., .., clock, v, w)``, each robot's clock and command last."""


@njit(error_model="numpy")
def _compose(pend: np.ndarray, has: np.ndarray, k: int, sa: float, sb: float, q: np.ndarray) -> None:
    """Robot ``k``'s pending ``(a, b, Q upper)`` after one more prediction, of shear ``(sa, sb)``
    (:func:`swarmloc.engine.blocks.moved`; :func:`~swarmloc.estimators.cekf.compose_pending`)."""
    dx, dy = sb, -sa
    if not has[k]:
        pend[k, 0], pend[k, 1] = sa, sb
        pend[k, 2:] = q
        has[k] = True
        return
    q00, q01, q02, q11, q12, q22 = pend[k, 2], pend[k, 3], pend[k, 4], pend[k, 5], pend[k, 6], pend[k, 7]
    a02, a12 = q02 - dy * q22, q12 + dx * q22
    pend[k, 0] -= dy
    pend[k, 1] += dx
    pend[k, 2] = q00 - 2 * dy * q02 + dy * dy * q22 + q[0]
    pend[k, 3] = q01 - dy * q12 + dx * a02 + q[1]
    pend[k, 4] = a02 + q[2]
    pend[k, 5] = q11 + 2 * dx * q12 + dx * dx * q22 + q[3]
    pend[k, 6] = a12 + q[4]
    pend[k, 7] = q22 + q[5]


@njit(error_model="numpy")
def flush(P: np.ndarray, pend: np.ndarray, has: np.ndarray) -> None:
    """Every robot's pending prediction applied to the joint ``P`` (:func:`~swarmloc.estimators.cekf.flush_pending`)."""
    N = P.shape[0]
    for k in range(has.shape[0]):
        if not has[k]:
            continue
        i = 3 * k
        a, b = pend[k, 0], pend[k, 1]
        if a != 0.0 or b != 0.0:  # no shear (the invariant filters' predictions): only the noise
            for c in range(N):
                P[i, c], P[i + 1, c] = B.shear(P[i, c], P[i + 1, c], P[i + 2, c], a, b)
            for r in range(N):
                P[r, i], P[r, i + 1] = B.shear(P[r, i], P[r, i + 1], P[r, i + 2], a, b)
        u = pend[k, 2:]
        P[i, i] += u[0]
        P[i, i + 1] += u[1]
        P[i, i + 2] += u[2]
        P[i + 1, i] += u[1]
        P[i + 1, i + 1] += u[3]
        P[i + 1, i + 2] += u[4]
        P[i + 2, i] += u[2]
        P[i + 2, i + 1] += u[4]
        P[i + 2, i + 2] += u[5]
        has[k] = False


@cache
def predict_kernel() -> Any:
    """The engine's scalar prediction (:func:`swarmloc.engine.scalar.predict_source`) compiled: ``predict(x0, x1,
    x2, p00, p01, p02, p11, p12, p22, v, w, dt, qn) -> (x (3), P upper triangle (6))``, ``qn`` the noise model's
    coefficients (:func:`~swarmloc.engine.replay_io.noise_tuple`)."""
    ns: dict[str, Any] = {"math": math, "np": np}
    exec(predict_source(), ns)  # noqa: S102 - our own generated code
    return njit(error_model="numpy")(ns["predict"])


@cache
def _kernels(invariant: bool = False, distributed: bool = False) -> Any:
    """Compile the replay loop (:func:`stamp_loop`) (once per process and form; the noise model is an argument, in
    the loop's constants) over the state ``(X, P, pend, has, tc, v, w)``. ``invariant``: world-frame errors
    (``iekf``, ``diekf``). ``distributed`` (with ``invariant``: ``diekf``'s nodes): each robot starts at its own
    first input and answers from then on (``screen_started`` of :mod:`swarmloc.engine.formulas`), and a detected
    robot moves to the detection's stamp only when it takes the update (its node answers a query from a prediction
    it does not store; it moves when the broadcast updates it)."""
    advance, marginal, fuse, _ = steps(invariant, distributed)

    @njit(error_model="numpy", inline="always")  # no call between the loop and its step
    def detect(X: FloatArray, P: FloatArray, pend: FloatArray, has: BoolArray, tc: FloatArray, v: FloatArray,
               w: FloatArray, qn: Noise, t0: FloatArray, t: float, q: int, i: int, j: int, kind: int, z: FloatArray,
               R: FloatArray, thr: FloatArray, gate: bool, relative: bool, lm_on: bool, lxy: FloatArray,
               lcov: FloatArray) -> tuple[int, int]:  # fmt: skip
        if distributed:
            res, why = F.screen_started(kind, i, j, t, t0, relative, lm_on)
        else:
            res, why = F.screen_central(kind, i, j, relative, lm_on)
        if res == 0:
            st, reason = fuse(X, P, pend, has, tc, v, w, qn, t, q, i, j, kind, z, R, lxy, lcov, thr, gate)
            return st, reason
        return res, why

    return stamp_loop(advance, detect, marginal)


@cache
def steps(invariant: bool = False, distributed: bool = False) -> tuple[Any, Any, Any, Any]:
    """The compiled steps of the replay loop (:func:`_kernels`): ``advance(X, pend, has, tc, v, w, qn, k, t)``
    (robot ``k`` to ``t``, its prediction pending; ``qn`` the noise model's coefficients,
    :func:`~swarmloc.engine.replay_io.noise_tuple`), ``marginal(X, P, pend, has, tc, v, w, qn, k, t, out_x, out_P, o)``
    (robot ``k``'s Cartesian belief at ``t`` into record ``o``, nothing stored), ``fuse(X, P, pend, has, tc, v, w,
    qn, t, q, i, j, kind, z, R, lxy, lcov, thr, gate) -> (outcome, reason)`` (detection ``q`` of observer ``i``,
    target ``j``: a robot's index, or a landmark's code) and ``belief(X, P, pend, has, tc, v, w, qn, k, t) -> (x,
    P)`` (robot ``k`` at ``t`` in the filter's error frame, nothing stored: what ``marginal`` records). They index
    robots by their rows of the arrays passed, so a cluster's views of them run the same steps
    (:mod:`swarmloc.engine.joint_clusters`)."""
    advance, belief, marginal = _moves(predict_kernel(), invariant)
    return advance, marginal, _fusion(advance, invariant, distributed), belief


def _moves(predict: Any, invariant: bool) -> tuple[Any, Any, Any]:
    """:func:`steps`' ``advance``, ``belief`` and ``marginal`` (a robot moved, its belief read) over the compiled
    prediction ``predict`` (:func:`predict_kernel`)."""

    @njit(error_model="numpy")
    def advance(X: FloatArray, pend: FloatArray, has: BoolArray, tc: FloatArray, v: FloatArray, w: FloatArray,
                qn: Noise, k: int, t: float) -> None:  # fmt: skip
        dt = t - tc[k]
        if not dt > 0:
            return
        i = 3 * k
        r = predict(X[i], X[i + 1], X[i + 2], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, v[k], w[k], dt, qn)
        q = np.array([r[3], r[4], r[5], r[6], r[7], r[8]])
        if invariant:  # the error transition is the identity: no shear, the noise in world-frame errors
            a, b, q = -0.0, 0.0, world_noise(r[0], r[1], q)
        else:
            a, b = B.moved(X[i], X[i + 1], r[0], r[1])
        X[i], X[i + 1], X[i + 2] = r[0], r[1], r[2]
        _compose(pend, has, k, a, b, q)
        tc[k] = t

    @njit(error_model="numpy")
    def belief(X: FloatArray, P: FloatArray, pend: FloatArray, has: BoolArray, tc: FloatArray, v: FloatArray,
               w: FloatArray, qn: Noise, k: int, t: float) -> tuple[FloatArray, FloatArray]:  # fmt: skip
        """Robot ``k``'s ``(x (3,), P (3, 3))`` at ``t`` (its filter's error frame), nothing stored."""
        i = 3 * k
        x, pd, hs, clock = X[i : i + 3].copy(), pend[k : k + 1].copy(), has[k : k + 1].copy(), tc[k : k + 1].copy()
        advance(x, pd, hs, clock, v[k : k + 1], w[k : k + 1], qn, 0, t)
        M = rows3(P[i : i + 3, i : i + 3])
        if hs[0]:
            M = B.predicted_block(M, pd[0, 0], pd[0, 1], (pd[0, 2], pd[0, 3], pd[0, 4], pd[0, 5], pd[0, 6], pd[0, 7]))
        return x, np.array(M)

    @njit(error_model="numpy")
    def marginal(X: FloatArray, P: FloatArray, pend: FloatArray, has: BoolArray, tc: FloatArray, v: FloatArray,
                 w: FloatArray, qn: Noise, k: int, t: float, out_x: FloatArray, out_P: FloatArray, o: int
                 ) -> None:  # fmt: skip
        x, M = belief(X, P, pend, has, tc, v, w, qn, k, t)
        out_x[o] = x
        if invariant:  # recorded Cartesian: N M N^T (blocks.sheared(M, -y, x), but BLAS's rounding: the bits kept)
            N = np.array([[1.0, 0.0, -x[1]], [0.0, 1.0, x[0]], [0.0, 0.0, 1.0]])
            M = N @ M @ N.T
        out_P[o] = M

    return advance, belief, marginal


def _fusion(advance: Any, invariant: bool, distributed: bool) -> Any:
    """:func:`steps`' ``fuse`` (a detection's update; with ``distributed``, the target's move undone when it does
    not take it) over the compiled ``advance`` (:func:`_moves`)."""

    @njit(error_model="numpy")
    def fuse(X: FloatArray, P: FloatArray, pend: FloatArray, has: BoolArray, tc: FloatArray, v: FloatArray,
             w: FloatArray, qn: Noise, t: float, q: int, i: int, j: int, kind: int, z: FloatArray, R: FloatArray,
             lxy: FloatArray, lcov: FloatArray, thr: FloatArray, gate: bool) -> tuple[int, int]:  # fmt: skip
        if not (distributed and j >= 0):
            return update(X, P, pend, has, tc, v, w, qn, t, q, i, j, kind, z, R, lxy, lcov, thr, gate)
        flush(P, pend, has)  # (world-frame noise: additive) the target's step to t is then all it has pending
        k = 3 * j
        xj, tj, Pjj = X[k : k + 3].copy(), tc[j], P[k : k + 3, k : k + 3].copy()
        st, why = update(X, P, pend, has, tc, v, w, qn, t, q, i, j, kind, z, R, lxy, lcov, thr, gate)
        if st != FUSED:  # not taken: the target stays where it was
            X[k : k + 3], tc[j], P[k : k + 3, k : k + 3], has[j] = xj, tj, Pjj, False
        return st, why

    @njit(error_model="numpy")
    def update(X: FloatArray, P: FloatArray, pend: FloatArray, has: BoolArray, tc: FloatArray, v: FloatArray,
               w: FloatArray, qn: Noise, t: float, q: int, i: int, j: int, kind: int, z: FloatArray, R: FloatArray,
               lxy: FloatArray, lcov: FloatArray, thr: FloatArray, gate: bool) -> tuple[int, int]:  # fmt: skip
        if j >= 0:  # a robot: predicted to the stamp (and kept there) before anything is read of it
            advance(X, pend, has, tc, v, w, qn, j, t)
        xk = X[3 * j : 3 * j + 3].copy() if j >= 0 else (lxy[NO_LANDMARK - 1 - j].copy() if kind != ABSOLUTE
                                                         else np.zeros(0))  # fmt: skip
        if degenerate(kind, X, 3 * i, xk):
            return REJECTED, R_DEGENERATE
        r, H, Rm = measure(kind, X, 3 * i, xk, z[q], R[q])
        own = np.arange(3 * i, 3 * i + 3)
        if j >= 0:
            cols = np.concatenate((own, np.arange(3 * j, 3 * j + 3)))
            if invariant:
                to_world(H, 3, xk[0], xk[1])
        else:
            cols = own
            if kind != ABSOLUTE:  # a map landmark: its covariance enters the noise
                Hk = H[:, 3:5].copy()
                Rm = Rm + Hk @ lcov[NO_LANDMARK - 1 - j] @ Hk.T
            H = H[:, :3].copy()
        if invariant:
            to_world(H, 0, X[3 * i], X[3 * i + 1])
        flush(P, pend, has)
        xn, Pn, nis, ok = kalman(X, P, r, H, cols, Rm, invariant)
        return commit(X, P, xn, Pn, nis, ok, thr[kind], gate)

    return fuse


def stamp_loop(advance: Any, detect: Any, record: Any) -> Any:
    """The compiled loop over the stamps of a timeline (this module's, the clusters', ``rdl``'s) around the steps of
    its form on the state ``(X, P, pend, has, tc, v, w)`` (:func:`steps`; a cluster's ``P`` is its clusters' blocks)
    and the noise model's coefficients ``qn`` (the constants' last, :func:`~swarmloc.engine.replay_io.noise_tuple`):
    ``advance(X, pend, has, tc, v, w, qn, k, t)``, ``detect(X, P, pend, has, tc, v, w, qn, t0, t, q, i, j, kind, z,
    R, thr, gate, relative, lm_on, lxy, lcov) -> (outcome, reason)`` (detection ``q`` of observer ``i``, target
    ``j``) and ``record(X, P, pend, has, tc, v, w, qn, k, t, out_x, out_P, o)`` (robot ``k``'s Cartesian belief at
    ``t`` into record ``o``, nothing stored). At a stamp: each detection, its observer moved to the stamp first;
    then the commands, each robot moved to the stamp before it starts its command (after the updates: they move
    every correlated heading); then, if recorded, every started robot. ``rdl``'s loop fills the same slots with its
    own state (:mod:`swarmloc.engine.pairs`). The state is unpacked once, not in each step (steps that take the
    state tuple whole cost this loop 15-24% on MRCLAM 6: the arrays' reference counts)."""

    @njit(error_model="numpy")
    def replay(state: State, vw: tuple[FloatArray, FloatArray], t0: FloatArray, stamps: FloatArray, d0: IntArray,
               det: tuple[IntArray, IntArray, IntArray, FloatArray, FloatArray], status: IntArray, reason: IntArray,
               const: Constants, cmd: tuple[IntArray, IntArray, FloatArray, FloatArray], rec: BoolArray,
               out: tuple[IntArray, IntArray, FloatArray, FloatArray]) -> int:  # noqa: ARG001  # fmt: skip
        X, P, pend, has, tc, v, w = state
        thr, gate, relative, lm_on, lxy, lcov, qn = const
        obs, tgt, kind, z, R = det
        c0, crow, cv, cw = cmd
        out_robot, out_stamp, out_x, out_P = out
        o = 0
        for s in range(stamps.shape[0]):
            t = stamps[s]
            for q in range(d0[s], d0[s + 1]):
                i = obs[q]
                advance(X, pend, has, tc, v, w, qn, i, t)  # the observer moves to its group's stamp
                status[q], reason[q] = detect(X, P, pend, has, tc, v, w, qn, t0, t, q, i, tgt[q], kind[q], z, R, thr,
                                              gate, relative, lm_on, lxy, lcov)  # fmt: skip
            for c in range(c0[s], c0[s + 1]):  # then the commands: a robot moves to t and starts its command
                advance(X, pend, has, tc, v, w, qn, crow[c], t)
                v[crow[c]] = cv[c]
                w[crow[c]] = cw[c]
            if rec[s]:
                for k in range(tc.shape[0]):
                    if t >= t0[k]:
                        record(X, P, pend, has, tc, v, w, qn, k, t, out_x, out_P, o)
                        out_robot[o] = k
                        out_stamp[o] = s
                        o += 1
        return o

    return replay


def run(loop: Any, st: State, vw: tuple[FloatArray, FloatArray], tl: Timeline, starts: FloatArray, const: Constants
        ) -> Replayed:  # fmt: skip
    """A compiled replay loop (:func:`stamp_loop`'s: ``loop(st, vw, starts, stamps, d0, det,
    status, reason, const, cmd, rec, out)``) over ``tl`` from the state ``st`` (its commands ``vw``) and each robot's
    start ``starts (n,)``: ``(status, reason, records)`` as :func:`replay_joint` returns them."""
    m = len(tl.det)
    status, reason = np.zeros(m, dtype=np.int64), np.zeros(m, dtype=np.int64)
    k = int(sum(np.count_nonzero(tl.stamps[tl.record] >= s) for s in starts.tolist()))
    out = (np.zeros(k, dtype=np.int64), np.zeros(k, dtype=np.int64), np.zeros((k, 3)), np.zeros((k, 3, 3)))
    d = tl.det
    det = (d.observer, d.target, d.kind, np.ascontiguousarray(d.z), np.ascontiguousarray(d.R))
    loop(st, vw, starts, tl.stamps, tl.d0, det, status, reason, const, (tl.c0, tl.robot, tl.v, tl.w), tl.record, out)
    return status.astype(np.int8), reason.astype(np.int8), out


def replay_joint(tl: Timeline, x: np.ndarray, P: np.ndarray, t0: float | np.ndarray, noise: UnicycleNoise, *,
                 invariant: bool = False, **switches: Unpack[Switches]) -> Replayed:  # fmt: skip
    """The centralized EKF over ``tl`` (robots as rows, the engine's codes) from Cartesian beliefs ``x (n, 3)``,
    ``P (n, 3, 3)`` (uncorrelated) at ``t0`` [s]: one float, every robot's clock (the centralized nodes), or each
    robot's start ``(n,)`` (``inf``: never starts), with ``invariant`` only: ``diekf``'s nodes (:func:`_kernels`,
    ``distributed``).

    ``switches``: the nodes' (:class:`~swarmloc.engine.replay_io.Switches`: gate, relative and landmark measurements,
    the map); ``invariant``: the invariant EKF (world-frame errors,
    :class:`~swarmloc.estimators.InvariantEKF`; with per-robot starts the distributed one,
    :class:`~swarmloc.estimators.DistributedInvariantEKF`, whose replicas together are its joint state).
    Returns ``(status, reason, records)``: each detection's outcome and reason code (rows of ``tl.det``) and the
    records ``(robot row, stamp index, x (K, 3), P (K, 3, 3))`` (Cartesian), every started robot at every recorded
    stamp, in stamp then row order.
    """
    n = x.shape[0]
    distributed = np.ndim(t0) == 1
    if distributed and not invariant:
        raise ValueError("replay_joint: per-robot starts are diekf's (invariant=True); cekf starts at one t0")
    X, J, clock, starts = joint_start(x, P, t0, invariant)
    st = (X.reshape(3 * n), J[0], np.zeros((n, 8)), np.zeros(n, dtype=np.bool_), clock, np.zeros(n), np.zeros(n))
    const = constants(noise_tuple(noise), **switches)
    return run(_kernels(bool(invariant), bool(distributed)), st, st[5:], tl, starts, const)
