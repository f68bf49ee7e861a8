"""Line extraction from one range scan: split-and-merge, a total-least-squares fit in ``(rho, alpha)``, and its
covariance from the range (and bearing) noise.

A line is ``{p : p . n(alpha) = rho}``, ``n(alpha) = (cos alpha, sin alpha)``, ``rho >= 0`` [m], ``alpha`` in
``(-pi, pi]`` [rad]; its tangent is ``t(alpha) = (-sin alpha, cos alpha)``. A segment adds its extent: the tangential
coordinates ``s = p . t`` of its end points.

Why no library: no maintained PyPI package extracts lines from 2-D scans with split-and-merge, and
``skimage.measure.ransac`` fits one model at a time (a sequential RANSAC on top of it, plus scikit-image as a new
dependency) and gives no covariance; the covariance needs the fit's per-point Jacobians (below) anyway.

**Fit.** The total-least-squares line through points ``p_i`` minimizes ``E = sum_i (n . p_i - rho)^2``: ``n`` is the
eigenvector of the scatter matrix with the smaller eigenvalue and ``rho = n . pbar``.

**Covariance** (first order; Arras and Siegwart 1997 in another form): the fit solves ``F(theta, p) = 0`` with
``theta = (rho, alpha)``, ``F1 = sum d_i``, ``F2 = sum d_i (t . p_i)``, ``d_i = n . p_i - rho``. Implicit
differentiation gives ``d theta / d p_i = -A^-1 B_i`` with ``A = [[-N, N t.pbar], [-N t.pbar, S_tt - sum d_i^2]]``,
``S_tt = sum (t . p_i)^2`` and ``B_i = [n^T; (t . p_i) n^T + d_i t^T]``; a point at range ``r_i`` and bearing
``phi_i`` has covariance ``sigma_r^2 u u^T + sigma_phi^2 r_i^2 v v^T`` (``u = (cos phi_i, sin phi_i)``,
``v = (-sin phi_i, cos phi_i)``), so ``C = sum_i J_i C_i J_i^T``. Checked against Monte Carlo in the tests.

**End points** (:func:`extract_lines`). A segment's end is *closed* when the scan shows where the wall ends, *open*
when the wall may go on unseen. Closed: a corner (the split point that two runs of split-and-merge share, where
two walls meet) or a jump edge (the next beam returns from *behind* the line: the wall ends between the two
beams; the end is then put half a beam spacing past the last point, the middle of where it can be). Open: the
scan's first or last beam, a next beam without a return (out of range, or a teammate), or one that returns from in
front of the line (an occluder hides the rest). Each end has a variance [m^2] along the line: the quantization of
one beam spacing ``d`` (uniform: ``d^2 / 12``) plus the range noise. :class:`~swarmloc.mapping.LineMap` averages
closed ends and extends open ones (union), instead of the union of all extents (the farthest of many noisy ends).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarmloc.gaussian import symmetric

__all__ = ["LineFit", "extract_lines", "fit_line", "split_and_merge"]


@dataclass(frozen=True)
class LineFit:
    """A fitted segment: ``rho`` [m], ``alpha`` [rad], ``cov`` ``(2, 2)`` of ``(rho, alpha)``, ``endpoints``
    ``(2, 2)`` [m] (the first and last points projected onto the line) and the number of points ``n``."""

    rho: float
    alpha: float
    cov: np.ndarray
    endpoints: np.ndarray
    n: int
    closed: tuple[bool, bool] = (False, False)
    end_var: tuple[float, float] = (0.0, 0.0)
    """Whether each end (first, last point in scan order) is where the wall ends, and its variance along the line
    [m^2] from the beam spacing and range noise (module docstring)."""


def normal_tangent(alpha: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """A line's unit normal ``(cos alpha, sin alpha)`` and tangent ``(-sin alpha, cos alpha)`` (``(..., 2)`` each)."""
    a = np.asarray(alpha, dtype=float)
    return np.stack([np.cos(a), np.sin(a)], -1), np.stack([-np.sin(a), np.cos(a)], -1)


