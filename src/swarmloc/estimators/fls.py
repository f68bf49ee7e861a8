"""A per-robot fixed-lag smoother (``"fls"``): the robot's recent poses re-estimated by GTSAM at every detection.

Each node keeps a **window**: its robot's poses (``Pose2``) at its recent detection instants, newest last, and
the factors between them:

* a prior on the oldest pose: what the poses that left the window knew (their marginal, below);
* odometry: between consecutive poses, the unicycle increment and its covariance as the motion model gives them
  (:func:`swarmloc.kernels.cartesian.predict_one` from a zero covariance in the older pose's frame, the same
  prediction ``dekf`` uses, turned to the ``Pose2`` tangent by :func:`~swarmloc.kernels.cartesian.to_group`);
* landmarks and absolute fixes: one factor per detection on the pose it was made at, with the measurement models
  of :mod:`swarmloc.sensors.models` (range-bearing, range, bearing, relative pose, absolute; a landmark's
  position covariance added to the noise, as the filters do);
* neighbours: the detected robot's pose is a variable of the window with the neighbour's answered marginal
  (:class:`~swarmloc.messages.BeliefQuery`) as its prior, tied to the observer's pose by the measurement factor.

At every detection group the window is solved again by Gauss-Newton (GTSAM's sparse elimination) from the previous
estimates (so the odometry and measurement Jacobians are relinearized at the smoothed poses, which a filter cannot
do). Poses older than ``lag`` seconds before the newest one leave the window: the factors that touch them are
linearized at the current estimate and eliminated (GTSAM :class:`gtsam.Marginals` of that sub-graph), which leaves a
Gaussian prior on the oldest pose kept. Between detections the node predicts its present from the newest pose's
marginal.

**Handoff without double counting: covariance intersection on the exchanged marginals.** A neighbour's answer may
already hold information that came from this robot (earlier answers, through any chain of robots), in unknown
amounts. As ``ci`` does for a filter, the node fuses it by covariance intersection: for a weight ``w``,
``blockdiag(Sigma_i / w, Sigma_k / (1 - w))`` bounds the joint covariance of the robot's and the neighbour's
estimates whatever their correlation (Julier & Uhlmann 1997). On a window this is exact and cheap: every factor
already in the window has its information multiplied by ``w`` (so the window's marginal of any pose is divided by
``w``, and so is its joint with every other pose of the window), the neighbour's prior has covariance
``Sigma_k / (1 - w)``, and the measurement noise, independent of both, is kept. ``w`` is ``ci``'s closed form,
computed at the node's present belief (:func:`swarmloc.kernels.ci.point_weight`,
:func:`~swarmloc.kernels.ci.pose_weight`). The answers the node gives are its present marginal, like every
``BeliefQuery`` estimator's; nothing else is exchanged, so the node runs over the network as ``ci`` does.

**History and replay.** A window is plain data (poses, estimates, factor records with their information scale),
never a live GTSAM object: the node's history keeps the window after each entry, a late input is replayed from
the window before it, and the result is a function of the inputs alone (GTSAM's solves are deterministic).
GTSAM's ``BatchFixedLagSmoother`` / ``IncrementalFixedLagSmoother`` (exposed by the 4.3 wheel) hold mutable C++
state that the history would have to copy after every entry; rebuilding the window's graph costs about as much as
one of their updates for windows of this size and makes the replay exact by construction.

**Causal.** ``belief_at(t)`` is the belief after the inputs stamped ``<= t`` (the node's contract), i.e. the
smoother's estimate of the newest pose, predicted to ``t``: a filtered estimate with relinearized history, not
the (better) smoothed estimate of a past pose. That one is the **delayed output** (option ``delayed=True``,
``[filter] delayed_output``): each pose as it leaves the window, ``lag`` s late, with its covariance
(:attr:`WindowSolver.lagged_log`); reports score it as ``"<name>_delayed"`` (:mod:`swarmloc.evaluation.delayed`)
and network nodes publish it (:mod:`swarmloc.net.publishing`).

**The delayed output's covariance: the window's marginal, bounded where factors share errors.** The marginal of a
window pose is its estimate's covariance when every factor's error is independent of the others'. ``flsd``'s
pseudo-factors are not: each is another robot's update, whose error holds that robot's estimate, which the prior
(the window's past) and the other pseudo-factors share in amounts the window does not know. The newest pose's
marginal is right anyway (each pseudo-factor is the filter's update given its belief then), but a pose filed
``lag`` s later has the information of the pseudo-factors after it too, counted as independent of its prior's:
MRCLAM 6's delayed output was more over-confident than the causal belief (ANEES/dof 1.82 against 1.53). The
filed covariance is the estimate's, bounded whatever that correlation (:func:`delayed_covariances`): the window's
estimate is ``M^-1`` times the sum of the factors' gradients; with the shared ones before and after the pose
``a`` and ``b``, ``Cov(g_a + g_b) <= Cov(g_a) / w + Cov(g_b) / (1 - w)`` (covariance intersection, Julier & Uhlmann
1997: the conservative fusion of a two-filter smoother's forward and backward estimates, Fraser & Potter 1969,
whose correlation is unknown) gives ``M^-1 (L_a / w + L_b / (1 - w) + L_r) M^-1``. The estimates are unchanged.
``fls`` has no such factors (its neighbours are fused by covariance intersection, which scales the whole window
at each one): its filed covariance is the marginal.

**Never less sure than the filter was.** The bound assumes nothing about how much of a pose's information is
shared, so where most of it came through teammates (no landmarks) it can exceed the covariance ``flsd``'s exact
filter had at that pose's stamp. Both are consistent estimates of one pose; ``flsd`` files the one with the smaller
covariance (determinant, Cartesian): its causal belief at the stamp (the filter's after the last input stamped
then, kept with the pose in the window: :attr:`Window.causal`) where the window's bound is larger, the window's
estimate otherwise (:attr:`WindowSolver.lagged_causal` lists the stamps filed as the causal belief). The choice
looks at the two covariances only, never at an error; it is part of the window, so a replay of late input files
what the ordered run filed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.linalg import splu

from swarmloc.estimators.dekf import linearize
from swarmloc.events import Detection, Kind
from swarmloc.gaussian import GroupGaussian, symmetric
from swarmloc.kernels import cartesian as C
from swarmloc.kernels.ci import point_weight, pose_weight
from swarmloc.lie import SE2, wrap_angle
from swarmloc.messages import Message
from swarmloc.node import FUSED, NUMERICAL, Group, Outcome, RobotNode, belief_of, usable_covariance
from swarmloc.sensors.models import model

__all__ = [
    "TINY_VARIANCE", "Factor", "FactorBlocks", "FixedLagSmoother", "FlsState", "OfSolver", "Window", "WindowSolver",
    "delayed_covariances", "load_gtsam",
]  # fmt: skip

_ZERO3 = np.zeros(3)
_ZERO33 = np.zeros((3, 3))
TINY_VARIANCE = 1e-12
"""Variance [m^2, rad^2] added to the diagonal of an odometry factor's covariance (a zero-length increment)."""


