"""The compiled pieces the engine's replays share (numba; :mod:`swarmloc.engine.formulas` compiled on scalars, with
:mod:`swarmloc.engine.blocks`): a detection's residual, Jacobian and noise (:func:`measure`), the positive-definite
check, the world-frame pieces of the invariant filters, the Kalman update on a few columns of a joint covariance
(:func:`kalman`, the nodes' own compiled) and the order of its outcomes (:func:`verdict`), and the loop forms of
:func:`swarmloc.kernels.cartesian.matmul` and ``logdets`` that the nodes' kernels compiled in the engine use.
:mod:`swarmloc.engine.joint`, :mod:`swarmloc.engine.joint_clusters` and :mod:`swarmloc.engine.pairs` build their loops
from them. Units: metres, radians; angles wrapped to (-pi, pi]."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit
from numba.extending import overload

from swarmloc.engine import blocks as B
from swarmloc.engine import numba_xp
from swarmloc.engine.codes import ABSOLUTE, FUSED, POSE, R_NUMERICAL, REJECTED
from swarmloc.engine.formulas import RANGE_BEARING, build
from swarmloc.kernels import cartesian as C


def _compile(fn: Any) -> Any:
    return njit(error_model="numpy")(fn)


F = build(numba_xp, _compile)
"""The shared formulas (:mod:`swarmloc.engine.formulas`) compiled by numba on scalars."""


@overload(C.matmul, jit_options={"error_model": "numpy"})
def _matmul(A: Any, B: Any) -> Any:
    """:func:`swarmloc.kernels.cartesian.matmul` compiled, for every replay that compiles the nodes' kernels (registered
    on importing this module): the product of small matrices or vectors as loops."""
    if A.ndim == 1 and B.ndim == 1:

        def dot(A: Any, B: Any) -> Any:
            acc = 0.0
            for c in range(A.shape[0]):
                acc += A[c] * B[c]
            return acc

        return dot
    if A.ndim == 1:

        def vecmat(A: Any, B: Any) -> Any:
            return C.matmul(B.T, A)  # the same products in the same order

        return vecmat
    if B.ndim == 1:

        def matvec(A: Any, B: Any) -> Any:
            out = np.empty(A.shape[0])
            for i in range(A.shape[0]):
                acc = 0.0
                for c in range(A.shape[1]):
                    acc += A[i, c] * B[c]
                out[i] = acc
            return out

        return matvec

    def matmat(A: Any, B: Any) -> Any:
        out = np.empty((A.shape[0], B.shape[1]))
        for i in range(A.shape[0]):
            for j in range(B.shape[1]):
                acc = 0.0
                for c in range(A.shape[1]):
                    acc += A[i, c] * B[c, j]
                out[i, j] = acc
        return out

    return matmat


@overload(C.logdets, jit_options={"error_model": "numpy"})
def _logdets(a: Any, A: Any, b: Any, B: Any, R: Any) -> Any:
    """:func:`swarmloc.kernels.cartesian.logdets` compiled: each matrix formed and its ``slogdet`` taken in turn."""

    def each(a: Any, A: Any, b: Any, B: Any, R: Any) -> Any:
        m = R.shape[0]
        out = np.empty(a.shape[0])
        M = np.empty((m, m))
        for k in range(a.shape[0]):
            for i in range(m):
                for j in range(m):
                    M[i, j] = a[k] * A[i, j] + b[k] * B[i, j] + R[i, j]
            out[k] = np.linalg.slogdet(M)[1]
        return out

    return each


@overload(C.joseph_blocks, jit_options={"error_model": "numpy"})
def _joseph_blocks(P: Any, K: Any, U: Any, S: Any) -> Any:
    """:func:`swarmloc.kernels.cartesian.joseph_blocks` compiled: ``W = U - K S``, then each entry of the upper
    triangle and its mirror, ``P[a, b] - sum_k K[a, k] U[b, k] + W[a, k] K[b, k]``, averaged (``n x m`` temporaries
    only)."""

    def loops(P: Any, K: Any, U: Any, S: Any) -> Any:
        N, m = K.shape
        W = U.copy()
        for a in range(N):
            for k in range(m):
                for ll in range(m):
                    W[a, k] -= K[a, ll] * S[ll, k]
        Pn = np.empty((N, N))
        for a in range(N):
            for b in range(a, N):
                ab, ba = P[a, b], P[b, a]
                for k in range(m):
                    ab -= K[a, k] * U[b, k] + W[a, k] * K[b, k]
                    ba -= K[b, k] * U[a, k] + W[b, k] * K[a, k]
                Pn[a, b] = Pn[b, a] = 0.5 * (ab + ba)
        return Pn

    return loops


@njit(error_model="numpy")
def rows3(M: np.ndarray, fill: float = 0.0) -> B.Mat:
    """``M (m, m)``, ``m <= 3``, as 3x3 rows of entries (:mod:`swarmloc.engine.blocks`' matrices), padded with
    ``fill`` on the diagonal and zeros."""
    P = np.zeros((3, 3))
    for a in range(3):
        P[a, a] = fill
    m = M.shape[0]
    P[:m, :m] = M
    return (P[0, 0], P[0, 1], P[0, 2]), (P[1, 0], P[1, 1], P[1, 2]), (P[2, 0], P[2, 1], P[2, 2])


@njit(error_model="numpy")
def usable(P: np.ndarray) -> bool:
    """Finite and positive definite (:func:`swarmloc.node.update.usable_covariance`: a Cholesky factorization)."""
    N = P.shape[0]
    if N == 3 and np.isfinite(P).all():  # the node's leading minors with a margin, for a team of one
        m2 = P[0, 0] * P[1, 1] - P[1, 0] * P[1, 0]
        m3 = (P[0, 0] * (P[1, 1] * P[2, 2] - P[2, 1] * P[2, 1]) - P[1, 0] * (P[1, 0] * P[2, 2] - P[2, 1] * P[2, 0])
              + P[2, 0] * (P[1, 0] * P[2, 1] - P[1, 1] * P[2, 0]))  # fmt: skip
        tr = P[0, 0] + P[1, 1] + P[2, 2]
        if P[0, 0] > 0 and m2 > 1e-9 * tr * tr and m3 > 1e-9 * tr * tr * tr:
            return True
    if not np.isfinite(P).all():
        return False
    L = np.zeros_like(P)
    for j in range(N):
        d = P[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0:
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, N):
            s = P[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return True


@njit(error_model="numpy")
def measure(kind: int, X: np.ndarray, i: int, xk: np.ndarray, zq: np.ndarray, Rq: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Residual ``r (m,)``, Jacobian ``H (m, 3 + len(xk))`` (observer's columns, then the target's) and noise
    ``R (m, m)`` of a detection of ``kind`` by the robot at rows ``i:i+3`` of ``X`` of a target at ``xk`` (a
    robot's pose, a landmark's position, nothing for an absolute fix): :func:`swarmloc.engine.formulas.measure`'s
    first ``m`` rows, a relative pose's noise made Cartesian."""
    w = xk.shape[0]
    target = (xk[0] if w > 0 else 0.0, xk[1] if w > 1 else 0.0, xk[2] if w > 2 else 0.0)
    r3, H3, B3 = F.measure(kind, X[i], X[i + 1], X[i + 2], target, (zq[0], zq[1], zq[2]))
    m = 3 if kind == ABSOLUTE or kind == POSE else (2 if kind == RANGE_BEARING else 1)
    r, H = np.array(r3)[:m].copy(), np.array(H3)[:m, : 3 + w].copy()
    if kind == POSE:
        B = np.array(B3)
        return r, H, B @ Rq[:3, :3].copy() @ B.T
    return r, H, Rq[:m, :m].copy()


@njit(error_model="numpy")
def degenerate(kind: int, X: np.ndarray, i: int, xk: np.ndarray) -> bool:
    """:func:`swarmloc.engine.blocks.degenerate` of a detection by the robot at rows ``i:i+3`` of ``X`` of a target at
    ``xk`` (none for an absolute fix: never degenerate)."""
    return bool(xk.shape[0] >= 2 and B.degenerate(kind, X[i], X[i + 1], xk[0], xk[1]))


@njit(error_model="numpy")
def left_correct(X: np.ndarray, delta: np.ndarray) -> None:
    """Every robot's pose ``X[3k:3k+3]`` corrected by its world-frame ``delta[3k:3k+3]``, written into ``delta``:
    the Cartesian pose of ``exp(hat(delta_k)) g(x_k)`` (:func:`swarmloc.engine.formulas.left_correct`)."""
    for i in range(0, X.shape[0], 3):
        delta[i], delta[i + 1], delta[i + 2] = F.left_correct(X[i], X[i + 1], X[i + 2], delta[i], delta[i + 1],
                                                              delta[i + 2])  # fmt: skip


@njit(error_model="numpy")
def to_world(H: np.ndarray, c: int, x: float, y: float) -> None:
    """The Cartesian Jacobian block ``H[:, c:c+3]`` of a pose at ``(x, y)`` made one of its world-frame error, in
    place: ``H N`` with ``N = [[1, 0, -y], [0, 1, x], [0, 0, 1]]`` (:func:`swarmloc.kernels.invariant.world_basis`)."""
    for k in range(H.shape[0]):
        H[k, c + 2] = B.to_world(H[k, c], H[k, c + 1], H[k, c + 2], x, y)


@njit(error_model="numpy")
def world_noise(x: float, y: float, q: np.ndarray) -> np.ndarray:
    """:func:`swarmloc.engine.formulas.world_noise` of an upper triangle ``q (6,)``, as an array."""
    return np.array(F.world_noise(x, y, (q[0], q[1], q[2], q[3], q[4], q[5])))


_blocks = _compile(C.kalman_update_blocks)


@njit(error_model="numpy")
def kalman(X: np.ndarray, P: np.ndarray, r: np.ndarray, H: np.ndarray, cols: np.ndarray, R: np.ndarray,
            invariant: bool = False) -> tuple[np.ndarray, np.ndarray, float, bool]:  # fmt: skip
    """The Kalman update on the columns ``cols`` of ``P``, the nodes' own
    (:func:`swarmloc.kernels.cartesian.kalman_update_blocks`) compiled: ``(x+, P+, nis, ok)``, every robot's heading
    wrapped. ``invariant``: ``P`` is of world-frame errors and each robot's pose is corrected on the group,
    ``exp(hat(K r)) g`` (:func:`left_correct` of the update's ``K r``), not by ``x + K r``."""
    if invariant:
        xn, Pn, nis, ok = _blocks(np.zeros(X.shape[0]), P, r, H, cols, R, np.zeros(0, np.int64))
        left_correct(X, xn)
    else:
        xn, Pn, nis, ok = _blocks(X, P, r, H, cols, R, np.arange(2, X.shape[0], 3))
    return xn, Pn, nis, ok


@njit(error_model="numpy")
def verdict(nis: float, ok: bool, Pn: np.ndarray, threshold: float, gate: bool) -> tuple[int, int]:
    """The outcome of a Kalman update as :func:`swarmloc.node.update.gated_kalman` decides it, in its order: the
    gate (:func:`swarmloc.engine.formulas.gate_rules`), then a result that is not finite or not positive definite
    (:func:`usable`) is rejected; ``(0, 0)``: take it."""
    st, why, done = F.gate_rules((0, 0, False), nis, threshold, gate)
    if done:
        return st, why
    if not (ok and usable(Pn)):
        return REJECTED, R_NUMERICAL
    return 0, 0


@njit(error_model="numpy")
def commit(X: np.ndarray, P: np.ndarray, xn: np.ndarray, Pn: np.ndarray, nis: float, ok: bool, threshold: float,
           gate: bool) -> tuple[int, int]:  # fmt: skip
    """A joint update's :func:`verdict` and, when taken, its ``(xn, Pn)`` written into the state ``(X, P)`` in place:
    ``(outcome, reason)``."""
    st, why = verdict(nis, ok, Pn, threshold, gate)
    if st:
        return st, why
    X[:] = xn
    P[:, :] = Pn
    return FUSED, 0
