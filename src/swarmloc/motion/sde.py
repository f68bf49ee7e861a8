"""Euler-Maruyama sampling of the body-twist SDE ``(g^-1 dg)^v = h dt + H dw`` on SE(2) (thesis 4.12, 5.1).

Geometric scheme: ``g_{k+1} = g_k exp((h(t_k) dt + H dw_k)^)`` with ``dw_k ~ N(0, dt I)``; it keeps every sample
exactly in SE(2) and, for constant ``h`` and ``H = 0``, reproduces ``g_0 exp(t h^)`` exactly.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, overload

import numpy as np

from swarmloc.lie import SE2

TwistFn = Callable[[float], np.ndarray]


@overload
def euler_maruyama(
    g0: np.ndarray, h: np.ndarray | TwistFn, H: np.ndarray, t: float, n_steps: int, n_paths: int,
    rng: np.random.Generator, return_path: Literal[False] = False
) -> np.ndarray: ...  # fmt: skip
@overload
def euler_maruyama(
    g0: np.ndarray, h: np.ndarray | TwistFn, H: np.ndarray, t: float, n_steps: int, n_paths: int,
    rng: np.random.Generator, return_path: Literal[True]
) -> tuple[np.ndarray, np.ndarray]: ...  # fmt: skip
def euler_maruyama(
    g0: np.ndarray,
    h: np.ndarray | TwistFn,
    H: np.ndarray,
    t: float,
    n_steps: int,
    n_paths: int,
    rng: np.random.Generator,
    return_path: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Sample ``n_paths`` solutions of the SDE on ``[0, t]`` with ``n_steps`` equal steps.

    ``g0``: start pose ``(3, 3)`` or ``(n_paths, 3, 3)``; ``h``: constant twist ``(3,)`` / ``(n_paths, 3)`` or a
    function of time returning one; ``H``: ``(3, m)`` noise matrix (per sqrt-second). Returns the final poses
    ``(n_paths, 3, 3)``; with ``return_path`` also the path ``(n_steps + 1, n_paths, 3, 3)`` (including ``g0``).
    Vectorized over paths; the only Python loop is over time steps.
    """
    H = np.asarray(H, dtype=float)
    if H.ndim != 2 or H.shape[0] != 3:
        raise ValueError(f"euler_maruyama: H must have shape (3, m), got {H.shape}")
    if n_steps < 1 or n_paths < 1:
        raise ValueError("euler_maruyama: n_steps and n_paths must be >= 1")
    dt = float(t) / n_steps
    sq = np.sqrt(dt)
    g0 = np.broadcast_to(np.asarray(g0, dtype=float), (n_paths, 3, 3))
    x, y = g0[:, 0, 2].copy(), g0[:, 1, 2].copy()
    th = np.arctan2(g0[:, 1, 0], g0[:, 0, 0])
    path = np.empty((n_steps + 1, 3, n_paths)) if return_path else None
    if path is not None:
        path[0] = x, y, th
    for k in range(n_steps):
        hk = h(k * dt) if callable(h) else h
        xi = np.asarray(hk, dtype=float) * dt + sq * _noise(rng.standard_normal((n_paths, H.shape[1])), H)
        x, y, th = compose_exp_xyt(x, y, th, xi)
        if path is not None:
            path[k + 1] = x, y, th
    g = SE2.from_xytheta(x, y, th)
    if path is not None:
        return g, SE2.from_xytheta(path[:, 0], path[:, 1], path[:, 2])
    return g


def _noise(dw: np.ndarray, H: np.ndarray) -> np.ndarray:
    """``dw @ H.T`` by einsum: a (n, 2) @ (2, 3) BLAS call can be ~50x slower under thread oversubscription."""
    return np.einsum("...k,ik->...i", dw, H)


def compose_exp_xyt(
    x: np.ndarray, y: np.ndarray, th: np.ndarray, xi: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(x, y, th) <- (x, y, th) exp(xi^)`` in Cartesian form (the same product as ``g @ SE2.exp(xi)``, cheaper).

    ``th`` is accumulated without wrapping. ``xi`` ``(..., 3)``; ``x, y, th`` broadcast with ``xi[..., 0]``.
    """
    v1, v2, a = xi[..., 0], xi[..., 1], xi[..., 2]
    A = np.sinc(a / np.pi)  # sin(a)/a, exact at 0
    hs = np.sinc(a / (2 * np.pi))
    B = 0.5 * a * hs * hs  # (1 - cos a)/a without cancellation
    dx = A * v1 - B * v2
    dy = B * v1 + A * v2
    c, s = np.cos(th), np.sin(th)
    return x + c * dx - s * dy, y + s * dx + c * dy, th + a
