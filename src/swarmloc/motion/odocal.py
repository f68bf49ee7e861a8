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
baseline); the heading change is unwrapped about its prediction under the current estimate, and a pair whose
residual exceeds :data:`CUT` beyond what any calibration within :data:`BOUNDS` explains is an outlier. The estimate
in force at ``t`` is the weighted least-squares one over the pairs ending before ``t`` with an exponential
forgetting of time constant ``memory`` [s] (counted back from the newest pair) and a Gaussian prior at the
uncalibrated model, clipped to :data:`BOUNDS`. This is Roy & Thrun's online self-calibration ("Online
self-calibration for mobile robots", ICRA 1999: odometry parameters fitted by maximum likelihood to the
localization's own corrected motion, with exponential decay) in the linear form of Martinelli, Tomatis & Siegwart
("Simultaneous localization and odometry self calibration for mobile robot", Autonomous Robots 2007, whose
augmented-state filter is replaced here by a separate estimate the filter does not carry). No ground truth is read.

The logs are keyed by stamp, and a posterior filed at ``t`` drops what was filed after it (a replay from ``t`` files
it again in order), so a replay of late input rewrites entries rather than adding them; the estimate at ``t`` reads
pairs ending before ``t`` only: a replay gives the in-order run's numbers."""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right

import numpy as np

from swarmloc.lie import wrap_angle

__all__ = ["BASELINE", "BOUNDS", "CUT", "OdometryCalibration", "pair_terms"]

BASELINE = 5.0
"""Least time [s] between the two posteriors of a pair (shorter: the corrections' noise swamps the motion)."""
CUT = 0.5
"""Heading residual [rad], beyond what the bounds explain, that makes a pair an outlier."""
BOUNDS = ((0.8, 1.2), (0.8, 1.2), (-0.05, 0.05))
"""Bounds of ``a_v``, ``a_w`` and ``b_w`` [rad/s]."""
PRIOR_STD = (0.2, 0.2, 0.02)
"""Std of the Gaussian prior on ``a_v``, ``a_w`` (at 1) and ``b_w`` [rad/s] (at 0)."""
MAX_GAP = 6.0
"""Most time between the two posteriors of a pair, in baselines (sparse detections: a longer pair, less weight)."""
FLOOR = (1e-3, 1e-3)
"""Per second of baseline: the model's variance floor of a pair's heading [rad^2/s] and distance [m^2/s]."""


