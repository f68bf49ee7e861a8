"""The engine's formulas, written once: the numba replay loops and the JAX device stamp call the same functions.

:func:`build` makes them for an array namespace ``xp`` and a compiler ``jit``: with :mod:`swarmloc.engine.numba_xp`
and ``numba.njit`` they are scalar functions that numba compiles into the loops of :mod:`swarmloc.engine.joint`,
:mod:`~swarmloc.engine.pairs`, :mod:`~swarmloc.engine.joint_clusters` and :mod:`~swarmloc.engine.numba_ops`; with
``jax.numpy`` (no ``jit``: the stamp is jitted whole) they act elementwise inside :mod:`swarmloc.engine.jax_stamp`'s
device stamp; with ``numpy`` they screen a stamp's detections (:mod:`swarmloc.engine.outcomes`). Only the drivers
differ: loops that branch and write in place, or array code that selects (``where``) and returns new arrays.

A function here computes every branch it selects from (``xp.where``), as the array forms must: a value a branch does
not take may be ``inf`` or NaN and is dropped. The expressions are those the numba loops had (same operations, same
order), so the numba replays give the same bits as before. Decisions are *rules* in the order the nodes apply them:
:func:`rule` threads ``(outcome, reason, decided)`` through them, the first rule that holds deciding (codes of
:mod:`swarmloc.engine.codes`). Units: metres, radians, seconds; angles wrapped to (-pi, pi].
"""

from __future__ import annotations

import math
from functools import cache
from types import ModuleType
from typing import Any, TypeAlias

from swarmloc.engine.codes import (
    ABSOLUTE,
    GATED,
    NO_LANDMARK,
    POSE,
    R_LANDMARKS_OFF,
    R_NO_LANDMARK,
    R_NONFINITE,
    R_NOT_STARTED,
    R_OBSERVER,
    R_OFF,
    R_SELF,
    R_TEAM,
    R_UNUSABLE,
    REJECTED,
    UNKNOWN,
    UNKNOWN_ROBOT,
    UNUSABLE,
)
from swarmloc.events import Kind
from swarmloc.kernels.ci import W_BOUNDS, WEIGHT_GRID
from swarmloc.sensors import planar as planar_models
from swarmloc.sensors.models import KIND_ORDER
from swarmloc.sensors.planar import Jit, plain

RANGE_BEARING, RANGE, BEARING = KIND_ORDER[Kind.RANGE_BEARING], KIND_ORDER[Kind.RANGE], KIND_ORDER[Kind.BEARING]
_W_LO, _W_HI = W_BOUNDS
W_STEP = (_W_HI - _W_LO) / (WEIGHT_GRID - 1)
"""The spacing of the covariance-intersection weight's grid (:func:`swarmloc.kernels.ci.joint_weight`)."""


Value: TypeAlias = Any
"""A formula's value: a float, int or bool of one robot or detection in a numba loop, an array (elementwise) in
numpy or inside the jitted device stamp; numba's scalars and jax's arrays and tracers have no common type, so it is
not checked."""
Rules: TypeAlias = tuple[Value, Value, Value]
"""Decisions so far, ``(outcome, reason, decided)`` (:func:`rule`)."""
Vec3: TypeAlias = tuple[Value, Value, Value]
"""A pose ``(x, y, theta)``, a measurement's three entries, or a 3x3 matrix's row."""
Mat3: TypeAlias = tuple[Vec3, Vec3, Vec3]
"""A 3x3 matrix as rows of entries."""
Row6: TypeAlias = tuple[Value, Value, Value, Value, Value, Value]
"""A Jacobian row over the observer's and the target's pose, or a covariance's upper triangle."""


