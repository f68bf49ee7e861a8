"""The batched team engine: every robot's filter state in arrays, one step for the whole team.

:class:`Engine` holds the state of ``N`` robots (row ``r`` is robot ``r``): for ``"expfusion"`` and ``"ci"`` the
SE(2) mean ``(N, 3, 3)`` and exponential-coordinate covariance ``(N, 3, 3)`` (right perturbation), for ``"dekf"``
the Cartesian ``(x, y, theta)`` ``(N, 3)`` and covariance ``(N, 3, 3)`` (world frame); per robot its clock [s] and
command ``(v [m/s], w [rad/s])``. It computes exactly what the per-robot nodes of :mod:`swarmloc.estimators`
compute when the in-process runner drives them (:mod:`swarmloc.node`), batched:

* **Clocks.** A robot is predicted from its clock to a stamp only when it has an input there (a detection group
  or a command), in one step with the command in force, as a node's history entry does. A neighbour's answer and a
  recorded belief are its state predicted to the stamp *without* storing it (:meth:`Engine.belief`).
* **Order at one stamp.** Groups (key ``(t, 1, observer)``) come before commands (key ``(t, 2, robot)``), and the
  groups in observer order: observer ``i`` is answered by neighbour ``j`` with ``j``'s belief *after* ``j``'s own
  group at ``t`` when ``j < i`` and *before* it when ``j > i`` (Gauss-Seidel). To stay batched, the groups of one
  stamp are scheduled in **levels**: an observer's level is 1 + the largest level of its targets with a smaller id
  that also have a group at ``t`` (0 if none), found by iterating ``np.maximum.at`` over the edges; all groups of
  one level fuse in one batched call per detection position, reading the neighbours' states after the groups of
  lower levels (``j < i``) or from the snapshot before the stamp's groups (``j > i``).
* **Fusion** is the nodes' (gate, iterations, order, outcome rules): through :mod:`swarmloc.kernels` batched
  over the observers of a level. The EKF has a faster path (``fast=True``, default) for relative poses and absolute
  fixes: the formulas of :mod:`swarmloc.engine.soa` on numpy or jax, or compiled by numba with the groups of a
  level in parallel threads (``backend``); range/bearing always takes the kernels. Covariance intersection
  follows the installed :class:`~swarmloc.estimators.ExpCI` (closed-form weight, or the search of
  :func:`~swarmloc.kernels.ci.ci_search`).

Detections are given as :class:`Detections` (arrays, robots as row indices). The engine trusts its input: a
driver validates it (:func:`swarmloc.engine.run_engine` applies the nodes' checks). Landmarks are not supported
(use the nodes); ``"rdl"`` neither: its pairwise updates change the *target's* state too.
"""

from __future__ import annotations

import inspect
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarmloc.engine.backends import BACKENDS, make_ops
from swarmloc.estimators.ci import ExpCI
from swarmloc.estimators.expfusion import DEGENERATE, NUMERICAL
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import ci as KCI
from swarmloc.kernels import group as K
from swarmloc.kernels.ci import ci_search
from swarmloc.lie import SE2
from swarmloc.motion import UnicycleNoise, odometry_increment
from swarmloc.node import chi2_ppf
from swarmloc.sensors import models
from swarmloc.sensors.models import KIND_ORDER

_CLOSED_FORM_CI = "pose_weight" in inspect.getsource(ExpCI._ci)
"""Whether :class:`~swarmloc.estimators.ExpCI` picks its weight in closed form (``kernels.ci.pose_weight``,
``point_weight``) or by :func:`~swarmloc.kernels.ci.ci_search`: the engine follows the estimator installed."""

ENGINE_ESTIMATORS = ("expfusion", "dekf", "ci")
"""Estimators the engine runs (the per-robot nodes of the same names)."""

KINDS = {v: k for k, v in KIND_ORDER.items()}
"""Kind code (the canonical order of :data:`swarmloc.sensors.models.KIND_ORDER`) -> name."""
ABSOLUTE, POSE = KIND_ORDER["absolute"], KIND_ORDER["pose"]
ZDIM = {KIND_ORDER[k]: m for k, m in (("absolute", 3), ("pose", 3), ("range_bearing", 2), ("range", 1), ("bearing", 1))}

SOA_MIN_ROWS = 2048
"""On numpy, batches smaller than this take the stacked-matrix kernels even on the fast path: the
structure-of-arrays forms make ~1400 array calls per update, a cost that only large batches amortize."""

NO_TARGET = -1
"""Target code of an absolute fix."""
UNKNOWN_ROBOT = -2
"""Target code of a robot outside the team or a landmark not in the map (the detection is counted ``unknown``)."""
UNUSABLE = -3
"""Target code of a detection its group holds but no filter can use (no target id, the pose of a landmark):
counted ``rejected``."""