def pair_terms(
    t: np.ndarray, v: np.ndarray, w: np.ndarray, w_cal: np.ndarray, t0: float, t1: float, theta0: float
) -> tuple[float, float, np.ndarray]:
    """``(int w dt, t1 - t0, D)`` over ``[t0, t1]`` for the commands ``(v, w)`` stamped ``t`` (increasing), each held
    until the next; ``D = int v (cos theta, sin theta) dt`` with ``theta`` integrated from ``theta0`` at ``t0`` with the
    calibrated yaw rates ``w_cal`` (each held segment an exact arc). Before the first command: at rest."""
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
    chord = vv * dt * np.sinc(wc * dt / (2.0 * np.pi))  # exact for a held (v, w): sin(h) / h, h = w dt / 2
    D = np.array([np.sum(chord * np.cos(th)), np.sum(chord * np.sin(th))])
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
        self._poses: dict[float, tuple[float, np.ndarray, float, float]] = {}
        """stamp -> (stamp, (x, y, theta), position variance [m^2], heading variance [rad^2])"""
        self._anchors: set[float] = set()
        """The stamps of the posteriors that start or end a pair of the chain"""
        self._pairs: dict[float, np.ndarray] = {}
        """end stamp -> the pair's row ``(t, W, T, y_theta, |D|, y_D)``, all but ``t`` times the root of its weight"""
        self._stamps: list[float] = []
        self._rows = np.zeros((0, 6))
        self._dirty = False
        self._cache: dict[int, np.ndarray] = {}

    # ------------------------------------------------------------------------------------------------ inputs
    def record_command(self, t: float, v: float, w: float) -> None:
        """File the command ``(v, w)`` set at ``t`` [s] (a replay overwrites it)."""
        self._cmds[float(t)] = (float(v), float(w), self.apply(t, v, w)[1])

    def record_pose(self, t: float, pose: np.ndarray, cov: np.ndarray) -> None:
        """File the posterior ``pose`` ``(x, y, theta)`` after fusion at ``t`` [s], with its covariance ``cov`` (3x3,
        position then heading; a body-frame one serves: only traces are read), and the pair it ends, if any. Pairs
        are chained, each from the end of the one before (they share no interval: correlated pairs would count the
        same motion many times); the chain restarts after a gap beyond :data:`MAX_GAP` baselines or an outlier. A
        posterior filed at ``t`` is a replay from ``t``: what was filed after it is dropped (filed again in order)."""
        t = float(t)
        self._poses = {k: p for k, p in self._poses.items() if k < t}
        self._anchors = {k for k in self._anchors if k < t}
        if any(k >= t for k in self._pairs):
            self._pairs = {k: p for k, p in self._pairs.items() if k < t}
            self._dirty = True
        pose = np.asarray(pose, dtype=float)
        self._poses[t] = (t, pose, 0.5 * float(cov[0, 0] + cov[1, 1]), float(cov[2, 2]))
        var_p, var_th = self._poses[t][2:]
        tj = max(self._anchors, default=None)
        if tj is None or tj < t - MAX_GAP * self.baseline or tj not in self._poses:
            self._anchors.add(t)  # a chain starts here
            return
        if tj > t - self.baseline:
            return
        _, pj, vpj, vthj = self._poses[tj]
        self._anchors.add(t)
        stamps = sorted(k for k in self._cmds if tj - self.baseline <= k <= t)
        c = np.array([self._cmds[k] for k in stamps]).reshape(-1, 3)
        W, T, D = pair_terms(np.array(stamps), c[:, 0], c[:, 1], c[:, 2], tj, t, float(pj[2]))
        a = self.params(t)
        pred = a[1] * W + a[2] * T
        res = wrap_angle(float(pose[2] - pj[2]) - pred)  # the heading change unwrapped about its prediction
        reach = max(abs(b - a[1]) for b in BOUNDS[1]) * abs(W)
        reach += max(abs(b - a[2]) for b in BOUNDS[2]) * T
        if abs(res) > CUT + reach:  # more than any calibration within the bounds explains: the chain restarts here
            return
        y_th = pred + res
        n = float(np.hypot(*D))
        y_d = float(D @ (pose[:2] - pj[:2]) / n) if n > 0 else 0.0
        w_th = 1.0 / (var_th + vthj + FLOOR[0] * T)
        w_d = 1.0 / (var_p + vpj + FLOOR[1] * T)
        sh, sd = math.sqrt(w_th), math.sqrt(w_d)
        self._pairs[t] = np.array([t, W * sh, T * sh, y_th * sh, n * sd, y_d * sd])
        self._dirty = True
        self._prune(t)

    # ------------------------------------------------------------------------------------------------ estimate
    def params(self, t: float) -> np.ndarray:
        """``(a_v, a_w, b_w)`` in force at ``t`` [s]: from the pairs ending before ``t``."""
        if self._dirty:
            self._stamps = sorted(self._pairs)
            self._rows = np.array([self._pairs[k] for k in self._stamps]).reshape(-1, 6)
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
        lo, hi = np.array(BOUNDS).T
        out: np.ndarray = np.clip(np.array([a_v, a_w, b_w]), lo, hi)
        return out

    def _prune(self, t: float) -> None:
        """Forget what no pair or estimate reads again: commands and posteriors older than two baselines beyond
        :data:`MAX_GAP` before ``t`` (a replay goes back the node's horizon, less than that), pairs beyond five
        memories."""
        old = t - (MAX_GAP + 2.0) * self.baseline
        if len(self._cmds) > 4096:
            self._cmds = {k: c for k, c in self._cmds.items() if k >= old}
        if len(self._poses) > 256:
            self._poses = {k: p for k, p in self._poses.items() if k >= old}
            self._anchors = {k for k in self._anchors if k >= old}
        if len(self._pairs) > 4096:
            self._pairs = {k: p for k, p in self._pairs.items() if k >= t - 5.0 * self.memory}
