"""Online process-noise adaptation from a filter's own innovations (the ``adaptive`` option of ``diekf`` and
``flsd``): a robust, windowed covariance-matching scale of the process noise.

An innovation ``r`` (``m`` dof) with covariance ``S = H P H^T + R`` gives three numbers
(:func:`innovation_terms`): its NIS ``e = r^T S^-1 r``, the measurement's share ``a = tr(S^-1 R)`` and the
prediction's share ``b = m - a = tr(S^-1 H P H^T)``. If the predicted covariance is ``k`` times too small,
``E[e] = a + k b``: covariance matching (Mehra, "Approaches to adaptive filtering", IEEE TAC 1972; Mohamed &
Schwarz, "Adaptive Kalman filtering for INS/GPS", J. Geodesy 1999) estimates ``k`` from a window of innovations,
and scaling the predicted covariance rather than ``Q`` itself is the variational-Bayes adaptive filter's choice
(Huang, Zhang, Wu & Chambers, "A novel adaptive Kalman filter with inaccurate process and measurement noise
covariance matrices", IEEE TAC 2018; Sarkka & Nummenmaa, IEEE TAC 2009, for ``R``), here in its scalar form. The
robot's process noise is scaled by

    ``lam(t) = (nu0 + sum_k lam_k (min(e_k, c_k) - a_k)) / (nu0 + sum_k b_k)``,  clipped to ``[LOW, HIGH]``,

over its own detections (fused or gated) stamped in ``[t - window, t)``, ``lam_k`` the scale in force when each
was formed: one window's fixed-point step to where the window's innovations match their covariance, with a prior
of ``nu0`` dof at the scale 1 (the inverse-gamma prior of the variational filters). Where the prediction's share is
small (a precise model, a noisy sensor) a small excess NIS means a large scale, which is what the plain NIS ratio
``lam e / m`` misses. The outlier guard caps each ``e_k`` at ``c_k``, the ``GUARD`` chi-square quantile of ``m_k``
dof (a gated detection counts at the cap): one wrong detection moves the sums by at most ``lam_k c_k``.

``LOW = 1``: the scale only adds to the model's process noise, never removes from it. With MRCLAM's time-correlated
camera errors, weighted by each reading's share of its stream's information (:mod:`swarmloc.sensors.decorrelate`),
the innovations are smaller than white-noise theory says (on dataset 6, median NIS/dof 0.03, mean 0.71 without
landmarks) and a scale allowed below 1 made ``diekf`` over-confident there (docs/mrclam.md, "Adaptive process
noise"). Truth-free: only the filter's innovations are read.

**The median variant** (:class:`MedianScale`, ``[filter] diekf_adaptive = "median"``) also scales *down*, to
``FLOOR``, and reads the bulk of the innovations rather than their mean: MRCLAM's heading errors are mostly far
smaller than the model's and now and then large, which a mean (capped or not) cannot see. Only innovations whose
prediction share ``b``, at the scale in force, is at least ``SHARE m`` count (readings after a spell of dead
reckoning, as the held-out score's are; the many measurement-dominated ones read small under correlated camera
errors whatever the process noise). Over those stamped in ``[t - window, t)`` the scale ``lam`` solves

    ``median_k e_k(lam) / med_m = 1``,  ``e_k(lam) = sum_i c_ki / (1 + (lam / lam_k) mu_ki)``,  ``lam`` in
    ``[FLOOR, 1]``

(``med_m`` the chi-square median of ``m`` dof; ``mu_i``, ``c_i = (v_i^T r)^2`` from the generalized eigenvectors
of ``(S - R) v = mu R v``, ``v^T R v = 1``, :attr:`Innovation.modes`: ``e_k(lam)`` is the NIS had the prediction
been formed at ``lam``), covariance matching on the median (robust to the heavy tail). It needs ``MIN_COUNT``
such innovations in the window, one at least of a landmark (robot-robot innovations cannot see the team's common
drift: scaled down from them alone, ``diekf`` was over-confident on dataset 6 without landmarks, docs/mrclam.md);
otherwise the scale is 1.

The log is keyed by the detection's key, so a replay of late input rewrites an entry rather than adding one, and
the scale at ``t`` reads entries stamped before ``t`` only: a replay gives the in-order run's numbers."""

from __future__ import annotations

from abc import ABC, abstractmethod
from bisect import bisect_left
from typing import Any, Literal, NamedTuple

import numpy as np

from swarmloc.node import chi2_ppf

__all__ = [
    "FLOOR",
    "GUARD",
    "HIGH",
    "LOW",
    "MIN_COUNT",
    "SHARE",
    "Innovation",
    "MedianScale",
    "NoiseScale",
    "in_force",
    "innovation_terms",
    "scale_for",
    "scaled",
]

GUARD = 0.997
"""Chi-square probability of the outlier cap on one NIS."""
LOW, HIGH = 1.0, 100.0
"""Bounds of the process-noise scale (module docstring: why not below 1)."""
FLOOR, SHARE, MIN_COUNT = 0.003, 0.5, 5
"""The median variant's lowest scale, least prediction share per dof, and fewest innovations in a window. The
floor is where it stops binding on MRCLAM: dataset 9's held-out score is the same at 0.001 (docs/mrclam.md)."""


