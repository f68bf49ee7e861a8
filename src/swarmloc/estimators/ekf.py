"""EKF-family estimators in Cartesian coordinates ``(x, y, theta)``: the distributed EKF and the centralized CL-EKF.

Prediction (both): the mean moves along the exact arc of the odometry ``(v, w)`` over ``dt`` (the same mean as
the exponential-coordinate estimator, so comparisons isolate the filters, not the integrators; the thesis'
eq. 5.13 is its Euler approximation), the covariance by the linearization

    P <- Phi P Phi^T + B Sigma_inc B^T,   Phi = [[1, 0, -dy], [0, 1, dx], [0, 0, 1]],   B = diag(R(theta+), 1),

where ``(dx, dy)`` is the world-frame displacement and ``Sigma_inc`` the increment covariance of eq. (5.4) in
the robot's frame at the end of the interval (thesis eqs. 2.4-2.5, 5.15-5.16 with the same process noise as
:class:`~swarmloc.estimators.expfusion.ExpFusion`).

Updates use :mod:`swarmloc.sensors.models` (relative pose, range-bearing, range, bearing; robots or landmarks
with known position and standard deviation, slides 9-11 and 18-19). The distributed EKF (thesis 2.6-2.12,
Roumeliotis & Bekey) adds the neighbour's covariance, obtained over the channel, to the innovation covariance
and ignores the cross-correlation; the centralized EKF (slides 15-17) keeps the joint covariance of the team
and is exact to first order.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from swarmloc.estimators.base import (
    Channel,
    Estimator,
    cartesian_to_group,
    group_to_cartesian,
    landmark_state,
)
from swarmloc.events import Detection
from swarmloc.gaussian import GroupGaussian
from swarmloc.motion import UnicycleNoise, odometry_increment
from swarmloc.sensors import models


def cartesian_increment(
    x: np.ndarray, v: float, w: float, dt: float, noise: UnicycleNoise
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """New mean, ``Phi`` and the additive process covariance for one odometry step (module docstring)."""
    inc_mean, inc_cov = odometry_increment(float(v), float(w), float(dt), noise)
    c, s = np.cos(x[2]), np.sin(x[2])
    dx = c * inc_mean[0, 2] - s * inc_mean[1, 2]
    dy = s * inc_mean[0, 2] + c * inc_mean[1, 2]
    th = models.wrap(x[2] + np.arctan2(inc_mean[1, 0], inc_mean[0, 0]))
    new = np.array([x[0] + dx, x[1] + dy, float(th)])
    Phi = np.array([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]])
    cn, sn = np.cos(th), np.sin(th)
    B = np.array([[cn, -sn, 0.0], [sn, cn, 0.0], [0.0, 0.0, 1.0]])
    return new, Phi, B @ inc_cov @ B.T


def _predicted(x: np.ndarray, P: np.ndarray, dt: float, v: float, w: float, noise: UnicycleNoise) -> GroupGaussian:
    if dt <= 0:
        return cartesian_to_group(x, P)
    xn, Phi, Qd = cartesian_increment(x, v, w, dt, noise)
    return cartesian_to_group(xn, Phi @ P @ Phi.T + Qd)


def measurement_noise(d: Detection) -> np.ndarray:
    """Noise covariance of ``d.z`` in the coordinates the Cartesian models predict."""
    cov = np.asarray(d.cov, dtype=float)
    if d.kind == "pose":
        return models.pose_noise_to_cartesian(np.asarray(d.z, dtype=float), cov)
    return cov


class DistributedEKF(Estimator):
    """Distributed EKF (thesis 2.1 and 5.2): one Cartesian EKF per robot, neighbours' covariances as noise."""

    name = "dekf"

    def _init_state(self, initial: Mapping[int, GroupGaussian]) -> None:
        self._x: dict[int, np.ndarray] = {}
        self._P: dict[int, np.ndarray] = {}
        for r, b in initial.items():
            self._x[r], self._P[r] = group_to_cartesian(b)

    def predict(self, robot: int, t0: float, t1: float, v: float, w: float) -> None:
        self._check_robot(robot)
        if t1 <= t0:
            return
        x, Phi, Qd = cartesian_increment(self._x[robot], v, w, t1 - t0, self.noise)
        self._x[robot] = x
        self._P[robot] = Phi @ self._P[robot] @ Phi.T + Qd
        self.stats["predict"] += 1

    def belief(self, robot: int) -> GroupGaussian:
        self._check_robot(robot)
        return cartesian_to_group(self._x[robot], self._P[robot])

    def predicted_belief(self, robot: int, dt: float, v: float, w: float) -> GroupGaussian:
        self._check_robot(robot)
        return _predicted(self._x[robot], self._P[robot], dt, v, w, self.noise)

    def _target(self, robot: int, t: float, d: Detection, channel: Channel) -> tuple[np.ndarray, np.ndarray] | None:
        tgt = self.resolve_target(robot, t, d, channel)
        return group_to_cartesian(tgt) if isinstance(tgt, GroupGaussian) else tgt

    def update(self, robot: int, t: float, detections: Sequence[Detection], channel: Channel) -> None:
        self._check_robot(robot)
        for d in self.usable(robot, detections):
            x, P = self._x[robot], self._P[robot]
            if d.kind == "absolute":
                h, Hi, extra = x, np.eye(3), np.zeros((3, 3))
                kind = "pose"
            else:
                tgt = self._target(robot, t, d, channel)
                if tgt is None:
                    continue
                xk, Pk = tgt
                h, Hi, Hk = models.predict(d.kind, x, xk)
                extra = Hk @ Pk @ Hk.T
                kind = d.kind
            R = measurement_noise(d)
            S = Hi @ P @ Hi.T + extra + R
            r = models.residual(kind, d.z, h)
            if self.gated(float(r @ np.linalg.solve(S, r)), len(r)):
                continue
            K = P @ Hi.T @ np.linalg.inv(S)
            xn = x + K @ r
            xn[2] = models.wrap(xn[2])
            IKH = np.eye(3) - K @ Hi
            self._x[robot] = xn
            self._P[robot] = IKH @ P @ IKH.T + K @ (extra + R) @ K.T  # Joseph form
            self.stats["fused"] += 1
        self.stats["update"] += 1