def fit_line(r: np.ndarray, phi: np.ndarray, sigma_r: float, sigma_phi: float = 0.0) -> LineFit:
    """Total-least-squares line through the points at ranges ``r`` [m] and bearings ``phi`` [rad] (sensor frame),
    with the first-order covariance of ``(rho, alpha)`` for range noise std ``sigma_r`` [m] and bearing noise std
    ``sigma_phi`` [rad] (see the module docstring). Needs at least 2 finite points."""
    r = np.asarray(r, dtype=float)
    phi = np.asarray(phi, dtype=float)
    if r.shape != phi.shape or r.ndim != 1 or r.size < 2 or not (np.isfinite(r).all() and np.isfinite(phi).all()):
        raise ValueError("fit_line: r and phi must be finite 1-D arrays of equal length >= 2")
    u = np.stack([np.cos(phi), np.sin(phi)], -1)
    p = r[:, None] * u
    pbar = p.mean(axis=0)
    q = p - pbar
    _, vec = np.linalg.eigh(q.T @ q)
    n = vec[:, 0]
    rho = float(n @ pbar)
    if rho < 0:
        n, rho = -n, -rho
    alpha = float(np.arctan2(n[1], n[0]))
    t = np.array([-n[1], n[0]])
    N = r.size
    tp = p @ t
    d = p @ n - rho
    A = np.array([[-N, tp.sum()], [-tp.sum(), (tp**2).sum() - (d**2).sum()]])
    B = np.stack([np.broadcast_to(n, (N, 2)), tp[:, None] * n + d[:, None] * t], axis=1)  # (N, 2, 2)
    J = -np.linalg.solve(A, B)  # (N, 2, 2): d(rho, alpha) / d p_i
    v = np.stack([-u[:, 1], u[:, 0]], -1)
    Cp = (
        sigma_r**2 * u[:, :, None] * u[:, None, :] + (sigma_phi * r)[:, None, None] ** 2 * v[:, :, None] * v[:, None, :]
    )
    C = np.einsum("nij,njk,nlk->il", J, Cp, J)
    ends = rho * n + np.outer(tp[[0, -1]], t)
    return LineFit(rho, alpha, symmetric(C), ends, N)


def _split(p: np.ndarray, lo: int, hi: int, tol: float, out: list[tuple[int, int]]) -> None:
    """Recursive split of points ``p[lo:hi]`` at the farthest point from the chord while it is over ``tol``."""
    a, b = p[lo], p[hi - 1]
    e = b - a
    L = np.hypot(*e)
    if hi - lo <= 2 or L == 0:
        out.append((lo, hi))
        return
    dist = np.abs(e[0] * (p[lo:hi, 1] - a[1]) - e[1] * (p[lo:hi, 0] - a[0])) / L
    k = int(np.argmax(dist))
    if dist[k] <= tol or k in (0, hi - lo - 1):
        out.append((lo, hi))
        return
    _split(p, lo, lo + k + 1, tol, out)
    _split(p, lo + k, hi, tol, out)


def _max_residual(p: np.ndarray) -> float:
    q = p - p.mean(axis=0)
    _, vec = np.linalg.eigh(q.T @ q)
    return float(np.abs(q @ vec[:, 0]).max())


def split_and_merge(points: np.ndarray, tol: float = 0.03, max_gap: float = 0.2) -> list[tuple[int, int]]:
    """Index ranges ``[lo, hi)`` of collinear runs in ordered points ``(n, 2)`` [m] (NaN rows: no return).

    The scan is cut at missing returns and where consecutive points are more than ``max_gap`` [m] apart; each
    piece is split recursively at the point farthest from its chord while that is over ``tol`` [m]; neighbouring
    runs whose joint fit stays within ``tol`` are merged back."""
    ok = np.isfinite(points).all(axis=1)
    runs: list[tuple[int, int]] = []
    i, n = 0, points.shape[0]
    while i < n:
        if not ok[i]:
            i += 1
            continue
        j = i + 1
        while j < n and ok[j] and np.hypot(*(points[j] - points[j - 1])) <= max_gap:
            j += 1
        pieces: list[tuple[int, int]] = []
        _split(points, i, j, tol, pieces)
        merged = [pieces[0]]
        for lo, hi in pieces[1:]:
            plo, _ = merged[-1]
            if _max_residual(points[plo:hi]) <= tol:
                merged[-1] = (plo, hi)
            else:
                merged.append((lo, hi))
        runs += merged
        i = j
    return runs


