"""Multi-robot Monte Carlo localization (Fox, Burgard, Kruppa & Thrun 2000) as a distributed node.

Each node keeps a weighted particle set ``(x, y, theta)`` (world frame) of its own robot.

**Motion.** Every particle moves by its own draw of the odometry increment of :mod:`swarmloc.motion.unicycle`:
``g <- g exp(dt (v, 0, w)^) exp(y)``, ``y ~ N(0, Sigma_inc)`` with ``Sigma_inc`` the closed-form increment
covariance (5.4) of the node's :class:`~swarmloc.motion.UnicycleNoise` (right perturbation, as the Gaussian filters
use it; their mean prediction is the particles' noise-free motion).

**Landmarks and absolute fixes** weight the particles by the measurement likelihood of
:mod:`swarmloc.sensors.models` (range, bearing, range-bearing; absolute ``(x, y, theta)`` fixes), with the
landmark's position standard deviation added to the noise through the model's Jacobian.

**Detections of robots (Fox et al.).** In the paper the detecting robot's samples, pushed through the detection
model, give samples of the detected robot's pose; a *density tree* is fitted to them and the detected robot's
particles are reweighted by that density. Here the roles are the ones of this node design: robot ``i`` detects
``j`` and only ever receives ``j``'s belief as a Gaussian (:class:`~swarmloc.messages.BeliefAnswer`: SE(2) mean,
exponential-coordinate covariance). The density of ``j``'s belief pushed through the relative measurement,
linearized in the neighbour's pose only (exact in ``x_i``), ``p(z | x_i) = N(z; h(x_i, mu_j), R + H_j P_j H_j^T)``
(``P_j``: ``j``'s covariance in Cartesian coordinates), scores ``i``'s particles for the gate and the injection's
likelihood averages (below); the update itself is the (inverse) covariance intersection of the next paragraph.

**Detections of robots are fused by (inverse) covariance intersection, not reweighting.** Reweighting by the density
above treats the neighbour's belief as independent of the robot's own, which it is not once the pair has met: fusing
every detection of a robot seen at 5 Hz counts the same information again and again, and information goes round the
team (Fox et al. 2000 assume the detections independent, as the distributed EKF does; ``sim:random``, 4 robots,
seeds 1-13: team ANEES/dof 48.8). Instead, the particle set's fitted Gaussian ``(mu, Sigma)`` (below) is fused with
the answer by a rule that stays consistent however much information the two already share. A relative pose makes the
answer a full Gaussian of the robot's own pose (:func:`~swarmloc.kernels.group.relative_to_pseudo`), fused by
inverse covariance intersection (Noack, Sijs, Reinhardt & Hanebeck, Automatica 2017; :mod:`swarmloc.kernels.ici`),
which counts the unknown common information once and is at least as tight as covariance intersection (the default
simulated team, ``sim:random``, 4 robots, 30 s, seeds 0-9: team RMSE 0.056 m, ANEES/dof 0.50 with CI, at the edge of
the band; 0.051 m, 0.55 with ICI). A range or a bearing observes only part of the pose, which ICI cannot take; it is
fused by covariance intersection with independent measurement noise (Julier & Uhlmann 1997; Carrillo-Arce et al.,
IROS 2013) as the ``ci`` estimator does (:mod:`swarmloc.kernels.ci` for the weight ``w``,
:mod:`swarmloc.kernels.group` for the update of ``(mu, Sigma / w)`` with the answer's covariance over ``1 - w``).
The particles are then moved onto that posterior by the affine map of exponential coordinates that takes the prior
Gaussian to it (the deterministic ensemble transform of the ensemble square-root filters, Tippett et al. 2003):
``g_n <- mu' exp(A log(mu^-1 g_n))``, ``A = L' L^-1`` (``L``, ``L'``: Cholesky factors of ``Sigma`` and ``Sigma'``);
weights unchanged, so the set keeps its shape (modes, skew) while its first two moments become the fused
posterior's. Landmarks and absolute fixes, independent information, still reweight the particles by their likelihood
(unless that would collapse the set, below).

**Answers.** A neighbour's :class:`~swarmloc.messages.BeliefQuery`, and :meth:`belief_at`, get a Gaussian fitted to
the particles in exponential coordinates: the weighted Karcher mean ``mu`` (three Gauss-Newton steps from the
weighted Cartesian/circular mean) and ``Sigma = sum_n w_n y_n y_n^T``, ``y_n = log(mu^-1 g_n)`` (right
perturbation), plus :data:`COV_FLOOR` on the diagonal so that a collapsed set still gives a usable covariance.

**Landmarks that would collapse the set.** When a landmark's likelihood is much narrower than the set, or falls in
its tail, reweighting leaves a handful of particles, and after resampling a cloud of millimetres around a wrong
pose (MRCLAM dataset 6, landmarks only, first 300 s: team ANEES/dof 7.5). When the effective sample size after a
landmark's reweighting would fall below :data:`ENSEMBLE_ESS` times the particles, its likelihood ``l`` is split
as ``l = l^gamma l^(1 - gamma)``, as in the ensemble Kalman particle filter of Frei & Künsch (Biometrika 2013):
``l^gamma``, ``gamma`` the largest exponent that keeps the effective sample size at :data:`ENSEMBLE_ESS` times the
particles (:func:`split_exponent`; their automatic choice: as close to the particle update as degeneracy allows),
reweights the particles; ``l^(1 - gamma)``, the same Gaussian measurement with its noise and the landmark's
covariance over ``1 - gamma``, is fused by the iterated EKF update on the group of the reweighted set's fitted
Gaussian (:func:`swarmloc.kernels.group.point_update`), the particles moved onto it by the same ensemble
transform. (Frei & Künsch take the Kalman part first; here the particle part is, a tempered reweighting as in
progressive correction, Musso, Oudjane & Le Gland 2001, so that the Gaussian part sees the weights it leaves.) With
``ENSEMBLE_ESS = 0.5``, the default resampling threshold, a landmark never leaves fewer effective samples than the
resampling rule tolerates. The rule looks at the weights only: it also fires at the first detections of a global
localization and as a kidnapped robot recovers, where part of the likelihood still reweights the random particles
that landed near the truth (the tests converge within 5 s and 8 s).
Until the split, the rule was the split at 0 (all of a collapsing landmark by the Gaussian step, below a tenth of
the particles): landmarks that left between a tenth and a half of the particles still shrank the set by
reweighting alone, and all of MRCLAM 6 ended at ANEES/dof 2.25 (the first 120 s: 2.22).
With both rules, robots by CI (``swarmloc compare``, team position RMSE / ANEES per dof): ``sim:random`` (4 robots,
60 s, seeds 1-13): RMSE 0.248 m / ANEES/dof 0.69 (reweighting every answer: 0.235 m / 48.8); MRCLAM 6, landmarks on,
first 300 s: 0.229 m / 1.50 (split at 0: 0.226 m / 1.90; reweighting only: 0.256 m / 9.45), all of it: 0.231 m /
1.75 (split at 0: 0.234 m / 2.25; reweighting only: 0.243 m / 9.86).

**Weights, gating, resampling.** Weights are updated in the log domain. A detection is ``gated`` (not fused, no
resampling) when no particle explains it: the smallest normalized innovation squared over the particles exceeds the
chi-square gate (when ``gate`` is set), or the likelihood is negligible, i.e. the weights multiplied by
``exp(-nis / 2)`` would all underflow (``log sum w exp(-nis/2) < log(tiny)``). After a group with a fused
detection, low-variance (systematic) resampling runs when the effective sample size ``1 / sum w^2`` falls below
``resample_threshold * particles``.

**Global localization and kidnapping.** ``initial_box = (xmin, xmax, ymin, ymax)`` (or :meth:`global_localization`)
starts from particles uniform over the box (any heading) instead of samples of the initial belief. Kidnapping is
handled by the random-particle injection of augmented MCL (Thrun, Burgard & Fox, *Probabilistic Robotics*, 8.3.5):
the state carries a slow and a fast exponential average (:data:`ALPHA_SLOW`, :data:`ALPHA_FAST`, per evaluated
detection) of the measurement likelihood ``sum_n w_n exp(-nis_n / 2)``; a group with a usable detection first
replaces ``round(N * random_fraction * max(0, 1 - w_fast / w_slow))`` particles (chosen at random) by particles
uniform over ``bounds`` (default: ``initial_box``, else the landmarks' bounding box grown by
:data:`BOUNDS_MARGIN`) at the mean weight, then weighs them with the others. ``random_fraction = 1`` is the
textbook rule; smaller values temper it; 0 (the default) switches injection off. While tracking, ``w_fast``
follows ``w_slow`` and little is injected (first 120 s of MRCLAM dataset 6, 200 particles: team RMSE 0.25 m
without injection, 0.25 m with ``random_fraction = 0.02``, 0.24 m with 0.2, 0.48 m with 1; a *fixed* rate of 2% per
group gave 0.54 m, the random particles that happen to fit one range-bearing detection pulling the fitted mean);
when a kidnapped robot's detections stop fitting, ``w_fast``
collapses and up to ``random_fraction`` of the set is redrawn at every group until some particles land near the
true pose. Injection happens even when the group's detections are then gated (otherwise a kidnapped robot, whose
detections every particle fails to explain, would never get a particle near the truth).

**Determinism.** Every random draw comes from a :class:`numpy.random.Generator` seeded with
``(seed, robot, what, stamps)``: the prediction from ``t0`` to ``t1`` with the bits of ``(t0, t1)``, a group's
injection and resampling with the bits of its stamp, the initial particles with the start time. A state is thus a
deterministic function of the state before and the entry applied, so replaying an entry (late input, shuffled
arrival within the horizon) gives bitwise the same particles. States are immutable: their arrays are read-only and
every step builds new ones.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from swarmloc.estimators.particles import (
    ensemble_transform,
    fit_gaussian,
    landmark_split,
    logsumexp,
    quadratic,
    sqrt_cov3,
    systematic_resample,
)
from swarmloc.events import Kind
from swarmloc.gaussian import GroupGaussian
from swarmloc.kernels import cartesian as C
from swarmloc.kernels import group as K
from swarmloc.kernels.ci import point_weight
from swarmloc.kernels.ici import inverse_ci
from swarmloc.lie import SE2, exp_xyt, wrap_angle
from swarmloc.messages import Message
from swarmloc.motion import UnicycleNoise, odometry_increment_terms
from swarmloc.node import FUSED, Group, Outcome, RobotNode, belief_of
from swarmloc.sensors import models

DEGENERATE = "degenerate geometry: the target is at the observer's position for every particle"
NUMERICAL = "the weights are not finite"
NEGLIGIBLE = "likelihood negligible for every particle"
BOUNDS_MARGIN = 1.0
"""[m] margin around the landmarks' bounding box for the default region of random particles."""
LOG_TINY = math.log(np.finfo(float).tiny)
ALPHA_SLOW = 0.02
ALPHA_FAST = 0.3
"""Smoothing factors, per evaluated detection, of the slow and fast averages of the likelihood (augmented MCL)."""
ENSEMBLE_ESS = 0.5
"""A landmark detection whose reweighting would leave an effective sample size below this fraction of the particles
is split: the part of its likelihood that keeps the effective sample size at this fraction reweights, the rest
updates the set by the Gaussian update and the ensemble transform (module docstring)."""

