"""The centralized cooperative-localization EKF (lecture slides 15-19): one node for the whole team.

Not distributed: one filter sees every robot's odometry and every detection, and keeps the joint Cartesian state
``X = (x_1, y_1, theta_1, ..., x_n, y_n, theta_n)`` and its ``3n x 3n`` covariance. It is exact to first order and
is the reference the distributed estimators are scored against. Each robot's block has its own clock and
command; a detection predicts both the observer and the detected robot to the detection's stamp before the joint
update, so the centralized filter compares like with like with the distributed ones (whose neighbours answer
with their belief at that stamp). Updates are the Joseph-form Kalman update on the joint state, one detection at
a time (exact for a joint Kalman update with independent measurement noise), touching only what the detection's
two 3-column blocks of ``H`` need (:func:`swarmloc.kernels.cartesian.kalman_update_blocks`: ``O(n^2)`` per
detection instead of ``O(n^3)``); a run of odometry is predicted in one float loop per robot
(:meth:`CentralizedEKF._advance_commands`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar, NamedTuple

import numpy as np

from swarmloc.estimators.dekf import DEGENERATE
from swarmloc.events import Kind
from swarmloc.gaussian import GroupGaussian
from swarmloc.kernels import cartesian as C
from swarmloc.messages import Message
from swarmloc.node import FUSED, Group, Outcome, TeamNode, belief_of, gated_kalman
from swarmloc.sensors.models import model


class TeamState(NamedTuple):
    """Joint state ``X (3n,)``, covariance ``P (3n, 3n)``, each robot's time [s] and command ``(v, w)``, and each
    robot's predictions not yet applied to ``P`` (``pend``).

    A prediction of robot ``k`` is ``P <- Phi P Phi^T + Q`` on its rows and columns, with ``Phi`` the identity but for
    ``(0, 2) = -dy`` and ``(1, 2) = dx``. Such ``Phi`` compose by adding those two entries, so successive predictions
    are kept as one ``(a, b, Q)`` per robot (``pend[k]``, the upper triangle of ``Q``) and applied to ``P`` when an
    update needs the joint covariance (:func:`flush_pending`): the mean is always current.
    """

    X: np.ndarray
    P: np.ndarray
    t: tuple[float, ...]
    cmd: tuple[tuple[float, float], ...]
    pend: tuple[tuple[float, ...] | None, ...]


def shear_upper(q: tuple[float, ...], dx: float, dy: float) -> tuple[float, ...]:
    """``Phi Q Phi^T`` for symmetric ``Q`` given by its upper triangle ``(q00, q01, q02, q11, q12, q22)``."""
    q00, q01, q02, q11, q12, q22 = q
    a02, a12 = q02 - dy * q22, q12 + dx * q22
    return (
        q00 - 2 * dy * q02 + dy * dy * q22, q01 - dy * q12 + dx * a02, a02,
        q11 + 2 * dx * q12 + dx * dx * q22, a12, q22,
    )  # fmt: skip


def compose_pending(old: tuple[float, ...] | None, dx: float, dy: float, q: Sequence[float]) -> tuple[float, ...]:
    """A robot's pending ``(a, b, Q)`` after one more prediction with shear ``(dx, dy)`` and process covariance
    ``q`` (upper triangle): ``Phi_new (Phi_old P Phi_old^T + Q_old) Phi_new^T + Q_new``."""
    if old is None:
        return (-dy, dx, *q)
    shared = shear_upper(old[2:], dx, dy)
    return (old[0] - dy, old[1] + dx, *(u + w_ for u, w_ in zip(shared, q, strict=True)))


def clock_and_pending(s: Any, k: int, t: float, pend_k: tuple) -> tuple[tuple, tuple, tuple]:
    """``(t, cmd, pend)`` of a team state with robot ``k``'s clock at ``t`` and its pending prediction ``pend_k``."""
    times = list(s.t)
    times[k] = t
    pend = list(s.pend)
    pend[k] = pend_k
    return tuple(times), s.cmd, tuple(pend)


