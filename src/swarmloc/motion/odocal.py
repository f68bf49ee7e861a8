"""Online, truth-free calibration of one robot's odometry (``diekf``'s ``odocal`` option): scale factors on the
commanded forward and angular velocities and a yaw-rate bias, estimated from the filter's own corrected motion.

Convention: the robot moves with ``v' = a_v v`` [m/s] and ``w' = a_w w + b_w`` [rad/s] for a command ``(v, w)``; the
filter predicts with ``(v', w')`` (:meth:`OdometryCalibration.apply`). The estimate compares the filter's posterior
means after its own fused detections, ``L`` apart or more (:data:`BASELINE`), with the commands between them (each
held until the next record, as the filters do): for posteriors ``(p_j, theta_j)`` at ``t_j`` and ``(p_k, theta_k)``
at ``t_k``

    wrap(theta_k - theta_j) = a_w int w dt + b_w (t_k - t_j),      u^T (p_k - p_j) = a_v |D|,

with ``D = int v (cos theta, sin theta) dt`` along the filter's own predicted heading and ``u = D / |D|``: both
linear in the unknowns. Each pair is weighted by the inverse of its variance (the two posteriors' variances summed,
taken independent: conservative, they are positively correlated, plus a floor for the model's error over the
baseline); pairs whose heading residual under the current estimate exceeds :data:`CUT` are outliers. The estimate
in force at ``t`` is the weighted least-squares one over the pairs ending before ``t`` with an exponential
forgetting of time constant ``memory`` [s] (counted back from the newest pair) and a Gaussian prior at the
uncalibrated model, clipped to :data:`BOUNDS`. This is Roy & Thrun's online self-calibration ("Online
self-calibration for mobile robots", ICRA 1999: odometry parameters fitted by maximum likelihood to the
localization's own corrected motion, with exponential decay) in the linear form of Martinelli, Tomatis & Siegwart
("Simultaneous localization and odometry self calibration for mobile robot", Autonomous Robots 2007, whose
augmented-state filter is replaced here by a separate estimate the filter does not carry). No ground truth is read.

The logs are keyed by stamp (commands) and by stamp and detection key (posteriors), so a replay of late input
rewrites entries rather than adding them, and the estimate at ``t`` reads pairs ending before ``t`` only: a replay
gives the in-order run's numbers."""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from typing import Any

import numpy as np

__all__ = ["BASELINE", "BOUNDS", "CUT", "OdometryCalibration", "pair_terms"]

BASELINE = 10.0
"""Least time [s] between the two posteriors of a pair (shorter: the corrections' noise swamps the motion)."""
CUT = 0.5
"""Heading residual [rad] beyond which a pair is an outlier."""
BOUNDS = ((0.8, 1.2), (0.8, 1.2), (-0.05, 0.05))
"""Bounds of ``a_v``, ``a_w`` and ``b_w`` [rad/s]."""
PRIOR_STD = (0.1, 0.1, 0.01)
"""Std of the Gaussian prior on ``a_v``, ``a_w`` (at 1) and ``b_w`` [rad/s] (at 0)."""
FLOOR = (1e-3, 1e-3)
"""Per second of baseline: the model's variance floor of a pair's heading [rad^2/s] and distance [m^2/s]."""


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def pair_terms(
    t: np.ndarray, v: np.ndarray, w: np.ndarray, w_cal: np.ndarray, t0: float, t1: float, theta0: float
) -> tuple[float, float, np.ndarray]:
    """``(int w dt, t1 - t0, D)`` over ``[t0, t1]`` for the commands ``(v, w)`` stamped ``t`` (increasing), each held
    until the next; ``D = int v (cos theta, sin theta) dt`` with ``theta`` integrated from ``theta0`` at ``t0`` with the
    calibrated yaw rates ``w_cal`` (midpoint of each held segment). Before the first command: at rest."""
    i0 = max(bisect_right(t, t0) - 1, 0)
    i1 = bisect_left(t, t1)
    edges = np.concatenate([[t0], t[i0 + 1 : i1], [t1]])
    if t.size == 0 or t[i0] > t0:  # nothing in force at t0: at rest until the first command
        edges = np.concatenate([[t0], t[i0:i1], [t1]]) if t.size else np.array([t0, t1])
        idx = np.concatenate([[-1], np.arange(i0, i1)])
    else:
        idx = np.arange(i0, i1)
    dt = np.diff(edges)
    vv = np.where(idx >= 0, v[idx], 0.0) if t.size else np.zeros_like(dt)
    ww = np.where(idx >= 0, w[idx], 0.0) if t.size else np.zeros_like(dt)
    wc = np.where(idx >= 0, w_cal[idx], 0.0) if t.size else np.zeros_like(dt)
    th = theta0 + np.concatenate([[0.0], np.cumsum(wc * dt)[:-1]]) + 0.5 * wc * dt
    D = np.array([np.sum(vv * np.cos(th) * dt), np.sum(vv * np.sin(th) * dt)])
    return float(np.sum(ww * dt)), float(t1 - t0), D