def extract_lines(
    ranges: np.ndarray,
    angles: np.ndarray,
    sigma_r: float,
    *,
    sigma_phi: float = 0.0,
    tol: float | None = None,
    max_gap: float = 0.2,
    min_points: int = 6,
    min_length: float = 0.2,
) -> list[LineFit]:
    """The line segments of one scan (sensor frame): ranges ``(B,)`` [m] (NaN: no return) at beam ``angles``
    ``(B,)`` [rad]. Runs of split-and-merge (``tol`` default ``max(0.02, 4 sigma_r)`` m) with at least
    ``min_points`` points and ``min_length`` [m] are fitted with :func:`fit_line`."""
    ranges = np.asarray(ranges, dtype=float)
    angles = np.asarray(angles, dtype=float)
    if ranges.shape != angles.shape or ranges.ndim != 1:
        raise ValueError(f"extract_lines: ranges {ranges.shape} and angles {angles.shape} must be equal 1-D shapes")
    tol = max(0.02, 4 * sigma_r) if tol is None else tol
    pts = ranges[:, None] * np.stack([np.cos(angles), np.sin(angles)], -1)
    out = []
    runs = split_and_merge(pts, tol, max_gap)
    starts, stops = {lo for lo, _ in runs}, {hi - 1 for _, hi in runs}
    for lo, hi in runs:
        if hi - lo < min_points:
            continue
        f = fit_line(ranges[lo:hi], angles[lo:hi], sigma_r, sigma_phi)
        if np.hypot(*(f.endpoints[1] - f.endpoints[0])) >= min_length:
            out.append(_with_ends(f, pts, lo, hi, lo in stops, hi - 1 in starts, tol, sigma_r))
    return out


def _with_ends(f: LineFit, pts: np.ndarray, lo: int, hi: int, corner0: bool, corner1: bool, tol: float,
               sigma_r: float) -> LineFit:  # fmt: skip
    """``f`` with its ends classified (closed or open), jump-edge ends moved half a beam spacing outwards, and the
    ends' variances along the line (module docstring). ``corner0``/``corner1``: the end point is shared with the
    neighbouring run."""
    n, t = normal_tangent(f.alpha)
    ends = f.endpoints.copy()
    closed, var = [False, False], [0.0, 0.0]
    for e, (last, inner, nxt, corner) in enumerate(((lo, lo + 1, lo - 1, corner0), (hi - 1, hi - 2, hi, corner1))):
        d = float(np.hypot(*(pts[last] - pts[inner])))  # beam spacing at this end [m]
        var[e] = d * d / 12 + sigma_r**2
        if corner:
            closed[e] = True
        elif 0 <= nxt < pts.shape[0] and np.isfinite(pts[nxt]).all():
            u = pts[nxt] / np.hypot(*pts[nxt])
            cos_in = float(u @ n)  # the next beam meets the line at range rho / cos_in, if cos_in > 0
            behind = cos_in <= 0 or np.hypot(*pts[nxt]) > f.rho / cos_in + tol
            if behind:
                closed[e] = True
                out = 1.0 if (ends[e] - ends[1 - e]) @ t > 0 else -1.0
                ends[e] = ends[e] + 0.5 * d * out * t
    return LineFit(f.rho, f.alpha, f.cov, ends, f.n, (closed[0], closed[1]), (var[0], var[1]))