def load_gtsam() -> Any:
    try:
        import gtsam
    except ImportError as exc:  # pragma: no cover - gtsam is a dependency of the 'fls' and 'dev' extras
        raise ImportError("the 'fls' estimator needs GTSAM: pip install 'swarmloc[fls]' (gtsam>=4.3)") from exc
    return gtsam


class Factor(NamedTuple):
    """One factor of a window. ``kind``: ``"odometry"`` (between poses ``a`` and ``b``: ``z`` the increment
    ``(x, y, theta)`` in ``a``'s frame, ``R`` its ``Pose2``-tangent covariance), ``"unary"`` (a detection of a
    landmark or an absolute fix made at pose ``a``: ``z``, the model's noise ``R`` plus the landmark's
    covariance, ``target`` the landmark's ``(x, y)`` or None) or ``"neighbour"`` (a detection of robot ``b``'s
    pose variable, which has ``target``, the answered ``(mean (3, 3), cov (3, 3))``, as its prior).
    ``"pseudo"`` (a linear Gaussian factor on pose ``a``, error ``R (x - z) - target`` with ``x`` the Cartesian pose:
    what :mod:`swarmloc.estimators.fls_team` files for its filter's other updates).
    ``scale``: the multiplier of its information (covariance intersection); ``meas``: the detection kind."""

    kind: str
    a: int
    b: int
    meas: str
    z: np.ndarray
    R: np.ndarray
    target: Any
    scale: float

    @classmethod
    def odometry(cls, a: int, b: int, rel: np.ndarray, Q: np.ndarray) -> Factor:
        """The odometry factor between poses ``a`` and ``b``: the Cartesian increment ``rel`` ``(x, y, theta)`` in
        ``a``'s frame with its covariance ``Q``, as a ``Pose2``-tangent covariance (plus :data:`TINY_VARIANCE`)."""
        _, Qg = C.to_group(rel, Q)
        return cls("odometry", a, b, "", rel, Qg + TINY_VARIANCE * np.eye(3), None, 1.0)

    @classmethod
    def unary(cls, d: Detection, target: tuple[str, Any], R: np.ndarray, a: int = -1) -> Factor:
        """Detection ``d`` of a landmark (``target``: ``("landmark", (p, C))`` as ``_classify`` answers) or an absolute
        fix, made at pose ``a``, with noise ``R`` (the model's plus the landmark's propagated covariance)."""
        lm = None if target[0] == Kind.ABSOLUTE else np.asarray(target[1][0], dtype=float)
        return cls("unary", a, -1, d.kind, np.asarray(d.z, dtype=float), R, lm, 1.0)


