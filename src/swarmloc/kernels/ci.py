"""Covariance intersection (Julier & Uhlmann 1997): the weight search, batched.

For an unknown correlation between a robot's belief ``Sigma_i`` and a neighbour's ``Sigma_k``,
``blockdiag(Sigma_i / w, Sigma_k / (1 - w))`` bounds their joint covariance for every ``w`` in ``(0, 1)``; the
measurement noise, independent of both, is fused as usual ("CI with independent measurement noise",
Carrillo-Arce et al., IROS 2013). The weight is chosen to minimize ``log det`` of the fused covariance.

:func:`ci_search` does that for a whole batch at once: a grid of weights is evaluated in one batched call of the
fusion, refined around the best point a few times, and finished by the vertex of the parabola through the best
grid point and its neighbours. With the defaults (9 points, 4 rounds) the weight is located to within
``(hi - lo) / 8 / 4**3 ~ 2e-3`` before the parabola, in 5 batched calls of the fusion.

:func:`point_weight` and :func:`pose_weight` choose the weight in closed form instead, from the fusion linearized
at the prior (one fusion at the chosen weight follows, instead of five or six batched ones). Any weight gives a
valid CI (the fused covariance bounds the error whatever the correlation); the linearized choice only makes it
slightly less tight where the update is strongly nonlinear. With ``J(w) = w A + H^T (R + C / (1 - w))^-1 H`` the
linearized posterior information (``A = Sigma_i^-1``; ``C`` the neighbour's covariance seen through the
measurement), the cost ``-log det J(w)`` is convex in ``w`` (``J`` is matrix-concave: a parallel sum, linear in
``1 - w``, plus ``w A``), so its minimum is found on a grid and refined by the parabola through the grid's best
point and its neighbours. The determinant lemma reduces it to ``m x m`` determinants for ``m`` measured values.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from swarmloc.arrays import BoolArray, FloatArray
from swarmloc.kernels import group as K
from swarmloc.lie import SE2
from swarmloc.lie.base import SEGroup

W_BOUNDS = (1e-3, 1 - 1e-3)
"""Range searched for the CI weight ``w`` of the robot's own belief."""

Fuse = Callable[[FloatArray], tuple[FloatArray, FloatArray]]
"""``fuse(w) -> (mean, cov)`` for weights ``w`` of shape ``(k, *batch)``; results have leading shape ``(k, *batch)``."""


def _cost(cov: FloatArray) -> FloatArray:
    sign, logdet = np.linalg.slogdet(cov)
    return np.where((sign > 0) & np.isfinite(logdet), logdet, np.inf)


