"""The compiled replays' block math, written once: a pose's shear on the rows and columns of a covariance, the
world-frame Jacobian column, the 3x3 inverse, the degenerate-geometry rule.

Scalar functions that numba compiles into the loops of :mod:`swarmloc.engine.joint`, :mod:`~swarmloc.engine.pairs`
and :mod:`~swarmloc.engine.joint_clusters` (through :mod:`~swarmloc.engine.joint_math`), written on
:mod:`swarmloc.engine.numba_xp` as :mod:`swarmloc.engine.formulas` is: a selection computes both values
(``xp.where``). A matrix is a tuple of rows of entries. Units: metres, radians.
"""

from __future__ import annotations

from typing import Any

from numba import njit

from swarmloc.engine import numba_xp as xp
from swarmloc.events import Kind
from swarmloc.sensors import planar
from swarmloc.sensors.models import KIND_ORDER

_RANGE_BEARING = KIND_ORDER[Kind.RANGE_BEARING]
Row = tuple[float, float, float]
"""A row of a 3x3 matrix: its entries."""
Mat = tuple[Row, Row, Row]
"""A 3x3 matrix as its rows."""


def _compile(fn: Any) -> Any:
    return njit(error_model="numpy")(fn)


@_compile
def moved(x0: Any, y0: Any, x1: Any, y1: Any) -> tuple[Any, Any]:
    """The shear ``(a, b)`` a prediction from ``(x0, y0)`` to ``(x1, y1)`` puts on a pose's covariance (its
    Jacobian's heading column): ``(-(y1 - y0), x1 - x0)``."""
    return -(y1 - y0), x1 - x0


@_compile
def shear(r0: Any, r1: Any, r2: Any, a: Any, b: Any) -> tuple[Any, Any]:
    """Rows (or columns) ``r0, r1`` of a pose's block after the shear ``(a, b)``: ``(r0 + a r2, r1 + b r2)``;
    ``r2`` (the heading's) is unchanged."""
    return r0 + a * r2, r1 + b * r2


@_compile
def sheared(M: Mat, a: Any, b: Any) -> Mat:
    """The 3x3 ``M`` sheared on both sides, ``A M A^T`` with ``A = [[1, 0, a], [0, 1, b], [0, 0, 1]]``: its rows
    (:func:`shear`), then its columns."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = M
    (r00, r10), (r01, r11), (r02, r12) = shear(m00, m10, m20, a, b), shear(m01, m11, m21, a, b), \
        shear(m02, m12, m22, a, b)  # fmt: skip
    c0, c1, c2 = shear(r00, r01, r02, a, b), shear(r10, r11, r12, a, b), shear(m20, m21, m22, a, b)
    return (c0[0], c0[1], r02), (c1[0], c1[1], r12), (c2[0], c2[1], m22)


@_compile
def _pick(c: Any, s: Row, m: Row) -> Row:
    return xp.where(c, s[0], m[0]), xp.where(c, s[1], m[1]), xp.where(c, s[2], m[2])


@_compile
def _pick3(c: Any, S: Mat, M: Mat) -> Mat:
    """``S`` where ``c``, else ``M`` (3x3)."""
    return _pick(c, S[0], M[0]), _pick(c, S[1], M[1]), _pick(c, S[2], M[2])


@_compile
def predicted_block(M: Mat, a: Any, b: Any, u: tuple[Any, ...]) -> Mat:
    """A pose's 3x3 block ``M`` after its pending prediction: sheared by ``(a, b)`` (:func:`sheared`; skipped
    when both are zero, as the invariant filters' predictions are) and given the noise ``u`` (upper triangle
    ``u00, u01, u02, u11, u12, u22``)."""
    go = xp.logical_or(a != 0.0, b != 0.0)
    S = sheared(M, a, b)
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = _pick3(go, S, M)
    return ((m00 + u[0], m01 + u[1], m02 + u[2]), (m10 + u[1], m11 + u[3], m12 + u[4]),
            (m20 + u[2], m21 + u[4], m22 + u[5]))  # fmt: skip


@_compile
def to_world(h0: Any, h1: Any, h2: Any, x: Any, y: Any) -> Any:
    """A Jacobian row's heading entry ``h2`` of a pose at ``(x, y)`` made its world-frame error's (``H N``, ``N =
    [[1, 0, -y], [0, 1, x], [0, 0, 1]]``: :func:`swarmloc.kernels.invariant.world_basis`)."""
    return h2 + (-y * h0 + x * h1)


_near = planar.build(xp, _compile).degenerate


@_compile
def degenerate(kind: Any, x0: Any, y0: Any, x1: Any, y1: Any) -> Any:
    """Whether a detection of ``kind`` by the robot at ``(x0, y0)`` of a target at ``(x1, y1)`` is refused as
    degenerate: a range or a bearing (range-bearing, range, bearing) of a point where it is undefined
    (:mod:`swarmloc.sensors.planar`'s ``degenerate``)."""
    return xp.logical_and(kind >= _RANGE_BEARING, _near(x0, y0, x1, y1))
