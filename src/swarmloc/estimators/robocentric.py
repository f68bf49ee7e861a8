"""Relative mutual localization (lecture slides 22-28): robot 1 estimates its teammates' poses in its own moving
frame ("robocentric"), with one joint EKF or with one separate EKF per teammate; and absolute mutual localization
(slide 30): the relative poses of the robots' fixed frames.

State: ``q_j = (x_j, y_j, theta_j)``, the pose of robot ``j``'s frame in robot 1's frame, ``j = 2..n`` (here
indexed ``0..n-2``); metres and radians. Odometry is a displacement ``u_j = (r_x, r_y, phi)`` of robot ``j`` over one
step, in its own frame at the start of the step. Prediction (slide 25)::

    p_j' = R(phi_1)^T [p_j - r_1 + R(theta_j) r_j]        theta_j' = theta_j + phi_j - phi_1

Measurements are relative poses ``z_ab`` = pose of robot ``b`` in robot ``a``'s frame, with additive Gaussian noise
on ``(x, y, theta)``; robot 1 is index ``-1`` below (its pose in its own frame is the identity). Types (slide 25):
(a) ``z_1j = q_j``, (b) ``z_j1 = q_j^-1``, (c) ``z_jh = q_j^-1 q_h``.

* :class:`JointRobocentricEKF` keeps the full ``3(n-1)`` covariance (O(n^2)), Jacobians analytic.
* :class:`SeparateRobocentricEKF` keeps one 3x3 filter per teammate (the block-diagonal covariance of slide 26). A
  type (c) measurement ``z_jh`` is turned into robot 1's frame with the *estimate* of ``q_j``, ``q_j_hat z_jh``, and
  fused into ``q_h``'s filter with the measurement noise only (slide 27), so ``q_h``'s estimate comes to depend on
  ``q_j``'s while the filter believes the two independent: over-confidence (slide 28).
"""

from __future__ import annotations

import numpy as np

from swarmloc.lie import SE2, wrap_angle

__all__ = [
    "JointRobocentricEKF",
    "SeparateRobocentricEKF",
    "absolute_mutual",
    "compose",
    "inverse",
    "relative_measurement",
]


