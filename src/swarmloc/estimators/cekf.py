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

**SE(3).** With SE(3) initial beliefs the same node keeps each robot's position ``p_k`` (world frame) and attitude
``R_k`` and the joint covariance ``P (6n, 6n)`` of the errors ``(dp_k, dtheta_k)`` (``p_true = p + dp``, ``R_true =
R exp(dtheta^)``), the error of the distributed ``dekf``: a prediction of robot ``k`` over its body twist applies
``F = [[I, -R t_inc^], [0, R_inc^T]]`` to its rows and columns of ``P`` (its cross-covariances move with it) and adds
``G Sigma_inc G^T``; a ``"pose3"``, ``"rbe3"`` or ``"bearing3"`` detection of a robot, or a ``"rbe3"`` /
``"bearing3"`` one of a known 3-D landmark, is one Joseph-form update of the joint state on the two robots' columns,
applied on the group (:mod:`swarmloc.kernels.cartesian3`). The group picks the node's :class:`TeamForm` once
(:data:`FORMS`). It tracks every correlation, so it does not double count; its Jacobians are evaluated at the
current estimates, so without absolute information it may still gain spurious information along the team's
unobservable rigid motion (the world-frame ``diekf`` does not).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar, NamedTuple, Protocol, cast

import numpy as np

from swarmloc.estimators.dekf import KERNELS
from swarmloc.events import Detection, Kind
from swarmloc.gaussian import symmetric
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import cartesian3 as C3
from swarmloc.lie import SE2, SE3, wrap_angle
from swarmloc.lie.base import SEGroup
from swarmloc.motion import UnicycleNoise
from swarmloc.motion.twist3 import TwistNoise
from swarmloc.node import FUSED, Gate, Group, Outcome, TeamNode, gated_kalman
from swarmloc.sensors.models3 import group_model


class TeamState(NamedTuple):
    """Joint state ``X (3n,)``, covariance ``P (3n, 3n)``, each robot's time [s] and command ``(v, w)``, each
    robot's predictions not yet applied to ``P`` (``pend``), and, for first-estimates Jacobians (``fej``), each
    robot's first estimate at its clock ``L (3n,)`` (None for the other forms).

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
    L: np.ndarray | None = None


def shear_upper(q: Sequence[float], dx: float, dy: float) -> tuple[float, ...]:
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


def clock_and_pending(
    s: TeamState, k: int, t: float, pend_k: tuple[float, ...] | None
) -> tuple[tuple[float, ...], tuple[tuple[float, float], ...], tuple[tuple[float, ...] | None, ...]]:
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
        a, b = pd[:2]
        row = P[i + 2].copy()
        P[i] += a * row
        P[i + 1] += b * row
        col = P[:, i + 2].copy()
        P[:, i] += a * col
        P[:, i + 1] += b * col
        P[i : i + 3, i : i + 3] += C.sym3(pd[2:])
    return TeamState(s.X, P, s.t, s.cmd, (None,) * len(s.pend), s.L)


def team_state(node: TeamNode, t0: float, group: type[SEGroup] = SE2, start: Any = None) -> TeamState:
    """The team's Cartesian state at ``t0`` [s] from every robot's initial belief: on SE(2) ``X (3n,)``, on SE(3)
    every robot's pose ``X (n, 4, 4)``; each robot's block of ``X`` and ``P`` from its belief ``(mean, cov)`` by
    ``start`` (default the group's :func:`~swarmloc.kernels.cartesian.from_group`,
    :func:`~swarmloc.kernels.cartesian3.from_group`)."""
    n, d = len(node.robots), group.dim
    X, P = np.zeros(3 * n) if d == 3 else np.zeros((n, 4, 4)), np.zeros((d * n, d * n))
    for r, b in node.initial.items():
        i = node._idx[r]
        x, P[i : i + d, i : i + d] = (start or KERNELS[group].from_group)(b.mean, b.cov)
        X[slice(i, i + 3) if d == 3 else i // d] = x
    return TeamState(X, P, (t0,) * n, ((0.0, 0.0),) * n, (None,) * n)


def planar_noise(node: TeamNode) -> UnicycleNoise:
    """The odometry noise of an SE(2) team (:func:`~swarmloc.node.robot.check_model` checked it)."""
    if not isinstance(node.noise, UnicycleNoise):
        raise TypeError(f"{node.name}: an SE(2) team's noise is a UnicycleNoise, not {type(node.noise).__name__}")
    return node.noise


def increment(
    node: TeamNode, s: TeamState, robot: int, t: float
) -> tuple[int, int, tuple[float, ...], np.ndarray] | None:
    """``(k, i, terms, X)`` of predicting ``robot`` (block ``k``, first row ``i``) to ``t`` [s]:
    :func:`~swarmloc.kernels.cartesian.increment_terms` with its command, and a copy of the joint mean with the
    robot's new pose; None when ``t`` is not later."""
    k = node._idx[robot] // 3
    dt = t - s.t[k]
    if dt <= 0:
        return None
    i = 3 * k
    v, w = s.cmd[k]
    terms = C.increment_terms(s.X[i : i + 3], v, w, dt, planar_noise(node))
    X = s.X.copy()
    X[i : i + 3] = terms[:3]
    return k, i, terms, X