_INIT, _PREDICT, _GROUP = 1, 2, 3


def _bits(t: float) -> tuple[int, int]:
    """A float's 64 bits as two 32-bit words (seed material)."""
    (u,) = struct.unpack("<Q", struct.pack("<d", float(t)))
    return u & 0xFFFFFFFF, u >> 32


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


class MclState(NamedTuple):
    """A node's filter state: time [s], command ``(v, w)``, particles ``(N, 3)`` as ``(x, y, theta)``, normalized
    weights ``(N,)``, running counts of resamplings and injected particles (replays recount them exactly), the
    slow and fast averages of the measurement likelihood that set the injection rate (augmented MCL)."""

    t: float
    v: float
    w: float
    particles: np.ndarray
    weights: np.ndarray
    resamples: int = 0
    injected: int = 0
    w_slow: float = 0.0
    w_fast: float = 0.0


class MonteCarloLocalization(RobotNode):
    """Multi-robot Monte Carlo localization: one weighted particle set per robot (module docstring).

    Parameters
    ----------
    robot, initial, noise: as :class:`~swarmloc.node.robot.RobotNode` (``initial`` is sampled for the
        initial particles unless ``initial_box`` is given).
    particles: number of particles (>= 2).
    seed: integer mixed into every random draw (with the robot id and the stamps).
    resample_threshold: resample when the effective sample size falls below this fraction of ``particles``
        (in [0, 1]; 0: never, 1: after every fused group).
    random_fraction: in [0, 1]: the fraction of the particles replaced by uniform ones at a group with a usable
        detection is ``random_fraction * max(0, 1 - w_fast / w_slow)`` (augmented MCL; 0: no injection).
    initial_box: ``(xmin, xmax, ymin, ymax)`` [m]: start from particles uniform over this box (global localization).
    bounds: ``(xmin, xmax, ymin, ymax)`` [m] of the random particles; default ``initial_box``, else the landmarks'
        bounding box grown by :data:`BOUNDS_MARGIN`.
    roughen: Gordon, Salmond & Smith's (1993) roughening after each resampling: every particle moves by a normal
        draw of std ``roughen * E_d * N^(-1/3)`` in each of ``x``, ``y``, ``theta`` (``E_d``: the resampled set's
        extent in that coordinate); 0 (default): none.
    regularise: the belief is the Gaussian of the set's Gaussian-kernel density estimate with Silverman's bandwidth
        (regularised particle filter): the fitted covariance times ``1 + h^2``, ``h = (4 / (5 N))^(1/7)``.
    Other keywords: see :class:`~swarmloc.node.base.Node` (``t0``, ``horizon``, ``gate``, ``landmarks``,
    ``use_relative``, ``use_landmarks``).
    """

    name = "mcl"

    def __init__(
        self,
        robot: int,
        initial: GroupGaussian,
        *,
        noise: UnicycleNoise,
        particles: int = 500,
        seed: int = 0,
        resample_threshold: float = 0.5,
        random_fraction: float = 0.0,
        initial_box: Sequence[float] | None = None,
        bounds: Sequence[float] | None = None,
        roughen: float = 0.0,
        regularise: bool = False,
        **kw: Any,
    ) -> None:
        cls = type(self).__name__
        if not (isinstance(particles, int | np.integer) and not isinstance(particles, bool) and particles >= 2):
            raise ValueError(f"{cls}: 'particles' must be an integer >= 2, got {particles!r}")
        if not (isinstance(seed, int | np.integer) and not isinstance(seed, bool) and seed >= 0):
            raise ValueError(f"{cls}: 'seed' must be a non-negative integer, got {seed!r}")
        if not (isinstance(resample_threshold, int | float) and 0 <= resample_threshold <= 1):
            raise ValueError(f"{cls}: 'resample_threshold' must be in [0, 1], got {resample_threshold!r}")
        if not (isinstance(random_fraction, int | float) and 0 <= random_fraction <= 1):
            raise ValueError(f"{cls}: 'random_fraction' must be in [0, 1], got {random_fraction!r}")
        if not (isinstance(roughen, int | float) and not isinstance(roughen, bool) and 0 <= roughen <= 1):
            raise ValueError(f"{cls}: 'roughen' must be in [0, 1], got {roughen!r}")
        if not isinstance(regularise, bool):
            raise ValueError(f"{cls}: 'regularise' must be True or False, got {regularise!r}")
        self.roughen = float(roughen)
        self.regularise = regularise
        self.n_particles = int(particles)
        self.seed = int(seed)
        self.resample_threshold = float(resample_threshold)
        self.random_fraction = float(random_fraction)
        self.initial_box = None if initial_box is None else self._box(cls, "initial_box", initial_box)
        self._bounds_arg = None if bounds is None else self._box(cls, "bounds", bounds)
        super().__init__(robot, initial, noise=noise, **kw)
        self.bounds = self._default_bounds()
        if self.random_fraction > 0 and self.bounds is None:
            raise ValueError(f"{cls}: 'random_fraction' > 0 needs 'bounds', 'initial_box' or landmarks")

    @classmethod
    def global_localization(
        cls, robot: int, box: Sequence[float], *, noise: UnicycleNoise, **kw: Any
    ) -> MonteCarloLocalization:
        """A node that does not know where its robot starts: particles uniform over ``box`` =
        ``(xmin, xmax, ymin, ymax)`` [m] with any heading (the box also bounds the random particles)."""
        b = cls._box(cls.__name__, "box", box)
        centre = SE2.from_xytheta([(b[0] + b[1]) / 2, (b[2] + b[3]) / 2, 0.0])
        spread = np.diag([((b[1] - b[0]) / 2) ** 2, ((b[3] - b[2]) / 2) ** 2, np.pi**2])
        return cls(robot, GroupGaussian(SE2, centre, spread), noise=noise, initial_box=b, **kw)

    @staticmethod
    def _box(cls: str, name: str, box: Sequence[float]) -> tuple[float, float, float, float]:
        try:
            b = tuple(float(v) for v in box)
        except (TypeError, ValueError):
            raise ValueError(f"{cls}: '{name}' must be (xmin, xmax, ymin, ymax), got {box!r}") from None
        if len(b) != 4 or not all(math.isfinite(v) for v in b) or not (b[0] < b[1] and b[2] < b[3]):
            raise ValueError(f"{cls}: '{name}' must be finite (xmin, xmax, ymin, ymax) with min < max, got {box!r}")
        return b[0], b[1], b[2], b[3]

    def _default_bounds(self) -> tuple[float, float, float, float] | None:
        if self._bounds_arg is not None:
            return self._bounds_arg
        if self.initial_box is not None:
            return self.initial_box
        if self.landmarks:
            xs = [v[0] for v in self.landmarks.values()]
            ys = [v[1] for v in self.landmarks.values()]
            m = BOUNDS_MARGIN
            return (min(xs) - m, max(xs) + m, min(ys) - m, max(ys) + m)
        return None

    # -------------------------------------------------------------------------------------------- randomness
    def _rng(self, what: int, *stamps: float) -> np.random.Generator:
        words = [self.seed & 0xFFFFFFFF, self.seed >> 32, self.robot & 0xFFFFFFFF, what]
        for t in stamps:
            words.extend(_bits(t))
        return np.random.Generator(np.random.PCG64(words))

    def _uniform(self, rng: np.random.Generator, n: int, box: tuple[float, float, float, float]) -> np.ndarray:
        u = rng.random((n, 3))
        x = box[0] + (box[1] - box[0]) * u[:, 0]
        y = box[2] + (box[3] - box[2]) * u[:, 1]
        return np.stack([x, y, wrap_angle(np.pi * (2 * u[:, 2] - 1))], axis=-1)

    # -------------------------------------------------------------------------------------------- node hooks
    def _initial_state(self, t0: float) -> MclState:
        n = self.n_particles
        rng = self._rng(_INIT, t0)
        if self.initial_box is not None:
            p = self._uniform(rng, n, self.initial_box)
        else:
            L = np.linalg.cholesky(self.initial.cov)
            y = rng.standard_normal((n, 3)) @ L.T
            p = SE2.to_xytheta(self.initial.mean @ SE2.exp(y, validate=False))
        return MclState(float(t0), 0.0, 0.0, _frozen(p), _frozen(np.full(n, 1.0 / n)))

    def _advance(self, s: MclState, robot: int, t: float) -> MclState:
        dt = t - s.t
        if dt <= 0:
            return s
        c, sn, tx, ty, S11, S12, S13, S22, S23, S33 = odometry_increment_terms(s.v, s.w, dt, self.noise)
        L = sqrt_cov3(S11, S12, S13, S22, S23, S33)
        rng = self._rng(_PREDICT, s.t, t)
        y = rng.standard_normal((s.particles.shape[0], 3)) @ L.T
        ex, ey, ea = exp_xyt(y).T
        # increment mean exp(dt (v, 0, w)^) composed with the noise exp(y), then applied to each particle
        ix, iy = tx + c * ex - sn * ey, ty + sn * ex + c * ey
        ia = math.atan2(sn, c) + ea
        p = s.particles
        ct, st = np.cos(p[:, 2]), np.sin(p[:, 2])
        new = np.stack([p[:, 0] + ct * ix - st * iy, p[:, 1] + st * ix + ct * iy, wrap_angle(p[:, 2] + ia)], axis=-1)
        return s._replace(t=t, particles=_frozen(new))

    def _set_command(self, s: MclState, robot: int, v: float, w: float) -> MclState:
        return s._replace(v=v, w=w)

    def _belief(self, s: MclState, robot: int) -> GroupGaussian:
        mean, cov = fit_gaussian(s.particles, s.weights)
        if self.regularise:
            cov = cov * (1.0 + (4.0 / (5.0 * s.particles.shape[0])) ** (2.0 / 7.0))
        return belief_of(mean, cov)

    def _fuse_group(self, s: MclState, g: Group) -> tuple[MclState, list[Outcome], list[Message]]:
        targets = [self._classify(g, d) for d in g.detections]
        usable = [t[0] not in ("rejected", "unknown") for t in targets]
        if not any(usable):
            return s, list(targets), []
        rng = self._rng(_GROUP, g.t)
        p, w, k = self._inject(s, rng)
        injected = s.injected + k
        n = p.shape[0]
        with np.errstate(divide="ignore"):
            lw = np.log(w)
        outcomes: list[Outcome] = []
        fused = False
        w_slow, w_fast = s.w_slow, s.w_fast
        for d, target in zip(g.detections, targets, strict=True):
            if target[0] in ("rejected", "unknown"):
                outcomes.append(target)
                continue
            lik = self._likelihood(d, p, target)
            if lik is None:
                outcomes.append(("rejected", DEGENERATE))
                continue
            nis, logdet = lik
            log_avg = logsumexp(lw - 0.5 * nis)  # log of the weighted mean of exp(-nis / 2)
            avg = math.exp(log_avg) if log_avg >= LOG_TINY else 0.0
            w_slow += ALPHA_SLOW * (avg - w_slow)
            w_fast += ALPHA_FAST * (avg - w_fast)
            alive = np.isfinite(lw)
            best = float(np.min(nis[alive])) if alive.any() else math.inf
            verdict = self._gated(best, len(d.z))
            if verdict is not None:
                outcomes.append(verdict)
                continue
            if avg == 0.0:
                outcomes.append(("gated", NEGLIGIBLE))
                continue
            if target[0] == "robot":
                moved = self._neighbour_moved(p, np.exp(lw - logsumexp(lw)), d, target[1])
                if moved is None:
                    outcomes.append(("rejected", NUMERICAL))
                    continue
                p = moved
                fused = True
                outcomes.append(FUSED)
                continue
            q = nis + logdet - np.min(logdet)
            new = lw - 0.5 * q
            total = logsumexp(new)
            if not math.isfinite(total):
                outcomes.append(("rejected", NUMERICAL))
                continue
            wn = np.exp(new - total)
            if target[0] == "landmark" and 1.0 / float(wn @ wn) < ENSEMBLE_ESS * n:
                split = landmark_split(p, lw, q, d, target[1], ENSEMBLE_ESS * n)
                if split is not None:
                    p, lw = split
                    fused = True
                    outcomes.append(FUSED)
                    continue
            lw = new - total
            fused = True
            outcomes.append(FUSED)
        if not fused and k == 0:
            return s._replace(w_slow=w_slow, w_fast=w_fast), outcomes, []
        w = np.exp(lw)
        w /= w.sum()
        resamples = s.resamples
        if fused and 1.0 / float(w @ w) < self.resample_threshold * n:
            idx = systematic_resample(w, float(rng.random()))
            p = p[idx]
            w = np.full(n, 1.0 / n)
            resamples += 1
            if self.roughen > 0:
                ext = np.ptp(p, axis=0)
                ext[2] = np.ptp(wrap_angle(p[:, 2] - p[0, 2]))  # the heading's extent around one of the particles
                p = p + rng.normal(size=p.shape) * (self.roughen * ext * n ** (-1.0 / 3.0))
                p[:, 2] = wrap_angle(p[:, 2])
        if p is not s.particles:
            p = _frozen(np.array(p))
        return MclState(s.t, s.v, s.w, p, _frozen(w), resamples, injected, w_slow, w_fast), outcomes, []

    def _inject(self, s: MclState, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, int]:
        """Particles and weights after the augmented-MCL injection of a group, and how many were replaced."""
        p, w = s.particles, s.weights
        n = p.shape[0]
        k = round(n * self.injection_fraction(s)) if self.bounds is not None else 0
        if k > 0 and self.bounds is not None:
            idx = rng.choice(n, size=k, replace=False)
            p = p.copy()
            p[idx] = self._uniform(rng, k, self.bounds)
            w = w.copy()
            w[idx] = 1.0 / n
            w /= w.sum()
        return p, w, k

    def _neighbour_moved(self, p: np.ndarray, w: np.ndarray, d: Any, answer: Any) -> np.ndarray | None:
        """Particles ``p`` (weights ``w``) moved onto the fusion of their fitted Gaussian with the neighbour's
        ``answer`` through detection ``d``: inverse covariance intersection for a relative pose, covariance
        intersection for a range or bearing (module docstring); None when the update is not usable."""
        mean, cov = fit_gaussian(p, w)
        nb_mean, nb_cov = answer.belief_arrays()
        R = np.asarray(d.cov, dtype=float)
        with np.errstate(all="ignore"):
            if d.kind == Kind.POSE:
                nu, W = K.relative_to_pseudo(SE2, nb_mean, nb_cov, SE2.from_xytheta(d.z), R)
                m2, c2, _ = inverse_ci(SE2, mean, cov, nu, W)
            else:
                wc = float(point_weight(mean, cov, d.kind, d.z, R, nb_mean, nb_cov))
                meas = K.PointMeasurement(d.kind, d.z, R, nb_mean, nb_cov / (1 - wc), True)
                m2, c2, ok = K.point_update(mean, cov / wc, meas)
                if not bool(ok):
                    return None
        return ensemble_transform(p, mean, cov, m2, c2)

    @property
    def particle_counts(self) -> dict[str, int]:
        """Resamplings and injected particles so far (carried in the latest state: replays recount them)."""
        s = self._history.last_state()
        return {"resamples": s.resamples, "injected": s.injected} if s is not None else {"resamples": 0, "injected": 0}

    def injection_fraction(self, s: MclState) -> float:
        """Fraction of the particles replaced by random ones at the next group: ``random_fraction * max(0, 1 -
        w_fast / w_slow)`` (augmented MCL; 0 before any likelihood was averaged)."""
        if self.random_fraction <= 0 or s.w_slow <= 0:
            return 0.0
        return self.random_fraction * max(0.0, 1.0 - s.w_fast / s.w_slow)

    def _likelihood(self, d: Any, p: np.ndarray, target: tuple[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
        """Per particle: normalized innovation squared ``(N,)`` and log-determinant ``(N,)`` of the innovation
        covariance of ``d`` against a classified target (the models of :mod:`swarmloc.sensors.models`, with the
        target's covariance through its Jacobian); None when the geometry is degenerate for all particles."""
        z = np.asarray(d.z, dtype=float)
        R = np.asarray(d.cov, dtype=float)
        n = p.shape[0]
        if target[0] == Kind.ABSOLUTE:
            r = models.residual(Kind.POSE, z, p)
            S = np.broadcast_to(R, (n, 3, 3))
            bad = None
        else:
            if target[0] == "robot":
                xk, Pk = C.from_group(*target[1].belief_arrays())
            else:
                xk, Pk = target[1]
            m = models.MODELS[d.kind]
            if d.kind == Kind.POSE:  # H_k = diag(R^T, 1)
                h, _, T = models.predict(d.kind, p, xk)
                S = m.noise(z, R) + T @ Pk @ np.swapaxes(T, -1, -2)
                bad = None
            else:
                bad = m.degenerate(p, xk[:2])
                if bad.all():
                    return None
                h, _, J = models.predict(d.kind, np.where(bad[:, None], p - 1.0, p), xk[:2])  # finite; bad rows dropped
                S = R + J @ Pk[:2, :2] @ np.swapaxes(J, -1, -2)
            r = m.residual(z, h)
        nis, logdet = quadratic(r, S)
        if bad is not None and bad.any():
            nis = np.where(bad, np.inf, nis)
        nis = np.where(np.isfinite(nis), nis, np.inf)
        return nis, np.where(np.isfinite(logdet), logdet, 0.0)
