"""The engine's fast EKF path compiled with numba (backend ``"numba"``, optional: ``pip install numba``).

The per-robot functions are the formulas of :mod:`swarmloc.engine.soa` turned into straight-line scalar code
(:mod:`swarmloc.engine.scalar`) and compiled by numba, so the three fast backends share one formula source. Around
them, loops over robots (``numba.prange``: ``NUMBA_NUM_THREADS`` threads), and the kernels that screen and fuse a
stamp's pose, absolute and range-bearing detections in place: :meth:`NumbaOps.fuse_serial` in canonical order on
one thread, :meth:`NumbaOps.fuse_levels` level by level (the Gauss-Seidel levels of :mod:`swarmloc.engine.stamp`),
the groups of one level in parallel; both from one template (``_SCREEN``, ``_FUSE``). Compiled once per process
(a few seconds): the noise model's coefficients are an argument (``qn``), not constants compiled in. Units: m, rad, s.
"""

from __future__ import annotations

import math
import textwrap
from functools import cache
from typing import Any, TypeAlias

import numpy as np
from numba import get_num_threads, njit, prange

from swarmloc.arrays import BoolArray, FloatArray, IntArray
from swarmloc.engine.codes import (
    ABSOLUTE,
    FUSED,
    GATED,
    NO_LANDMARK,
    PENDING,
    POSE,
    R_DEGENERATE,
    R_NONFINITE,
    R_NUMERICAL,
    REJECTED,
)
from swarmloc.engine.detections import Detections, Timeline
from swarmloc.engine.joint_math import F
from swarmloc.engine.replay_io import constants, noise_tuple
from swarmloc.engine.scalar import absolute_source, landmark_source, pose_source, predict_source
from swarmloc.events import Kind
from swarmloc.motion import UnicycleNoise
from swarmloc.node.update import Gate
from swarmloc.sensors.models import KIND_ORDER

Rows: TypeAlias = tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]
"""The engine's arrays a compiled stamp updates in place: ``(x (n, 3), P (n, 3, 3), clock, start, v, w (n,))``."""
Updated: TypeAlias = tuple[FloatArray, FloatArray, FloatArray, BoolArray, BoolArray]
"""A batch of updates: ``(x+, P+, nis, ok, positive definite)`` (the kernels' ``ok`` is both flags)."""


_UP = "{a}[{i}, 0, 0], {a}[{i}, 0, 1], {a}[{i}, 0, 2], {a}[{i}, 1, 1], {a}[{i}, 1, 2], {a}[{i}, 2, 2]"
_X = "{a}[{i}, 0], {a}[{i}, 1], {a}[{i}, 2]"
_UP2 = "{a}[{i}, 0, 0], {a}[{i}, 0, 1], {a}[{i}, 1, 1]"
_X2 = "{a}[{i}, 0], {a}[{i}, 1]"


def _args(a: str, i: str, up: bool = False, two: bool = False) -> str:
    return ((_UP2 if up else _X2) if two else (_UP if up else _X)).format(a=a, i=i)


_XP = f"{_args('x', 'i')}, {_args('P', 'i', True)}"


_STORE = """
{o}[{i}, 0] = r[0]
{o}[{i}, 1] = r[1]
{o}[{i}, 2] = r[2]
{oP}[{i}, 0, 0] = r[3]
{oP}[{i}, 0, 1] = r[4]
{oP}[{i}, 1, 0] = r[4]
{oP}[{i}, 0, 2] = r[5]
{oP}[{i}, 2, 0] = r[5]
{oP}[{i}, 1, 1] = r[6]
{oP}[{i}, 1, 2] = r[7]
{oP}[{i}, 2, 1] = r[7]
{oP}[{i}, 2, 2] = r[8]"""


def _store(o: str, oP: str, i: str, indent: int) -> str:
    pad = " " * indent
    return "\n".join(pad + line for line in _STORE.format(o=o, oP=oP, i=i).strip().splitlines())


def _advance(indent: int) -> str:
    """Code moving robot ``i`` to ``t`` in place when its clock ``tc[i]`` is behind: predicted, stored, clock set."""
    code = f"""if tc[i] < t:
    r = predict({_XP}, v[i], w[i], t - tc[i], qn)
{_store("x", "P", "i", 4)}
    tc[i] = t"""
    return textwrap.indent(code, " " * indent)