def flush_pending(s: TeamState) -> TeamState:
    """The state with every robot's pending predictions applied to ``P``."""
    if not any(s.pend):
        return s
    P = s.P.copy()
    for k, pd in enumerate(s.pend):
        if pd is None:
            continue
        i = 3 * k
        a, b, q00, q01, q02, q11, q12, q22 = pd
        row = P[i + 2].copy()
        P[i] += a * row
        P[i + 1] += b * row
        col = P[:, i + 2].copy()
        P[:, i] += a * col
        P[:, i + 1] += b * col
        P[i : i + 3, i : i + 3] += np.array([[q00, q01, q02], [q01, q11, q12], [q02, q12, q22]])
    return TeamState(s.X, P, s.t, s.cmd, (None,) * len(s.pend))


class CentralizedEKF(TeamNode):
    """Centralized CL-EKF with the joint covariance of the team. Parameters: :class:`~swarmloc.node.team.TeamNode`'s
    (every robot's initial SE(2) belief by id, the odometry noise, the association policy, the node's keywords)."""

    name = "cekf"
    lazy_odometry = True
    error_frame: ClassVar[str] = "cartesian"
    lin_log: list | None = None
    """Set to a list to record every applied linearization (:mod:`swarmloc.evaluation.observability`)."""

    @property
    def _angles(self) -> tuple[int, ...]:
        """Indices of the headings in the joint state (wrapped in innovations)."""
        return tuple(range(2, 3 * len(self.robots), 3))

    # ------------------------------------------------------------------------------------------------ filter
    def _initial_state(self, t0: float) -> TeamState:
        n = 3 * len(self.robots)
        X, P = np.zeros(n), np.zeros((n, n))
        for r, b in self.initial.items():
            i = self._idx[r]
            X[i : i + 3], P[i : i + 3, i : i + 3] = C.from_group(b.mean, b.cov)
        n_r = len(self.robots)
        return TeamState(X, P, (t0,) * n_r, ((0.0, 0.0),) * n_r, (None,) * n_r)

    def _increment(self, s: Any, robot: int, t: float) -> tuple[int, int, tuple[float, ...]] | None:
        """``(k, i, terms)`` of predicting ``robot`` (block ``k``, first row ``i``) to ``t``:
        :func:`~swarmloc.kernels.cartesian.increment_terms` with its command; None when ``t`` is not later."""
        k = self._idx[robot] // 3
        dt = t - s.t[k]
        if dt <= 0:
            return None
        i = 3 * k
        v, w = s.cmd[k]
        return k, i, C.increment_terms(s.X[i : i + 3], v, w, dt, self.noise)

    def _advance(self, s: TeamState, robot: int, t: float) -> TeamState:
        step = self._increment(s, robot, t)
        if step is None:
            return s
        k, i, (x0, y0, th, dx, dy, *q) = step
        X = s.X.copy()
        X[i], X[i + 1], X[i + 2] = x0, y0, th
        self._log_shear(t, robot, dx, dy)
        return TeamState(X, s.P, *clock_and_pending(s, k, t, compose_pending(s.pend[k], dx, dy, q)))

    def _log_shear(self, t: float, robot: int, dx: float, dy: float) -> None:
        """Record a prediction's transition ``Phi`` (the shear by ``(dx, dy)``) when the linearization log is on."""
        if self.lin_log is not None:
            self.lin_log.append(("predict", t, robot, np.array([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]])))

    def _set_command(self, s: TeamState, robot: int, v: float, w: float) -> TeamState:
        cmd = list(s.cmd)
        cmd[self._idx[robot] // 3] = (v, w)
        return TeamState(s.X, s.P, s.t, tuple(cmd), s.pend)

    def _advance_commands(self, s: Any, cmds: Any) -> Any:
        """A run of odometry, each robot in one float loop (:func:`swarmloc.kernels.cartesian.predict_run`: the same
        bits as one :meth:`_advance` per command, its pending ``(a, b, Q)`` composed as there; tests/test_node.py
        checks it for every estimator)."""
        if self.measure_time or self.lin_log is not None:  # the log records each prediction
            return super()._advance_commands(s, cmds)
        per: dict[int, list[tuple[float, float, float]]] = {}
        for t, robot, v, w in cmds:
            per.setdefault(self._idx[robot] // 3, []).append((t, v, w))
        X = None
        times, cmd, pend = list(s.t), list(s.cmd), list(s.pend)
        for k, run in per.items():
            i = 3 * k
            old = pend[k]
            q, shear = ((0.0,) * 6, (0.0, 0.0)) if old is None else (old[2:], old[:2])
            x, q, t, cmd[k], shear = C.predict_run(
                tuple(s.X[i : i + 3].tolist()), q, times[k], cmd[k], shear, run, self.noise
            )
            if t != times[k]:
                if X is None:
                    X = s.X.copy()
                X[i], X[i + 1], X[i + 2] = x
                times[k] = t
                pend[k] = (*shear, *q)
        return TeamState(s.X if X is None else X, s.P, tuple(times), tuple(cmd), tuple(pend))

    def _belief(self, s: TeamState, robot: int) -> GroupGaussian:
        i = self._idx[robot]
        P = s.P[i : i + 3, i : i + 3]
        pd = s.pend[i // 3]
        if pd is not None:  # the robot's marginal with its pending predictions
            q = shear_upper((P[0, 0], P[0, 1], P[0, 2], P[1, 1], P[1, 2], P[2, 2]), pd[1], -pd[0])
            q00, q01, q02, q11, q12, q22 = (u + w for u, w in zip(q, pd[2:], strict=True))
            P = np.array([[q00, q01, q02], [q01, q11, q12], [q02, q12, q22]])
        return belief_of(*C.to_group(s.X[i : i + 3], P))

    def joint_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint state ``(3n,)`` and covariance ``(3n, 3n)`` in the filter's error coordinates (Cartesian here;
        world-frame errors for ``iekf``) with every robot predicted to ``t`` [s] (robots in increasing id order)."""
        at = (t, 3, 0, ())
        s = self._history.state_before(at)
        for r in self.robots:
            s = self._adv(s, r, t, at)
        s = flush_pending(s)
        return s.X.copy(), s.P.copy()

    # ------------------------------------------------------------------------------------------------ update
    def _fuse_group(self, s: TeamState, g: Group) -> tuple[TeamState, list[Outcome], list[Message]]:
        outcomes: list[Outcome] = []
        i = self._idx[g.observer]
        si = slice(i, i + 3)
        own = np.arange(i, i + 3)
        for d in g.detections:
            target = self._classify(g, d)
            if target[0] in ("rejected", "unknown"):
                outcomes.append(target)
                continue
            m = model(d.kind)
            R = m.noise(d.z, d.cov)
            xi = s.X[si]
            # H is zero but in the observer's (and the detected robot's) 3 columns: H holds those, cols says which
            if target[0] == Kind.ABSOLUTE:
                h, H, _ = m.predict(xi)
                cols, r = own, m.residual(d.z, h)
            else:
                if target[0] == "robot":
                    s = self._adv(s, target[1], g.t)  # the detected robot at the detection's stamp
                    k = self._idx[target[1]]
                    xk, Ck = s.X[k : k + 3], None
                else:
                    xk, Ck = target[1]
                if m.degenerate(xi, xk):
                    outcomes.append(("rejected", DEGENERATE))
                    continue
                h, Hi, Hk = m.predict(xi, xk)
                if Ck is None:
                    H, cols = np.hstack([Hi, Hk]), np.r_[own, k : k + 3]
                else:
                    H, cols = Hi, own
                    R = R + Hk @ Ck @ Hk.T
                r = m.residual(d.z, h)
            sf = flush_pending(s)  # pending predictions applied only for an update (so a rejected one changes no bit)
            res = gated_kalman(sf.X, sf.P, r, H, R, self.gate, cols=cols, angles=self._angles)
            if isinstance(res[0], str):
                outcomes.append(res)
                continue
            s = TeamState(*res, sf.t, sf.cmd, sf.pend)
            if self.lin_log is not None:
                blocks = {g.observer: H[:, :3]}  # H holds the observer's columns, then the detected robot's
                if target[0] == "robot":
                    blocks[target[1]] = H[:, 3:6]
                self.lin_log.append(("update", g.t, blocks, R))
            outcomes.append(FUSED)
        return s, outcomes, []