class Window(NamedTuple):
    """The smoother's window: pose variable ids and stamps [s] (oldest first), the estimate of every variable
    (``id -> (x, y, theta)``; neighbour variables included), the prior on the oldest pose (``mean (x, y, theta)``,
    ``Pose2``-tangent covariance, information scale), the factors, the next free variable id, and the owner's causal
    belief at a pose's stamp where it keeps one (``id -> (x (3,), P (3, 3))`` Cartesian; ``flsd``'s, module
    docstring)."""

    poses: tuple[int, ...]
    stamps: tuple[float, ...]
    est: dict[int, np.ndarray]
    prior: tuple[np.ndarray, np.ndarray, float]
    factors: tuple[Factor, ...]
    next_id: int
    causal: Mapping[int, tuple[np.ndarray, np.ndarray]] = MappingProxyType({})


_Factors = tuple[list[Factor], dict[int, np.ndarray], int, float]
"""A window's parts as a detection group is fused into it: its factors, the estimates, the next free variable id
and the prior's information scale."""


class FlsState(NamedTuple):
    """A node's state: time [s], command ``(v, w)``, the present belief (Cartesian ``x (3,)``, ``P (3, 3)``), the
    increment since the newest pose of the window (``rel (3,)`` in that pose's frame, covariance ``Q (3, 3)``)
    and the window."""

    t: float
    v: float
    w: float
    x: np.ndarray
    P: np.ndarray
    rel: np.ndarray
    Q: np.ndarray
    win: Window


# ---------------------------------------------------------------------------------------------------- GTSAM
def _pose2(g: Any, x: np.ndarray) -> Any:
    return g.Pose2(float(x[0]), float(x[1]), float(x[2]))


def _xyt(p: Any) -> np.ndarray:
    return np.array([p.x(), p.y(), p.theta()])


def _body(H: np.ndarray, theta: float) -> np.ndarray:
    """A Jacobian w.r.t. world ``(x, y, theta)`` turned into one w.r.t. ``Pose2``'s tangent (body-frame right
    perturbation: ``dp = R(theta) d_xy``, ``dtheta = d_theta``)."""
    c, s = math.cos(theta), math.sin(theta)  # on Python floats: one factor's few rows, called per linearization
    return np.array([[a * c + b * s, -a * s + b * c, *rest] for a, b, *rest in np.asarray(H, dtype=float).tolist()])