PENDING, FUSED, GATED, REJECTED, UNKNOWN = range(5)
OUTCOMES = ("pending", "fused", "gated", "rejected", "unknown")
REASONS = (
    "",
    "the target is the observer itself",
    "relative measurements are switched off",
    "no answer: the robot is not in the team",
    "no answer: the robot had not started",
    "the observer had not started",
    "no usable target (a robot detection without a target id, or the pose of a landmark)",
    "non-finite innovation",
    DEGENERATE,
    NUMERICAL,
)
R_SELF, R_OFF, R_TEAM, R_NOT_STARTED, R_OBSERVER, R_UNUSABLE, R_NONFINITE, R_DEGENERATE, R_NUMERICAL = range(1, 10)


@dataclass(frozen=True)
class Detections:
    """Detections at one stamp, as arrays of length ``M``.

    ``observer`` ``(M,)``: robot row; ``target`` ``(M,)``: robot row, :data:`NO_TARGET` (absolute fix) or
    :data:`UNKNOWN_ROBOT`; ``kind`` ``(M,)``: code of :data:`KINDS`; ``z`` ``(M, 3)``: the measurement in its first
    ``m`` entries (``m`` = :data:`ZDIM` of the kind: pose ``(x [m], y [m], theta [rad])``, range [m] / bearing
    [rad]); ``R`` ``(M, 3, 3)``: its noise covariance in the leading ``m x m`` block (conventions of
    :class:`swarmloc.events.Detection`).
    """

    observer: np.ndarray
    target: np.ndarray
    kind: np.ndarray
    z: np.ndarray
    R: np.ndarray

    def __len__(self) -> int:
        return int(self.observer.shape[0])

    def take(self, idx: np.ndarray) -> Detections:
        return Detections(self.observer[idx], self.target[idx], self.kind[idx], self.z[idx], self.R[idx])

    def canonical(self) -> Detections:
        """Sorted by observer, then the nodes' canonical order within a group (kind, target, z)."""
        z = self.z
        order = np.lexsort((z[:, 2], z[:, 1], z[:, 0], self.target, self.kind, self.observer))
        return self.take(order)

    @classmethod
    def poses(cls, observer: np.ndarray, target: np.ndarray, z: np.ndarray, R: np.ndarray) -> Detections:
        """Relative-pose detections (``R`` ``(3, 3)`` or ``(M, 3, 3)``)."""
        m = observer.shape[0]
        kind = np.full(m, POSE, dtype=np.int64)
        return cls(observer, target, kind, z, np.broadcast_to(R, (m, 3, 3)))


State = tuple[np.ndarray, np.ndarray]
"""Rows of filter states: ``(mean (B, 3, 3), cov (B, 3, 3))`` on the group or ``(x (B, 3), P (B, 3, 3))`` (EKF)."""


def usable(Cs: np.ndarray) -> np.ndarray:
    """``(B,)``: finite and positive definite (a Cholesky factorization exists), as the nodes'
    :func:`~swarmloc.node.update.usable_covariance`, batched."""
    out = np.isfinite(Cs).all(axis=(-1, -2))
    idx = np.flatnonzero(out)
    if idx.size:
        try:
            np.linalg.cholesky(Cs[idx])
        except np.linalg.LinAlgError:
            for i in idx:
                try:
                    np.linalg.cholesky(Cs[i])
                except np.linalg.LinAlgError:
                    out[i] = False
    return out


def kalman_rows(x: np.ndarray, P: np.ndarray, r: np.ndarray, H: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, ...]:
    """:func:`swarmloc.kernels.cartesian.kalman_update` batched, row by row where a singular innovation covariance
    makes the batched inverse fail (the kernel then answers that row alone)."""
    xn, Pn, nis, ok = C.kalman_update(x, P, r, H, R)
    if not np.isnan(nis).all() or x.shape[0] <= 1:
        return xn, Pn, nis, ok
    rows = [C.kalman_update(x[i], P[i], r[i], H[i], R[i]) for i in range(x.shape[0])]
    return tuple(np.array([row[k] for row in rows]) for k in range(4))