class CentralizedEKF(Estimator):
    """Centralized cooperative-localization EKF with the joint covariance of the team (slides 15-19).

    Not distributed: one filter sees every robot's odometry and every detection. The reference that the
    distributed estimators are scored against.
    """

    name = "cekf"
    distributed = False

    def _init_state(self, initial: Mapping[int, GroupGaussian]) -> None:
        self._idx = {r: 3 * i for i, r in enumerate(self.robots)}
        n = 3 * len(self.robots)
        self._X = np.zeros(n)
        self._P = np.zeros((n, n))
        for r, b in initial.items():
            i = self._idx[r]
            self._X[i : i + 3], self._P[i : i + 3, i : i + 3] = group_to_cartesian(b)

    def predict(self, robot: int, t0: float, t1: float, v: float, w: float) -> None:
        self._check_robot(robot)
        if t1 <= t0:
            return
        i = self._idx[robot]
        sl = slice(i, i + 3)
        x, Phi, Qd = cartesian_increment(self._X[sl], v, w, t1 - t0, self.noise)
        self._X[sl] = x
        P = self._P
        P[sl, :] = Phi @ P[sl, :]
        P[:, sl] = P[:, sl] @ Phi.T
        P[sl, sl] += Qd
        self.stats["predict"] += 1

    def belief(self, robot: int) -> GroupGaussian:
        self._check_robot(robot)
        i = self._idx[robot]
        return cartesian_to_group(self._X[i : i + 3], self._P[i : i + 3, i : i + 3])

    def predicted_belief(self, robot: int, dt: float, v: float, w: float) -> GroupGaussian:
        self._check_robot(robot)
        i = self._idx[robot]
        return _predicted(self._X[i : i + 3], self._P[i : i + 3, i : i + 3], dt, v, w, self.noise)

    def joint_covariance(self) -> np.ndarray:
        """The full ``3n x 3n`` covariance (robots in sorted id order)."""
        return self._P.copy()

    def update(self, robot: int, t: float, detections: Sequence[Detection], channel: Channel) -> None:
        self._check_robot(robot)
        i = self._idx[robot]
        n = self._X.size
        for d in self.usable(robot, detections):
            xi = self._X[i : i + 3]
            extra = np.zeros((len(d.z), len(d.z)))
            if d.kind == "absolute":
                h = xi.copy()
                H = np.zeros((3, n))
                H[:, i : i + 3] = np.eye(3)
                kind = "pose"
            elif d.target_is_robot:
                if not self.use_relative or d.target == robot or d.target not in self._idx:
                    if d.target not in self._idx:
                        self.stats["unknown"] += 1
                    elif d.target == robot:
                        self.stats["rejected"] += 1
                    continue
                k = self._idx[d.target]
                h, Hi, Hk = models.predict(d.kind, xi, self._X[k : k + 3])
                H = np.zeros((len(h), n))
                H[:, i : i + 3] = Hi
                H[:, k : k + 3] = Hk
                kind = d.kind
            else:
                if self.use_landmarks and d.kind == "pose":  # a landmark is a point: it has no relative pose
                    self.stats["rejected"] += 1
                    continue
                lm = landmark_state(self.landmarks, d.target) if self.use_landmarks else None
                if lm is None:
                    if self.use_landmarks:
                        self.stats["unknown"] += 1
                    continue
                h, Hi, Hk = models.predict(d.kind, xi, lm[0])
                H = np.zeros((len(h), n))
                H[:, i : i + 3] = Hi
                extra = Hk @ lm[1] @ Hk.T
                kind = d.kind
            R = measurement_noise(d) + extra
            PHt = self._P @ H.T
            S = H @ PHt + R
            r = models.residual(kind, d.z, h)
            if self.gated(float(r @ np.linalg.solve(S, r)), len(r)):
                continue
            K = PHt @ np.linalg.inv(S)
            self._X = self._X + K @ r
            for j in range(2, n, 3):
                self._X[j] = models.wrap(self._X[j])
            IKH = np.eye(n) - K @ H
            self._P = IKH @ self._P @ IKH.T + K @ R @ K.T
            self.stats["fused"] += 1
        self.stats["update"] += 1


__all__ = ["DistributedEKF", "CentralizedEKF", "cartesian_increment"]