class OdometryCalibration:
    """One robot's odometry calibration (module docstring), a part of its node: it files the commands
    (:meth:`record_command`) and the posteriors after fusion (:meth:`record_pose`) and gives the calibrated command
    (:meth:`apply`). ``memory`` [s]: the forgetting's time constant; ``baseline`` [s]: :data:`BASELINE`."""

    def __init__(self, memory: float = 300.0, baseline: float = BASELINE) -> None:
        self.memory = float(memory)
        self.baseline = float(baseline)
        self._cmds: dict[float, tuple[float, float, float]] = {}
        """stamp [s] -> (v, w, calibrated w)"""
        self._poses: dict[tuple[float, Any], tuple[float, np.ndarray, float, float]] = {}
        """(stamp, key) -> (stamp, (x, y, theta), position variance [m^2], heading variance [rad^2])"""
        self._pairs: dict[tuple[float, Any], tuple[float, float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        """(stamp, key) -> (stamp, weight, heading rows A, y, distance rows A, y)"""
        self._stamps: list[float] = []
        self._rows = np.zeros((0, 6))
        self._dirty = False
        self._cache: dict[int, np.ndarray] = {}

    # ------------------------------------------------------------------------------------------------ inputs
    def record_command(self, t: float, v: float, w: float) -> None:
        """File the command ``(v, w)`` set at ``t`` [s] (a replay overwrites it)."""
        self._cmds[float(t)] = (float(v), float(w), self.apply(t, v, w)[1])

    def record_pose(self, t: float, key: Any, pose: np.ndarray, cov: np.ndarray) -> None:
        """File the posterior ``pose`` ``(x, y, theta)`` at ``t`` [s] after the detection keyed ``key``, with its
        covariance ``cov`` (3x3, position then heading; a body-frame one serves: only traces are read), and the
        pair it ends, if any."""
        t = float(t)
        pose = np.asarray(pose, dtype=float)
        var_p, var_th = 0.5 * float(cov[0, 0] + cov[1, 1]), float(cov[2, 2])
        self._poses[(t, key)] = (t, pose, var_p, var_th)
        older = [e for e in self._poses.values() if e[0] <= t - self.baseline]
        if not older:
            return
        tj, pj, vpj, vthj = max(older, key=lambda e: e[0])
        if tj < t - 2.0 * self.baseline:
            return
        stamps = sorted(k for k in self._cmds if tj - self.baseline <= k <= t)
        c = np.array([self._cmds[k] for k in stamps]).reshape(-1, 3)
        W, T, D = pair_terms(np.array(stamps), c[:, 0], c[:, 1], c[:, 2], tj, t, float(pj[2]))
        a = self.params(t)
        y_th = _wrap(float(pose[2] - pj[2]))
        if abs(y_th - (a[1] * W + a[2] * T)) > CUT:
            self._pairs.pop((t, key), None)
            return
        n = float(np.hypot(*D))
        y_d = float(D @ (pose[:2] - pj[:2]) / n) if n > 0 else 0.0
        w_th = 1.0 / (var_th + vthj + FLOOR[0] * T)
        w_d = 1.0 / (var_p + vpj + FLOOR[1] * T)
        self._pairs[(t, key)] = (t, 1.0, np.array([W, T]) * w_th**0.5, np.array([y_th * w_th**0.5]),
                                 np.array([n * w_d**0.5]), np.array([y_d * w_d**0.5]))  # fmt: skip
        self._dirty = True
        self._prune(t)

    # ------------------------------------------------------------------------------------------------ estimate
    def params(self, t: float) -> np.ndarray:
        """``(a_v, a_w, b_w)`` in force at ``t`` [s]: from the pairs ending before ``t``."""
        if self._dirty:
            rows = sorted(self._pairs.values(), key=lambda r: r[0])
            self._stamps = [r[0] for r in rows]
            self._rows = np.array([[r[0], *r[2], r[3][0], r[4][0], r[5][0]] for r in rows]).reshape(-1, 6)
            self._cache.clear()
            self._dirty = False
        i1 = bisect_left(self._stamps, t)
        if i1 not in self._cache:
            self._cache[i1] = self._solve(self._rows[:i1])
        return self._cache[i1]

    def apply(self, t: float, v: float, w: float) -> tuple[float, float]:
        """The calibrated command ``(a_v v, a_w w + b_w)`` in force at ``t`` [s]; at rest (``v = w = 0``) it stays
        at rest (a stopped robot does not drift by the bias)."""
        if v == 0.0 and w == 0.0:
            return 0.0, 0.0
        a = self.params(t)
        return float(a[0] * v), float(a[1] * w + a[2])

    def _solve(self, rows: np.ndarray) -> np.ndarray:
        """The forgetting, prior-regularized least squares of ``rows`` (``t``, heading row ``(W, T)`` and ``y``,
        distance row and ``y``, each scaled by the square root of its weight; module docstring), clipped to the
        bounds."""
        s = 1.0 / np.asarray(PRIOR_STD) ** 2
        f = np.exp(-(rows[-1, 0] - rows[:, 0]) / self.memory) if rows.size else np.zeros(0)
        ah, yh, an, yd = rows[:, 1:3], rows[:, 3], rows[:, 4], rows[:, 5]
        Ah = np.diag(s[1:]) + (ah * f[:, None]).T @ ah
        bh = np.array([s[1], 0.0]) + (ah * f[:, None]).T @ yh
        a_v = (s[0] + float(f @ (an * yd))) / (s[0] + float(f @ (an * an)))
        a_w, b_w = np.linalg.solve(Ah, bh)
        return np.clip(np.array([a_v, a_w, b_w]), [b[0] for b in BOUNDS], [b[1] for b in BOUNDS])

    def _prune(self, t: float) -> None:
        """Forget what no pair or estimate reads again: commands and posteriors older than four baselines before
        ``t`` (a replay goes back the node's horizon, less than that), pairs beyond five memories."""
        old = t - 4.0 * self.baseline
        if len(self._cmds) > 4096:
            self._cmds = {k: c for k, c in self._cmds.items() if k >= old}
        if len(self._poses) > 256:
            self._poses = {k: p for k, p in self._poses.items() if p[0] >= old}
        if len(self._pairs) > 4096:
            self._pairs = {k: p for k, p in self._pairs.items() if p[0] >= t - 5.0 * self.memory}