def _map_landmark(target: str, indent: int) -> str:
    """Code of a map landmark's range-bearing update of observer ``i`` (detection ``q``, target code ``target``):
    rejected as degenerate at the landmark's position, else ``r`` the landmark kernel's result."""
    lines = [
        f"k = {NO_LANDMARK} - 1 - {target}",
        "if degenerate(x[i, 0], x[i, 1], lxy[k, 0], lxy[k, 1]):",
        f"    status[q] = {REJECTED}",
        f"    reason[q] = {R_DEGENERATE}",
        "    continue",
        f"r = landmark({_args('x', 'i')}, {_args('P', 'i', True)}, {_args('lxy', 'k', two=True)}, "
        f"{_args('lcov', 'k', True, True)}, z[q, 0], z[q, 1], R[q, 0, 0], R[q, 0, 1], R[q, 1, 1])",
    ]
    return "\n".join(" " * indent + line for line in lines)


RANGE_BEARING = KIND_ORDER[Kind.RANGE_BEARING]


_KINDS = f"""
    for q in range(m):
        if kind[q] != {RANGE_BEARING} and (kind[q] != {ABSOLUTE} and kind[q] != {POSE} or tgt[q] <= {NO_LANDMARK}):
            return -1  # another kind (or a pose of a landmark code): nothing done; the caller takes the general path
"""[1:-1]
"""Template of the in-place kernels: a stamp with a detection of a kind they do not take is left to the caller."""

_SCREEN = f"""
        i = obs[q]
        j = tgt[q]  # screen_stamp(): the checks before any fusion, in their order
        status[q], reason[q], needs = screen_stamp(kind[q], i, j, t >= t0[i], t >= t0[min(max(j, 0), n - 1)],
                                                   relative, lm_on)
        if not t >= t0[i]:
            continue
        at_lm = j <= {NO_LANDMARK}  # a landmark's range-bearing (kinds checked above)
        robot = kind[q] != {ABSOLUTE} and not at_lm
{_advance(8)}
        if lev[i] < 0:
            lev[i] = 0
        if needs and j < i and lev[j] >= 0 and lev[j] + 1 > lev[i]:
            lev[i] = lev[j] + 1
        if lev[i] > top:
            top = lev[i]"""[1:]
"""Template of the in-place kernels (loop over rows ``q``): row ``q`` screened by
:func:`swarmloc.engine.formulas.screen_stamp` (as :func:`swarmloc.engine.outcomes.screen` does), its observer ``i``
moved to ``t`` and stored, its level (``lev``)."""

_FUSE = f"""
        if at_lm:
{_map_landmark("j", 12)}
        elif not robot:
            r = absolute({_args("x", "i")}, {_args("P", "i", True)}, {_args("z", "q")}, {_args("R", "q", True)})
        elif kind[q] == {RANGE_BEARING}:  # a robot's: its position and covariance as an uncertain landmark's
            if tc[j] < t:  # (answered as below: predicted, not stored, when it has no input at t)
                a = predict({_args("nx", "j")}, {_args("nP", "j", True)}, v[j], w[j], t - tc[j], qn)
                a0, a1, c00, c01, c11 = a[0], a[1], a[3], a[4], a[6]
            else:
                a0, a1, c00, c01, c11 = nx[j, 0], nx[j, 1], nP[j, 0, 0], nP[j, 0, 1], nP[j, 1, 1]
            if degenerate(x[i, 0], x[i, 1], a0, a1):
                status[q] = {REJECTED}
                reason[q] = {R_DEGENERATE}
                continue
            r = landmark({_args("x", "i")}, {_args("P", "i", True)}, a0, a1, c00, c01, c11, z[q, 0], z[q, 1],
                         R[q, 0, 0], R[q, 0, 1], R[q, 1, 1])
        elif tc[j] < t:  # a neighbour without input at t: its answer predicted, not stored
            k = predict({_args("nx", "j")}, {_args("nP", "j", True)}, v[j], w[j], t - tc[j], qn)
            r = pose({_args("x", "i")}, {_args("P", "i", True)}, k[0], k[1], k[2], k[3], k[4], k[5], k[6], k[7],
                     k[8], {_args("z", "q")}, {_args("R", "q", True)})
        else:  # j < i: after its own group at t; j > i: before its group (Gauss-Seidel, as the nodes)
            r = pose({_args("x", "i")}, {_args("P", "i", True)}, {_args("nx", "j")}, {_args("nP", "j", True)},
                     {_args("z", "q")}, {_args("R", "q", True)})
        if gate:
            if not math.isfinite(r[9]):
                status[q] = {REJECTED}
                reason[q] = {R_NONFINITE}
                continue
            if r[9] > thr[kind[q]]:
                status[q] = {GATED}
                continue
        if not r[10]:
            status[q] = {REJECTED}
            reason[q] = {R_NUMERICAL}
            continue
{_store("x", "P", "i", 8)}
        status[q] = {FUSED}"""[1:]
