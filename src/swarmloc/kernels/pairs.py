"""The pair math of recursive decentralized localization (``rdl``, ``irdl``: :mod:`swarmloc.estimators.rdl`), written
once: the factors' pending shear, their rescaling after an update, and the pair's joint prior (the tracked
cross-covariance, or covariance intersection where the correlation is unknown).

:func:`build` makes the functions with a compiler ``jit``, as :func:`swarmloc.engine.formulas.build` does: the
functions themselves (:data:`PAIRS`, what the nodes call; no numba needed) or ``numba.njit``'s (the engine's
compiled replay, :mod:`swarmloc.engine.pairs`). They are numpy code that numba compiles: small arrays, loops,
``np.linalg``, products through :func:`~swarmloc.kernels.cartesian.matmul` (loops when compiled). A factor
``sigma_il (3, 3)`` of robot ``i`` for robot ``l`` is stored with the shear ``(sa, sb)`` that ``i``'s predictions
since its last update owe it (:class:`~swarmloc.estimators.rdl.RdlFilter`); covariances are of
Cartesian (``rdl``) or world-frame (``irdl``) errors, the math is the same.
"""

from __future__ import annotations

from functools import cache
from types import ModuleType

import numpy as np

from swarmloc.gaussian import positive_definite as _positive_definite
from swarmloc.kernels.cartesian import logdets, matmul
from swarmloc.sensors.planar import Jit, plain

CI_WEIGHTS = np.linspace(0.02, 0.98, 49)
"""The covariance-intersection weights the pair prior tries (``ci_prior``)."""
CI_WEIGHTS.setflags(write=False)


@cache
def build(jit: Jit = plain) -> ModuleType:
    """The pair functions compiled by ``jit``, as the attributes of a module object (numba compiles a module's
    attribute as a global of its own): ``sheared``, ``rescaled``, ``tracked``, ``ci_prior``, ``pair_prior``."""

    @jit
    def sheared(sig: np.ndarray, sa: float, sb: float) -> np.ndarray:
        """Factors ``(..., 3, 3)`` with the pending shear applied, ``S(sa, sb) @ sigma`` with ``S = [[1, 0, sa],
        [0, 1, sb], [0, 0, 1]]`` (a new array)."""
        out = sig.copy()
        out[..., 0, :] += sa * sig[..., 2, :]
        out[..., 1, :] += sb * sig[..., 2, :]
        return out

    @jit
    def rescaled(P_new: np.ndarray, P_old: np.ndarray, sig: np.ndarray, sa: float, sb: float) -> np.ndarray:
        """Every factor of ``sig (k, 3, 3)`` after its robot's update from ``P_old`` to ``P_new``, ``sigma_il <-
        P_new P_old^-1 S(sa, sb) sigma_il`` (Luft et al.'s approximation of the third-party correlations), no
        pending shear left; ``sig`` itself where every factor is zero."""
        if not sig.any():
            return sig
        M = matmul(P_new, np.linalg.inv(P_old))
        f = sheared(sig, sa, sb)
        for k in range(f.shape[0]):
            f[k] = matmul(M, f[k])
        return f

    @jit
    def tracked(fi: np.ndarray, fj: np.ndarray, met: bool) -> bool:
        """Whether a pair's correlation is known from the observer's factor ``fi``, the target's ``fj``, and whether
        the observer has met the target (exchanged with it, since its start): met, both sides must still track it
        (non-zero: a zero factor was dropped by an exchange that did not complete); never met, the target must not
        track one either (independent). Else an exchange did not complete, or one side restarted."""
        return bool(fi.any() and fj.any()) if met else not fj.any()

    positive_definite = jit(_positive_definite)  # finite, with a Cholesky factorization

    @jit
    def ci_prior(Pi: np.ndarray, Pj: np.ndarray, H: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, int]:
        """The pair's joint prior ``(2n, 2n)`` when the cross-covariance is unknown: ``blockdiag(Pi / w, Pj / (1 -
        w))``, which bounds the joint covariance for every ``w`` in (0, 1) and every cross-covariance (covariance
        intersection), ``w`` from :data:`CI_WEIGHTS` maximizing the smaller of the two robots' gains ``log det
        P_prior - log det P_post`` of the joint update (``H (m, 2n)``, ``R (m, m)``), flag 1 when both gain; else
        ``w`` maximizing the observer's own gain, flag 0 when it gains (it alone takes the update), -1 when not
        (the measurement is too weak to pay for the bound).

        The gains in measurement space (the matrix determinant lemma on each robot's block of the posterior), for
        every weight at once: with ``A = Hi Pi Hi^T``, ``B = Hj Pj Hj^T`` and ``S = A / w + B / (1 - w) + R``, the
        observer's gain is ``n log w + log det S - log det(B / (1 - w) + R)``, the target's ``n log(1 - w) + log det
        S - log det(A / w + R)``."""
        n = Pi.shape[0]
        Hi, Hj = np.ascontiguousarray(H[:, :n]), np.ascontiguousarray(H[:, n:])
        A = matmul(matmul(Hi, Pi), Hi.T)
        B = matmul(matmul(Hj, Pj), Hj.T)
        w = CI_WEIGHTS
        a, b, none = 1.0 / w, 1.0 / (1.0 - w), np.zeros(w.shape[0])
        ls = logdets(a, A, b, B, R)
        gi = n * np.log(w) + ls - logdets(none, A, b, B, R)
        gj = n * np.log(1.0 - w) + ls - logdets(a, A, none, B, R)
        ok_i = np.isfinite(gi)
        both = np.where(ok_i & np.isfinite(gj), np.minimum(gi, gj), -np.inf)
        kb, flag = np.argmax(both), 1
        if not both[kb] >= 0.0:
            own = np.where(ok_i, gi, -np.inf)
            kb = np.argmax(own)
            flag = 0 if own[kb] > 0.0 else -1
        P = np.zeros((2 * n, 2 * n))
        P[:n, :n] = Pi / CI_WEIGHTS[kb]
        P[n:, n:] = Pj / (1.0 - CI_WEIGHTS[kb])
        return P, flag

    @jit
    def pair_prior(Pi: np.ndarray, Pj: np.ndarray, fi: np.ndarray, fj: np.ndarray, met: bool, H: np.ndarray,
                   R: np.ndarray) -> tuple[np.ndarray, int]:  # fmt: skip
        """The pair's joint prior ``(6, 6)`` and whether both robots take the update (flag 1): with the tracked
        cross-covariance ``fi fj^T`` where the correlation is known (``tracked``) and the result positive definite,
        else bounded by covariance intersection (``ci_prior``, its flag)."""
        if tracked(fi, fj, met):
            P = np.zeros((6, 6))
            P[:3, :3] = Pi
            P[3:, 3:] = Pj
            Pij = matmul(fi, fj.T)
            P[:3, 3:] = Pij
            P[3:, :3] = Pij.T
            if positive_definite(P):
                return P, 1
        return ci_prior(Pi, Pj, H, R)

    out = ModuleType(f"{__name__}[{getattr(jit, '__name__', jit)}]")
    out.__dict__.update(sheared=sheared, rescaled=rescaled, tracked=tracked, positive_definite=positive_definite,
                        ci_prior=ci_prior, pair_prior=pair_prior)  # fmt: skip
    return out


PAIRS = build()
"""The pair functions as plain numpy (the nodes')."""
