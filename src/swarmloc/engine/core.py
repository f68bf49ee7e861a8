"""The batched team engine: every robot's filter state in arrays, one step for the whole team.

:class:`Engine` holds the state of ``N`` robots (row ``r`` is robot ``r``): for ``"expfusion"`` and ``"ci"`` the
SE(2) mean ``(N, 3, 3)`` and exponential-coordinate covariance ``(N, 3, 3)`` (right perturbation), for ``"dekf"``
the Cartesian ``(x, y, theta)`` ``(N, 3)`` and covariance ``(N, 3, 3)`` (world frame); per robot its clock [s] and
command ``(v [m/s], w [rad/s])``. It computes exactly what the per-robot nodes of :mod:`swarmloc.estimators`
compute when the in-process runner drives them (:mod:`swarmloc.node`), batched:

* **SE(3) teams** (initial means ``(N, 4, 4)``, covariances ``(N, 6, 6)``; the group is the beliefs'): the nodes of
  :data:`~swarmloc.estimators.ESTIMATORS_SE3`. ``"expfusion"`` and ``"ci"`` keep the SE(3) mean and covariance,
  ``"dekf"`` the pose ``(N, 4, 4)`` and the covariance ``(N, 6, 6)`` of its ``(dp, dtheta)`` error
  (:mod:`swarmloc.estimators.dekf` on SE(3)); the command is the body twist, ``v (N, 3)`` [m/s] and ``w (N, 3)``
  [rad/s] (a scalar per robot, a stop, broadcasts to the three axes), the noise a
  :class:`~swarmloc.motion.twist3.TwistNoise`; the increments, prediction and ``"pose3"`` model are
  :mod:`swarmloc.engine.se3` (numpy only), the fusions :mod:`~swarmloc.engine.fuse_exp` and
  :mod:`~swarmloc.engine.fuse_ci` and :mod:`~swarmloc.engine.fuse_ekf` on SE(3). Other kinds are rejected as the
  nodes reject them (``kind ... is not supported on SE(3)``).

* **Clocks.** A robot is predicted from its clock to a stamp only when it has an input there (a detection group
  or a command), in one step with the command in force, as a node's history entry does. A neighbour's answer and a
  recorded belief are its state predicted to the stamp *without* storing it (:meth:`Engine.belief`).
* **Order at one stamp.** Groups (key ``(t, 1, observer)``) come before commands (key ``(t, 2, robot)``), and the
  groups in observer order: observer ``i`` is answered by neighbour ``j`` with ``j``'s belief *after* ``j``'s own
  group at ``t`` when ``j < i`` and *before* it when ``j > i`` (Gauss-Seidel). To stay batched, the groups of one
  stamp are scheduled in levels (:mod:`swarmloc.engine.stamp`: 1 + the largest level of an observer's targets with
  a smaller id that also have a group at ``t``, found by iterating ``np.maximum.at`` over the edges); all groups of
  one level fuse in one batched call per detection position.
* **Fusion** is the nodes' (gate, iterations, order, outcome rules), one module per estimator, batched over the
  observers of a level: :mod:`~swarmloc.engine.fuse_ekf` (the EKF; relative poses and absolute fixes take a faster
  path, ``fast=True``, default: the formulas of :mod:`swarmloc.engine.soa` on numpy or jax, or compiled by numba
  with the groups of a level in parallel threads, ``backend``), :mod:`~swarmloc.engine.fuse_exp` (the thesis
  estimator) and :mod:`~swarmloc.engine.fuse_ci` (covariance intersection, with the weight rule the installed
  :class:`~swarmloc.estimators.ExpCI` declares, :attr:`~swarmloc.estimators.ExpCI.ci_weight`). Outcomes are
  decided and counted as the nodes do by :mod:`swarmloc.engine.outcomes`.

Detections are given as :class:`~swarmloc.engine.detections.Detections` (arrays, robots as row indices). The
engine trusts its input: a driver validates it (:func:`swarmloc.engine.run_engine` applies the nodes' checks).
**Landmarks** (a map ``id -> (x, y, std_x, std_y)``, the nodes' option) run with ``"dekf"`` on SE(2): a landmark
detection's target is its row in the map (:meth:`Engine.landmark_code`), its state the map's position and
covariance (:func:`swarmloc.node.landmark_state`), fused as the node fuses it (a range-bearing detection on the
fast path, :func:`swarmloc.engine.soa.landmark_update`); the other estimators refuse a map. ``"rdl"`` is not an
estimator of this class (its pairwise updates change the *target's* state too, and it keeps factors per pair): it
and the centralized ``"cekf"`` replay compiled, :mod:`swarmloc.engine.pairs` and :mod:`swarmloc.engine.joint`
(:func:`swarmloc.engine.run_engine`).

The engine's modules are layers, each importing only modules below it (an import-linter contract in pyproject.toml):
``replay``, ``swarm`` -> ``core`` -> ``fuse_ci`` -> ``fuse_exp``, ``fuse_ekf`` -> ``stamp`` ->
``outcomes`` -> ``detections``; ``fuse_ekf`` -> ``se3``; ``core`` -> ``backends`` -> ``numba_ops`` -> ``scalar`` ->
``soa``; ``core`` -> ``resident`` -> ``jax_stamp``; and all of them -> ``codes``.
"""