def _measurement_factor(g: Any, f: Factor, keys: list[int]) -> Any:
    """A :class:`gtsam.CustomFactor` for a unary or neighbour factor, error ``h(x) - z`` (wrapped) with the
    model's Jacobians of :mod:`swarmloc.sensors.models`."""
    m = model(f.meas)
    z = f.z
    landmark = f.target if f.kind == "unary" else None

    def error(this: Any, values: Any, H: Any) -> np.ndarray:
        xi = _xyt(values.atPose2(this.keys()[0]))
        if f.kind == "neighbour":
            xk = _xyt(values.atPose2(this.keys()[1]))
            h, Hi, Hk = m.predict(xi, xk)
        else:
            h, Hi, Hk = m.predict(xi, landmark) if landmark is not None else m.predict(xi)
        e = -np.asarray(m.residual(z, h), dtype=float)  # h - z, angles wrapped
        if H is not None:
            H[0] = _body(np.asarray(Hi, dtype=float), xi[2])
            if f.kind == "neighbour":
                H[1] = _body(np.asarray(Hk, dtype=float), xk[2])
        return e

    return g.CustomFactor(g.noiseModel.Gaussian.Covariance(f.R / f.scale), keys, error)


def _pseudo_factor(g: Any, f: Factor) -> Any:
    """A :class:`gtsam.CustomFactor` for a linear Gaussian factor on pose ``a``: error ``A (x - z) - b`` (``x``
    Cartesian, the angle of ``x - z`` wrapped; ``A = f.R (m, 3)`` whitened, ``b = f.target (m,)``)."""
    A = f.R
    b = f.target

    def error(this: Any, values: Any, H: Any) -> np.ndarray:
        x = _xyt(values.atPose2(this.keys()[0]))
        d = x - f.z
        d[2] = wrap_angle(d[2])
        if H is not None:
            H[0] = _body(A, x[2])
        e: np.ndarray = A @ d - b
        return e

    return g.CustomFactor(g.noiseModel.Unit.Create(len(b)), [f.a], error)


def _graph(g: Any, win: Window, factors: tuple[Factor, ...] | None = None, prior: bool = True) -> Any:
    """The window's factor graph (``factors``: a subset, default all; ``prior``: include the oldest pose's)."""
    graph = g.NonlinearFactorGraph()
    if prior:
        mean, cov, scale = win.prior
        graph.add(g.PriorFactorPose2(win.poses[0], _pose2(g, mean), g.noiseModel.Gaussian.Covariance(cov / scale)))
    for f in win.factors if factors is None else factors:
        if f.kind == "odometry":
            noise = g.noiseModel.Gaussian.Covariance(f.R / f.scale)
            graph.add(g.BetweenFactorPose2(f.a, f.b, _pose2(g, f.z), noise))
        elif f.kind == "unary":
            graph.add(_measurement_factor(g, f, [f.a]))
        elif f.kind == "pseudo":
            graph.add(_pseudo_factor(g, f))
        else:
            graph.add(_measurement_factor(g, f, [f.a, f.b]))
            mean, cov = f.target
            graph.add(g.PriorFactorPose2(f.b, _pose2(g, mean), g.noiseModel.Gaussian.Covariance(cov / f.scale)))
    return graph