@cache
def build(xp: Any, jit: Jit = plain) -> ModuleType:
    """The formulas for namespace ``xp``, each compiled by ``jit`` (see the module docstring), as the attributes
    of a module object (numba compiles a module's attribute as it compiles a global of its own)."""
    out = ModuleType(f"{__name__}[{getattr(xp, '__name__', xp)}]")
    for part in (_decisions, _geometry, _weights):
        out.__dict__.update(part(xp, jit))
    return out


def _decisions(xp: Any, jit: Jit) -> dict[str, Any]:
    """The rules: screening before a state is read, the gate after an update."""

    @jit
    def rule(d: Rules, cond: Value, outcome: Value, reason: Value) -> Rules:
        """``d = (outcome, reason, decided)`` after one more rule: ``cond`` decides unless an earlier rule did."""
        st, why, done = d
        take = xp.logical_and(cond, xp.logical_not(done))
        return xp.where(take, outcome, st), xp.where(take, reason, why), xp.logical_or(done, cond)

    @jit
    def decided(d: Rules, otherwise: Value) -> tuple[Value, Value]:
        """``(outcome, reason)`` of the rules ``d``: the deciding rule's, or ``(otherwise, 0)``."""
        return xp.where(d[2], d[0], otherwise), xp.where(d[2], d[1], 0)

    @jit
    def landmark_rules(kind: Value, j: Value, lm_on: Value) -> Rules:
        """The replays' first rules: an absolute fix goes on; a landmark's detection (target code ``j <=
        NO_LANDMARK``) is refused with landmarks off, unknown when not in the map, else goes on."""
        lm = j <= NO_LANDMARK
        d = (0, 0, kind == ABSOLUTE)
        d = rule(d, xp.logical_and(lm, xp.logical_not(lm_on)), REJECTED, R_LANDMARKS_OFF)
        d = rule(d, j == NO_LANDMARK, UNKNOWN, R_NO_LANDMARK)
        return rule(d, lm, 0, 0)

    @jit
    def screen_central(kind: Value, i: Value, j: Value, relative: Value, lm_on: Value) -> tuple[Value, Value]:
        """``(outcome, reason)`` a centralized node decides before reading a state (``(0, 0)``: go on), its
        ``_classify`` as codes: observer ``i``, target code ``j``."""
        d = landmark_rules(kind, j, lm_on)
        d = rule(d, j == UNKNOWN_ROBOT, xp.where(relative, UNKNOWN, REJECTED), xp.where(relative, R_TEAM, R_OFF))
        d = rule(d, j < 0, REJECTED, R_UNUSABLE)
        d = rule(d, xp.logical_not(relative), REJECTED, R_OFF)
        d = rule(d, j == i, REJECTED, R_SELF)
        return d[0], d[1]

    @jit
    def screen_started(kind: Value, i: Value, j: Value, t: Value, t0: Value, relative: Value,
                       lm_on: Value) -> tuple[Value, Value]:  # fmt: skip
        """As :func:`screen_central` for the distributed nodes (:meth:`~swarmloc.node.base.Node._classify`): a
        teammate answers only from its start ``t0[j]`` [s] on (``t0`` every robot's)."""
        started = t >= t0[xp.maximum(j, 0)]
        d = landmark_rules(kind, j, lm_on)
        d = rule(d, j == UNUSABLE, REJECTED, R_UNUSABLE)  # worded from the detection by the caller
        d = rule(d, xp.logical_not(relative), REJECTED, R_OFF)
        d = rule(d, j == UNKNOWN_ROBOT, UNKNOWN, R_TEAM)
        d = rule(d, j == i, REJECTED, R_SELF)
        d = rule(d, xp.logical_not(started), UNKNOWN, R_NOT_STARTED)
        return d[0], d[1]

    @jit
    def screen_stamp(kind: Value, i: Value, j: Value, observer_on: Value, target_on: Value, relative: Value,
                     lm_on: Value) -> tuple[Value, Value, Value]:  # fmt: skip
        """The engine's screening of one detection of a stamp (:func:`swarmloc.engine.outcomes.screen`):
        ``(outcome, reason, needs)``, ``needs`` whether it is pending and asks robot ``j`` for its state;
        ``observer_on``, ``target_on``: whether the observer and (a robot) target have started."""
        lm = xp.logical_and(j <= NO_LANDMARK, kind != ABSOLUTE)
        robot = xp.logical_and(kind != ABSOLUTE, xp.logical_not(lm))
        d = (0, 0, False)
        d = rule(d, xp.logical_not(observer_on), REJECTED, R_OBSERVER)
        d = rule(d, xp.logical_and(robot, xp.logical_not(relative)), REJECTED, R_OFF)
        d = rule(d, xp.logical_and(lm, xp.logical_not(lm_on)), REJECTED, R_LANDMARKS_OFF)
        d = rule(d, xp.logical_and(lm, j == NO_LANDMARK), UNKNOWN, R_NO_LANDMARK)
        d = rule(d, xp.logical_and(lm, kind == POSE), REJECTED, R_UNUSABLE)  # a point has no heading
        d = rule(d, xp.logical_and(robot, j == UNUSABLE), REJECTED, R_UNUSABLE)
        d = rule(d, xp.logical_and(robot, j == i), REJECTED, R_SELF)
        d = rule(d, xp.logical_and(robot, j < 0), UNKNOWN, R_TEAM)
        d = rule(d, xp.logical_and(robot, xp.logical_not(target_on)), UNKNOWN, R_NOT_STARTED)
        return d[0], d[1], xp.logical_and(robot, xp.logical_not(d[2]))

    @jit
    def gate_rules(d: Rules, nis: Value, threshold: Value, gate: Value) -> Rules:
        """The gate's rules after an update (:func:`swarmloc.node.update.gated_kalman`): with the gate on, a
        non-finite normalized innovation squared ``nis`` is rejected, one above ``threshold`` gated."""
        d = rule(d, xp.logical_and(gate, xp.logical_not(xp.isfinite(nis))), REJECTED, R_NONFINITE)
        return rule(d, xp.logical_and(gate, nis > threshold), GATED, 0)

    return {k: v for k, v in locals().items() if k not in ("xp", "jit")}