from __future__ import annotations

from collections import Counter
from typing import TYPE_CHECKING, Any, TypeAlias, TypeVar, overload

import numpy as np

from swarmloc.arrays import BoolArray
from swarmloc.engine import se3 as E3
from swarmloc.engine.backends import BACKENDS, JaxOps, make_ops
from swarmloc.engine.codes import KIND_NAMES, NO_LANDMARK, PENDING, POSE3, REJECTED, landmark_code
from swarmloc.engine.detections import Detections, Timeline
from swarmloc.engine.fuse_ci import CiFusion
from swarmloc.engine.fuse_ekf import EkfFusion
from swarmloc.engine.fuse_exp import ExpFusionLevel
from swarmloc.engine.jax_stamp import covered
from swarmloc.engine.outcomes import screen, tally, tally_table
from swarmloc.engine.resident import DeviceTeam, HostState, HostTeam
from swarmloc.engine.stamp import Fusion, Stamp, State, levels, runs, schedule
from swarmloc.estimators.ci import ExpCI
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import group as K
from swarmloc.lie import SE2, SE3
from swarmloc.lie.base import SEGroup
from swarmloc.motion import UnicycleNoise, odometry_increment
from swarmloc.motion.twist3 import TwistNoise
from swarmloc.node.inputs import landmark_state
from swarmloc.node.update import Gate

if TYPE_CHECKING:
    from jax import Array

    from swarmloc.engine.backends import FastOps
    from swarmloc.engine.numba_ops import NumbaOps

__all__ = ["ENGINE_ESTIMATORS", "Detections", "Engine", "levels"]

ENGINE_ESTIMATORS = ("expfusion", "dekf", "ci")
"""Estimators the engine runs (the per-robot nodes of the same names)."""

_N = TypeVar("_N", UnicycleNoise, TwistNoise)

Records: TypeAlias = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""A compiled replay's beliefs, filled in place (:meth:`Engine.replay_timeline`): ``(robot (K,), stamp index (K,),
x (K, 3), P (K, 3, 3), count (1,))``, rows ``:count[0]`` written."""


class _Held:
    """A field of the engine's team on the host (:class:`~swarmloc.engine.resident.HostState`), to read: a team on
    jax's device downloads it first when the device holds it newer."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, eng: None, owner: type) -> _Held: ...
    @overload
    def __get__(self, eng: Engine, owner: type | None = None) -> np.ndarray: ...
    def __get__(self, eng: Engine | None, owner: type | None = None) -> np.ndarray | _Held:
        if eng is None:  # on the class (documentation tools): the descriptor
            return self
        array: np.ndarray = getattr(eng.team.host(self.name), self.name)
        return array