class WindowSolver:
    """The window's solve and marginalization: a part of the smoother nodes (their :attr:`~FixedLagSmoother.solver`),
    with ``lag`` [s], ``max_iterations`` (both checked; ``where``: the owner's name for the messages) and the
    delayed output."""

    lagged_log: dict[float, tuple[np.ndarray, np.ndarray]] | None
    """The smoothed (delayed) output, None: off (the option ``delayed=True`` or a dict set here turns it on). Every
    pose leaving the window is filed there, ``stamp [s] -> (x (3,), P (3, 3))``: its estimate ``(x, y, theta)`` and
    Cartesian covariance from the whole window's solve at that moment (at least ``lag`` seconds of later inputs; the
    latest replay's): the marginal, bounded by :func:`delayed_covariances` where pseudo-factors share errors."""
    lagged_when: dict[float, float] | None
    """``stamp [s] -> t [s]``: when each pose of :attr:`lagged_log` was filed (the solve's stamp). A filing is final
    once the node's history has passed ``t`` by a horizon: no late input replays that solve any more."""
    lagged_fresh: list[float] | None
    """None, or a list a driver empties: the stamps filed (or filed again by a replay) since it last did."""
    lagged_scale: dict[float, float]
    """``stamp [s] -> scale``: the online scale of the process noise in force at each filed pose's stamp (where the
    node has one, :attr:`scale_at`), for whoever carries the pose forward through the odometry
    (:func:`swarmloc.evaluation.delayed.carried`); dropped with the pose by whoever drops it."""
    scale_at: Callable[[float], float] | None
    """The owner's online scale of its process noise at a time [s] (None: the noise as given)."""
    lagged_causal: set[float]
    """The stamps of :attr:`lagged_log` filed as the owner's causal belief at the pose (:attr:`Window.causal`): where
    the window kept one with a smaller covariance determinant than the window's estimate (module docstring)."""

    def __init__(self, where: str, lag: float, max_iterations: int, delayed: bool) -> None:
        if not (isinstance(lag, int | float) and math.isfinite(lag) and lag > 0):
            raise ValueError(f"{where}: 'lag' must be a positive number of seconds, got {lag!r}")
        if not (isinstance(max_iterations, int) and max_iterations >= 1):
            raise ValueError(f"{where}: 'max_iterations' must be an integer >= 1, got {max_iterations!r}")
        if not isinstance(delayed, bool):
            raise ValueError(f"{where}: 'delayed' must be true or false, got {delayed!r}")
        self.lag = float(lag)
        self.max_iterations = max_iterations
        self.lagged_log = {} if delayed else None
        self.lagged_when = None
        self.lagged_fresh = None
        self.lagged_scale = {}
        self.scale_at = None
        self.lagged_causal = set()
        self._g = load_gtsam()

    def _file_lagged(self, ts: float, x: np.ndarray, P: np.ndarray, t: float,
                     causal: tuple[np.ndarray, np.ndarray] | None = None) -> None:  # fmt: skip
        """File pose ``ts``'s smoothed estimate and marginal, solved at ``t``, in the delayed output; ``causal``:
        the owner's causal belief at ``ts``, filed instead where its covariance is the smaller (determinant)."""
        if self.lagged_log is None:
            return
        if causal is not None and np.linalg.det(causal[1]) < np.linalg.det(P):
            x, P = causal
            self.lagged_causal.add(ts)
        else:
            self.lagged_causal.discard(ts)
        self.lagged_log[ts] = (x, P)
        if self.lagged_when is None:
            self.lagged_when = {}
        self.lagged_when[ts] = t
        if self.lagged_fresh is not None:
            self.lagged_fresh.append(ts)
        if self.scale_at is not None:
            self.lagged_scale[ts] = self.scale_at(ts)

    def solve(self, win: Window, newest: int, t: float) -> tuple[Window, np.ndarray, np.ndarray] | None:
        """Solve the window (Gauss-Newton from its estimates), take the newest pose's marginal and
        marginalize the poses older than ``t - lag``: ``(window, x (3,), P (3, 3) Cartesian)`` or None when the
        solve fails (not finite, or a singular marginal)."""
        g = self._g
        graph = _graph(g, win)
        values = g.Values()
        for k, xk in win.est.items():
            values.insert(k, _pose2(g, xk))
        try:
            result = values
            for _ in range(self.max_iterations):  # a fixed count: the result is a smooth function of the inputs
                result = result.retract(graph.linearize(result).optimize())
            est = {k: _xyt(result.atPose2(k)) for k in win.est}
            if not all(np.isfinite(v).all() for v in est.values()):
                return None
            marginals = g.Marginals(graph, result)
            x = est[newest]
            P = _cartesian_cov(x[2], marginals.marginalCovariance(newest))
            if not usable_covariance(P):
                return None
            win = win._replace(est=est)
            cutoff = t - self.lag
            k0 = next(i for i, ts in enumerate(win.stamps) if ts >= cutoff or i == len(win.stamps) - 1)
            if k0 > 0:
                if self.lagged_log is not None:
                    covs = [np.asarray(marginals.marginalCovariance(pid)) for pid in win.poses[:k0]]
                    if any(f.kind == "pseudo" for f in win.factors):
                        covs = delayed_covariances(_factor_blocks(graph.linearize(result), win), win, covs)
                    for pid, ts, cov in zip(win.poses[:k0], win.stamps[:k0], covs, strict=True):
                        self._file_lagged(ts, est[pid], _cartesian_cov(est[pid][2], cov), t, win.causal.get(pid))
                win = self._marginalize(win, k0, result)
        except RuntimeError:  # GTSAM: an indeterminant system
            return None
        return win, x, P

    def _marginalize(self, win: Window, k0: int, values: Any) -> Window:
        """Eliminate the window's first ``k0`` poses (and the neighbour variables tied to them): the factors
        touching them, linearized at ``values``, become a Gaussian prior on the pose ``k0``."""
        g = self._g
        drop = set(win.poses[:k0])
        keep = win.poses[k0]
        out = [f for f in win.factors if f.a in drop]
        gone = drop | {f.b for f in out if f.kind == "neighbour"}
        sub = _graph(g, win, tuple(out))
        cov = g.Marginals(sub, values).marginalCovariance(keep)
        delta = sub.linearize(values).optimize()
        mean = _xyt(values.atPose2(keep).retract(delta.at(keep)))
        est = {k: v for k, v in win.est.items() if k not in gone}
        factors = tuple(f for f in win.factors if f.a not in drop)
        causal = {k: v for k, v in win.causal.items() if k not in drop}
        return Window(win.poses[k0:], win.stamps[k0:], est, (mean, np.array(cov), 1.0), factors, win.next_id, causal)