Adaptive = bool | Literal["median"]
"""``diekf``'s ``adaptive`` option: False, True (:class:`NoiseScale`) or ``"median"`` (:class:`MedianScale`)."""


def in_force(adaptive: Adaptive, landmarks: Any, use_landmarks: bool = True) -> Adaptive:
    """``adaptive`` as it acts on a ``diekf`` with the landmark map ``landmarks``: the median variant reads landmark
    innovations only, so where no landmark can be fused (no map, or landmarks off) its scale is 1 and it is the fixed
    noise, ``False`` (the node builds no scale, the engine replays it as it is)."""
    return False if adaptive == "median" and not (landmarks and use_landmarks) else adaptive


def scale_for(adaptive: Adaptive, landmarks: Any, use_landmarks: bool = True) -> NoiseScale | MedianScale | None:
    """The scale a node with the landmark map ``landmarks`` builds for ``adaptive`` (:func:`in_force`): a
    :class:`MedianScale`, a :class:`NoiseScale`, or None (the noise as given)."""
    adaptive = in_force(adaptive, landmarks, use_landmarks)
    return MedianScale() if adaptive == "median" else NoiseScale() if adaptive else None


class Innovation(NamedTuple):
    """One innovation's terms: NIS ``e``, measurement share ``a = tr(S^-1 R)``, dof ``m``."""

    e: float
    a: float
    m: int
    modes: tuple[tuple[float, float], ...] = ()
    """``(c_i, mu_i)`` (module docstring, the median variant): ``e = sum c_i / (1 + mu_i)``, ``a = sum 1 / (1 +
    mu_i)``; empty where ``R`` is not positive definite."""
    landmark: bool = False
    """Whether the detection was of a landmark (absolute) rather than a robot."""


def innovation_terms(r: np.ndarray, S: np.ndarray, R: np.ndarray, landmark: bool = False) -> Innovation | None:
    """The :class:`Innovation` of residual ``r`` with covariance ``S`` and measurement noise ``R``, of a landmark or
    not (None: ``S`` singular or the terms not finite)."""
    try:
        X = np.linalg.solve(S, np.column_stack([r, R]))
    except np.linalg.LinAlgError:
        return None
    e, a = float(r @ X[:, 0]), float(np.trace(X[:, 1:]))
    if not (np.isfinite(e) and np.isfinite(a)):
        return None
    return Innovation(e, a, len(r), _modes(r, S, R), landmark)


def _modes(r: np.ndarray, S: np.ndarray, R: np.ndarray) -> tuple[tuple[float, float], ...]:
    """:attr:`Innovation.modes` of ``(r, S, R)``: with ``R = L L^T`` and ``L^-1 (S - R) L^-T = U diag(mu) U^T``,
    ``c = (U^T L^-1 r)^2`` (empty: ``R`` not positive definite)."""
    try:
        L = np.linalg.cholesky(R)
    except np.linalg.LinAlgError:
        return ()
    Li = np.linalg.inv(L)
    mu, U = np.linalg.eigh(Li @ (S - R) @ Li.T)
    c = (U.T @ (Li @ r)) ** 2
    return tuple(zip(c.tolist(), np.maximum(mu, 0.0).tolist(), strict=True))


def scaled(P0: np.ndarray, P1: np.ndarray, lam: float) -> np.ndarray:
    """The covariance ``P0 + lam (P1 - P0)``: a prediction's process noise scaled."""
    return P1 if lam == 1.0 else P0 + lam * (P1 - P0)


class _Windowed(ABC):
    """What both scales share: the log of innovations keyed ``(stamp, key)`` (each entry's first item its stamp),
    its rows sorted by stamp (rebuilt when the log changed), the window of rows in force at a time, and the scaled
    prediction. ``_rebuild`` is each scale's own."""

    def __init__(self, window: float) -> None:
        self.window = float(window)
        self._log: dict[tuple[float, Any], Any] = {}
        self._stamps: list[float] = []
        self._dirty = False

    @abstractmethod
    def scale(self, t: float) -> float: ...

    def inflate(self, P0: np.ndarray, P1: np.ndarray, t: float) -> np.ndarray:
        """The covariance after a prediction ending at ``t`` [s] that took ``P0`` to ``P1``, its process noise
        ``P1 - P0`` scaled."""
        return scaled(P0, P1, self.scale(t))

    def _span(self, t: float) -> tuple[int, int]:
        """The rows stamped in ``[t - window, t)``: ``(first, past the last)``, the rows rebuilt first if the log
        changed."""
        if self._dirty:
            self._rebuild()
            self._dirty = False
        return bisect_left(self._stamps, t - self.window), bisect_left(self._stamps, t)

    def _rows(self) -> list[Any]:
        """The log's entries sorted by stamp (and their stamps kept), the entries no scale reads again forgotten
        (older than two windows before the newest: a replay goes back the node's horizon, less than a window)."""
        if self._log:
            newest = max(k[0] for k in self._log)
            for k in [k for k in self._log if k[0] < newest - 2 * self.window]:
                del self._log[k]
        rows = sorted(self._log.values(), key=lambda v: v[0])
        self._stamps = [v[0] for v in rows]
        return rows

    @abstractmethod
    def _rebuild(self) -> None:
        """Each scale's own: its window's numbers from :meth:`_rows`."""


