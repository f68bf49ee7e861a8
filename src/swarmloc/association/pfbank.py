"""A bank of particle filters, one per robot met (Stegagno's slides 61-63): the filtering stage after PMR.

Robot ``i`` (ego) keeps, for every robot ``j`` it has met, particles of ``q_j``, the pose of ``j`` in ego's frame
(independence assumption of slide 62: the marginals, not the joint). Inputs, all as planar poses ``(x, y, theta)``
with covariances in exponential coordinates with right perturbation (the convention of :mod:`swarmloc.gaussian`):

* ego's motion ``delta_i`` (pose of ego's new frame in its old one) with noise ``cov``: every particle of every
  filter becomes ``q_j <- (delta_i exp(n))^-1 q_j`` (slide 63's ``q_j (-) (delta_i (+) n)``);
* ``j``'s motion ``delta_j`` (from communication): ``q_j <- q_j delta_j exp(n)``;
* PMR's hypotheses for ``j`` (its pose in every global solution, each a Gaussian measurement ``h = q_j exp(m)``,
  ``m ~ N(0, R_h)``): the likelihood of a particle is the mixture ``1/H sum_h N(log(q^-1 h); 0, R_h)`` (slide 63).

A filter starts at the first hypotheses for its robot (particles drawn from the mixture, the measurement not
reused). When no particle explains any hypothesis (every Mahalanobis distance beyond ``reset_nis``) the update is
skipped and counted ``unexplained``; after ``reset_after`` such updates in a row (a kidnapping or a lost track, not
one spurious registration among clutter) the filter is re-initialized from the latest hypotheses, counted
``reset``. Systematic resampling when the effective sample size drops below ``resample_ess`` of the particles.

Estimate (:meth:`ParticleFilterBank.estimate`): the particles, embedded as ``(x, y, L cos theta, L sin theta)``,
are split into *modes* (connected components of the graph linking particles closer than ``mode_radius``); modes
holding at least ``ambiguity_mass`` of the weight are significant, and the estimate is *ambiguous* while more than
one persists, or while none does (particles scattered over many small modes: a lost filter). The Gaussian handed
out is that of the heaviest mode: mean on SE(2) (iterated weighted mean of the exponential coordinates) and
covariance of ``log(mu^-1 q)`` over the particles within a 99.9% chi-square gate of it.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated

import msgspec
import numpy as np

from swarmloc.gaussian import GroupGaussian, check_covariance, symmetric
from swarmloc.lie import SE2, between_xyt, compose_xyt, exp_xyt, log_xyt, wrap_angle

__all__ = ["BankEstimate", "BankSettings", "ParticleFilterBank"]

Hypothesis = tuple[np.ndarray, np.ndarray]
"""A measurement of a neighbour's pose in ego's frame: ``(pose (3,) (x, y, theta), cov (3, 3))``."""


@dataclass(frozen=True)
class BankEstimate:
    """One filter's estimate: ``gaussian`` of the heaviest mode (mean in SE(2), covariance in exponential
    coordinates), ``ambiguous`` while more than one significant mode persists, ``modes``: ``(pose (3,), mass)`` of
    every significant mode, heaviest first, and ``ess``: the effective sample size."""

    robot: int
    gaussian: GroupGaussian
    ambiguous: bool
    modes: list[tuple[np.ndarray, float]]
    ess: float


def _sample(rng: np.random.Generator, cov: np.ndarray, n: int) -> np.ndarray:
    """``n`` draws of ``N(0, cov)``: the numbers of ``rng.multivariate_normal(..., method="cholesky")``."""
    return rng.standard_normal((n, 3)) @ np.linalg.cholesky(cov).T


def _components(adj: np.ndarray) -> np.ndarray:
    """Connected components of a symmetric boolean adjacency ``(n, n)`` (diagonal set), labelled 0, 1, ... in the
    order of their smallest member (as ``scipy.sparse.csgraph.connected_components`` labels them): each node takes
    the smallest label among its neighbours until none changes."""
    n = len(adj)
    label = np.arange(n)
    while True:
        new = np.where(adj, label[None, :], n).min(1)
        new = new[new]  # jump to the label's own label: halves the rounds on long chains
        if np.array_equal(new, label):
            return np.unique(label, return_inverse=True)[1]
        label = new


def _compose_exp(mu: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``mu exp(y)`` for one pose ``mu`` and one tangent vector ``y`` ``(3,)`` (scalar math)."""
    x0, x1, a = float(y[0]), float(y[1]), float(y[2])
    if abs(a) < 0.05:
        a2 = a * a
        A = (((a2 / 362880 - 1 / 5040) * a2 + 1 / 120) * a2 - 1 / 6) * a2 + 1.0
        B = a * ((((a2 / 3628800 - 1 / 40320) * a2 + 1 / 720) * a2 - 1 / 24) * a2 + 0.5)
    else:
        A, B = math.sin(a) / a, (1.0 - math.cos(a)) / a
    dx, dy = A * x0 - B * x1, B * x0 + A * x1
    c, s = math.cos(mu[2]), math.sin(mu[2])
    th = wrap_angle(mu[2] + a)
    return np.array([mu[0] + c * dx - s * dy, mu[1] + s * dx + c * dy, th])