def _runs(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(starts, position)`` of runs of equal consecutive ``keys``: where each run starts, each element's index
    within its run."""
    n = keys.shape[0]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]) if n else np.zeros(0, dtype=np.int64)
    lengths = np.diff(np.r_[starts, n])
    return starts, np.arange(n) - np.repeat(starts, lengths)


def levels(n: int, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Longest-path level of ``n`` nodes over the edges ``src -> dst`` (an acyclic graph): ``level[i] = 1 + max
    level[j]`` over edges ``j -> i``, 0 without any; vectorized (one ``np.maximum.at`` per level)."""
    level = np.zeros(n, dtype=np.int64)
    if src.size == 0:
        return level
    while True:
        new = np.zeros(n, dtype=np.int64)
        np.maximum.at(new, dst, level[src] + 1)
        if np.array_equal(new, level):
            return level
        level = new


class Engine:
    """A team's filters as arrays (see the module docstring).

    Parameters
    ----------
    estimator: ``"expfusion"``, ``"dekf"`` or ``"ci"``.
    mean, cov: initial beliefs ``(N, 3, 3)`` each: SE(2) means and exponential-coordinate covariances (as the
        nodes' initial :class:`~swarmloc.gaussian.GroupGaussian`).
    noise: process noise of the odometry.
    t0: start time(s) [s] of the initial beliefs, scalar or ``(N,)``; ``inf``: a robot that never starts (it
        answers nobody, like a node without input).
    gate, order, iterations, point_iterations, use_relative: as the nodes (:class:`~swarmloc.estimators.ExpFusion`,
        :class:`~swarmloc.estimators.Node`).
    backend: ``"numpy"``, ``"jax"`` or ``"numba"`` (the last two: fast EKF path only, ``estimator="dekf"``,
        ``fast=True``; with numba the groups of one level fuse in parallel threads, ``NUMBA_NUM_THREADS``).
    fast: EKF relative poses and absolute fixes through :mod:`swarmloc.engine.soa` instead of the stacked-matrix
        kernels (same results to rounding, several times faster).
    landmarks, horizon, use_landmarks: accepted so that the nodes' options can be passed; a non-empty
        ``landmarks`` map raises (not supported), the horizon plays no role (input comes in stamp order).
    """

    def __init__(
        self,
        estimator: str,
        mean: np.ndarray,
        cov: np.ndarray,
        *,
        noise: UnicycleNoise,
        t0: float | np.ndarray = 0.0,
        gate: float | None = None,
        order: int = 2,
        iterations: int = 2,
        point_iterations: int = 3,
        use_relative: bool = True,
        backend: str = "numpy",
        fast: bool = True,
        landmarks: Any = None,
        horizon: float | None = None,
        use_landmarks: bool = True,
    ) -> None:
        if estimator not in ENGINE_ESTIMATORS:
            why = " (its pairwise updates change the target's state: use the nodes)" if estimator == "rdl" else ""
            raise ValueError(f"Engine: unsupported estimator {estimator!r}{why}; choose from {list(ENGINE_ESTIMATORS)}")
        if backend not in BACKENDS:
            raise ValueError(f"Engine: unknown backend {backend!r}; choose from {list(BACKENDS)}")
        if backend != "numpy" and not (estimator == "dekf" and fast):
            raise ValueError(f"Engine: backend {backend!r} runs the fast EKF path only (estimator='dekf', fast=True)")
        if landmarks:
            raise ValueError("Engine: landmarks are not supported; run the nodes (swarmloc.runner.run)")
        if gate is not None and not (0 < gate < 1):
            raise ValueError(f"Engine: 'gate' must be a probability in (0, 1) or None, got {gate!r}")
        if order not in (1, 2):
            raise ValueError(f"Engine: 'order' must be 1 or 2, got {order!r}")
        mean = np.asarray(mean, dtype=float)
        cov = np.asarray(cov, dtype=float)
        if mean.ndim != 3 or mean.shape[1:] != (3, 3) or cov.shape != mean.shape:
            raise ValueError(f"Engine: mean and cov must be (N, 3, 3), got {mean.shape} and {cov.shape}")
        n = mean.shape[0]
        self.estimator = estimator
        self.n = n
        self.noise = noise
        self.gate = gate
        self.order = order
        self.iterations = iterations
        self.point_iterations = point_iterations
        self.use_relative = use_relative
        self.fast = bool(fast) and estimator == "dekf"
        self.backend = backend
        self.ops = make_ops(backend, noise) if self.fast else None
        self.t0 = np.broadcast_to(np.asarray(t0, dtype=float), (n,)).copy()
        self.t = self.t0.copy()
        self.v = np.zeros(n)
        self.w = np.zeros(n)
        if estimator == "dekf":
            self.a, self.b = C.from_group(mean, cov)
        else:
            self.a, self.b = mean.copy(), cov.copy()
        self.counts: Counter[str] = Counter()
        """Detections in and their outcomes (``fused``, ``gated``, ``rejected``, ``unknown``), as the nodes count."""
        self.reasons: Counter[str] = Counter()
        """``"<outcome>: <reason>"`` -> count for rejected and unknown detections."""
        self.last_levels = 0
        """Levels the last :meth:`fuse` scheduled (diagnostics)."""

    # ------------------------------------------------------------------------------------------------ state
    def _advance(self, s: State, v: np.ndarray, w: np.ndarray, dt: np.ndarray) -> State:
        """Rows ``s`` predicted over ``dt`` [s] with their commands; rows with ``dt <= 0`` (or NaN) unchanged."""
        move = np.flatnonzero(dt > 0)
        if move.size == 0:
            return s
        if move.size == dt.shape[0] and self.fast:
            return self.ops.predict(s[0], s[1], v, w, dt)
        a, b = s[0].copy(), s[1].copy()
        if move.size == dt.shape[0]:
            move = slice(None)
        if self.fast:
            a[move], b[move] = self.ops.predict(s[0][move], s[1][move], v[move], w[move], dt[move])
        elif self.estimator == "dekf":
            a[move], b[move], _ = C.predict(s[0][move], s[1][move], v[move], w[move], dt[move], self.noise)
        else:
            inc_mean, inc_cov = odometry_increment(v[move], w[move], dt[move], self.noise)
            a[move], b[move] = K.predict(SE2, s[0][move], s[1][move], inc_mean, inc_cov, self.order)
        return a, b

    def _rows(self, idx: np.ndarray, t: float) -> State:
        """States of robots ``idx`` predicted to ``t`` (not stored)."""
        return self._advance((self.a[idx], self.b[idx]), self.v[idx], self.w[idx], t - self.t[idx])

    def predict(self, robots: np.ndarray, t: float) -> None:
        """Predict ``robots`` (rows) to ``t`` [s] and store it (robots already there, or not started, unchanged)."""
        robots = np.asarray(robots, dtype=np.int64)
        dt = t - self.t[robots]
        go = robots[dt > 0]
        if go.size == 0:
            return
        if go.size == self.n:  # everybody: no gather
            self.a, self.b = self._advance((self.a, self.b), self.v, self.w, t - self.t)
        else:
            self.a[go], self.b[go] = self._rows(go, t)
        self.t[go] = t

    def set_command(self, robots: np.ndarray, v: np.ndarray, w: np.ndarray) -> None:
        """Odometry ``(v [m/s], w [rad/s])`` in force from each robot's clock on (call :meth:`predict` first)."""
        self.v[robots] = v
        self.w[robots] = w

    def belief(self, t: float, robots: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Beliefs of ``robots`` (default all) at ``t`` [s], predicted from their clocks and not stored:
        SE(2) means ``(B, 3, 3)`` and exponential-coordinate covariances ``(B, 3, 3)`` (the nodes' ``belief_at``)."""
        idx = np.arange(self.n) if robots is None else np.asarray(robots, dtype=np.int64)
        a, b = self._rows(idx, t)
        if self.estimator == "dekf":
            return C.to_group(a, b)
        return a, b

    def step(
        self,
        t: float,
        detections: Detections | None = None,
        commands: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
        *,
        presorted: bool = False,
    ) -> None:
        """Everything stamped ``t`` [s]: the detection groups, then the commands ``(robots, v, w)`` starting at ``t``.

        Robots with a command or a group at ``t`` are predicted to ``t`` first (what the nodes do at either entry);
        ``presorted``: the detections are already in :meth:`Detections.canonical` order.
        """
        t = float(t)
        if commands is not None:
            self.predict(commands[0], t)
        if detections is not None and len(detections):
            self.fuse(t, detections, presorted=presorted)
        if commands is not None:
            self.set_command(*commands)

    # ------------------------------------------------------------------------------------------------ fusion
    def fuse(self, t: float, det: Detections, *, presorted: bool = False) -> np.ndarray:
        """Fuse every detection group stamped ``t`` [s] (observers predicted to ``t`` first); returns the outcome
        code of each detection (:data:`OUTCOMES`), in the order of ``det`` once sorted canonically."""
        if not presorted:
            det = det.canonical()
        m = len(det)
        status = np.zeros(m, dtype=np.int8)
        reason = np.zeros(m, dtype=np.int8)
        if m == 0:
            return status
        obs, tgt, kind = det.observer, det.target, det.kind
        robot = kind != ABSOLUTE
        tgt_c = np.clip(tgt, 0, self.n - 1)
        obs_ok = t >= self.t0[obs]
        _set(status, reason, ~obs_ok, REJECTED, R_OBSERVER)
        if not self.use_relative:
            _set(status, reason, obs_ok & robot, REJECTED, R_OFF)
        _set(status, reason, (status == PENDING) & robot & (tgt == UNUSABLE), REJECTED, R_UNUSABLE)
        _set(status, reason, (status == PENDING) & robot & (tgt == obs), REJECTED, R_SELF)
        _set(status, reason, (status == PENDING) & robot & (tgt < 0), UNKNOWN, R_TEAM)
        _set(status, reason, (status == PENDING) & robot & ~(t >= self.t0[tgt_c]), UNKNOWN, R_NOT_STARTED)
        needs = (status == PENDING) & robot  # needs the target's answer

        starts, pos = _runs(obs)
        observers = obs[starts][obs_ok[starts]]
        if observers.size == 0:
            self._count(status, reason)
            return status
        self.predict(observers, t)
        mark = np.zeros(self.n, dtype=bool)  # robots involved: observers and answering neighbours, O(N)
        mark[observers] = True
        mark[tgt[needs]] = True
        U = np.flatnonzero(mark)
        local = np.cumsum(mark) - 1  # robot row -> row of U
        lo = local[obs]
        lt = local[tgt_c]
        observer = np.zeros(self.n, dtype=bool)
        observer[observers] = True
        is_obs = observer[U]
        if U.size == self.n and not np.any(self.t < t):  # everybody at t already: fuse in place
            cur = (self.a, self.b)
            prior = (self.a.copy(), self.b.copy())
        else:
            prior = self._rows(U, t)  # observers already at t; others' answers predicted, not stored
            cur = (prior[0].copy(), prior[1].copy())
        edge = needs & (tgt < obs) & is_obs[np.where(needs, lt, 0)]
        level = levels(U.size, lt[edge], lo[edge])
        row_level = np.where(obs_ok, level[np.where(obs_ok, lo, 0)], -1)
        top = int(row_level.max())
        self.last_levels = top + 1
        pend = kind[status == PENDING]
        if self.backend == "numba" and np.all((pend == ABSOLUTE) | (pend == POSE)):
            # compiled: groups of a level in parallel threads, levels in order
            ok_groups = starts[obs_ok[starts]]
            ends = np.r_[starts[1:], m][obs_ok[starts]]
            g_level = row_level[ok_groups]
            order = np.argsort(g_level, kind="stable")
            bounds = np.searchsorted(g_level[order], np.arange(top + 2))
            thr = chi2_ppf(self.gate, 3) if self.gate is not None else None
            self.ops.fuse_groups(cur, prior, det, np.where(obs_ok, lo, 0), np.where(needs, lt, 0), status, reason,
                                 thr, ok_groups[order], ends[order], bounds)  # fmt: skip
            self._store(U, is_obs, cur)
            self._count(status, reason)
            return status
        ctx = _Ctx(self, det, status, reason, pos, lo, lt, needs, prior, cur)
        fuse_rows = {"dekf": self._fuse_sequential, "ci": self._fuse_sequential, "expfusion": self._fuse_exp}
        if top == 0:
            fuse_rows[self.estimator](ctx, np.flatnonzero(obs_ok))
        else:
            order = np.argsort(row_level, kind="stable")
            bounds = np.searchsorted(row_level[order], np.arange(top + 2))
            for lv in range(top + 1):
                rows = order[bounds[lv] : bounds[lv + 1]]
                if rows.size:
                    fuse_rows[self.estimator](ctx, rows)
        self._store(U, is_obs, cur)
        self._count(status, reason)
        return status

    def _store(self, U: np.ndarray, is_obs: np.ndarray, cur: State) -> None:
        """Write the observers' fused states back (the neighbours' predicted answers are not stored)."""
        if cur[0] is self.a:
            return
        done = U[is_obs]
        self.a[done] = cur[0][is_obs]
        self.b[done] = cur[1][is_obs]

    def _count(self, status: np.ndarray, reason: np.ndarray) -> None:
        self.counts["detections"] += int(status.size)
        tally = np.bincount(status, minlength=len(OUTCOMES))
        for code in (FUSED, GATED, REJECTED, UNKNOWN):
            self.counts[OUTCOMES[code]] += int(tally[code])
        if reason.any():
            pairs, n = np.unique(np.stack([status[reason > 0], reason[reason > 0]]), axis=1, return_counts=True)
            for (s, r), k in zip(pairs.T, n, strict=True):
                self.reasons[f"{OUTCOMES[s]}: {REASONS[r]}"] += int(k)

    # ------------------------------------------------------------------------------------------------ per level
    def _verdict(
        self, ctx: _Ctx, rows: np.ndarray, nis: np.ndarray, m: int, nonfinite: int = R_NONFINITE
    ) -> np.ndarray:
        """Apply the chi-square gate to ``rows`` (innovations ``nis`` of dimension ``m``); returns the rows that pass.
        Non-finite innovations are rejected with ``nonfinite``; no gate: all pass."""
        if self.gate is None:
            return np.ones(rows.size, dtype=bool)
        bad = ~np.isfinite(nis)
        with np.errstate(invalid="ignore"):
            gated = ~bad & (nis > chi2_ppf(self.gate, m))
        _set(ctx.status, ctx.reason, rows[bad], REJECTED, nonfinite)
        ctx.status[rows[gated]] = GATED
        return ~(bad | gated)

    def _fuse_sequential(self, ctx: _Ctx, rows: np.ndarray) -> None:
        """EKF and covariance intersection: one detection of each group at a time, in canonical order."""
        rows = rows[ctx.status[rows] == PENDING]
        if rows.size == 0:
            return
        p = ctx.pos[rows]
        for k in range(int(p.max()) + 1):
            at = rows[p == k]
            kinds = ctx.det.kind[at]
            for code in np.unique(kinds):
                sel = at[kinds == code]
                if self.estimator == "dekf":
                    self._ekf(ctx, sel, int(code))
                else:
                    self._ci(ctx, sel, int(code))

    def _ekf(self, ctx: _Ctx, rows: np.ndarray, code: int) -> None:
        det = ctx.det
        lo = ctx.lo[rows]
        x, P = ctx.cur[0][lo], ctx.cur[1][lo]
        m = ZDIM[code]
        z, Rm = det.z[rows, :m], det.R[rows, :m, :m]
        if self.fast and code in (ABSOLUTE, POSE) and (self.backend != "numpy" or rows.size >= SOA_MIN_ROWS):
            if code == ABSOLUTE:
                xn, Pn, nis, ok, pd = self.ops.absolute_update(x, P, z, Rm)
            else:
                xk, Pk = ctx.target(rows)
                xn, Pn, nis, ok, pd = self.ops.pose_update(x, P, xk, Pk, z, Rm)
            ok = ok & pd
        else:
            if code == ABSOLUTE:
                r, H, R = models.residual("pose", z, x), np.broadcast_to(np.eye(3), P.shape), Rm
            else:
                name = KINDS[code]
                xk, Pk = C.from_group(*C.to_group(*ctx.target(rows)))  # the answer travels as a group belief
                bad = models.degenerate(name, x, xk)
                if bad.any():
                    _set(ctx.status, ctx.reason, rows[bad], REJECTED, R_DEGENERATE)
                    rows, lo, x, P, z, Rm, xk, Pk = (a[~bad] for a in (rows, lo, x, P, z, Rm, xk, Pk))
                    if rows.size == 0:
                        return
                h, H, Hk = models.predict(name, x, xk)
                r = models.residual(name, z, h)
                Rz = models.pose_noise_to_cartesian(z, Rm) if code == POSE else Rm
                R = Rz + Hk @ Pk @ np.swapaxes(Hk, -1, -2)
            xn, Pn, nis, ok = kalman_rows(x, P, r, H, R)
            ok = ok & usable(Pn)
        keep = self._verdict(ctx, rows, nis, m)
        bad = keep & ~ok
        _set(ctx.status, ctx.reason, rows[bad], REJECTED, R_NUMERICAL)
        good = keep & ok
        ctx.status[rows[good]] = FUSED
        ctx.cur[0][lo[good]] = xn[good]
        ctx.cur[1][lo[good]] = Pn[good]

    def _pseudo(self, ctx: _Ctx, rows: np.ndarray, code: int) -> tuple[np.ndarray, np.ndarray]:
        """Pseudo-observations ``(nu, W)`` of the observers' own poses (absolute fixes, relative poses)."""
        det = ctx.det
        if code == ABSOLUTE:
            return K.absolute_to_pseudo(det.z[rows], det.R[rows])
        tm, tc = ctx.target(rows)
        return K.relative_to_pseudo(SE2, tm, tc, SE2.from_xytheta(det.z[rows]), det.R[rows], self.order)

    def _accept(self, ctx: _Ctx, rows: np.ndarray, m2: np.ndarray, c2: np.ndarray, why: int) -> None:
        """Store the updates of ``rows`` that are finite with a usable covariance; reject the others (``why``)."""
        ok = np.isfinite(m2).all(axis=(-1, -2)) & usable(c2)
        _set(ctx.status, ctx.reason, rows[~ok], REJECTED, why)
        ctx.status[rows[ok]] = FUSED
        lo = ctx.lo[rows[ok]]
        ctx.cur[0][lo] = m2[ok]
        ctx.cur[1][lo] = c2[ok]

    def _point(self, ctx: _Ctx, rows: np.ndarray, code: int) -> None:
        """Range/bearing of robots by the thesis estimator: gate, then the iterated update on the group."""
        det = ctx.det
        name, m = KINDS[code], ZDIM[code]
        lo = ctx.lo[rows]
        mean, cov = ctx.cur[0][lo], ctx.cur[1][lo]
        z, R = det.z[rows, :m], det.R[rows, :m, :m]
        tm, tc = ctx.target(rows)
        if self.gate is not None:
            nis = K.point_nis(mean, cov, name, z, R, tm, tc, True)
            keep = self._verdict(ctx, rows, nis, m, nonfinite=R_DEGENERATE)
            rows, lo, mean, cov, z, R, tm, tc = (a[keep] for a in (rows, lo, mean, cov, z, R, tm, tc))
        if rows.size == 0:
            return
        m2, c2, ok = K.point_update(mean, cov, name, z, R, tm, tc, True, self.point_iterations, self.order)
        _set(ctx.status, ctx.reason, rows[~ok], REJECTED, R_DEGENERATE)
        rows, m2, c2 = rows[ok], m2[ok], c2[ok]
        self._accept(ctx, rows, m2, c2, R_NUMERICAL)

    def _fuse_exp(self, ctx: _Ctx, rows: np.ndarray) -> None:
        """Thesis estimator: all pose pseudo-observations of a group at once (gated against the prior), then the
        range/bearing detections one at a time."""
        det = ctx.det
        rows = rows[ctx.status[rows] == PENDING]
        kinds = det.kind[rows]
        pseudo = rows[(kinds == ABSOLUTE) | (kinds == POSE)]
        if pseudo.size:
            nu = np.empty((pseudo.size, 3, 3))
            W = np.empty((pseudo.size, 3, 3))
            for code in (ABSOLUTE, POSE):
                sel = det.kind[pseudo] == code
                if sel.any():
                    nu[sel], W[sel] = self._pseudo(ctx, pseudo[sel], code)
            if self.gate:
                lo = ctx.lo[pseudo]
                nis = K.pseudo_nis(SE2, ctx.cur[0][lo], ctx.cur[1][lo], nu, W)
                keep = self._verdict(ctx, pseudo, nis, 3)
                pseudo, nu, W = pseudo[keep], nu[keep], W[keep]
            if pseudo.size:
                starts, _ = _runs(det.observer[pseudo])
                count = np.diff(np.r_[starts, pseudo.size])
                for c in np.unique(count):
                    first = starts[count == c]
                    idx = first[:, None] + np.arange(c)  # (B, c): each observer's pseudo-observations in order
                    lo = ctx.lo[pseudo[first]]
                    m2, c2 = K.fuse_pseudo(SE2, ctx.cur[0][lo], ctx.cur[1][lo], nu[idx], W[idx], self.order,
                                           self.iterations)  # fmt: skip
                    ok = np.isfinite(m2).all(axis=(-1, -2)) & usable(c2)
                    ctx.cur[0][lo[ok]] = m2[ok]
                    ctx.cur[1][lo[ok]] = c2[ok]
                    ctx.status[pseudo[idx[ok]].ravel()] = FUSED
                    _set(ctx.status, ctx.reason, pseudo[idx[~ok]].ravel(), REJECTED, R_NUMERICAL)
        points = rows[(kinds != ABSOLUTE) & (kinds != POSE)]
        if points.size:
            _, rank = _runs(det.observer[points])
            for k in range(int(rank.max()) + 1):
                at = points[rank == k]
                at = at[ctx.status[at] == PENDING]
                for code in np.unique(det.kind[at]):
                    self._point(ctx, at[det.kind[at] == code], int(code))

    def _ci(self, ctx: _Ctx, rows: np.ndarray, code: int) -> None:
        """Covariance intersection with the neighbour (robots); absolute fixes fused as independent information."""
        det = ctx.det
        order, its = self.order, self.iterations
        lo = ctx.lo[rows]
        mean, cov = ctx.cur[0][lo], ctx.cur[1][lo]
        if code == ABSOLUTE:
            nu, W = self._pseudo(ctx, rows, code)
            if self.gate is not None:
                keep = self._verdict(ctx, rows, K.pseudo_nis(SE2, mean, cov, nu, W), 3)
                rows, mean, cov, nu, W = (a[keep] for a in (rows, mean, cov, nu, W))
            if rows.size:
                m2, c2 = K.fuse_pseudo(SE2, mean, cov, nu[:, None], W[:, None], order, its)
                self._accept(ctx, rows, m2, c2, R_NUMERICAL)
            return
        name, m = KINDS[code], ZDIM[code]
        nb_mean, nb_cov = ctx.target(rows)
        z, R = det.z[rows, :m], det.R[rows, :m, :m]
        if code == POSE:
            meas = SE2.from_xytheta(z)
            if self.gate is not None:
                nu, W = K.relative_to_pseudo(SE2, nb_mean, nb_cov, meas, R, order)
                keep = self._verdict(ctx, rows, K.pseudo_nis(SE2, mean, cov, nu, W), 3)
                rows, mean, cov, nb_mean, nb_cov, meas, R = (
                    a[keep] for a in (rows, mean, cov, nb_mean, nb_cov, meas, R)
                )
        elif self.gate is not None:
            nis = K.point_nis(mean, cov, name, z, R, nb_mean, nb_cov, True)
            keep = self._verdict(ctx, rows, nis, m, nonfinite=R_DEGENERATE)
            rows, mean, cov, nb_mean, nb_cov, z, R = (a[keep] for a in (rows, mean, cov, nb_mean, nb_cov, z, R))
        if rows.size == 0:
            return
        why = R_NUMERICAL if code == POSE else R_DEGENERATE
        if not _CLOSED_FORM_CI:  # the weight searched by fusing at many weights (kernels.ci.ci_search)
            fuse = _ci_fuse(code, name, mean, cov, nb_mean, nb_cov, meas if code == POSE else z, R, self)
            m2, c2, _ = ci_search(fuse, (rows.size,))
            self._accept(ctx, rows, m2, c2, why)
            return
        # the weight in closed form from the fusion linearized at the prior, then one fusion (as ExpCI)
        if code == POSE:
            w = KCI.pose_weight(mean, cov, meas, R, nb_mean, nb_cov, order)[:, None, None]
            nu, W = K.relative_to_pseudo(SE2, nb_mean, nb_cov / (1 - w), meas, R, order)
            m2, c2 = K.fuse_pseudo(SE2, mean, cov / w, nu[:, None], W[:, None], order, its)
        else:
            w = KCI.point_weight(mean, cov, name, z, R, nb_mean, nb_cov)[:, None, None]
            m2, c2, ok = K.point_update(mean, cov / w, name, z, R, nb_mean, nb_cov / (1 - w), True,
                                        self.point_iterations, order)  # fmt: skip
            _set(ctx.status, ctx.reason, rows[~ok], REJECTED, R_DEGENERATE)
            rows, m2, c2 = rows[ok], m2[ok], c2[ok]
        self._accept(ctx, rows, m2, c2, why)


def _ci_fuse(
    code: int,
    name: str,
    mean: np.ndarray,
    cov: np.ndarray,
    nb_mean: np.ndarray,
    nb_cov: np.ndarray,
    meas: np.ndarray,
    R: np.ndarray,
    eng: Engine,
) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """The fusion at CI weights ``w (k, B)`` for :func:`~swarmloc.kernels.ci.ci_search` (as :class:`ExpCI`)."""
    order, its = eng.order, eng.iterations

    def fuse_pose(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        wc = w[..., None, None]
        nu, W = K.relative_to_pseudo(SE2, nb_mean, nb_cov / (1 - wc), meas, R, order)
        mu = np.broadcast_to(mean, (*w.shape, 3, 3))
        return K.fuse_pseudo(SE2, mu, cov / wc, nu[..., None, :, :], W[..., None, :, :], order, its)

    def fuse_point(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        wc = w[..., None, None]
        mu = np.broadcast_to(mean, (*w.shape, 3, 3))
        m2, c2, ok = K.point_update(
            mu, cov / wc, name, meas, R, nb_mean, nb_cov / (1 - wc), True, eng.point_iterations, order
        )
        return m2, np.where(ok[..., None, None], c2, np.nan)

    return fuse_pose if code == POSE else fuse_point


class _Ctx:
    """What the groups of one stamp share while their levels are fused."""

    __slots__ = ("eng", "det", "status", "reason", "pos", "lo", "lt", "needs", "prior", "cur")

    def __init__(self, eng: Engine, det: Detections, status: np.ndarray, reason: np.ndarray, pos: np.ndarray,
                 lo: np.ndarray, lt: np.ndarray, needs: np.ndarray, prior: State, cur: State) -> None:  # fmt: skip
        self.eng, self.det, self.status, self.reason, self.pos = eng, det, status, reason, pos
        self.lo, self.lt, self.needs, self.prior, self.cur = lo, lt, needs, prior, cur

    def target(self, rows: np.ndarray) -> State:
        """The neighbours' answers for ``rows``: after their own group at this stamp when their id is smaller than
        the observer's, before it otherwise."""
        lt = self.lt[rows]
        after = self.det.target[rows] < self.det.observer[rows]
        return tuple(
            np.where(after.reshape(-1, *[1] * (c.ndim - 1)), c[lt], p[lt])
            for c, p in zip(self.cur, self.prior, strict=True)
        )


def _set(status: np.ndarray, reason: np.ndarray, where: np.ndarray, outcome: int, why: int) -> None:
    """Outcome and reason of the detections ``where`` (a mask or indices)."""
    status[where] = outcome
    reason[where] = why
