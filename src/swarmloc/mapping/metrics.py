"""Map error against the true walls: end-point distances, Hausdorff distance, fraction of wall length covered."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["map_error", "point_segment_distance", "sample_segments"]


def point_segment_distance(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Distances [m] ``(n, L)`` from ``points`` ``(n, 2)`` to ``segments`` ``(L, 2, 2)``."""
    a = segments[None, :, 0]
    e = segments[None, :, 1] - a
    p = points[:, None, :] - a
    u = np.clip(np.einsum("nlj,nlj->nl", p, e) / np.einsum("nlj,nlj->nl", e, e), 0.0, 1.0)
    return np.linalg.norm(p - u[..., None] * e, axis=-1)


def sample_segments(segments: np.ndarray, step: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` [m] along ``segments`` ``(L, 2, 2)`` (end points included) and the index of the
    segment each came from."""
    pts, idx = [], []
    for i, (a, b) in enumerate(np.asarray(segments, dtype=float)):
        k = max(2, int(np.ceil(np.hypot(*(b - a)) / step)) + 1)
        pts.append(a + np.linspace(0, 1, k)[:, None] * (b - a))
        idx.append(np.full(k, i))
    if not pts:
        return np.zeros((0, 2)), np.zeros(0, dtype=int)
    return np.concatenate(pts), np.concatenate(idx)


def map_error(
    segments: np.ndarray,
    walls: np.ndarray,
    seen: np.ndarray | None = None,
    tol: float = 0.05,
    angle_tol: float = float(np.deg2rad(10.0)),
) -> dict[str, float]:
    """Errors of map ``segments`` ``(L, 2, 2)`` against true ``walls`` ``(W, 2, 2)`` [m]:

    * ``endpoint_mean``/``endpoint_max``: distance of each map end point to the nearest wall;
    * ``hausdorff``: the larger of the farthest map point from any wall and the farthest *seen* wall point from the
      map (``seen``: true points the sensors hit, ``(k, 2)``; wall points within 2 cm of one count as seen; all
      wall points when None);
    * ``covered``: fraction of the total wall length within ``tol`` [m] of a map segment within ``angle_tol``
      [rad] of the wall's direction; ``seen_fraction``: fraction of it that was seen (the most ``covered`` can be);
    * ``lines``: number of map segments.
    """
    segments = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    walls = np.asarray(walls, dtype=float)
    wp, wi = sample_segments(walls)
    seen_mask = np.ones(wp.shape[0], dtype=bool)
    if seen is not None:
        d, _ = cKDTree(np.asarray(seen, dtype=float)).query(wp, distance_upper_bound=0.02)
        seen_mask = np.isfinite(d)
    out = {"lines": float(segments.shape[0]), "seen_fraction": float(seen_mask.mean())}
    if segments.shape[0] == 0:
        return out | {"endpoint_mean": np.nan, "endpoint_max": np.nan, "hausdorff": np.nan, "covered": 0.0}
    ends = segments.reshape(-1, 2)
    de = point_segment_distance(ends, walls).min(axis=1)
    mp, _ = sample_segments(segments)
    h1 = point_segment_distance(mp, walls).min(axis=1).max()
    h2 = point_segment_distance(wp[seen_mask], segments).min(axis=1).max() if seen_mask.any() else 0.0
    dw = walls[:, 1] - walls[:, 0]
    ds = segments[:, 1] - segments[:, 0]
    cosang = np.abs(dw @ ds.T) / np.outer(np.linalg.norm(dw, axis=1), np.linalg.norm(ds, axis=1))
    parallel = cosang >= np.cos(angle_tol)  # (W, L)
    dist = point_segment_distance(wp, segments)  # (n, L)
    covered = ((dist <= tol) & parallel[wi]).any(axis=1)
    return out | {"endpoint_mean": float(de.mean()), "endpoint_max": float(de.max()), "hausdorff": float(max(h1, h2)),
                  "covered": float(covered.mean())}  # fmt: skip