def log_shear(node: TeamNode, t: float, robot: int, dx: float, dy: float) -> None:
    """Record a prediction's transition ``Phi`` (the shear by ``(dx, dy)``) when the linearization log is on."""
    if node.lin_log is not None:
        node.lin_log.append(("predict", t, robot, np.array([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]])))


def cartesian_belief(s: TeamState, i: int) -> tuple[np.ndarray, np.ndarray]:
    """The marginal of the robot whose block starts at ``i``, its pending predictions applied, as a
    right-perturbation belief ``(mean, cov)``."""
    P = s.P[i : i + 3, i : i + 3]
    pd = s.pend[i // 3]
    if pd is not None:
        q = shear_upper((P[0, 0], P[0, 1], P[0, 2], P[1, 1], P[1, 2], P[2, 2]), pd[1], -pd[0])
        P = C.sym3([u + w for u, w in zip(q, pd[2:], strict=True)])
    return C.to_group(s.X[i : i + 3], P)


def team_joint(s: TeamState) -> tuple[np.ndarray, np.ndarray]:
    """``X (3n,)`` and ``P (3n, 3n)`` of ``s`` with its pending predictions applied (copies)."""
    s = flush_pending(s)
    return s.X.copy(), s.P.copy()


def cartesian_cross(s: TeamState, i: int, ks: Sequence[int]) -> np.ndarray:
    """:meth:`~swarmloc.node.team.WorldCross.world_cross` of a Cartesian joint state: its blocks of ``P`` (pending
    predictions applied), the state being world ``(x, y, theta)``."""
    P = flush_pending(s).P
    return np.array([P[i : i + 3, k : k + 3] for k in ks]).reshape(-1, 3, 3)


def joint_correction(
    P: np.ndarray, starts: list[int], blocks: list[np.ndarray], r: np.ndarray, R: np.ndarray, gate: Gate
) -> tuple[np.ndarray, np.ndarray] | Outcome:
    """The gated Kalman update (:func:`~swarmloc.node.update.gated_kalman`, Joseph form) of a joint covariance
    ``P (n, n)`` by a measurement whose Jacobian is nonzero only in the ``d``-column blocks starting at ``starts``
    (``d`` a robot's error size; ``blocks``: the Jacobian's ``(m, d len(starts))`` columns there, in one or more
    pieces): the correction ``K r (n,)`` and ``P+``, or the outcome that stops it. Cost ``O(n^2 m)``."""
    H = np.hstack(blocks)
    d = H.shape[1] // len(starts)
    cols = np.concatenate([np.arange(i, i + d) for i in starts])
    return gated_kalman(np.zeros(P.shape[0]), P, r, H, R, gate, cols=cols, angles=())


class Linearization(Protocol):
    """Where a form evaluates its Jacobians and in which error coordinates it corrects (:func:`fuse_linearized`)."""

    dim: int
    """Size of one robot's error."""
    first_estimates: bool
    """Whether the Jacobians are evaluated at :meth:`lin_point` (else at the current estimates)."""

    def pose(self, s: TeamState, k: int) -> np.ndarray:
        """The current estimate of the robot whose block starts at ``k`` (SE(2): ``(x, y, theta)``; SE(3): the pose
        ``(4, 4)``)."""

    def lin_point(self, s: TeamState, k: int) -> np.ndarray:
        """The point of the robot whose block starts at ``k`` at which its Jacobians are evaluated."""

    def to_error(self, H: np.ndarray, x: np.ndarray) -> np.ndarray:
        """A Cartesian Jacobian block at ``x`` in the form's error coordinates."""

    def correct(self, s: TeamState, delta: np.ndarray, P: np.ndarray) -> TeamState:
        """``s`` (its predictions applied) corrected by ``delta`` in error coordinates, its covariance ``P``."""


def fuse_linearized(
    form: Linearization, node: TeamNode, s: TeamState, g: Group, d: Detection, target: tuple[str, Any]
) -> tuple[TeamState, Outcome]:
    """One classified detection of group ``g`` fused into the joint state ``s`` (one rank-``m`` correction of the
    blocks it involves, :func:`joint_correction`) at ``form``'s linearization, recorded in the node's ``lin_log``:
    the new state and its outcome (the state as it was, the detected robot predicted to the stamp, when the
    detection is not fused). On SE(3) (``form.dim`` 6) the models are :mod:`swarmloc.sensors.models3`'s, a kind or
    target they do not take is refused (:func:`~swarmloc.kernels.cartesian3.unsupported`) and the noise symmetrized.
    """
    planar = form.dim == 3
    why = None if planar else C3.unsupported(d, target)
    if why is not None:
        return s, ("rejected", why)
    m: Any = group_model(d.kind, planar)
    i = node._idx[g.observer]
    xi, li = form.pose(s, i), form.lin_point(s, i)
    starts, xk = [i], cast(Any, None)
    lk = Ck = xk
    if target[0] == "robot":
        s = node._adv(s, target[1], g.t)  # the detected robot at the detection's stamp
        k = node._idx[target[1]]
        starts, xk, lk = [i, k], form.pose(s, k), form.lin_point(s, k)
    elif target[0] != Kind.ABSOLUTE:
        xk, Ck = target[1]
        lk = xk
    lin = m.linearize(d.z, d.cov, xi, xk)
    if lin is None or (form.first_estimates and m.degenerate(li, lk)):
        return s, ("rejected", m.why_degenerate)
    r, Hi, Hk, R = lin
    if form.first_estimates:
        _, Hi, Hk = m.predict(li, lk)
    blocks = [form.to_error(Hi, li)] + [form.to_error(Hk, lk) for _ in starts[1:]]
    if Ck is not None:
        R = R + Hk @ Ck @ Hk.T
    sf = flush_pending(s)
    res = joint_correction(sf.P, starts, blocks, r, R if planar else symmetric(R), node.gate)
    if isinstance(res[0], str):
        return s, res
    s = form.correct(sf, *res)
    if node.lin_log is not None:
        robots = {k: r for r, k in node._idx.items()}
        node.lin_log.append(("update", g.t, {robots[k]: H for k, H in zip(starts, blocks, strict=True)}, R))
    return s, FUSED


class TeamForm:
    """``cekf``'s joint Cartesian state of a team on ``group`` (:class:`TeamState`) and its models: on SE(2)
    ``(x, y, theta)`` per robot, predictions kept pending, the planar models (:mod:`swarmloc.sensors.models`); on
    SE(3) every robot's pose and the joint covariance of the errors ``(dp, dtheta)`` (module docstring,
    :mod:`swarmloc.kernels.cartesian3`). A :class:`~swarmloc.node.team.JointForm` whose Jacobians are evaluated at the
    current estimates (:func:`fuse_linearized`)."""

    first_estimates = False
    joint = staticmethod(team_joint)
    world_cross = staticmethod(cartesian_cross)
    fuse = fuse_linearized  # the detection loop, at this form's linearization

    def __init__(self, group: type[SEGroup] = SE2) -> None:
        self.group, self.dim = group, group.dim

    def initial(self, node: TeamNode, t0: float) -> TeamState:
        return team_state(node, t0, self.group)

    def advance(self, node: TeamNode, s: TeamState, robot: int, t: float) -> TeamState:
        if self.dim == 6:
            return self._advance3(node, s, robot, t)
        step = increment(node, s, robot, t)
        if step is None:
            return s
        k, _, (_, _, _, dx, dy, *q), X = step
        log_shear(node, t, robot, dx, dy)
        return TeamState(X, s.P, *clock_and_pending(s, k, t, compose_pending(s.pend[k], dx, dy, q)))

    @staticmethod
    def _advance3(node: TeamNode, s: TeamState, robot: int, t: float) -> TeamState:
        """:meth:`advance` on SE(3): ``F`` on the robot's rows and columns of ``P``, ``G Sigma_inc G^T`` added."""
        k = node._idx[robot] // 6
        dt = t - s.t[k]
        if dt <= 0:
            return s
        if not isinstance(node.noise, TwistNoise):
            raise TypeError(f"{node.name}: an SE(3) team's noise is a TwistNoise, not {type(node.noise).__name__}")
        X = s.X.copy()
        X[k], F, G, S = C3.step(s.X[k], *s.cmd[k], dt, node.noise)
        i = 6 * k
        P = s.P.copy()
        P[i : i + 6, :] = F @ P[i : i + 6, :]
        P[:, i : i + 6] = P[:, i : i + 6] @ F.T
        P[i : i + 6, i : i + 6] = symmetric(P[i : i + 6, i : i + 6] + G @ S @ G.T)
        return TeamState(X, P, *clock_and_pending(s, k, t, None))

    def belief(self, s: TeamState, i: int) -> tuple[np.ndarray, np.ndarray]:
        if self.dim == 6:
            mean, cov = C3.to_group(s.X[i // 6], s.P[i : i + 6, i : i + 6])
            return mean, cov
        return cartesian_belief(s, i)

    def pose(self, s: TeamState, k: int) -> np.ndarray:
        out: np.ndarray = s.X[k : k + 3] if self.dim == 3 else s.X[k // 6]
        return out

    lin_point = pose

    def to_error(self, H: np.ndarray, x: np.ndarray) -> np.ndarray:
        return H

    def correct(self, s: TeamState, delta: np.ndarray, P: np.ndarray) -> TeamState:
        if self.dim == 6:
            X = C3.correct(s.X, delta.reshape(-1, 6))
        else:
            X = s.X + delta
            X[2::3] = wrap_angle(X[2::3])
        return TeamState(X, P, s.t, s.cmd, s.pend, s.L)

    def advance_commands(
        self, node: TeamNode, s: TeamState, cmds: Sequence[tuple[float, int, float, float]]
    ) -> TeamState:
        """A run of odometry, each robot in one float loop (:func:`swarmloc.kernels.cartesian.predict_run`: the same
        bits as one :meth:`advance` per command, its pending ``(a, b, Q)`` composed as there)."""
        per: dict[int, list[tuple[float, float, float]]] = {}
        for t, robot, v, w in cmds:
            per.setdefault(node._idx[robot] // 3, []).append((t, v, w))
        X = None
        noise = planar_noise(node)
        times, cmd, pend = list(s.t), list(s.cmd), list(s.pend)
        for k, run in per.items():
            i = 3 * k
            old = pend[k]
            a, b, q00, q01, q02, q11, q12, q22 = (0.0,) * 8 if old is None else old
            x, q, t, cmd[k], shear = C.predict_run(
                tuple(s.X[i : i + 3].tolist()), (q00, q01, q02, q11, q12, q22), times[k], cmd[k], (a, b), run, noise
            )
            if t != times[k]:
                if X is None:
                    X = s.X.copy()
                X[i], X[i + 1], X[i + 2] = x
                times[k] = t
                pend[k] = (*shear, *q)
        return TeamState(s.X if X is None else X, s.P, tuple(times), tuple(cmd), tuple(pend))


FORMS: dict[type, TeamForm] = {SE2: TeamForm(SE2), SE3: TeamForm(SE3)}
"""The joint-state form of each group."""


class CentralizedEKF(TeamNode):
    """Centralized CL-EKF with the joint covariance of the team. Parameters: :class:`~swarmloc.node.team.TeamNode`'s
    (every robot's initial SE(2) or SE(3) belief by id, the odometry noise, the association policy (SE(2) only), the
    node's keywords). On SE(3) it takes ``"pose3"``, ``"rbe3"`` and ``"bearing3"`` detections of robots and
    ``"rbe3"`` / ``"bearing3"`` ones of known 3-D landmarks."""

    name = "cekf"
    lazy_odometry = True
    groups: ClassVar[tuple[type, ...]] = (SE2, SE3)
    forms = FORMS
    error_frame: ClassVar[str] = "cartesian"

    def _advance_commands(self, s: Any, cmds: Sequence[tuple[float, int, float, float]]) -> Any:
        """A run of odometry (:meth:`TeamForm.advance_commands` on SE(2); tests/test_node.py checks it for every
        estimator)."""
        if self._form is FORMS[SE2] and not self.measure_time and self.lin_log is None:
            return FORMS[SE2].advance_commands(self, s, cmds)  # the log records each prediction: not with it
        return super()._advance_commands(s, cmds)