def _geometry(xp: Any, jit: Jit) -> dict[str, Any]:
    """Angles, measurements, the invariant filters' noise and correction."""

    planar = planar_models.build(xp, jit)
    wrap = planar.wrap  # an angle [rad] wrapped to (-pi, pi] (:func:`swarmloc.lie.wrap_angle`)
    pose, range_bearing, rotation, degenerate = planar.pose, planar.range_bearing, planar.rotation, planar.degenerate
    pose_residual, range_bearing_residual = planar.pose_residual, planar.range_bearing_residual

    @jit
    def pick6(c: Value, a: Row6, b: Row6) -> Row6:
        return (xp.where(c, a[0], b[0]), xp.where(c, a[1], b[1]), xp.where(c, a[2], b[2]), xp.where(c, a[3], b[3]),
                xp.where(c, a[4], b[4]), xp.where(c, a[5], b[5]))  # fmt: skip

    @jit
    def measure(kind: Value, x0: Value, y0: Value, th: Value, xk: Vec3, z: Vec3) -> tuple[Vec3, tuple[Row6, Row6, Row6],
                                                                                            Mat3]:  # fmt: skip
        """Residual ``r (3)``, Jacobian rows ``H (3 x 6)`` (the observer's columns, then the target's) and the rows of
        the rotation ``B(z)`` that makes a relative pose's noise Cartesian, of a detection of ``kind`` by the robot at
        ``(x0, y0, th)`` of a target at ``xk = (x, y, theta)``, measured ``z``: the models of
        :mod:`swarmloc.sensors.planar` and their residuals, selected by ``kind``. A 1- or 2-row measurement (range,
        bearing; range-bearing) fills the first rows, the rest zero."""
        (bx, by, heading), Hp, Hq = pose(x0, y0, th, xk[0], xk[1], xk[2])
        (rng, look), (hr, hb), (kr, kb) = range_bearing(x0, y0, th, xk[0], xk[1])
        h_rng = (hr[0], hr[1], hr[2], kr[0], kr[1], 0.0)
        h_brg = (hb[0], hb[1], hb[2], kb[0], kb[1], 0.0)
        zero = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        is_abs, is_pose, is_rb = kind == ABSOLUTE, kind == POSE, kind == RANGE_BEARING
        one = pick6(kind == RANGE, h_rng, h_brg)  # a 1-row measurement's row
        h0 = pick6(is_abs, (1.0, 0.0, 0.0, 0.0, 0.0, 0.0), pick6(is_pose, (*Hp[0], *Hq[0]), pick6(is_rb, h_rng, one)))
        h1 = pick6(is_abs, (0.0, 1.0, 0.0, 0.0, 0.0, 0.0), pick6(is_pose, (*Hp[1], *Hq[1]), pick6(is_rb, h_brg, zero)))
        h2 = pick6(is_abs, (0.0, 0.0, 1.0, 0.0, 0.0, 0.0), pick6(is_pose, (*Hp[2], *Hq[2]), zero))
        ra, rp = pose_residual(z, (x0, y0, th)), pose_residual(z, (bx, by, heading))  # an absolute fix's, a pose's
        # a range-bearing's and a range's (its first entry); a bearing's: the bearing entry of (range, z[0])
        rr, rb = range_bearing_residual(z, (rng, look)), range_bearing_residual((rng, z[0]), (rng, look))[1]
        r0 = xp.where(is_abs, ra[0], xp.where(is_pose, rp[0], xp.where(kind == BEARING, rb, rr[0])))
        r1 = xp.where(is_abs, ra[1], xp.where(is_pose, rp[1], xp.where(is_rb, rr[1], 0.0)))
        r2 = xp.where(is_abs, ra[2], xp.where(is_pose, rp[2], 0.0))
        return (r0, r1, r2), (h0, h1, h2), rotation(z[2])

    @jit
    def world_noise(x: Value, y: Value, q: Row6) -> Row6:
        """A step's Cartesian process noise (upper triangle ``q00, q01, q02, q11, q12, q22``) at the new pose ``(x,
        y)`` as the world-frame error's, ``N^-1 Q N^-T`` (:func:`swarmloc.kernels.invariant.cartesian_to_world_cov`;
        the products of :class:`swarmloc.estimators.InvariantEKF`'s prediction), upper triangle."""
        q00, q01, q02, q11, q12, q22 = q
        a02, a12 = q02 + y * q22, q12 - x * q22
        return (q00 + 2 * y * q02 + y * y * q22, q01 - x * q02 + y * a12, a02, q11 - 2 * x * q12 + x * x * q22, a12,
                q22)  # fmt: skip

    @jit
    def left_correct(x: Value, y: Value, th: Value, d0: Value, d1: Value, d2: Value) -> Vec3:
        """The pose ``(x, y, th)`` corrected by its world-frame ``(d0, d1, d2)``: the Cartesian pose of ``exp(hat(d))
        g`` (:func:`swarmloc.kernels.invariant.left_correct`; the Taylor branches of :func:`swarmloc.lie.SE2.exp`
        below 0.05)."""
        c, s = xp.cos(d2), xp.sin(d2)
        t2 = d2 * d2
        near = xp.abs(d2) < 0.05
        safe = xp.where(near, 1.0, d2)
        A = xp.where(near, (((t2 / 362880.0 - 1.0 / 5040.0) * t2 + 1.0 / 120.0) * t2 - 1.0 / 6.0) * t2 + 1.0,
                     xp.sin(safe) / safe)  # fmt: skip
        B = xp.where(near, d2 * ((((t2 / 3628800.0 - 1.0 / 40320.0) * t2 + 1.0 / 720.0) * t2 - 1.0 / 24.0) * t2 + 0.5),
                     safe * (2.0 * xp.sin(safe / 2) ** 2 / (safe * safe)))  # fmt: skip
        ct, st = xp.cos(th), xp.sin(th)
        return (c * x - s * y + (A * d0 - B * d1), s * x + c * y + (B * d0 + A * d1),
                wrap(xp.arctan2(s * ct + c * st, c * ct - s * st)))  # fmt: skip

    return {k: v for k, v in locals().items() if k not in ("xp", "jit", "planar")}