"""Template of the in-place kernels: pending row ``q`` of observer ``i`` fused into ``(x, P)``, its neighbour ``j``
read in ``(nx, nP)``; its outcome in ``status`` and ``reason``."""


def _update_rows(name: str, args: str, call: str) -> str:
    """Code of the loop ``{name}_rows(x, P, {args})``: kernel ``call`` (of row ``i``) on every row, in parallel."""
    return f"""
def {name}_rows(x, P, {args}):
    n = x.shape[0]
    ox, oP, nis, ok = np.empty_like(x), np.empty_like(P), np.empty(n), np.empty(n, dtype=np.bool_)
    for i in prange(n):
        r = {call}
{_store("ox", "oP", "i", 8)}
        nis[i] = r[9]
        ok[i] = r[10]
    return ox, oP, nis, ok
"""


_ROWS = "\n\n".join((
    _update_rows("pose", "xk, Pk, z, R", f"pose({_XP}, {_args('xk', 'i')}, {_args('Pk', 'i', True)}, "
                 f"{_args('z', 'i')}, {_args('R', 'i', True)})"),
    _update_rows("landmark", "lk, L, z, R", f"landmark({_XP}, {_args('lk', 'i', two=True)}, "
                 f"{_args('L', 'i', True, True)}, {_args('z', 'i', two=True)}, {_args('R', 'i', True, True)})"),
    _update_rows("absolute", "z, R", f"absolute({_XP}, {_args('z', 'i')}, {_args('R', 'i', True)})"),
))  # fmt: skip