class OfSolver:
    """A smoother node's attribute that is its window solver's (``node.solver.<name>``): ``lag`` and the delayed
    output, which drivers read and set on the node (:mod:`swarmloc.net.publishing`,
    :mod:`swarmloc.evaluation.delayed`)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, node: Any, owner: type | None = None) -> Any:
        return self if node is None else getattr(node.solver, self.name)

    def __set__(self, node: Any, value: Any) -> None:
        setattr(node.solver, self.name, value)


class FixedLagSmoother(RobotNode):
    """Per-robot fixed-lag smoother over its recent poses (GTSAM), covariance intersection with neighbours.

    Parameters (besides :class:`~swarmloc.node.robot.RobotNode`'s)
    ---------------------------------------------------------------
    lag: seconds [s] of poses kept in the window behind the newest one (> 0).
    max_iterations: Gauss-Newton iterations per solve (>= 1), always all of them: a solve that stopped at a
        convergence threshold would make the result jump with rounding, and the history's replay of late input
        must give the ordered run's result.
    delayed: keep the smoothed (delayed) output in :attr:`~WindowSolver.lagged_log` (default off).
    """

    name = "fls"
    lag = OfSolver()
    lagged_log = OfSolver()
    lagged_when = OfSolver()
    lagged_fresh = OfSolver()
    lagged_scale = OfSolver()
    lagged_causal = OfSolver()

    def __init__(self, robot: int, initial: GroupGaussian, *, lag: float = 2.0, max_iterations: int = 3,
                 delayed: bool = False, **kw: Any) -> None:  # fmt: skip
        self.solver = WindowSolver(type(self).__name__, lag, max_iterations, delayed)
        super().__init__(robot, initial, **kw)

    # ------------------------------------------------------------------------------------------------ filter
    def _initial_state(self, t0: float) -> FlsState:
        x, P = C.from_group(self.initial.mean, self.initial.cov)
        win = Window((0,), (t0,), {0: x}, (x, np.array(self.initial.cov, dtype=float), 1.0), (), 1)
        return FlsState(t0, 0.0, 0.0, x, P, _ZERO3, _ZERO33, win)

    def _advance(self, s: FlsState, robot: int, t: float) -> FlsState:
        dt = t - s.t
        if dt <= 0:
            return s
        x, P, _, _ = C.predict_one(s.x, s.P, s.v, s.w, dt, self.noise)
        rel, Q, _, _ = C.predict_one(s.rel, s.Q, s.v, s.w, dt, self.noise)
        return FlsState(t, s.v, s.w, x, P, rel, Q, s.win)

    def _set_command(self, s: FlsState, robot: int, v: float, w: float) -> FlsState:
        return s._replace(v=v, w=w)

    def _belief(self, s: FlsState, robot: int) -> GroupGaussian:
        return belief_of(*C.to_group(s.x, s.P))

    def _fuse_group(self, s: FlsState, g: Group) -> tuple[FlsState, list[Outcome], list[Message]]:
        win = s.win
        mean_i, cov_i = C.to_group(s.x, s.P)
        new_pose = win.stamps[-1] != g.t
        pid = win.next_id if new_pose else win.poses[-1]
        next_id = win.next_id + 1 if new_pose else win.next_id
        est = dict(win.est)
        factors = list(win.factors)
        prior_scale = win.prior[2]
        if new_pose:
            factors.append(Factor.odometry(win.poses[-1], pid, s.rel, s.Q))
            est[pid] = s.x

        def fuse(acc: _Factors, d: Detection, target: tuple[str, Any]) -> tuple[_Factors, Outcome]:
            """Detection ``d`` of a classified ``target`` as a factor on pose ``pid`` (a neighbour's: covariance
            intersection with the window), or the outcome that stops it."""
            factors, est, next_id, prior_scale = acc
            lin = linearize(d, s.x, target)
            if isinstance(lin, str):
                return acc, ("rejected", lin)
            r, Hi, R_eff, _ = lin
            if self.gate.p is not None:
                verdict = self._gated(float(r @ np.linalg.solve(Hi @ s.P @ Hi.T + R_eff, r)), len(r))
                if verdict is not None:
                    return acc, verdict
            if target[0] != "robot":
                return (factors + [Factor.unary(d, target, R_eff, pid)], est, next_id, prior_scale), FUSED
            z = np.asarray(d.z, dtype=float)
            nb_mean, nb_cov = target[1].belief_arrays()
            R = np.asarray(d.cov, dtype=float)
            if d.kind == Kind.POSE:
                w = float(pose_weight(mean_i, cov_i, SE2.from_xytheta(z), R, nb_mean, nb_cov))
            else:
                w = float(point_weight(mean_i, cov_i, d.kind, z, R, nb_mean, nb_cov))
            # covariance intersection: every factor already in the window keeps w of its information
            factors = [f._replace(scale=f.scale * w) for f in factors]
            nid = next_id
            est = {**est, nid: C.from_group(nb_mean, nb_cov)[0]}
            m = model(d.kind)
            factors.append(Factor("neighbour", pid, nid, d.kind, z, m.noise(z, R), (est[nid], nb_cov / (1 - w)), 1.0))
            return (factors, est, next_id + 1, prior_scale * w), FUSED

        (factors, est, next_id, prior_scale), outcomes = self._fuse_each((factors, est, next_id, prior_scale), g, fuse)
        if FUSED not in outcomes:
            return s, outcomes, []
        stamps = win.stamps + ((g.t,) if new_pose else ())
        poses = win.poses + ((pid,) if new_pose else ())
        win2 = Window(poses, stamps, est, (win.prior[0], win.prior[1], prior_scale), tuple(factors), next_id)
        solved = self.solver.solve(win2, pid, g.t)
        if solved is None:
            return s, [("rejected", NUMERICAL) if o == FUSED else o for o in outcomes], []
        win3, x, P = solved
        return FlsState(s.t, s.v, s.w, x, P, _ZERO3, _ZERO33, win3), outcomes, []


class FactorBlocks(NamedTuple):
    """A window's Gauss-Newton system at its solution, split for :func:`delayed_covariances`: ``slot`` (variable id
    -> its first row), the information ``M`` of every factor (sparse; ``Pose2`` tangent, 3 rows a variable), and
    the factors whose errors may correlate with the window's past: ``(position, rows, A)`` with ``position`` the
    index in ``poses`` of the pose it is on (-1: the prior on the oldest pose), ``rows`` the rows of its variables
    in ``M`` and ``A`` its whitened Jacobian."""

    slot: dict[int, int]
    M: Any
    shared: list[tuple[int, np.ndarray, np.ndarray]]


def _factor_blocks(lin: Any, win: Window) -> FactorBlocks:
    """The linearized window graph ``lin`` (:func:`_graph`'s factor order: the prior, then each factor's one or two)
    as :class:`FactorBlocks`: the prior and the ``"pseudo"`` factors (another robot's update of this pose, whose
    error holds that robot's, which the other pseudo-factors and the prior share) are the shared ones."""
    slot = {k: 3 * i for i, k in enumerate(sorted(win.est))}
    # per linear factor: the position of the pose a shared factor is on, None for the others
    where: list[int | None] = [-1]
    for f in win.factors:
        where += [win.poses.index(f.a)] if f.kind == "pseudo" else [None] * (2 if f.kind == "neighbour" else 1)
    shared = []
    ii, jj, vv = [], [], []
    for i, pos in enumerate(where):
        fac = lin.at(i)
        rows = np.concatenate([np.arange(slot[k], slot[k] + 3) for k in fac.keys()])
        ii.append(np.repeat(rows, rows.size))
        jj.append(np.tile(rows, rows.size))
        vv.append(np.asarray(fac.information(), dtype=float).ravel())
        if pos is not None:
            shared.append((pos, rows, np.asarray(fac.jacobian()[0], dtype=float)))
    n = 3 * len(slot)
    M = coo_matrix((np.concatenate(vv), (np.concatenate(ii), np.concatenate(jj))), shape=(n, n)).tocsc()
    return FactorBlocks(slot, M, shared)


def delayed_covariances(blocks: FactorBlocks, win: Window, marginals: list[np.ndarray]) -> list[np.ndarray]:
    """The covariance (``Pose2`` tangent) of the smoothed estimate of each of the window's first poses, from their
    ``marginals`` (the window's ``M^-1``), bounded whatever the correlation between the factors that share another
    robot's errors (:class:`FactorBlocks`'s ``shared``) before and after the pose.

    The estimate is ``M^-1`` times the sum of each factor's whitened gradient ``g_f``; the marginal ``M^-1`` holds
    when every ``g_f`` is independent. Split at pose ``k`` into ``a`` (the prior and the shared factors on poses up
    to ``k``: the forward, filtered part), ``b`` (the shared factors after ``k``) and the independent rest ``r``
    (odometry, own detections), ``Cov(g_a + g_b) <= Cov(g_a) / w + Cov(g_b) / (1 - w)`` for every ``w`` in (0, 1)
    (covariance intersection, Julier & Uhlmann 1997), so ``M^-1 (L_a / w + L_b / (1 - w) + L_r) M^-1`` bounds the
    estimate's covariance (the sandwich form of a two-filter smoother's fusion of its forward and backward parts,
    Fraser & Potter 1969). ``w`` minimizes the bound's trace weighed by the marginal's inverse:
    ``w = sqrt(a) / (sqrt(a) + sqrt(b))``. No shared factor after ``k``: the marginal ``M^-1``."""
    k0 = len(marginals)
    cols = np.concatenate([np.arange(blocks.slot[p], blocks.slot[p] + 3) for p in win.poses[:k0]])
    unit = np.zeros((blocks.M.shape[0], cols.size))
    unit[cols, np.arange(cols.size)] = 1.0
    columns = splu(blocks.M).solve(unit)  # the columns of M^-1 of the poses filed
    out = []
    for k in range(k0):
        E = columns[:, 3 * k : 3 * k + 3]
        marginal = marginals[k]
        parts = [np.zeros((3, 3)), np.zeros((3, 3))]
        for pos, rows, A in blocks.shared:
            J = A @ E[rows]
            parts[pos > k] += J.T @ J
        La, Lb = parts
        Winv = np.linalg.inv(marginal)
        a, b = math.sqrt(max(float(np.trace(Winv @ La)), 0.0)), math.sqrt(max(float(np.trace(Winv @ Lb)), 0.0))
        if a == 0 or b == 0:  # nothing shared on one side: the factors are independent
            out.append(marginal)
            continue
        w = a / (a + b)
        bound = marginal + La * (1 / w - 1) + Lb * (1 / (1 - w) - 1)
        out.append(symmetric(bound))
    return out


def _cartesian_cov(theta: float, cov: np.ndarray) -> np.ndarray:
    """A ``Pose2``-tangent (body-frame) covariance as a world-frame Cartesian ``(x, y, theta)`` one."""
    B = C.rot_block(theta)
    out: np.ndarray = B @ cov @ B.T
    return out
