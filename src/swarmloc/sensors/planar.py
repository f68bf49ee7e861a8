"""The planar measurement models' math, written once on an array namespace ``xp``: predictions, Jacobians, the angle
wrap, the residuals ``z - h`` (angles wrapped) and the rotation that makes a relative pose's noise Cartesian.

:func:`build` makes the functions for ``xp`` and a compiler ``jit``. The nodes' batched models
(:mod:`swarmloc.sensors.models`) use them with ``numpy`` on arrays; the engine's compiled replays use them with
:mod:`swarmloc.engine.numba_xp` and ``numba.njit`` on the scalars of one detection
(:mod:`swarmloc.engine.formulas`' ``measure``); the fast EKF path (:mod:`swarmloc.engine.soa`) with ``numpy``,
``jax.numpy`` or the traced scalars of :mod:`swarmloc.engine.scalar`. So every form evaluates the same expressions
in the same order, and only its namespace's ``cos``, ``sin``, ``sqrt``, ``arctan2`` and ``mod`` differ.

The observer is at ``(x0, y0, th)`` in the world frame; a target robot at ``(xk, yk, thk)``, a point (a landmark, or
a robot seen as a point) at ``(px, py)``. A model returns ``(h, Hi, Hk)``: the prediction's entries, the rows of its
Jacobian with respect to the observer's state and with respect to the target's, as tuples of entries (an entry: an
array or a float of ``xp``, or a float constant). Measurements are in the observer's body frame (x forward, y left);
bearings and relative headings are wrapped to (-pi, pi]. Range and bearing divide by the range: the callers reject
a target within :data:`MIN_RANGE` of the observer (``degenerate``). Units: metres, radians.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cache
from types import ModuleType
from typing import Any, Protocol, TypeVar

MIN_RANGE = 1e-6
"""Predicted ranges [m] below this make the range and bearing models undefined (``degenerate`` of :func:`build`)."""

_PI = math.pi
_TAU = 2 * math.pi
_F = TypeVar("_F", bound=Callable[..., Any])


class Jit(Protocol):
    """A compiler of the functions: a function in, a function of the same signature out (``numba.njit``'s
    dispatcher, or the function itself)."""

    def __call__(self, fn: _F, /) -> _F: ...

    def __hash__(self) -> int: ...  # a key of the cache of :func:`build`


def plain(fn: _F) -> _F:
    """No compiler: the function itself (the numpy and jax forms)."""
    return fn


@cache
def build(xp: Any, jit: Jit = plain) -> ModuleType:
    """The planar models for namespace ``xp``, each compiled by ``jit``, as the attributes of a module object:
    ``wrap``, ``offset``, ``pose``, ``range_bearing``, ``pose_residual``, ``range_bearing_residual``, ``degenerate``,
    ``rotation`` (see the module docstring)."""

    @jit
    def wrap(a: Any) -> Any:
        """An angle [rad] wrapped to (-pi, pi]: ``pi - mod(pi - a, 2 pi)`` (:func:`swarmloc.lie.wrap_angle`)."""
        return _PI - xp.mod(_PI - a, _TAU)

    @jit
    def offset(x0: Any, y0: Any, th: Any, px: Any, py: Any) -> tuple[Any, Any, Any, Any, Any, Any]:
        """``(dx, dy, c, s, bx, by)``: the point's offset from the observer in the world frame ``(dx, dy)``, the
        observer's heading's ``(cos, sin)`` and the offset in the observer's frame ``(bx, by) = R(th)^T (dx, dy)``."""
        dx, dy = px - x0, py - y0
        c, s = xp.cos(th), xp.sin(th)
        return dx, dy, c, s, c * dx + s * dy, -s * dx + c * dy

    @jit
    def pose(x0: Any, y0: Any, th: Any, xk: Any, yk: Any, thk: Any) -> Any:
        """Pose of the robot at ``(xk, yk, thk)`` in the observer's frame, ``(R^T (p_k - p), thk - th)`` (thesis
        eqs. 2.6-2.9): ``h (3)``, ``Hi (3 x 3)``, ``Hk (3 x 3)``."""
        dx, dy, c, s, bx, by = offset(x0, y0, th, xk, yk)
        Hi = ((-c, -s, by), (s, -c, -bx), (0.0, 0.0, -1.0))
        Hk = ((c, s, 0.0), (-s, c, 0.0), (0.0, 0.0, 1.0))
        return (bx, by, wrap(thk - th)), Hi, Hk

    @jit
    def range_bearing(x0: Any, y0: Any, th: Any, px: Any, py: Any) -> Any:
        """Range [m] and bearing [rad] of the point at ``(px, py)`` (lecture slides 19, eqs. 3-4): ``h (2)``, ``Hi
        (2 x 3)``, ``Hk (2 x 2)`` (the point's position; a robot target's heading column is zero)."""
        dx, dy, c, s, bx, by = offset(x0, y0, th, px, py)
        q = dx * dx + dy * dy
        rng = xp.sqrt(q)
        Hi = ((-dx / rng, -dy / rng, 0.0), (dy / q, -dx / q, -1.0))
        Hk = ((dx / rng, dy / rng), (-dy / q, dx / q))
        return (rng, wrap(xp.arctan2(by, bx))), Hi, Hk

    @jit
    def pose_residual(z: Any, h: Any) -> tuple[Any, Any, Any]:
        """``z - h`` of a pose ``(x, y, theta)`` (a relative pose, or an absolute fix against the observer's own
        state), entries indexed ``z[0..2]``: ``(dx, dy, wrap(dtheta))``."""
        return z[0] - h[0], z[1] - h[1], wrap(z[2] - h[2])

    @jit
    def range_bearing_residual(z: Any, h: Any) -> tuple[Any, Any]:
        """``z - h`` of a range [m] and bearing [rad], entries indexed ``z[0..1]``: ``(dr, wrap(db))``. A range's
        residual is its first entry, a bearing's its second."""
        return z[0] - h[0], wrap(z[1] - h[1])

    @jit
    def degenerate(x0: Any, y0: Any, px: Any, py: Any) -> Any:
        """Whether the point at ``(px, py)`` is within :data:`MIN_RANGE` of the observer at ``(x0, y0)``, where its
        range and bearing are undefined: a detection the callers reject instead of fusing NaNs."""
        return xp.hypot(px - x0, py - y0) < MIN_RANGE

    @jit
    def rotation(a: Any) -> Any:
        """Rows of ``B(a) = [[cos a, -sin a, 0], [sin a, cos a, 0], [0, 0, 1]]``: with ``a`` a measured relative
        pose's heading, ``B R B^T`` is the Cartesian covariance of a pose noise ``R`` given on the exponential
        coordinates of ``m_true^-1 m_measured`` (right perturbation; first order)."""
        c, s = xp.cos(a), xp.sin(a)
        return (c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)

    out = ModuleType(f"{__name__}[{getattr(xp, '__name__', type(xp).__name__)}]")
    out.__dict__.update({k: v for k, v in locals().items() if k not in ("xp", "jit", "out")})
    return out
