"""One stamp's fusion, shared by the estimators' fusions (:mod:`swarmloc.engine.fuse_ekf`, ``fuse_exp``,
``fuse_ci``): the Gauss-Seidel schedule (:func:`levels`), the state of the stamp being fused (:class:`Stamp`) and
the base of a fusion of one level (:class:`Fusion`, :class:`Sequential`).

The groups of one stamp are scheduled in **levels**: an observer's level is 1 + the largest level of its targets
with a smaller id that also have a group at the stamp (0 if none). All groups of one level fuse in one batched
call per detection position, reading the neighbours' states after the groups of lower levels (``j < i``) or from
the snapshot before the stamp's groups (``j > i``).
"""

from __future__ import annotations

import numpy as np

from swarmloc.arrays import BoolArray
from swarmloc.engine.codes import FUSED, PENDING, R_NONFINITE, REJECTED
from swarmloc.engine.detections import Detections
from swarmloc.engine.outcomes import gate_rows, mark
from swarmloc.gaussian import positive_definite
from swarmloc.kernels.group import FUSE_ITERATIONS, POINT_ITERATIONS
from swarmloc.node.update import Gate

State = tuple[np.ndarray, np.ndarray]
"""Rows of filter states: ``(mean (B, 3, 3), cov (B, 3, 3))`` on the group or ``(x (B, 3), P (B, 3, 3))`` (EKF)."""


def runs(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def schedule(n: int, det: Detections, needs: np.ndarray, obs_ok: np.ndarray,
             observers: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The robots a stamp involves and its levels: ``(U, lo, lt, is_obs, row_level)``, ``U`` the rows of the
    observers ``observers`` (the running ones) and of the neighbours the pending detections ``needs`` ask, ``lo``,
    ``lt`` each detection's observer and target as rows of ``U`` (a target that is no robot: clipped, unused),
    ``is_obs`` which rows of ``U`` are observers, ``row_level`` each detection's level (-1 where its observer does not
    run); ``n`` robots in the team."""
    mark = np.zeros(n, dtype=bool)  # robots involved: observers and answering neighbours, O(N)
    mark[observers] = True
    mark[det.target[needs]] = True
    U = np.flatnonzero(mark)
    local = np.cumsum(mark) - 1  # robot row -> row of U
    lo = local[det.observer]
    lt = local[np.clip(det.target, 0, n - 1)]
    observer = np.zeros(n, dtype=bool)
    observer[observers] = True
    is_obs = observer[U]
    edge = needs & (det.target < det.observer) & is_obs[np.where(needs, lt, 0)]
    level = levels(U.size, lt[edge], lo[edge])
    row_level = np.where(obs_ok, level[np.where(obs_ok, lo, 0)], -1)
    return U, lo, lt, is_obs, row_level


def usable(Cs: np.ndarray) -> BoolArray:
    """``(B,)``: finite and positive definite (a Cholesky factorization exists), as the nodes'
    :func:`~swarmloc.node.update.usable_covariance`, batched."""
    out: BoolArray = np.isfinite(Cs).all(axis=(-1, -2))
    idx = np.flatnonzero(out)
    if idx.size:
        try:
            np.linalg.cholesky(Cs[idx])
        except np.linalg.LinAlgError:
            for i in idx:
                out[i] = positive_definite(Cs[i])
    return out


class Stamp:
    """What the groups of one stamp share while their levels are fused.

    ``det``: the stamp's detections (canonical order); ``status``, ``reason``: their outcomes so far
    (:mod:`swarmloc.engine.outcomes`); ``pos``: each detection's position in its group; ``lo``, ``lt``: rows of the
    observer and the target in ``prior`` and ``cur``; ``prior``: the involved robots' states before the stamp's
    groups; ``cur``: their states as the levels are fused (updated in place).
    """

    __slots__ = ("det", "status", "reason", "pos", "lo", "lt", "prior", "cur")

    def __init__(self, det: Detections, status: np.ndarray, reason: np.ndarray, pos: np.ndarray, lo: np.ndarray,
                 lt: np.ndarray, prior: State, cur: State) -> None:  # fmt: skip
        self.det, self.status, self.reason, self.pos = det, status, reason, pos
        self.lo, self.lt, self.prior, self.cur = lo, lt, prior, cur

    def target(self, rows: np.ndarray) -> State:
        """The neighbours' answers for ``rows``: after their own group at this stamp when their id is smaller than
        the observer's, before it otherwise."""
        lt = self.lt[rows]
        after = self.det.target[rows] < self.det.observer[rows]
        return tuple(
            np.where(after.reshape(-1, *[1] * (c.ndim - 1)), c[lt], p[lt])
            for c, p in zip(self.cur, self.prior, strict=True)
        )

    def mark(self, where: np.ndarray, outcome: int, why: int) -> None:
        mark(self.status, self.reason, where, outcome, why)

    def gate(self, rows: np.ndarray, nis: np.ndarray, gate: Gate, m: int, nonfinite: int = R_NONFINITE) -> np.ndarray:
        """:func:`~swarmloc.engine.outcomes.gate_rows` on ``rows``: the mask of those that pass."""
        return gate_rows(self.status, self.reason, rows, nis, gate, m, nonfinite)

    def store(self, rows: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
        """The updated states ``(a, b)`` of the observers of ``rows``: their detections are fused."""
        self.status[rows] = FUSED
        lo = self.lo[rows]
        self.cur[0][lo] = a
        self.cur[1][lo] = b

    def accept(self, rows: np.ndarray, a: np.ndarray, b: np.ndarray, why: int) -> None:
        """Store the updates of ``rows`` that are finite with a usable covariance; reject the others (``why``)."""
        ok = np.isfinite(a).all(axis=(-1, -2)) & usable(b)
        self.mark(rows[~ok], REJECTED, why)
        self.store(rows[ok], a[ok], b[ok])


class Fusion:
    """The fusion of one level of a stamp's groups by one estimator, with the nodes' options (:class:`Gate`,
    ``order``, ``iterations``, ``point_iterations``: :class:`~swarmloc.estimators.ExpFusion`)."""

    def __init__(
        self, gate: Gate, order: int = 2, iterations: int = FUSE_ITERATIONS, point_iterations: int = POINT_ITERATIONS
    ) -> None:
        self.gate = gate
        self.order = order
        self.iterations = iterations
        self.point_iterations = point_iterations
        self.landmarks: tuple[np.ndarray, np.ndarray] | None = None
        """The map's positions and covariances, ``(xy (L, 2), cov (L, 2, 2))``, or None (only the EKF fuses landmark
        detections)."""

    def fuse_level(self, st: Stamp, rows: np.ndarray) -> None:
        """Fuse the pending detections ``rows`` of the groups of one level (canonical order) into ``st.cur``."""
        raise NotImplementedError


class Sequential(Fusion):
    """One detection of each group at a time, in canonical order (the EKF, covariance intersection): position
    ``k`` of every group of the level, one batched :meth:`update` per kind."""

    def fuse_level(self, st: Stamp, rows: np.ndarray) -> None:
        rows = rows[st.status[rows] == PENDING]
        if rows.size == 0:
            return
        p = st.pos[rows]
        for k in range(int(p.max()) + 1):
            at = rows[p == k]
            kinds = st.det.kind[at]
            for code in np.unique(kinds):
                self.update(st, at[kinds == code], int(code))

    def update(self, st: Stamp, rows: np.ndarray, code: int) -> None:
        """Fuse ``rows`` (one per observer, all of kind ``code``)."""
        raise NotImplementedError