def _vertex_shift(
    cost: FloatArray, j: NDArray[np.intp], idx: Any, step: FloatArray | float
) -> tuple[FloatArray, FloatArray]:
    """Offset from grid point ``j`` (the minimum over axis 0 of ``cost (grid, *batch)``, batch indices ``idx``) of
    the vertex of the parabola through it and its neighbours, clipped to one ``step`` (zero at the grid's ends and
    where the three costs are not finite or not convex); and the cost at ``j``."""
    grid = cost.shape[0]
    jm, jp = np.maximum(j - 1, 0), np.minimum(j + 1, grid - 1)
    c0, c1, c2 = cost[(jm, *idx)], cost[(j, *idx)], cost[(jp, *idx)]
    den = c0 - 2 * c1 + c2
    inner = (j > 0) & (j < grid - 1) & np.isfinite(c0 + c1 + c2) & (den > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.where(inner, 0.5 * step * (c0 - c2) / np.where(inner, den, 1.0), 0.0)
    return np.clip(shift, -step, step), c1


def ci_search(
    fuse: Fuse,
    batch_shape: tuple[int, ...] = (),
    bounds: tuple[float, float] = W_BOUNDS,
    grid: int = 9,
    rounds: int = 4,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Minimize ``log det`` of the fused covariance over the CI weight, for every batch element.

    Returns ``(mean, cov, w)`` at the chosen weight (shapes ``(*batch, ...)`` and ``batch``).
    """
    lo, hi = bounds
    a = np.full(batch_shape, lo)
    b = np.full(batch_shape, hi)
    u = np.linspace(0.0, 1.0, grid).reshape(grid, *([1] * len(batch_shape)))
    idx = np.indices(batch_shape) if batch_shape else ()
    for _ in range(rounds):
        ws = a + (b - a) * u  # (grid, *batch)
        _, cov = fuse(ws)
        cost = _cost(cov)
        j = np.argmin(cost, axis=0)
        step = (b - a) / (grid - 1)
        best = ws[(j, *idx)]
        a = np.maximum(lo, best - step)
        b = np.minimum(hi, best + step)
    shift, c1 = _vertex_shift(cost, j, idx, step)  # the parabola through the best point and its neighbours
    w = np.clip(best + shift, lo, hi)
    mean, cov = fuse(w[None])
    # never worse than the best grid point (the parabola can miss on a flat or kinked cost)
    worse = _cost(cov[0]) > c1
    if np.any(worse):
        w = np.where(worse, best, w)
        mean, cov = fuse(w[None])
    return mean[0], cov[0], w


WEIGHT_GRID = 129
"""Weights evaluated by :func:`point_weight` and :func:`pose_weight` before the parabola."""


def minimize_on_grid(cost: Callable[[FloatArray], FloatArray], batch_shape: tuple[int, ...],
                      bounds: tuple[float, float]) -> FloatArray:  # fmt: skip
    """The minimizer over ``bounds`` of a convex ``cost(w (g, *batch)) -> (g, *batch)``: grid, then the vertex of the
    parabola through the best grid point and its neighbours (within one grid step)."""
    lo, hi = bounds
    g = WEIGHT_GRID
    ws = np.linspace(lo, hi, g).reshape(g, *([1] * len(batch_shape)))
    with np.errstate(divide="ignore", invalid="ignore"):
        c = cost(np.broadcast_to(ws, (g, *batch_shape)))
    c = np.where(np.isfinite(c), c, np.inf)
    j = np.argmin(c, axis=0)
    idx = np.indices(batch_shape) if batch_shape else ()
    step = (hi - lo) / (g - 1)
    shift, _ = _vertex_shift(c, j, idx, step)
    best: FloatArray = np.clip(lo + step * j + shift, lo, hi)
    return best


def _logdet_small(S: FloatArray) -> FloatArray:
    """``log det`` of ``(..., m, m)`` matrices, ``m <= 2`` in closed form (NaN where not positive)."""
    m = S.shape[-1]
    if m == 1:
        d = S[..., 0, 0]
    elif m == 2:
        d = S[..., 0, 0] * S[..., 1, 1] - S[..., 0, 1] * S[..., 1, 0]
    else:
        d = np.linalg.det(S)
    return np.log(np.where(d > 0, d, np.nan))


def point_weight(
    mean: FloatArray,
    cov: FloatArray,
    kind: str,
    z: FloatArray,
    R: FloatArray,
    nb_mean: FloatArray,
    nb_cov: FloatArray,
    bounds: tuple[float, float] = W_BOUNDS,
) -> FloatArray:
    """CI weight of the robot's own belief for a range/bearing measurement ``z`` of a neighbour, batched: means
    ``(..., 3, 3)``, covariances ``(..., 3, 3)``, ``R (..., m, m)``; returns ``(...)``.

    Linearized at the prior (:func:`swarmloc.kernels.group.point_model`: ``H``, and ``C = H_k Sigma_k H_k^T``), the
    posterior ``log det`` is, up to a constant, ``-3 log w - log det(S_w + H Sigma_i H^T / w) + log det S_w`` with
    ``S_w = R + C / (1 - w)`` (the determinant lemma): ``m x m`` determinants only. ``z`` is not needed (the
    linearized covariance does not depend on it); it is accepted for symmetry with the fusion's call.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        _, H, C, _ = K.point_model(kind, mean, nb_mean, nb_cov, True)
    Gi = H @ cov @ np.swapaxes(H, -1, -2)
    R = np.asarray(R, dtype=float)
    batch = np.broadcast_shapes(Gi.shape[:-2], R.shape[:-2])

    return minimize_on_grid(_joint_cost(Gi, C, R, 3), batch, bounds)


def joint_weight(A: FloatArray, B: FloatArray, R: FloatArray, dof: int,
                 bounds: tuple[float, float] = W_BOUNDS) -> float:  # fmt: skip
    """CI weight for a measurement of a neighbour by one robot of a ``dof``-dimensional state (a cluster of robots
    whose joint covariance is bounded by ``Sigma / w``): ``A = H_i P_ii H_i^T`` and ``B = H_j P_jj H_j^T``
    (``m x m``, the two sides' uncertainty seen by the measurement), ``R`` its noise. Minimizes the posterior
    ``log det`` of the whole state, ``-dof log w - log det(S_w + A / w) + log det S_w`` with ``S_w = R + B / (1 - w)``
    (the determinant lemma, as :func:`point_weight` with ``dof = 3``): a large state pays ``dof log w`` for every
    inflation, so its weight stays near 1 unless the neighbour is worth it."""
    return float(minimize_on_grid(_joint_cost(A, B, R, dof), (), bounds))


def _joint_cost(A: FloatArray, B: FloatArray, R: FloatArray, dof: int) -> Callable[[FloatArray], FloatArray]:
    """``w -> -dof log w - log det(S_w + A / w) + log det S_w``, ``S_w = R + B / (1 - w)``: the posterior log det of
    a ``dof``-dimensional state, up to a constant, under the CI weight ``w`` (:func:`point_weight`,
    :func:`joint_weight`)."""

    def cost(w: FloatArray) -> FloatArray:
        wc = w[..., None, None]
        S = R + B / (1 - wc)
        return -dof * np.log(w) - _logdet_small(S + A / wc) + _logdet_small(S)

    return cost


def pose_weight(
    mean: FloatArray,
    cov: FloatArray,
    meas: FloatArray,
    R: FloatArray,
    nb_mean: FloatArray,
    nb_cov: FloatArray,
    order: int = 2,
    bounds: tuple[float, float] = W_BOUNDS,
    group: type[SEGroup] = SE2,
) -> FloatArray:
    """CI weight of the robot's own belief for a relative-pose measurement ``meas`` (``(..., 3, 3)``, noise
    covariance ``R``) of a neighbour, batched; returns ``(...)``. ``group``: SE2 (default) or SE3 (``meas``
    ``(..., 4, 4)``, covariances ``(..., 6, 6)``).

    The neighbour becomes a pseudo-observation of the robot's pose (:func:`swarmloc.kernels.group.relative_to_pseudo`)
    whose covariance is ``W(w) = W_R + W_k / (1 - w)`` (linear in the neighbour's covariance); linearized at the
    prior (``Gamma`` of the residual), the posterior ``log det`` is, up to a constant,
    ``log det W(w) - log det(I + w W(w) A')`` with ``A' = Gamma^-T Sigma_i^-1 Gamma^-1``.
    """
    nu, W1 = K.relative_to_pseudo(group, nb_mean, nb_cov, meas, R, order)
    _, W0 = K.relative_to_pseudo(group, nb_mean, np.zeros_like(np.asarray(nb_cov, dtype=float)), meas, R, order)
    Wk = W1 - W0
    x = group.log(group.inverse(nu, validate=False) @ mean, validate=False)
    Gi = np.linalg.inv(K.gamma(group, x, order))
    eye = np.eye(group.dim)
    A = np.swapaxes(Gi, -1, -2) @ np.linalg.inv(cov) @ Gi
    batch = A.shape[:-2]

    def cost(w: FloatArray) -> FloatArray:
        wc = w[..., None, None]
        W = W0 + Wk / (1 - wc)
        s1, l1 = np.linalg.slogdet(W)
        s2, l2 = np.linalg.slogdet(eye + wc * (W @ A))
        return np.where((s1 > 0) & (s2 > 0), l1 - l2, np.inf)

    return minimize_on_grid(cost, batch, bounds)


# ------------------------------------------------------------------------------------------------ the fusions
class Pair(NamedTuple):
    """A neighbour's detection to fuse by covariance intersection, batched over leading axes: the robots' beliefs
    ``(mean, cov)``, the measurements (a relative pose ``meas`` as a group matrix, or a range/bearing ``z``) and their
    noise ``R``, the neighbours' answers ``(nb_mean, nb_cov)``. The node makes one unbatched, the engine
    (:mod:`swarmloc.engine.fuse_ci`) stacks."""

    mean: FloatArray
    cov: FloatArray
    meas: FloatArray
    R: FloatArray
    nb_mean: FloatArray
    nb_cov: FloatArray


def pose_fusion(group: type[SEGroup], pair: Pair, order: int, iterations: int, w: Any = None
                ) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """Relative poses: one fusion of the neighbour's pseudo-observation (:func:`swarmloc.kernels.group.fuse_pseudo`)
    at the CI weight ``w``, by default the closed form (:func:`pose_weight`); a ``w`` with leading axes of its own
    ``(k, ...)`` fuses at each (:func:`ci_search`). Returns ``(mean, cov)``."""
    mean, cov, meas, R, nb_mean, nb_cov = pair
    wc = np.asarray(pose_weight(*pair, order, group=group) if w is None else w)[..., None, None]
    nu, W = K.relative_to_pseudo(group, nb_mean, nb_cov / (1 - wc), meas, R, order)
    mu = np.broadcast_to(mean, (*wc.shape[:-2], *np.shape(mean)[-2:]))
    return K.fuse_pseudo(group, mu, cov / wc, nu[..., None, :, :], W[..., None, :, :], order, iterations)


def point_fusion(kind: str, pair: Pair, point_iterations: int, order: int, w: Any = None
                 ) -> tuple[FloatArray, FloatArray, BoolArray]:  # fmt: skip
    """Range/bearing ``pair.meas`` of a robot on SE(2): the iterated point update
    (:func:`swarmloc.kernels.group.point_update`) at the CI weight ``w``, by default the closed form
    (:func:`point_weight`; a ``w (k, ...)`` as in :func:`pose_fusion`); returns ``(mean, cov, ok)``, ok False where
    degenerate."""
    mean, cov, z, R, nb_mean, nb_cov = pair
    z = np.asarray(z, dtype=float)
    wc = np.asarray(point_weight(mean, cov, kind, z, R, nb_mean, nb_cov) if w is None else w)[..., None, None]
    meas = K.PointMeasurement(kind, z, R, nb_mean, nb_cov / (1 - wc), True)
    return K.point_update(np.broadcast_to(mean, (*wc.shape[:-2], 3, 3)), cov / wc, meas, point_iterations, order)


def pose_fusion_at(pair: Pair, order: int, iterations: int) -> Fuse:
    """The relative-pose fusion on SE(2) at CI weights ``w (k, ...)``, for :func:`ci_search`."""
    return lambda w: pose_fusion(SE2, pair, order, iterations, w)


def point_fusion_at(kind: str, pair: Pair, point_iterations: int, order: int) -> Fuse:
    """The range/bearing point update at CI weights ``w (k, ...)``, for :func:`ci_search` (NaN covariance where
    degenerate)."""

    def fuse(w: FloatArray) -> tuple[FloatArray, FloatArray]:
        m2, c2, ok = point_fusion(kind, pair, point_iterations, order, w)
        return m2, np.where(np.asarray(ok)[..., None, None], c2, np.nan)

    return fuse