def _log_rel(mu: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``log(mu^-1 q)`` ``(n, 3)`` for one pose ``mu`` ``(3,)`` and particles ``q`` ``(n, 3)``
    (:func:`~swarmloc.lie.log_xyt` of :func:`~swarmloc.lie.between_xyt` to rounding, ``mu``'s sine and cosine computed
    once)."""
    c, s = math.cos(mu[2]), math.sin(mu[2])
    dx, dy = q[:, 0] - mu[0], q[:, 1] - mu[1]
    t1, t2 = c * dx + s * dy, c * dy - s * dx
    a = wrap_angle(q[:, 2] - mu[2])
    t2a = a * a
    if float(np.abs(a).max()) < 0.05:  # all in the Taylor branch of (a/2) cot(a/2)
        k = (((-1 / 1209600 * t2a - 1 / 30240) * t2a - 1 / 720) * t2a - 1 / 12) * t2a + 1.0
    else:
        return log_xyt(np.column_stack([t1, t2, a]))
    h = 0.5 * a
    return np.column_stack([k * t1 + h * t2, k * t2 - h * t1, a])


class BankSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The bank's constants, each declared once with its range; :meth:`checked` builds one and checks every range
    (a direct construction does not: msgspec checks on conversion; :class:`ParticleFilterBank` checks what it is
    given)."""

    n_particles: Annotated[int, msgspec.Meta(ge=10, le=1_000_000)] = 1000
    """Particles per filter."""
    mode_radius: Annotated[float, msgspec.Meta(gt=0, le=100)] = 0.1
    """[m] particles closer than this (headings scaled by ``angle_scale``) are linked into one mode."""
    angle_scale: Annotated[float, msgspec.Meta(gt=0, le=100)] = 0.3
    """[m/rad] weight of the heading in the distance that links particles."""
    ambiguity_mass: Annotated[float, msgspec.Meta(gt=0, lt=0.5)] = 0.05
    """Smallest weight of a significant mode."""
    reset_nis: Annotated[float, msgspec.Meta(gt=0, le=1e6)] = 30.0
    """Mahalanobis squared beyond which a hypothesis explains no particle."""
    reset_after: Annotated[int, msgspec.Meta(ge=1, le=1_000_000)] = 1
    """Unexplained updates in a row before a filter restarts from the latest hypotheses."""
    resample_ess: Annotated[float, msgspec.Meta(gt=0, le=1)] = 0.5
    """Effective sample size, as a fraction of ``n_particles``, below which a filter resamples."""

    @classmethod
    def checked(cls, **values: object) -> BankSettings:
        """Settings from keyword values (the rest default), every range checked; ValueError naming the field."""
        try:
            return msgspec.convert(values, cls)
        except msgspec.ValidationError as exc:
            raise ValueError(f"ParticleFilterBank settings: {exc}") from None


class ParticleFilterBank:
    """Particle filters for the robots ego has met (module docstring), with the constants of ``settings``
    (:meth:`BankSettings.checked`; default: every default); ``rng`` seeds the particles' draws."""

    def __init__(self, settings: BankSettings | None = None, rng: np.random.Generator | int | None = None) -> None:
        if settings is not None and not isinstance(settings, BankSettings):
            raise TypeError(f"ParticleFilterBank: settings must be a BankSettings (BankSettings.checked(n_particles="
                            f"...)), got {settings!r}")  # fmt: skip
        self.settings = BankSettings() if settings is None else BankSettings.checked(**msgspec.structs.asdict(settings))
        self.n = self.settings.n_particles
        self.rng = np.random.default_rng(rng)
        self.unexplained: dict[int, int] = {}
        self.particles: dict[int, np.ndarray] = {}
        self.weights: dict[int, np.ndarray] = {}
        self.counts: Counter[str] = Counter()

    def known(self) -> list[int]:
        """Robots with a filter."""
        return sorted(self.particles)

    # ------------------------------------------------------------------------------------------ motion
    def predict_ego(self, delta: object, cov: object) -> None:
        """Ego moved by ``delta`` ``(x, y, theta)`` with noise ``cov`` (3x3, right perturbation): every filter."""
        d = np.asarray(delta, float).reshape(3)
        C = check_covariance(cov, 3, "ParticleFilterBank.predict_ego")
        for j, q in self.particles.items():
            step = compose_xyt(d[None], exp_xyt(_sample(self.rng, C, len(q))))
            self.particles[j] = between_xyt(step, q)

    def predict_neighbour(self, robot: int, delta: object, cov: object) -> None:
        """Robot ``robot`` moved by ``delta`` with noise ``cov`` (its odometry, by communication)."""
        if robot not in self.particles:
            return
        d = np.asarray(delta, float).reshape(3)
        C = check_covariance(cov, 3, "ParticleFilterBank.predict_neighbour")
        q = self.particles[robot]
        self.particles[robot] = compose_xyt(compose_xyt(q, d[None]), exp_xyt(_sample(self.rng, C, len(q))))

    # ------------------------------------------------------------------------------------------ measurement
    def update(self, robot: int, hypotheses: Sequence[Hypothesis]) -> str:
        """Measurement update of ``robot``'s filter with PMR's hypotheses; returns what happened: ``"none"`` (no
        hypothesis), ``"initialized"``, ``"unexplained"``, ``"reset"`` or ``"updated"`` (also counted in
        :attr:`counts`)."""
        if not hypotheses:
            self.counts["none"] += 1
            return "none"
        H = np.array([np.asarray(h, float).reshape(3) for h, _ in hypotheses])
        R = np.array([check_covariance(c, 3, "ParticleFilterBank.update", "hypothesis cov") for _, c in hypotheses])
        if robot not in self.particles:
            self._init(robot, H, R)
            self.counts["initialized"] += 1
            return "initialized"
        q, w = self.particles[robot], self.weights[robot]
        rel = between_xyt(q[:, None, :], H[None])  # (N, H, 3): q^-1 h
        y = log_xyt(rel)
        Ri = np.linalg.inv(R)
        m2 = np.einsum("nhi,hij,nhj->nh", y, Ri, y)
        if m2.min() > self.settings.reset_nis:
            self.unexplained[robot] = self.unexplained.get(robot, 0) + 1
            if self.unexplained[robot] < self.settings.reset_after:
                self.counts["unexplained"] += 1
                return "unexplained"
            self._init(robot, H, R)
            self.counts["reset"] += 1
            return "reset"
        self.unexplained[robot] = 0
        ll = -0.5 * m2 - 0.5 * np.log(np.linalg.det(R))[None]
        ll = np.logaddexp.reduce(ll, axis=1)
        lw = np.log(np.maximum(w, 1e-300)) + ll
        w = np.exp(lw - lw.max())
        w /= w.sum()
        self.weights[robot] = w
        if 1.0 / (w * w).sum() < self.settings.resample_ess * self.n:
            idx = self._systematic(w)
            self.particles[robot], self.weights[robot] = q[idx], np.full(self.n, 1.0 / self.n)
        self.counts["updated"] += 1
        return "updated"

    def _init(self, robot: int, H: np.ndarray, R: np.ndarray) -> None:
        self.unexplained[robot] = 0
        pick = self.rng.integers(0, len(H), self.n)
        noise = np.einsum("nij,nj->ni", np.linalg.cholesky(R)[pick], self.rng.standard_normal((self.n, 3)))
        self.particles[robot] = compose_xyt(H[pick], exp_xyt(noise))
        self.weights[robot] = np.full(self.n, 1.0 / self.n)

    def _systematic(self, w: np.ndarray) -> np.ndarray:
        u = (self.rng.random() + np.arange(self.n)) / self.n
        return np.minimum(np.searchsorted(np.cumsum(w), u), self.n - 1)

    # ------------------------------------------------------------------------------------------ estimate
    def modes(self, robot: int) -> list[tuple[np.ndarray, float]]:
        """Every mode of ``robot``'s filter as ``(particle indices, mass)``, heaviest first (small ones included)."""
        q, w = self.particles[robot], self.weights[robot]
        L = self.settings.angle_scale
        emb = np.column_stack([q[:, 0], q[:, 1], L * np.cos(q[:, 2]), L * np.sin(q[:, 2])])
        # every pair closer than mode_radius (a dense N x N test: cheaper than a k-d tree at a few hundred particles)
        sq = np.einsum("ni,ni->n", emb, emb)
        d2 = sq[:, None] + sq[None, :] - 2.0 * (emb @ emb.T)
        label = _components(d2 <= self.settings.mode_radius**2)
        mass = np.bincount(label, weights=w)
        order = np.argsort(-mass)
        return [(np.nonzero(label == c)[0], float(mass[c])) for c in order]

    def estimate(self, robot: int) -> BankEstimate:
        """The Gaussian of ``robot``'s heaviest mode and the ambiguity flag (module docstring)."""
        if robot not in self.particles:
            raise KeyError(f"ParticleFilterBank: no filter for robot {robot!r} (met: {self.known()})")
        q, w = self.particles[robot], self.weights[robot]
        found = self.modes(robot)
        significant = [(idx, m) for idx, m in found if m >= self.settings.ambiguity_mass]
        out = []
        first = None
        for idx, m in significant:
            mu, C = self._moments(q[idx], w[idx])
            first = (mu, C) if first is None else first
            out.append((mu, m))
        spread = not significant  # no mode holds ambiguity_mass: the particles are scattered (a lost filter)
        heaviest = found[0][0]
        mu, C = first if first is not None else self._moments(q[heaviest], w[heaviest])  # significant[0] is found[0]
        for _ in range(2):  # widen to every particle within the gate of the mode (its tails)
            y = _log_rel(mu, q)
            inside = np.einsum("ni,ij,nj->n", y, np.linalg.inv(C), y) <= 16.266
            mu, C = self._moments(q[inside], w[inside])
        g = GroupGaussian(SE2, SE2.from_xytheta(mu), C)
        return BankEstimate(robot, g, spread or len(significant) > 1, out, float(1.0 / (w * w).sum()))

    @staticmethod
    def _moments(q: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean on SE(2) (iterated in exponential coordinates) and covariance of ``log(mu^-1 q)``."""
        w = w / w.sum()
        # start at the weighted mean of the positions and the circular mean of the headings (near the fixed point:
        # about 3 iterations instead of 6-8 from the heaviest particle)
        th = math.atan2(float(w @ np.sin(q[:, 2])), float(w @ np.cos(q[:, 2])))
        mu = np.array([float(w @ q[:, 0]), float(w @ q[:, 1]), th])
        for _ in range(8):
            step = w @ _log_rel(mu, q)
            mu = _compose_exp(mu, step)
            if np.abs(step).max() < 1e-12:
                break
        y = _log_rel(mu, q)
        C = np.einsum("n,ni,nj->ij", w, y, y)
        C = symmetric(C) + np.eye(3) * 1e-12
        return mu, C
