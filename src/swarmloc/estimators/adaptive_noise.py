"""Online process-noise adaptation from a filter's own innovations (``diekf``'s ``adaptive`` option): a robust,
windowed covariance-matching scale of the process noise.

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

The log is keyed by the detection's key, so a replay of late input rewrites an entry rather than adding one, and
the scale at ``t`` reads entries stamped before ``t`` only: a replay gives the in-order run's numbers."""

from __future__ import annotations

from bisect import bisect_left
from typing import Any, NamedTuple

import numpy as np

from swarmloc.node import chi2_ppf

__all__ = ["GUARD", "HIGH", "LOW", "Innovation", "NoiseScale", "innovation_terms"]

GUARD = 0.997
"""Chi-square probability of the outlier cap on one NIS."""
LOW, HIGH = 1.0, 100.0
"""Bounds of the process-noise scale (module docstring: why not below 1)."""


class Innovation(NamedTuple):
    """One innovation's terms: NIS ``e``, measurement share ``a = tr(S^-1 R)``, dof ``m``."""

    e: float
    a: float
    m: int


def innovation_terms(r: np.ndarray, S: np.ndarray, R: np.ndarray) -> Innovation | None:
    """The :class:`Innovation` of residual ``r`` with covariance ``S`` and measurement noise ``R`` (None: ``S``
    singular or the terms not finite)."""
    try:
        X = np.linalg.solve(S, np.column_stack([r, R]))
    except np.linalg.LinAlgError:
        return None
    e, a = float(r @ X[:, 0]), float(np.trace(X[:, 1:]))
    return Innovation(e, a, len(r)) if np.isfinite(e) and np.isfinite(a) else None


class NoiseScale:
    """The process-noise scale of one robot's filter (module docstring), a part of its node.

    ``window`` [s]: how far back innovations count (longer than the node's replay horizon); ``prior_dof``: ``nu0``."""

    def __init__(self, window: float = 30.0, prior_dof: float = 4.0) -> None:
        self.window = float(window)
        self.prior_dof = float(prior_dof)
        self._log: dict[tuple[float, Any], tuple[float, float, float]] = {}
        """(stamp [s], key) -> (stamp, lam_k (min(e_k, c_k) - a_k), b_k)"""
        self._stamps: list[float] = []
        self._sums = np.zeros((1, 2))
        self._dirty = False

    def record(self, t: float, key: Any, inn: Innovation) -> None:
        """File the innovation ``inn`` of the detection keyed ``key`` stamped ``t`` [s] (a replay overwrites it)."""
        e = min(inn.e, chi2_ppf(GUARD, inn.m))
        self._log[(float(t), key)] = (float(t), self.scale(t) * (e - inn.a), inn.m - inn.a)
        self._dirty = True

    def scale(self, t: float) -> float:
        """The scale in force at ``t`` [s]: from the entries stamped in ``[t - window, t)``."""
        if self._dirty:
            self._rebuild()
        i0, i1 = bisect_left(self._stamps, t - self.window), bisect_left(self._stamps, t)
        if i1 == i0:
            return 1.0
        num, den = self._sums[i1] - self._sums[i0]
        return float(np.clip((self.prior_dof + num) / (self.prior_dof + den), LOW, HIGH))

    def inflate(self, P0: np.ndarray, P1: np.ndarray, t: float) -> np.ndarray:
        """The covariance after a prediction ending at ``t`` [s] that took ``P0`` to ``P1``, its process noise
        ``P1 - P0`` scaled."""
        lam = self.scale(t)
        return P1 if lam == 1.0 else P0 + lam * (P1 - P0)

    def _rebuild(self) -> None:
        """The window's prefix sums, the entries no scale reads again forgotten (older than two windows before the
        newest: a replay goes back the node's horizon, less than a window)."""
        newest = max(k[0] for k in self._log)
        for k in [k for k in self._log if k[0] < newest - 2 * self.window]:
            del self._log[k]
        rows = sorted(self._log.values(), key=lambda v: v[0])
        self._stamps = [v[0] for v in rows]
        self._sums = np.vstack([np.zeros((1, 2)), np.cumsum([[v[1], v[2]] for v in rows], axis=0)])
        self._dirty = False