def _weights(xp: Any, jit: Jit) -> dict[str, Any]:
    """Covariance intersection's weight: its cost on a grid and the refinement of the best point."""

    @jit
    def det3(s: Mat3) -> Value:
        """Determinant of the 3x3 ``s`` (rows of entries) by cofactors of the first row."""
        return (s[0][0] * (s[1][1] * s[2][2] - s[1][2] * s[2][1]) - s[0][1] * (s[1][0] * s[2][2] - s[1][2] * s[2][0])
                + s[0][2] * (s[1][0] * s[2][1] - s[1][1] * s[2][0]))  # fmt: skip

    @jit
    def plus(X: Mat3, Y: Mat3, k: Value) -> Mat3:
        """``X + Y / k`` of 3x3 rows of entries."""
        return ((X[0][0] + Y[0][0] / k, X[0][1] + Y[0][1] / k, X[0][2] + Y[0][2] / k),
                (X[1][0] + Y[1][0] / k, X[1][1] + Y[1][1] / k, X[1][2] + Y[1][2] / k),
                (X[2][0] + Y[2][0] / k, X[2][1] + Y[2][1] / k, X[2][2] + Y[2][2] / k))  # fmt: skip

    @jit
    def ci_cost(w: Value, A: Mat3, B: Mat3, R: Mat3, dof: Value) -> Value:
        """The cost :func:`swarmloc.kernels.ci.joint_weight` minimizes at weight ``w``, ``-dof log w - log det(S_w +
        A / w) + log det S_w`` with ``S_w = R + B / (1 - w)`` (3x3 rows of entries; a 1- or 2-row measurement padded
        with rows of the identity in ``R``, of zeros in ``A`` and ``B``: they add ``log 1``), ``inf`` where not
        finite."""
        S = plus(R, B, 1 - w)
        d1, d0 = det3(plus(S, A, w)), det3(S)
        v = -dof * xp.log(w) - xp.log(xp.where(d1 > 0, d1, math.nan)) + xp.log(xp.where(d0 > 0, d0, math.nan))
        return xp.where(xp.isfinite(v), v, math.inf)

    @jit
    def ci_grid(k: Value) -> Value:
        """Point ``k`` of the weight's grid (``numpy.linspace``'s)."""
        return xp.where(k == WEIGHT_GRID - 1, _W_HI, k * W_STEP + _W_LO)

    @jit
    def ci_vertex(j: Value, c0: Value, c1: Value, c2: Value) -> Value:
        """The weight from the grid's best point ``j`` and its neighbours' costs ``c0, c1, c2``: the vertex of their
        parabola, within one grid step, inside the bounds."""
        den = c0 - 2 * c1 + c2
        inner = xp.logical_and(xp.logical_and(xp.logical_and(j > 0, j < WEIGHT_GRID - 1), xp.isfinite(c0 + c1 + c2)),
                               den > 0)  # fmt: skip
        shift = xp.where(inner, xp.minimum(xp.maximum(0.5 * W_STEP * (c0 - c2) / xp.where(inner, den, 1.0), -W_STEP),
                                           W_STEP), 0.0)  # fmt: skip
        return xp.minimum(xp.maximum(_W_LO + W_STEP * j + shift, _W_LO), _W_HI)

    return {k: v for k, v in locals().items() if k not in ("xp", "jit")}