_LOOPS = f"""
def predict_rows(x, P, v, w, dt, qn):
    ox = np.empty_like(x)
    oP = np.empty_like(P)
    for i in prange(x.shape[0]):
        r = predict({_args("x", "i")}, {_args("P", "i", True)}, v[i], w[i], dt[i], qn)
{_store("ox", "oP", "i", 8)}
    return ox, oP


{_ROWS}

def predict_into(x, P, tc, v, w, robots, t, qn):
    for k in range(robots.shape[0]):
        i = robots[k]
{_advance(8)}


def fuse_serial(x, P, tc, t0, v, w, t, thr, gate, relative, lm_on, lxy, lcov, qn, obs, tgt, kind, z, R, status,
                reason, lev):
    m = obs.shape[0]
    n = x.shape[0]
{_KINDS}
    top = -1
    for q in range(m):
{_SCREEN}
        if status[q] != {PENDING}:
            continue
        nx, nP = x, P  # a neighbour j > i has not fused its own group yet
{_FUSE}
    return top + 1


def fuse_levels(x, P, tc, t0, v, w, t, thr, gate, relative, lm_on, lxy, lcov, qn, obs, tgt, kind, z, R, status,
                reason, lev, px, pP):
    m = obs.shape[0]
    n = x.shape[0]
{_KINDS}
    top = -1
    groups = 0
    g0, g1 = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)  # rows g0[g]:g1[g] of group g
    for q in range(m):  # screened, observers moved to t and their levels, in canonical order on one thread
{_SCREEN}
        if q == 0 or obs[q - 1] != i:  # a group's first row: its observer's state before the stamp's groups
            for a in range(3):
                px[i, a] = x[i, a]
                for b in range(3):
                    pP[i, a, b] = P[i, a, b]
            g0[groups] = q
            groups += 1
        g1[groups - 1] = q + 1
    bounds = np.zeros(top + 2, dtype=np.int64)  # groups by level (a counting sort, canonical order within a level)
    for g in range(groups):
        bounds[lev[obs[g0[g]]] + 1] += 1
    for lv in range(top + 1):
        bounds[lv + 1] += bounds[lv]
    fill = bounds[:-1].copy()
    order = np.empty(groups, dtype=np.int64)
    for g in range(groups):
        lv = lev[obs[g0[g]]]
        order[fill[lv]] = g
        fill[lv] += 1
    for lv in range(top + 1):  # levels in order, the groups of one level in parallel
        for h in prange(bounds[lv], bounds[lv + 1]):
            g = order[h]
            for q in range(g0[g], g1[g]):
                if status[q] != {PENDING}:
                    continue
                i = obs[q]
                j = tgt[q]
                at_lm = j <= {NO_LANDMARK}
                robot = kind[q] != {ABSOLUTE} and not at_lm
                if robot and j > i and lev[j] >= 0:  # an observer with a larger id: its snapshot
                    nx, nP = px, pP
                else:  # a smaller id (its level is done), or a robot without a group here (not changed)
                    nx, nP = x, P
{textwrap.indent(_FUSE, " " * 8)}
    return top + 1


def replay_serial(x, P, tc, t0, v, w, stamps, s0, thr, gate, relative, lm_on, lxy, lcov, qn, d0, obs, tgt, kind, z,
                  R, status, reason, lev, c0, crow, cv, cw, rec, out_robot, out_stamp, out_x, out_P, nout):
    n = x.shape[0]
    k = nout[0]
    for s in range(s0, stamps.shape[0]):
        t = stamps[s]
        c, e = c0[s], c0[s + 1]
        predict_into(x, P, tc, v, w, crow[c:e], t, qn)  # robots with a command at t move to t first
        a, b = d0[s], d0[s + 1]
        if b > a:
            lv = fuse_serial(x, P, tc, t0, v, w, t, thr, gate, relative, lm_on, lxy, lcov, qn, obs[a:b], tgt[a:b],
                             kind[a:b], z[a:b], R[a:b], status[a:b], reason[a:b], lev)
            for q in range(a, b):
                lev[obs[q]] = -1
            if lv < 0:
                nout[0] = k
                return s
        scatter2(v, w, crow[c:e], cv[c:e], cw[c:e])
        if rec[s]:
            for i in range(n):
                if not t >= t0[i]:
                    continue
                if tc[i] < t:  # the belief at t: predicted, not stored
                    r = predict({_args("x", "i")}, {_args("P", "i", True)}, v[i], w[i], t - tc[i], qn)
{_store("out_x", "out_P", "k", 20)}
                else:
                    out_x[k] = x[i]
                    out_P[k] = P[i]
                out_robot[k] = i
                out_stamp[k] = s
                k += 1
    nout[0] = k
    return stamps.shape[0]


def scatter2(a, b, rows, va, vb):
    for k in range(rows.shape[0]):
        a[rows[k]] = va[k]
        b[rows[k]] = vb[k]
"""


@cache
def _kernels() -> dict[str, Any]:
    """Compile the generated scalar functions and the loops around them (once per process; the noise model is the
    loops' argument ``qn``)."""
    ns: dict[str, Any] = {"math": math, "np": np, "prange": prange, "screen_stamp": F.screen_stamp,
                          "degenerate": F.degenerate}  # fmt: skip
    for src in (predict_source(), pose_source(), absolute_source(), landmark_source()):
        exec(src, ns)  # noqa: S102 - our own generated code
    for name in ("predict", "pose", "absolute", "landmark"):
        ns[name] = njit(error_model="numpy")(ns[name])
    exec(_LOOPS, ns)  # noqa: S102
    out = {}
    for name in ("predict_rows", "pose_rows", "absolute_rows", "landmark_rows"):
        out[name] = njit(parallel=True, error_model="numpy")(ns[name])
        out[name + "_serial"] = njit(error_model="numpy")(ns[name])  # prange runs as range
    out["fuse_levels"] = njit(parallel=True, error_model="numpy")(ns["fuse_levels"])  # compiled at its first call
    for name in ("predict_into", "fuse_serial", "scatter2", "replay_serial"):  # in place, one thread
        out[name] = ns[name] = njit(error_model="numpy")(ns[name])  # replay_serial calls fuse_serial compiled
    return out