class Engine:
    """A team's filters as arrays (see the module docstring).

    Parameters
    ----------
    estimator: ``"expfusion"``, ``"dekf"`` or ``"ci"``.
    mean, cov: initial beliefs ``(N, 3, 3)`` each: SE(2) means and exponential-coordinate covariances (as the
        nodes' initial :class:`~swarmloc.gaussian.GroupGaussian`); an SE(3) team: ``(N, 4, 4)`` and ``(N, 6, 6)``.
    noise: process noise of the odometry (:class:`~swarmloc.motion.twist3.TwistNoise` for an SE(3) team).
    t0: start time(s) [s] of the initial beliefs, scalar or ``(N,)``; ``inf``: a robot that never starts (it
        answers nobody, like a node without input).
    gate, order, iterations, point_iterations, use_relative: as the nodes (:class:`~swarmloc.estimators.ExpFusion`,
        :class:`~swarmloc.estimators.Node`); the gate is the nodes' :class:`~swarmloc.node.update.Gate`.
    backend: ``"numpy"``, ``"jax"`` (float64), ``"jax32"`` (float32 kernels on jax's device, float64 states; both
        keep the team on the device between stamps and run a stamp of poses, fixes and range-bearing detections,
        or one of commands only, as one device call, :mod:`swarmloc.engine.jax_stamp`) or
        ``"numba"`` (all but numpy: fast EKF path only, ``estimator="dekf"``,
        ``fast=True``, SE(2) teams; with numba the groups of one level fuse in parallel threads,
        ``NUMBA_NUM_THREADS``).
    fast: EKF relative poses and absolute fixes through :mod:`swarmloc.engine.soa` instead of the stacked-matrix
        kernels (same results to rounding, several times faster).
    landmarks, use_landmarks: the nodes' map of point landmarks ``id -> (x [m], y [m], std_x [m], std_y [m])`` and
        whether to fuse their detections (``"dekf"`` on SE(2) only; another estimator raises on a non-empty map).
    horizon: accepted so that the nodes' options can be passed; it plays no role (input comes in stamp order).

    The team's arrays are :attr:`team`'s (read them as ``a``, ``b`` (the states), ``t`` (clocks [s]), ``t0``, ``v``,
    ``w``); with the jax backends they stay on the device between stamps (:mod:`swarmloc.engine.resident`).
    """

    a, b, t, t0, v, w = _Held(), _Held(), _Held(), _Held(), _Held(), _Held()

    def __init__(
        self,
        estimator: str,
        mean: np.ndarray,
        cov: np.ndarray,
        *,
        noise: UnicycleNoise | TwistNoise,
        t0: float | np.ndarray = 0.0,
        gate: float | None = None,
        order: int = 2,
        iterations: int = K.FUSE_ITERATIONS,
        point_iterations: int = K.POINT_ITERATIONS,
        use_relative: bool = True,
        backend: str = "numpy",
        fast: bool = True,
        landmarks: Any = None,
        horizon: float | None = None,
        use_landmarks: bool = True,
    ) -> None:
        mean = np.asarray(mean, dtype=float)
        cov = np.asarray(cov, dtype=float)
        self.group: type[SEGroup] = _group_of(mean, cov)
        """The team's group, SE2 or SE3 (from the beliefs' shapes)."""
        gating = _check_options(estimator, backend, fast, landmarks, gate, order, self.group)
        n = mean.shape[0]
        self.estimator = estimator
        self.n = n
        self.noise = noise
        self.gate = gate
        self.order = order
        self.iterations = iterations
        self.point_iterations = point_iterations
        self.use_relative = use_relative
        self.fast = bool(fast) and estimator == "dekf" and self.group is SE2
        self.backend = backend
        self.ops = make_ops(backend, self._noise(UnicycleNoise)) if self.fast else None
        """The fast path's kernels (:func:`~swarmloc.engine.backends.make_ops`), None off the fast path."""
        self.numba = _numba(self.ops, backend)
        """The same kernels when they are numba's (their in-place and compiled-replay kernels), else None."""
        self.fusion = _fusion(estimator, gating, self.ops, backend, order, iterations, point_iterations, self.group)
        """The fusion of one level of a stamp's groups (:mod:`swarmloc.engine.fuse_ekf`, ``fuse_exp``, ``fuse_ci``)."""
        self.use_landmarks = bool(use_landmarks)
        self.landmark_rows, table = landmark_table(landmarks)
        """Landmark id -> its row in the map (sorted ids); :meth:`landmark_code` gives a detection's target code."""
        if table is not None:
            self.fusion.landmarks = table
        start = np.broadcast_to(np.asarray(t0, dtype=float), (n,)).copy()
        cmd = (n, 3) if self.group is SE3 else (n,)
        if estimator == "dekf" and self.group is SE3:
            a, b = E3.to_error(mean, cov)
        elif estimator == "dekf":
            a, b = (np.ascontiguousarray(s, dtype=float) for s in C.from_group(mean, cov))
        else:
            a, b = mean.copy(), cov.copy()
        host = HostState(a, b, start.copy(), start, np.zeros(cmd), np.zeros(cmd))
        self.team = DeviceTeam(host, self.ops.stamp) if isinstance(self.ops, JaxOps) else HostTeam(host)
        """Where the team's arrays live between stamps (:mod:`swarmloc.engine.resident`): jax's device with the jax
        backends, else the host."""
        self.counts: Counter[str] = Counter()
        """Detections in and their outcomes (``fused``, ``gated``, ``rejected``, ``unknown``), as the nodes count."""
        self.reasons: Counter[str] = Counter()
        """``"<outcome>: <reason>"`` -> count for rejected and unknown detections."""
        self.last_levels = 0
        """Levels the last :meth:`fuse` scheduled (diagnostics)."""

    def landmark_code(self, lid: Any) -> int:
        """Target code of a detection of landmark ``lid``: :func:`~swarmloc.engine.codes.landmark_code` of its row
        in the map, or :data:`~swarmloc.engine.codes.NO_LANDMARK` (not in the map: counted ``unknown``)."""
        return map_code(self.landmark_rows, lid)

    # ------------------------------------------------------------------------------------------------ state
    def _advance(self, s: State, v: np.ndarray, w: np.ndarray, dt: np.ndarray) -> State:
        """Rows ``s`` predicted over ``dt`` [s] with their commands; rows with ``dt <= 0`` (or NaN) unchanged."""
        move = np.flatnonzero(dt > 0)
        if move.size == 0:
            return s
        ops = self.ops  # None off the fast path
        if move.size == dt.shape[0] and ops is not None:
            xn, Pn = ops.predict(s[0], s[1], v, w, dt)
            return xn, Pn
        a, b = s[0].copy(), s[1].copy()
        rows: np.ndarray | slice = slice(None) if move.size == dt.shape[0] else move  # everybody: no gather
        x, P, v, w, dt = s[0][rows], s[1][rows], v[rows], w[rows], dt[rows]
        if ops is not None:
            a[rows], b[rows] = ops.predict(x, P, v, w, dt)
        elif self.group is SE3 and self.estimator == "dekf":  # body twists (swarmloc.engine.se3)
            a[rows], b[rows] = E3.predict_error(x, P, v, w, dt, self._noise(TwistNoise))
        elif self.group is SE3:
            a[rows], b[rows] = E3.predict_group(x, P, v, w, dt, self._noise(TwistNoise), self.order)
        elif self.estimator == "dekf":
            a[rows], b[rows], _ = C.predict(x, P, v, w, dt, self._noise(UnicycleNoise))
        else:
            inc_mean, inc_cov = odometry_increment(v, w, dt, self._noise(UnicycleNoise))
            a[rows], b[rows] = K.predict(SE2, x, P, inc_mean, inc_cov, self.order)
        return a, b

    def _noise(self, kind: type[_N]) -> _N:
        """:attr:`noise`, which a team of this group takes as a ``kind`` (SE(2): a
        :class:`~swarmloc.motion.UnicycleNoise`, SE(3): a :class:`~swarmloc.motion.twist3.TwistNoise`)."""
        noise = self.noise
        if not isinstance(noise, kind):
            raise TypeError(f"Engine: an {self.group.name} team's odometry noise is a {kind.__name__}, got "
                            f"{type(noise).__name__}")  # fmt: skip
        return noise

    def _rows(self, idx: np.ndarray, t: float) -> State:
        """States of robots ``idx`` predicted to ``t`` (not stored)."""
        s = self.team.host()
        return self._advance((s.a[idx], s.b[idx]), s.v[idx], s.w[idx], t - s.t[idx])

    def predict(self, robots: np.ndarray, t: float) -> None:
        """Predict ``robots`` (rows) to ``t`` [s] and store it (robots already there, or not started, unchanged)."""
        robots = np.asarray(robots, dtype=np.int64)
        team = self.team
        if isinstance(team, DeviceTeam) and team.resident():  # on the device, where the team is
            team.predict(t, self._mask(robots))
            return
        numba = self._serial_numba(robots.size)
        s = team.edit("a", "b", "t")
        if numba is not None:  # in place, no gather or scatter
            numba.predict_into(s.a, s.b, s.t, s.v, s.w, robots, t)
            return
        dt = t - s.t[robots]
        go = robots[dt > 0]
        if go.size == 0:
            return
        if go.size == self.n:  # everybody: no gather
            s.a, s.b = self._advance((s.a, s.b), s.v, s.w, t - s.t)
        else:
            s.a[go], s.b[go] = self._rows(go, t)
        s.t[go] = t

    def set_command(self, robots: np.ndarray, v: np.ndarray, w: np.ndarray) -> None:
        """Odometry ``(v [m/s], w [rad/s])`` in force from each robot's clock on (call :meth:`predict` first)."""
        team = self.team
        if isinstance(team, DeviceTeam):
            team.command(robots, v, w)
            return
        s = team.edit("v", "w")
        numba = self._serial_numba(len(robots))
        if numba is not None:
            numba.scatter2(s.v, s.w, robots, v, w)
            return
        if self.group is SE3:  # (k, 3) each; a scalar per robot (a stop) on all three axes, as the nodes
            v, w = (np.asarray(x, dtype=float).reshape(len(robots), -1) for x in (v, w))
        s.v[robots] = v
        s.w[robots] = w

    def state(self, t: float, robots: np.ndarray) -> State:
        """The filter states of ``robots`` (rows) at ``t`` [s] as the engine keeps them (``dekf``: Cartesian
        ``(B, 3)`` and ``(B, 3, 3)``), predicted from their clocks and not stored."""
        return self._rows(np.asarray(robots, dtype=np.int64), t)

    def belief(self, t: float, robots: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Beliefs of ``robots`` (default all) at ``t`` [s], predicted from their clocks and not stored:
        SE(2) means ``(B, 3, 3)`` and exponential-coordinate covariances ``(B, 3, 3)`` (the nodes' ``belief_at``;
        SE(3): ``(B, 4, 4)`` and ``(B, 6, 6)``)."""
        idx = np.arange(self.n) if robots is None else np.asarray(robots, dtype=np.int64)
        a, b = self._rows(idx, t)
        if self.estimator == "dekf" and self.group is SE3:
            return E3.to_group(a, b)
        if self.estimator == "dekf":
            return C.to_group(a, b)
        return a, b

    def step(
        self,
        t: float,
        detections: Detections | None = None,
        commands: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
        *,
        presorted: bool = False,
    ) -> None:
        """Everything stamped ``t`` [s]: the detection groups, then the commands ``(robots, v, w)`` starting at ``t``.

        Robots with a command or a group at ``t`` are predicted to ``t`` first (what the nodes do at either entry);
        ``presorted``: the detections are already in :meth:`Detections.canonical` order.
        """
        t = float(t)
        if detections is not None and len(detections):
            self._fuse(t, detections, presorted, None if commands is None else commands[0])
        elif commands is not None:
            self.predict(commands[0], t)
        if commands is not None:
            self.set_command(*commands)

    def compiled_replay(self, rows: int) -> bool:
        """Whether :meth:`replay_timeline` runs here: ``dekf`` on SE(2), fast, numba, at most ``rows`` detections
        or commands per stamp on one thread."""
        numba = self._serial_numba(rows)
        return self.fast and numba is not None and hasattr(numba, "replay_serial")

    def replay_timeline(self, tl: Timeline, s0: int, out: Records) -> tuple[int, int]:
        """Stamps ``s0:`` of ``tl`` in one compiled call (:meth:`NumbaOps.replay_serial
        <swarmloc.engine.numba_ops.NumbaOps.replay_serial>`; only where :meth:`compiled_replay`): what a
        :meth:`step` per stamp does, outcomes counted the same, beliefs of the record stamps appended to ``out``.
        Returns ``(stop, records)``: ``stop < len(tl)`` is a stamp with a detection the compiled kernel does not
        take, not done (the caller steps it with :meth:`step` and goes on from ``stop + 1``)."""
        m = len(tl.det)
        status, reason = np.zeros(m, dtype=np.int8), np.zeros(m, dtype=np.int8)
        s = self.team.edit("a", "b", "t", "v", "w")
        state = (s.a, s.b, s.t, s.t0, s.v, s.w)
        if self.numba is None:
            raise RuntimeError("Engine.replay_timeline: only where compiled_replay (numba's kernels)")
        stop, k = self.numba.replay_serial(state, tl, s0, self.use_relative, status, reason, self.fusion.gate,
                                         self.fusion.landmarks, self.use_landmarks, out)  # fmt: skip
        done = slice(int(tl.d0[s0]), int(tl.d0[stop]))
        tally(self.counts, self.reasons, status[done], reason[done])
        return stop, k

    # ------------------------------------------------------------------------------------------------ fusion
    def fuse(self, t: float, det: Detections, *, presorted: bool = False) -> np.ndarray:
        """Fuse every detection group stamped ``t`` [s] (observers predicted to ``t`` first); returns the outcome
        code of each detection (:data:`~swarmloc.engine.codes.OUTCOMES`), in the order of ``det`` once sorted
        canonically."""
        status = self._fuse(float(t), det, presorted, None)
        return np.asarray(status)[: len(det)]  # the device stamp's: downloaded here, and cut

    def _fuse(self, t: float, det: Detections, presorted: bool, move: np.ndarray | None) -> np.ndarray | Array:
        """:meth:`fuse`, the robots ``move`` (rows, or None: none) predicted to ``t`` first (a command's); the
        outcomes of the device stamp stay on the device, padded."""
        if not presorted:
            det = det.canonical()
        _check_rows(det, self.n)
        team = self.team
        if isinstance(team, DeviceTeam) and len(det) and covered(det):  # the stamp in one device call
            g = self.fusion
            outcomes, table, levels = team.stamp(t, self._mask(move), det, g.gate, self.use_relative,
                                                 self.use_landmarks, g.landmarks)  # fmt: skip
            self.last_levels = levels or self.last_levels  # as the level path: unchanged when no observer runs
            tally_table(self.counts, self.reasons, table)
            return outcomes
        if move is not None:
            self.predict(move, t)
        if len(det) == 0:
            return np.zeros(0, dtype=np.int8)
        numba = self.numba
        if numba is not None:  # screened and fused in place, on one thread or by levels
            status, reason = np.zeros(len(det), dtype=np.int8), np.zeros(len(det), dtype=np.int8)
            kernel = numba.fuse_serial if numba.serial(len(det)) else numba.fuse_levels
            s = team.edit("a", "b", "t")
            lv = kernel(s.a, s.b, s.t, s.t0, s.v, s.w, t, self.use_relative, det, status, reason, self.fusion.gate,
                        self.fusion.landmarks, self.use_landmarks)  # fmt: skip
            if lv >= 0:
                self.last_levels = lv or self.last_levels  # unchanged when no observer runs, as the level path
                tally(self.counts, self.reasons, status, reason)
                return status
        status, reason, obs_ok, needs = screen(det, t, self.t0, self.use_relative, self.use_landmarks)
        if self.group is SE3:
            needs &= ~self._refuse_kinds(det, status)
        starts, pos = runs(det.observer)
        observers = det.observer[starts][obs_ok[starts]]
        if observers.size:
            self.predict(observers, t)
            self._fuse_groups(t, det, status, reason, pos, starts, obs_ok, needs, observers)
        tally(self.counts, self.reasons, status, reason)
        return status

    def _mask(self, robots: np.ndarray | None) -> np.ndarray:
        """``(N,)``: whether each robot is one of ``robots`` (rows; None: none)."""
        mask = np.zeros(self.n, dtype=bool)
        if robots is not None:
            mask[robots] = True
        return mask

    def _refuse_kinds(self, det: Detections, status: np.ndarray) -> BoolArray:
        """An SE(3) team's pending detections of kinds other than ``"pose3"``: rejected, counted under the nodes'
        reason (``kind '<kind>' is not supported on SE(3)``); returns their mask."""
        bad: BoolArray = (status == PENDING) & (det.kind != POSE3)
        if bad.any():
            status[bad] = REJECTED
            codes, count = np.unique(det.kind[bad], return_counts=True)
            for code, k in zip(codes.tolist(), count.tolist(), strict=True):
                self.reasons[f"rejected: kind {KIND_NAMES[code]!r} is not supported on {SE3.name}"] += k
        return bad

    def _serial_numba(self, rows: int) -> NumbaOps | None:
        """The numba backend with ``rows`` rows on one thread: the in-place kernels (no gather, copy or levels)."""
        return self.numba if self.numba is not None and self.numba.serial(rows) else None

    def _fuse_groups(
        self,
        t: float,
        det: Detections,
        status: np.ndarray,
        reason: np.ndarray,
        pos: np.ndarray,
        starts: np.ndarray,
        obs_ok: np.ndarray,
        needs: np.ndarray,
        observers: np.ndarray,
    ) -> None:
        """The groups of the running ``observers`` (runs ``starts`` of ``det``), level by level; the outcomes go to
        ``status`` and ``reason``, the observers' fused states to the engine's."""
        U, lo, lt, is_obs, row_level = schedule(self.n, det, needs, obs_ok, observers)
        s = self.team.edit("a", "b")
        if U.size == self.n and not np.any(s.t < t):  # everybody at t already: fuse in place
            cur = (s.a, s.b)
            prior = (s.a.copy(), s.b.copy())
        else:
            prior = self._rows(U, t)  # observers already at t; others' answers predicted, not stored
            cur = (prior[0].copy(), prior[1].copy())
        self.last_levels = int(row_level.max()) + 1
        st = Stamp(det, status, reason, pos, lo, lt, prior, cur)
        order = np.argsort(row_level, kind="stable")
        bounds = np.searchsorted(row_level[order], np.arange(self.last_levels + 1))
        for lv in range(self.last_levels):
            rows = order[bounds[lv] : bounds[lv + 1]]
            if rows.size:
                self.fusion.fuse_level(st, rows)
        if cur[0] is not s.a:  # the observers' fused states (the neighbours' predicted answers are not stored)
            done = U[is_obs]
            s.a[done] = cur[0][is_obs]
            s.b[done] = cur[1][is_obs]


def _group_of(mean: np.ndarray, cov: np.ndarray) -> type[SEGroup]:
    """The team's group from the beliefs' shapes: ``(N, 3, 3)`` both (SE(2)), ``(N, 4, 4)`` and ``(N, 6, 6)``
    (SE(3))."""
    if mean.ndim == 3 and cov.ndim == 3 and mean.shape[0] == cov.shape[0]:
        if mean.shape[1:] == (3, 3) and cov.shape[1:] == (3, 3):
            return SE2
        if mean.shape[1:] == (4, 4) and cov.shape[1:] == (6, 6):
            return SE3
    raise ValueError(
        f"Engine: mean and cov must be (N, 3, 3) (SE(2)) or (N, 4, 4) and (N, 6, 6) (SE(3)), got {mean.shape} and "
        f"{cov.shape}"
    )


def _check_rows(det: Detections, n: int) -> None:
    """Refuse detections whose observer or robot target is no row of a team of ``n`` (the compiled paths would not
    index-check them: numba reads out of bounds, JAX clamps)."""
    if len(det) and (det.observer.min() < 0 or det.observer.max() >= n or det.target.max() >= n):
        bad = np.flatnonzero((det.observer < 0) | (det.observer >= n) | (det.target >= n))[0]
        raise ValueError(f"Engine.fuse: detection {bad} (canonical order) has observer {det.observer[bad]} and target "
                         f"{det.target[bad]}: robot rows must be in [0, {n})")  # fmt: skip


def _check_options(estimator: str, backend: str, fast: bool, landmarks: Any, gate: float | None, order: int,
                   group: type[SEGroup] = SE2) -> Gate:  # fmt: skip
    """The engine's refusals (what it cannot run, options out of range); returns the nodes' gate."""
    if estimator not in ENGINE_ESTIMATORS:
        why = " (its pairwise updates change the target's state: use the nodes)" if estimator == "rdl" else ""
        raise ValueError(f"Engine: unsupported estimator {estimator!r}{why}; choose from {list(ENGINE_ESTIMATORS)}")
    if backend not in BACKENDS:
        raise ValueError(f"Engine: unknown backend {backend!r}; choose from {list(BACKENDS)}")
    if group is SE3 and backend != "numpy":
        raise ValueError(f"Engine: backend {backend!r} runs SE(2) teams only; an SE(3) team runs on backend='numpy'")
    if backend != "numpy" and not (estimator == "dekf" and fast):
        raise ValueError(f"Engine: backend {backend!r} runs the fast EKF path only (estimator='dekf', fast=True)")
    if landmarks and (estimator != "dekf" or group is not SE2):
        raise ValueError(f"Engine: landmarks run with 'dekf' on SE(2) only, not {estimator!r} on {group.name}; run "
                         "the nodes (swarmloc.runner.run)")  # fmt: skip
    if order not in (1, 2):
        raise ValueError(f"Engine: 'order' must be 1 or 2, got {order!r}")
    try:
        return Gate(gate)
    except ValueError as exc:
        raise ValueError(f"Engine: {exc}") from None


def map_code(rows: dict[Any, int], lid: Any) -> int:
    """Target code of landmark ``lid`` in a map whose ids have rows ``rows`` (:func:`landmark_table`):
    :func:`~swarmloc.engine.codes.landmark_code` of its row, or :data:`~swarmloc.engine.codes.NO_LANDMARK`."""
    k = rows.get(lid)
    return NO_LANDMARK if k is None else landmark_code(k)


def landmark_table(landmarks: Any) -> tuple[dict[Any, int], tuple[np.ndarray, np.ndarray] | None]:
    """A landmark map ``id -> (x, y, std_x, std_y)`` as the engine keeps it: ``(rows, (xy (L, 2), cov (L, 2, 2)))``,
    rows in the order of the sorted ids, positions and covariances as the nodes take them
    (:func:`swarmloc.node.landmark_state`); ``({}, None)`` for no map."""
    if not landmarks:
        return {}, None
    ids = sorted(landmarks)
    states = [landmark_state(landmarks, lid) for lid in ids]
    planar = [s for s in states if s is not None and s[0].shape == (2,)]
    if len(planar) != len(states):
        raise ValueError("Engine: landmarks must be planar, id -> (x, y, std_x, std_y)")
    xy = np.stack([s[0] for s in planar])
    cov = np.stack([s[1] for s in planar])
    return {lid: k for k, lid in enumerate(ids)}, (xy, cov)


def _numba(ops: FastOps | None, backend: str) -> NumbaOps | None:
    """``ops`` when they are numba's kernels (backend ``"numba"``; their module is imported only then: numba is
    optional)."""
    if ops is None or backend != "numba":
        return None
    from swarmloc.engine.numba_ops import NumbaOps

    return ops if isinstance(ops, NumbaOps) else None


def _fusion(estimator: str, gate: Gate, ops: Any, backend: str, order: int, iterations: int,
            point_iterations: int, group: type[SEGroup] = SE2) -> Fusion:  # fmt: skip
    """The fusion of one level for ``estimator`` on ``group``; covariance intersection follows the weight rule the
    estimator declares (:attr:`ExpCI.ci_weight <swarmloc.estimators.ExpCI.ci_weight>`; on SE(3) the node takes the
    closed form, and so does the engine)."""
    options = {"order": order, "iterations": iterations, "point_iterations": point_iterations}
    if estimator == "dekf":
        return EkfFusion(gate, ops, backend, group, **options)
    if estimator == "ci":
        return CiFusion(gate, ExpCI.ci_weight, **options)
    return ExpFusionLevel(gate, group, **options)