class NoiseScale(_Windowed):
    """The process-noise scale of one robot's filter (module docstring), a part of its node.

    ``window`` [s]: how far back innovations count (longer than the node's replay horizon); ``prior_dof``: ``nu0``.
    Its log's entries: ``(stamp, lam_k (min(e_k, c_k) - a_k), b_k)``."""

    def __init__(self, window: float = 30.0, prior_dof: float = 4.0) -> None:
        super().__init__(window)
        self.prior_dof = float(prior_dof)
        self._sums = np.zeros((1, 2))

    def record(self, t: float, key: Any, inn: Innovation) -> None:
        """File the innovation ``inn`` of the detection keyed ``key`` stamped ``t`` [s] (a replay overwrites it)."""
        e = min(inn.e, chi2_ppf(GUARD, inn.m))
        self._log[(float(t), key)] = (float(t), self.scale(t) * (e - inn.a), inn.m - inn.a)
        self._dirty = True

    def scale(self, t: float) -> float:
        """The scale in force at ``t`` [s]: from the entries stamped in ``[t - window, t)``."""
        i0, i1 = self._span(t)
        if i1 == i0:
            return 1.0
        num, den = self._sums[i1] - self._sums[i0]
        return float(np.clip((self.prior_dof + num) / (self.prior_dof + den), LOW, HIGH))

    def _rebuild(self) -> None:
        """The window's prefix sums (:meth:`_Windowed._rows`)."""
        rows = self._rows()
        self._sums = np.vstack([np.zeros((1, 2)), np.cumsum([[v[1], v[2]] for v in rows], axis=0)])


class MedianScale(_Windowed):
    """The median variant of the process-noise scale (module docstring), the same interface as :class:`NoiseScale`.

    ``window`` [s]: how far back innovations count. Its log's entries: ``(stamp, landmark, c, mu at the scale 1,
    chi-square median of the dof)``."""

    def __init__(self, window: float = 60.0) -> None:
        super().__init__(window)
        self._landmarks = np.zeros(1)
        self._c = self._mu = np.zeros((0, 0))
        self._med = np.zeros(0)
        self._solved: dict[tuple[int, int], float] = {}

    def record(self, t: float, key: Any, inn: Innovation) -> None:
        """File the innovation ``inn`` of the detection keyed ``key`` stamped ``t`` [s] if it is prediction-dominated
        (a replay overwrites it, or drops it where it no longer is)."""
        k = (float(t), key)
        self._dirty = self._dirty or k in self._log
        self._log.pop(k, None)
        if not inn.modes or inn.m - inn.a < SHARE * inn.m:
            return
        c, mu = np.array(inn.modes).T
        self._log[k] = (float(t), inn.landmark, c, mu / self.scale(t), chi2_ppf(0.5, inn.m))
        self._dirty = True

    def scale(self, t: float) -> float:
        """The scale in force at ``t`` [s]: from the entries stamped in ``[t - window, t)``."""
        i0, i1 = self._span(t)
        if i1 - i0 < MIN_COUNT or self._landmarks[i1] == self._landmarks[i0]:
            return 1.0
        if (i0, i1) not in self._solved:
            self._solved[(i0, i1)] = self._solve(self._c[i0:i1], self._mu[i0:i1], self._med[i0:i1])
        return self._solved[(i0, i1)]

    @staticmethod
    def _solve(c: np.ndarray, mu: np.ndarray, med: np.ndarray) -> float:
        """``lam`` in ``[FLOOR, 1]`` where the median NIS ratio of the rows ``c``, ``mu`` ``(n, m)``, ``med``
        ``(n,)`` is 1 (module docstring), by bisection in ``log lam`` (the ratio falls as ``lam`` grows)."""

        def ratio(lam: float) -> float:
            return float(np.median(np.sum(c / (1.0 + lam * mu), axis=1) / med))

        lo, hi = np.log(FLOOR), 0.0
        if ratio(1.0) >= 1.0:
            return 1.0
        if ratio(FLOOR) <= 1.0:
            return FLOOR
        for _ in range(25):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ratio(float(np.exp(mid))) > 1.0 else (lo, mid)
        return float(np.exp(0.5 * (lo + hi)))

    def _rebuild(self) -> None:
        """The window's rows and landmark counts (:meth:`_Windowed._rows`)."""
        rows = self._rows()
        m = max((len(v[2]) for v in rows), default=0)  # fewer dof padded with c = 0
        self._landmarks = np.concatenate([[0], np.cumsum([v[1] for v in rows])])
        self._c = np.array([np.pad(v[2], (0, m - len(v[2]))) for v in rows]).reshape(len(rows), m)  # (0, 0): none
        self._mu = np.array([np.pad(v[3], (0, m - len(v[3]))) for v in rows]).reshape(len(rows), m)
        self._med = np.array([v[4] for v in rows])
        self._solved = {}