PARALLEL_MIN = 50_000
"""Rows (detections of a stamp, or robots predicted) below which the kernels run on one thread, in place; from it
on, :meth:`NumbaOps.fuse_levels` and the parallel row kernels. Measured on the shared 2-core machine on one slow
day (``fusion_step``, relative-pose swarms with 3 neighbours, robot-updates/s, one thread / two threads): 1.7e6 /
1.7-2.0e6 at 10k robots (30k rows) at twice the CPU time; 1.0e6 / 1.5-1.6e6 at 30k robots (90k rows); 1.2-1.3e6 /
1.7-1.9e6 at 100k robots; 0.87e6 / 0.88-0.93e6 at 1M robots (the neighbours' states out of the cache). Those are
quiet-machine figures: with other jobs on both cores (load 5-7) the two-thread path is slower than one thread, 2.3x
at 100k robots and 20x at 10k with numba's ``omp`` threading layer (its threads spin between the levels), 1.2x with
``workqueue`` (docs/benchmarks.md, 2026-12-05)."""


def _serial(rows: int) -> bool:
    """Whether ``rows`` rows run on one thread (below :data:`PARALLEL_MIN`, or one numba thread)."""
    return rows < PARALLEL_MIN or get_num_threads() <= 1


def _pick(k: dict[str, Any], name: str, rows: int) -> Any:
    return k[name + "_serial"] if _serial(rows) else k[name]


def _detections(det: Any) -> tuple[IntArray, IntArray, IntArray, FloatArray, FloatArray]:
    """The arrays of detections ``det`` as the in-place kernels take them: ``(observer, target, kind, z, R)``,
    C-contiguous, codes as int64 and the rest float."""
    f = np.ascontiguousarray
    return (f(det.observer, dtype=np.int64), f(det.target, dtype=np.int64), f(det.kind, dtype=np.int64),
            f(det.z, dtype=float), f(det.R, dtype=float))  # fmt: skip


