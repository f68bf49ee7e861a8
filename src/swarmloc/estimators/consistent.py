"""Consistent distributed fusion: covariance intersection in exponential coordinates, and recursive
decentralized localization that tracks cross-correlations (Luft, Schubert, Roumeliotis & Burgard, IJRR 2018).

Why two: the thesis fusion (and the distributed EKF) treat a neighbour's belief as independent of one's own.
After two robots have fused each other's information once, that is false, and repeating it double counts
(lecture slides 26-28): the filters become over-confident. There are two ways out.

* :class:`ExpCI` (``"ci"``) keeps the thesis' state (one Gaussian on SE(2) per robot, nothing else) and fuses
  the correlated part with *covariance intersection*: for any unknown correlation between the robot's belief
  ``Sigma_i`` and the neighbour's ``Sigma_k``, ``blockdiag(Sigma_i / w, Sigma_k / (1 - w))`` bounds their joint
  covariance (Julier & Uhlmann 1997), while the measurement noise, independent of both, is fused as usual
  ("CI with independent measurement noise", as in Carrillo-Arce et al., IROS 2013). ``w`` minimizes the
  determinant of the posterior. Consistent by construction, but conservative: it never gains as much as a
  filter that knows the correlations. Landmarks and absolute fixes are independent information and are fused
  normally.
* :class:`RecursiveDecentralized` (``"rdl"``) keeps, on each robot ``i``, its Cartesian state and covariance and a
  factor ``sigma_il`` for every other robot ``l`` such that the cross-covariance is
  ``Sigma_il = sigma_il sigma_li^T``. Prediction updates only the robot's own factors (``sigma_il <- Phi_i
  sigma_il``); a relative measurement needs only the two robots involved, which exchange state, covariance and
  their factors and perform the joint EKF update exactly; the cross-covariances with all other robots are
  updated approximately by ``Sigma_il+ = Sigma_ii+ Sigma_ii-^-1 Sigma_il-`` (Luft et al.). It reaches
  close to the centralized EKF's accuracy while staying (approximately) consistent, with pairwise
  communication only. Measured on MRCLAM dataset 6 with landmarks: RMSE 0.143 m vs the centralized 0.134 m,
  ANEES 1.37; without landmarks (team pose unobservable) the approximation fails: ANEES 24.8.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import partial

import numpy as np
from scipy.optimize import minimize_scalar

from swarmloc.estimators.base import Channel, Estimator, cartesian_to_group, group_to_cartesian, landmark_state
from swarmloc.estimators.ekf import _predicted, cartesian_increment, measurement_noise
from swarmloc.estimators.expfusion import ExpFusion, _Node
from swarmloc.events import Detection
from swarmloc.fusion import (
    fuse_point_measurement,
    fuse_pseudo,
    point_innovation,
    pseudo_innovation,
    relative_to_pseudo,
)
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.sensors import models

_W_BOUNDS = (1e-3, 1 - 1e-3)


def _best_weight(fuse_with_weight) -> tuple[np.ndarray, np.ndarray]:
    """Minimize ``log det`` of the fused covariance over the CI weight ``w``; return the fused belief."""

    def cost(w: float) -> float:
        return float(np.linalg.slogdet(fuse_with_weight(w)[1])[1])

    res = minimize_scalar(cost, bounds=_W_BOUNDS, method="bounded", options={"xatol": 1e-3})
    return fuse_with_weight(float(res.x))


class ExpCI(ExpFusion):
    """Thesis-style exponential-coordinate estimator with covariance-intersection fusion of neighbours."""

    name = "ci"

    def update(self, robot: int, t: float, detections: Sequence[Detection], channel: Channel) -> None:
        self._check_robot(robot)
        node = self._nodes[robot]
        for d in self.usable(robot, detections):
            if d.kind == "absolute" or not d.target_is_robot:
                # independent information: the usual update
                pseudo = self._pseudo(robot, t, d, channel)
                if pseudo is None:
                    self._update_other(robot, t, [d], channel)
                elif pseudo is not False and not self.gated(
                    partial(pseudo_innovation, node.mean, node.cov, pseudo[0], pseudo[1]), 3
                ):
                    node.mean, node.cov = fuse_pseudo(
                        SE2, node.mean, node.cov, pseudo[0][None], pseudo[1][None], self.order, self.iterations
                    )
                    self.stats["fused"] += 1
                continue
            nb = self.resolve_target(robot, t, d, channel)
            if nb is None:
                continue
            if self._ci_gated(node, d, nb):
                continue
            self._ci_fuse(node, d, nb)
            self.stats["fused"] += 1
        self.stats["update"] += 1

    def _ci_gated(self, node: _Node, d: Detection, nb: GroupGaussian) -> bool:
        if self.gate is None:
            return False
        R = np.asarray(d.cov, dtype=float)
        if d.kind == "pose":
            nu, W = relative_to_pseudo(SE2, nb.mean, nb.cov, SE2.from_xytheta(d.z), R, self.order)
            return self.gated(pseudo_innovation(node.mean, node.cov, nu, W), 3)
        nis = point_innovation(node.mean, node.cov, d.kind, d.z, R, np.asarray(nb.mean), np.asarray(nb.cov))
        return self.gated(nis, len(d.z))

    def _ci_fuse(self, node: _Node, d: Detection, nb: GroupGaussian) -> None:
        mu, cov = node.mean, node.cov
        nb_mean, nb_cov = np.asarray(nb.mean), np.asarray(nb.cov)
        R = np.asarray(d.cov, dtype=float)
        if d.kind == "pose":
            m = SE2.from_xytheta(d.z)

            def fuse(w: float) -> tuple[np.ndarray, np.ndarray]:
                nu, W = relative_to_pseudo(SE2, nb_mean, nb_cov / (1 - w), m, R, self.order)
                return fuse_pseudo(SE2, mu, cov / w, nu[None], W[None], self.order, self.iterations)

        else:

            def fuse(w: float) -> tuple[np.ndarray, np.ndarray]:
                return fuse_point_measurement(
                    mu, cov / w, d.kind, d.z, R, nb_mean, nb_cov / (1 - w), self.point_iterations, self.order
                )

        node.mean, node.cov = _best_weight(fuse)


class _RDLNode:
    __slots__ = ("x", "P", "sigma")

    def __init__(self, x: np.ndarray, P: np.ndarray, others: Sequence[int]) -> None:
        self.x = x
        self.P = P
        self.sigma = {l: np.zeros((3, 3)) for l in others}  # robots start independent


class RecursiveDecentralized(Estimator):
    """Recursive decentralized localization (Luft et al. 2018): pairwise exact updates, tracked correlations.

    Communication per relative measurement of robot ``j`` by robot ``i``: ``i`` asks ``j`` for
    ``(x_j, P_jj, sigma_ji)`` (request ``"rdl_state"``), computes the joint update, keeps its part and sends
    ``j`` its new ``(x_j, P_jj)`` (request ``"rdl_set"``). Nothing else of ``j`` is read.
    """

    name = "rdl"

    def _init_state(self, initial: Mapping[int, GroupGaussian]) -> None:
        self._nodes: dict[int, _RDLNode] = {}
        for r, b in initial.items():
            x, P = group_to_cartesian(b)
            self._nodes[r] = _RDLNode(x, P, [o for o in self.robots if o != r])

    # ------------------------------------------------------------------ protocol
    def predict(self, robot: int, t0: float, t1: float, v: float, w: float) -> None:
        self._check_robot(robot)
        if t1 <= t0:
            return
        n = self._nodes[robot]
        x, Phi, Qd = cartesian_increment(n.x, v, w, t1 - t0, self.noise)
        n.x = x
        n.P = Phi @ n.P @ Phi.T + Qd
        for l, s in n.sigma.items():
            n.sigma[l] = Phi @ s
        self.stats["predict"] += 1

    def belief(self, robot: int) -> GroupGaussian:
        self._check_robot(robot)
        n = self._nodes[robot]
        return cartesian_to_group(n.x, n.P)

    def predicted_belief(self, robot: int, dt: float, v: float, w: float) -> GroupGaussian:
        self._check_robot(robot)
        n = self._nodes[robot]
        return _predicted(n.x, n.P, dt, v, w, self.noise)

    def handle(self, robot: int, request: str, payload: dict) -> object:
        """Answer a neighbour's request (the only way another node touches this one)."""
        self._check_robot(robot)
        n = self._nodes[robot]
        src = payload.get("from")
        if src not in n.sigma:
            return None
        if request == "rdl_state":
            return n.x.copy(), n.P.copy(), n.sigma[src].copy()
        if request == "rdl_set":
            x, P = np.asarray(payload["x"], float), np.asarray(payload["P"], float)
            if x.shape != (3,) or P.shape != (3, 3) or not (np.isfinite(x).all() and np.isfinite(P).all()):
                return False
            self._rescale(n, P, exclude=src)
            n.x, n.P = x, P
            n.sigma[src] = np.eye(3)
            return True
        return None

    @staticmethod
    def _rescale(n: _RDLNode, P_new: np.ndarray, exclude: int | None = None) -> None:
        """``Sigma_il+ = P+ P-^-1 Sigma_il-`` for every other robot ``l`` (only this robot's factor changes)."""
        M = P_new @ np.linalg.inv(n.P)
        for l in n.sigma:
            if l != exclude:
                n.sigma[l] = M @ n.sigma[l]

    def update(self, robot: int, t: float, detections: Sequence[Detection], channel: Channel) -> None:
        self._check_robot(robot)
        n = self._nodes[robot]
        for d in self.usable(robot, detections):
            R = measurement_noise(d)
            if d.kind == "absolute" or not d.target_is_robot:
                self._private_update(n, d, R)
                continue
            if d.target == robot or d.target is None:
                self.stats["rejected"] += 1
                continue
            if d.kind == "pose" and not d.target_is_robot:
                self.stats["rejected"] += 1
                continue
            if not self.use_relative:
                continue
            if d.target not in n.sigma:
                self.stats["unknown"] += 1
                continue
            call = getattr(channel, "call", None)
            reply = call(d.target, t, "rdl_state", {"from": robot}) if call is not None else None
            if reply is None:
                self.stats["unknown"] += 1
                continue
            xj, Pjj, sigma_ji = reply
            Pij = n.sigma[d.target] @ sigma_ji.T
            h, Hi, Hj = models.predict(d.kind, n.x, xj)
            X = np.concatenate([n.x, xj])
            P = np.block([[n.P, Pij], [Pij.T, Pjj]])
            H = np.hstack([Hi, Hj])
            S = H @ P @ H.T + R
            r = models.residual(d.kind, d.z, h)
            if self.gated(float(r @ np.linalg.solve(S, r)), len(r)):
                continue
            K = P @ H.T @ np.linalg.inv(S)
            X = X + K @ r
            X[2], X[5] = models.wrap(X[2]), models.wrap(X[5])
            IKH = np.eye(6) - K @ H
            P = IKH @ P @ IKH.T + K @ R @ K.T
            if call(d.target, t, "rdl_set", {"from": robot, "x": X[3:], "P": P[3:, 3:]}) is not True:
                self.stats["unknown"] += 1
                continue
            self._rescale(n, P[:3, :3], exclude=d.target)
            n.x, n.P = X[:3], P[:3, :3]
            n.sigma[d.target] = P[:3, 3:]
            self.stats["fused"] += 1
        self.stats["update"] += 1

    def _private_update(self, n: _RDLNode, d: Detection, R: np.ndarray) -> None:
        if d.kind == "absolute":
            h, Hi, extra, kind = n.x, np.eye(3), np.zeros((3, 3)), "pose"
        else:
            lm = landmark_state(self.landmarks, d.target) if self.use_landmarks else None
            if lm is None:
                if self.use_landmarks:
                    self.stats["unknown"] += 1
                return
            h, Hi, Hk = models.predict(d.kind, n.x, lm[0])
            extra, kind = Hk @ lm[1] @ Hk.T, d.kind
        S = Hi @ n.P @ Hi.T + extra + R
        r = models.residual(kind, d.z, h)
        if self.gated(float(r @ np.linalg.solve(S, r)), len(r)):
            return
        K = n.P @ Hi.T @ np.linalg.inv(S)
        x = n.x + K @ r
        x[2] = models.wrap(x[2])
        IKH = np.eye(3) - K @ Hi
        P = IKH @ n.P @ IKH.T + K @ (extra + R) @ K.T
        self._rescale(n, P)
        n.x, n.P = x, P
        self.stats["fused"] += 1