def compose(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``a b`` for planar poses ``(x, y, theta)``, with the Jacobians with respect to ``a`` and ``b``."""
    R = SE2.rotation(a[2])
    out = np.array([*(a[:2] + R @ b[:2]), wrap_angle(a[2] + b[2])])
    Ja = np.eye(3)
    Ja[:2, 2] = np.array([[0.0, -1.0], [1.0, 0.0]]) @ R @ b[:2]
    Jb = np.eye(3)
    Jb[:2, :2] = R
    return out, Ja, Jb


def inverse(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``a^-1`` with its Jacobian."""
    R = SE2.rotation(a[2])
    p = -R.T @ a[:2]
    J = -np.eye(3)
    J[:2, :2] = -R.T
    J[:2, 2] = np.array([[0.0, -1.0], [1.0, 0.0]]) @ R.T @ a[:2]
    return np.array([*p, wrap_angle(-a[2])]), J


def relative_measurement(q: np.ndarray, a: int, b: int) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """Predicted ``z_ab`` (``-1`` is robot 1) from the stacked state ``q`` ``(n-1, 3)``, and its Jacobians per
    teammate index."""
    if a == -1:
        return q[b].copy(), {b: np.eye(3)}
    inv, Ji = inverse(q[a])
    if b == -1:
        return inv, {a: Ji}
    z, Ja, Jb = compose(inv, q[b])
    return z, {a: Ja @ Ji, b: Jb}


def _predict_one(
    q: np.ndarray, u1: np.ndarray, uj: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Slide 25's prediction of one ``q_j``: new state and Jacobians w.r.t. ``q_j``, ``u_1`` and ``u_j``."""
    R1 = SE2.rotation(u1[2])
    Rj = SE2.rotation(q[2])
    d = q[:2] - u1[:2] + Rj @ uj[:2]
    p = R1.T @ d
    new = np.array([*p, wrap_angle(q[2] + uj[2] - u1[2])])
    S = np.array([[0.0, -1.0], [1.0, 0.0]])
    Jq = np.zeros((3, 3))
    Jq[:2, :2] = R1.T
    Jq[:2, 2] = R1.T @ S @ Rj @ uj[:2]
    Jq[2, 2] = 1.0
    J1 = np.zeros((3, 3))
    J1[:2, :2] = -R1.T
    J1[:2, 2] = -(R1.T @ S) @ d  # d/dphi1 of R(phi1)^T d = -R1^T S d
    J1[2, 2] = -1.0
    Jj = np.zeros((3, 3))
    Jj[:2, :2] = R1.T @ Rj
    Jj[2, 2] = 1.0
    return new, Jq, J1, Jj


def _residual(z: np.ndarray, h: np.ndarray) -> np.ndarray:
    r: np.ndarray = z - h
    r[2] = wrap_angle(r[2])
    return r


class JointRobocentricEKF:
    """One EKF on all of robot 1's teammates ``q`` ``(n-1, 3)`` with the full covariance ``P`` ``(3(n-1), 3(n-1))``.

    ``Q1``, ``Q`` (per teammate): covariances of the odometry displacement noise of robot 1 and of each teammate.
    """

    def __init__(self, q0: np.ndarray, P0: np.ndarray, Q1: np.ndarray, Q: np.ndarray) -> None:
        self.q = np.array(q0, dtype=float).reshape(-1, 3)
        self.m = self.q.shape[0]
        self.P = np.array(P0, dtype=float).reshape(3 * self.m, 3 * self.m)
        self.Q1 = np.asarray(Q1, dtype=float)
        self.Q = np.asarray(Q, dtype=float).reshape(self.m, 3, 3)

    def predict(self, u1: np.ndarray, u: np.ndarray) -> None:
        """Robot 1 moved by ``u1``, teammate ``j`` by ``u[j]`` (displacements in their own frames)."""
        m = self.m
        F = np.zeros((3 * m, 3 * m))
        G1 = np.zeros((3 * m, 3))
        Qn = np.zeros((3 * m, 3 * m))
        for j in range(m):
            self.q[j], Jq, J1, Jj = _predict_one(self.q[j], u1, u[j])
            F[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] = Jq
            G1[3 * j : 3 * j + 3] = J1
            Qn[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] = Jj @ self.Q[j] @ Jj.T
        self.P = F @ self.P @ F.T + G1 @ self.Q1 @ G1.T + Qn  # robot 1's noise is common to every q_j

    def update(self, a: int, b: int, z: np.ndarray, R: np.ndarray) -> float:
        """Fuse ``z_ab`` (noise covariance ``R``); returns the normalized innovation squared."""
        h, Js = relative_measurement(self.q, a, b)
        H = np.zeros((3, 3 * self.m))
        for k, J in Js.items():
            H[:, 3 * k : 3 * k + 3] = J
        r = _residual(np.asarray(z, float), h)
        S = H @ self.P @ H.T + R
        K = np.linalg.solve(S, H @ self.P).T
        dx = (K @ r).reshape(self.m, 3)
        self.q = self.q + dx
        self.q[:, 2] = wrap_angle(self.q[:, 2])
        IKH = np.eye(3 * self.m) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T
        return float(r @ np.linalg.solve(S, r))


class SeparateRobocentricEKF:
    """``n-1`` independent 3x3 EKFs, one per teammate (slides 26-27)."""

    def __init__(self, q0: np.ndarray, P0: np.ndarray, Q1: np.ndarray, Q: np.ndarray) -> None:
        self.q = np.array(q0, dtype=float).reshape(-1, 3)
        self.m = self.q.shape[0]
        P0 = np.asarray(P0, dtype=float)
        self.Ps = np.stack([P0[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] for j in range(self.m)])
        self.Q1 = np.asarray(Q1, dtype=float)
        self.Q = np.asarray(Q, dtype=float).reshape(self.m, 3, 3)

    @property
    def P(self) -> np.ndarray:
        """The block-diagonal covariance these filters stand for."""
        out = np.zeros((3 * self.m, 3 * self.m))
        for j in range(self.m):
            out[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] = self.Ps[j]
        return out

    def predict(self, u1: np.ndarray, u: np.ndarray) -> None:
        for j in range(self.m):
            self.q[j], Jq, J1, Jj = _predict_one(self.q[j], u1, u[j])
            self.Ps[j] = Jq @ self.Ps[j] @ Jq.T + J1 @ self.Q1 @ J1.T + Jj @ self.Q[j] @ Jj.T

    def _fuse(self, j: int, z: np.ndarray, h: np.ndarray, H: np.ndarray, R: np.ndarray) -> float:
        r = _residual(z, h)
        S = H @ self.Ps[j] @ H.T + R
        K = np.linalg.solve(S, H @ self.Ps[j]).T
        self.q[j] = self.q[j] + K @ r
        self.q[j, 2] = wrap_angle(self.q[j, 2])
        IKH = np.eye(3) - K @ H
        self.Ps[j] = IKH @ self.Ps[j] @ IKH.T + K @ R @ K.T
        return float(r @ np.linalg.solve(S, r))

    def update(self, a: int, b: int, z: np.ndarray, R: np.ndarray) -> float:
        z = np.asarray(z, float)
        if a == -1:  # type (a): a direct measurement of q_b
            return self._fuse(b, z, self.q[b].copy(), np.eye(3), R)
        if b == -1:  # type (b): z = q_a^-1
            h, J = inverse(self.q[a])
            return self._fuse(a, z, h, J, R)
        # type (c): z_ab in robot a's frame, taken to robot 1's frame with the estimate of q_a (slide 27)
        zb, _, Jz = compose(self.q[a], z)
        return self._fuse(b, zb, self.q[b].copy(), np.eye(3), Jz @ R @ Jz.T)


def absolute_mutual(
    q1j: np.ndarray, P1j: np.ndarray, pose1: np.ndarray, P1: np.ndarray, posej: np.ndarray, Pj: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Absolute mutual localization (slide 30): the pose of robot ``j``'s fixed frame in robot 1's fixed frame,
    ``pose1 q1j posej^-1``, from the relative pose ``q1j`` of their moving frames and each robot's pose in its own
    fixed frame, with the first-order covariance (the three inputs independent)."""
    a, Ja1, Jaq = compose(pose1, q1j)
    inv, Jinv = inverse(posej)
    out, Jl, Jr = compose(a, inv)
    J1 = Jl @ Ja1
    Jq = Jl @ Jaq
    Jj = Jr @ Jinv
    return out, J1 @ P1 @ J1.T + Jq @ P1j @ Jq.T + Jj @ Pj @ Jj.T