class NumbaOps:
    """The fast EKF kernels compiled with numba (the interface of :class:`~swarmloc.engine.backends.NumpyOps`,
    plus a stamp's screening and fusion in place: :meth:`fuse_serial` on one thread, :meth:`fuse_levels` on
    several, and :meth:`replay_serial`)."""

    name = "numba"

    def __init__(self, noise: UnicycleNoise) -> None:
        self.noise = noise
        self.qn = noise_tuple(noise)
        self.k = _kernels()
        self._snapshot = (np.zeros((0, 3)), np.zeros((0, 3, 3)))  # fuse_levels' rows, kept between stamps
        self._warm_up()

    def _warm_up(self) -> None:
        """Compile every kernel now (on two robots), not inside the first timed step."""
        x, P = np.zeros((2, 3)), np.broadcast_to(np.eye(3), (2, 3, 3)).copy()
        one = np.ones(2)
        self.predict(x, P, one, one, one)
        self.pose_update(x, P, x + 1.0, P, x + 1.0, P)
        self.absolute_update(x, P, x, P)
        self.landmark_update(x, P, x[:, :2] + 1.0, P[:, :2, :2], x[:, :2] + 1.0, P[:, :2, :2])
        z = np.zeros((2, 3))
        det = Detections(np.array([0, 1]), np.array([1, 0]), np.array([1, 0]), z, P)
        status, reason = np.zeros(2, dtype=np.int8), np.zeros(2, dtype=np.int8)
        i = np.array([0, 1])
        for gate in (Gate(), Gate(0.5)):  # the serial variants; the parallel ones compile on their first large batch
            self.fuse_serial(x.copy(), P.copy(), np.zeros(2), np.zeros(2), one, one, 1.0, True, det, status.copy(),
                             reason.copy(), gate, (x[:, :2] + 1.0, P[:, :2, :2]))  # fmt: skip
        self.predict_into(x.copy(), P.copy(), np.zeros(2), one, one, i, 1.0)
        self.scatter2(one.copy(), one.copy(), i, one, one)

    def predict(self, x: np.ndarray, P: np.ndarray, v: np.ndarray, w: np.ndarray, dt: np.ndarray
                ) -> tuple[FloatArray, FloatArray]:  # fmt: skip
        kernel = _pick(self.k, "predict_rows", x.shape[0])
        xn, Pn = kernel(*(np.ascontiguousarray(a, dtype=float) for a in (x, P, v, w, dt)), self.qn)
        return xn, Pn

    def pose_update(self, x: np.ndarray, P: np.ndarray, xk: np.ndarray, Pk: np.ndarray, z: np.ndarray,
                    Rz: np.ndarray) -> Updated:  # fmt: skip
        return self._rows("pose_rows", x, P, xk, Pk, z, Rz)

    def absolute_update(self, x: np.ndarray, P: np.ndarray, z: np.ndarray, Rz: np.ndarray) -> Updated:
        return self._rows("absolute_rows", x, P, z, Rz)

    def landmark_update(self, x: np.ndarray, P: np.ndarray, lk: np.ndarray, L: np.ndarray, z: np.ndarray,
                        Rz: np.ndarray) -> Updated:  # fmt: skip
        return self._rows("landmark_rows", x, P, lk, L, z, Rz)

    def _rows(self, name: str, *arrays: np.ndarray) -> Updated:
        """Row kernel ``name`` (parallel or serial by the rows) on C-contiguous ``arrays``: ``(x+, P+, nis, ok,
        ok)``."""
        xn, Pn, nis, ok = _pick(self.k, name, arrays[0].shape[0])(*map(np.ascontiguousarray, arrays))
        return xn, Pn, nis, ok, ok

    def serial(self, rows: int) -> bool:
        """Whether ``rows`` rows run on one thread (then the engine takes :meth:`predict_into` and
        :meth:`fuse_serial`)."""
        return _serial(rows)

    def predict_into(self, x: np.ndarray, P: np.ndarray, tc: np.ndarray, v: np.ndarray, w: np.ndarray,
                     robots: np.ndarray, t: float) -> None:  # fmt: skip
        """Predict rows ``robots`` of ``(x, P)`` (clocks ``tc`` [s], commands ``v``, ``w``) to ``t`` [s] in place
        (rows already at or past ``t`` unchanged); one thread, no gather or scatter."""
        self.k["predict_into"](x, P, tc, v, w, np.asarray(robots, dtype=np.int64), float(t), self.qn)

    def fuse_serial(self, x: np.ndarray, P: np.ndarray, tc: np.ndarray, t0: np.ndarray, v: np.ndarray,
                    w: np.ndarray, t: float, use_relative: bool, det: Any, status: np.ndarray, reason: np.ndarray,
                    gate: Gate, landmarks: tuple[np.ndarray, np.ndarray] | None = None,
                    use_landmarks: bool = True) -> int:  # fmt: skip
        """A stamp's detections screened and their groups fused in place on one thread, in canonical (observer)
        order: what the nodes do.

        ``(x, P, tc)``: the engine's states and clocks (all robots), updated in place; ``t0``: start times [s]. Each
        detection is screened as :func:`swarmloc.engine.outcomes.screen` does, its observer (if started) predicted
        to ``t`` [s] and stored; a neighbour without input at ``t`` answers with its state predicted to ``t`` (not
        stored). Read in this order, a neighbour with a smaller id has already fused its own group and one with a
        larger id has not: the Gauss-Seidel order of the nodes, with no snapshot and no levels to schedule.
        Outcome rules of :class:`~swarmloc.estimators.DistributedEKF`; outcomes in ``status`` and ``reason``.

        Returns the number of levels the batched schedule would have (:func:`swarmloc.engine.stamp.levels`: the
        engine's ``last_levels``), or -1, having changed nothing, when a detection is of a kind other than a
        relative pose, an absolute fix or a range-bearing (the caller takes the general path). A robot's
        range-bearing is fused as a landmark's whose position and covariance are the neighbour's (the node's
        ``R + Hk Pk Hk^T``: the bearing and range of a position do not depend on its heading).
        ``landmarks``: the engine's map ``(xy (L, 2), cov (L, 2, 2))`` (:func:`swarmloc.engine.core.landmark_table`),
        landmark ``k`` a detection's target code :func:`~swarmloc.engine.codes.landmark_code` ``(k)``."""
        return self._in_place("fuse_serial", (x, P, tc, t0, v, w), t, use_relative, det, status, reason, gate,
                              landmarks, use_landmarks, ())  # fmt: skip

    def fuse_levels(self, x: np.ndarray, P: np.ndarray, tc: np.ndarray, t0: np.ndarray, v: np.ndarray,
                    w: np.ndarray, t: float, use_relative: bool, det: Any, status: np.ndarray, reason: np.ndarray,
                    gate: Gate, landmarks: tuple[np.ndarray, np.ndarray] | None = None,
                    use_landmarks: bool = True) -> int:  # fmt: skip
        """:meth:`fuse_serial` on ``NUMBA_NUM_THREADS`` threads, the same outcomes and states to the bit: one
        thread screens the rows, moves the observers to ``t`` and gives each group its level (the Gauss-Seidel
        schedule of :func:`swarmloc.engine.stamp.levels`) while copying each observer's state before the stamp's
        groups; then, level by level, the groups of a level fuse in parallel, a neighbour with a larger id read in
        that copy (its group may have run in an earlier level), one with a smaller id in the current states (its
        level is done), one without a group at ``t`` predicted, not stored. Returns the number of levels, or -1
        for a kind :meth:`fuse_serial` does not take (nothing done)."""
        n = x.shape[0]
        if self._snapshot[0].shape[0] != n:
            self._snapshot = (np.empty((n, 3)), np.empty((n, 3, 3)))
        return self._in_place("fuse_levels", (x, P, tc, t0, v, w), t, use_relative, det, status, reason, gate,
                              landmarks, use_landmarks, self._snapshot)  # fmt: skip

    def _in_place(self, name: str, state: Rows, t: float, use_relative: bool, det: Any, status: np.ndarray,
                  reason: np.ndarray, gate: Gate, landmarks: tuple[np.ndarray, np.ndarray] | None,
                  use_landmarks: bool, extra: tuple[()] | tuple[FloatArray, FloatArray]) -> int:  # fmt: skip
        const = constants(self.qn, gate.p, use_relative, use_landmarks, landmarks)
        lev = np.full(state[0].shape[0], -1, dtype=np.int64)  # every robot's level: none yet
        return int(self.k[name](*state, float(t), *const, *_detections(det), status, reason, lev, *extra))

    def replay_serial(self, state: Rows, tl: Timeline, s0: int, use_relative: bool, status: np.ndarray,
                      reason: np.ndarray, gate: Gate, landmarks: tuple[np.ndarray, np.ndarray] | None,
                      use_landmarks: bool, out: tuple[IntArray, IntArray, FloatArray, FloatArray, IntArray]
                      ) -> tuple[int, int]:  # fmt: skip
        """Stamps ``s0:`` of ``tl`` in one compiled loop on one thread: per stamp, the robots with a command moved
        to it, its detections through :meth:`fuse_serial` (outcomes into ``status`` and ``reason``, rows of
        ``tl.det``), its commands set, and with ``tl.record`` every started robot's state at the stamp (predicted,
        not stored) appended to ``out = (robot (K,), stamp index (K,), x (K, 3), P (K, 3, 3), count (1,))`` from
        row ``count[0]`` on. ``state = (x, P, tc, t0, v, w)``: the engine's arrays, updated in place.

        Returns ``(stop, records)``: ``stop`` the first stamp not done, ``len(tl)`` or a stamp with a detection of
        a kind :meth:`fuse_serial` does not take (nothing of it done: the caller steps it), and the records so
        far."""
        f = np.ascontiguousarray
        i64 = np.int64
        const = constants(self.qn, gate.p, use_relative, use_landmarks, landmarks)
        lev = np.full(state[0].shape[0], -1, dtype=i64)
        stop = self.k["replay_serial"](*state, f(tl.stamps, dtype=float), int(s0), *const, f(tl.d0, dtype=i64),
                                       *_detections(tl.det), status, reason, lev, f(tl.c0, dtype=i64),
                                       f(tl.robot, dtype=i64), f(tl.v, dtype=float), f(tl.w, dtype=float),
                                       f(tl.record, dtype=np.bool_), *out)  # fmt: skip
        return int(stop), int(out[-1][0])

    def scatter2(self, a: np.ndarray, b: np.ndarray, rows: np.ndarray, va: np.ndarray, vb: np.ndarray) -> None:
        """``a[rows] = va; b[rows] = vb`` (float arrays, in place)."""
        self.k["scatter2"](a, b, np.asarray(rows, dtype=np.int64), np.asarray(va, dtype=float),
                           np.asarray(vb, dtype=float))  # fmt: skip
