"""Data association of anonymous detections with robots: gated nearest neighbour and joint assignment.

Lecture slides 38-40 (Stegagno). A detection ``z`` of *some* robot, with model ``z = h(q_j) + nu``, is given the
identity ``j`` that minimises the Mahalanobis distance of its innovation (slide 38, eq. 8); ``m`` detections of
one scan are given distinct identities minimising the sum of those distances (slide 39, eq. 9), an assignment
problem solved here exactly with :func:`scipy.optimize.linear_sum_assignment` (the slides enumerate).

**Corrected formula.** Eq. 8 weighs the innovation with ``P_jj``, the target's state covariance. The innovation
``z - h(q_j)`` has covariance ``S_ij = H_i P_ii H_i^T + H_j P_jj H_j^T + R`` (observer and target independent, as
the distributed estimators take them), which is what a chi-square gate needs: with ``P_jj`` alone the distance is
not chi-square distributed (not even of the right units when ``z`` is a range and bearing). :func:`innovation_terms`
uses ``S_ij``; tests/test_association.py checks that the gated distance of a true association is chi-square with
``size(z)`` degrees of freedom by Monte Carlo. A centralized filter knows the cross-covariance ``P_ij`` of observer
and target and passes it (``cross``): ``S_ij`` then gains ``H_i P_ij H_j^T + H_j P_ji H_i^T`` and is the innovation
covariance its update uses, so the choice and the filter's gate weigh a detection alike (after a pair's mutual
detections their relative pose is known better than the two marginals say: left out, a teammate that is not the
one seen looks as likely as the marginals allow).

**Outcomes** of each detection (the node's counters): ``associated`` (given an identity), ``clutter`` (outside every
robot's gate: a false detection or a robot the team does not know), ``ambiguous`` (a second robot, or assignment,
is almost as likely: refused rather than guessed); a robot that was expected in view and given no detection is
``missed`` (:func:`joint`). Costs are squared Mahalanobis distances, arrays ``(m, n)``: detection by robot.

**Beyond the slides: the spread counts.** The squared distance alone favours a robot whose belief is spread wide
(its innovation covariance ``S`` is large, so every detection looks near it). With ``ln det S`` beside the costs
(:func:`innovation_terms`), a detection is also refused when another robot, in its gate or not, has a likelihood
``p(z | k)`` within the ambiguity ratio of the chosen one's (:func:`likely_rivals`: ``d2 + ln det S``, the
normalized distance of global-nearest-neighbour tracking, as in Blackman and Popoli, "Design and Analysis of
Modern Tracking Systems", 1999). Only refusals are added: a detection is never given a robot outside its gate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from swarmloc.gaussian import chi2_ppf, mahalanobis2
from swarmloc.sensors.models import MODELS

__all__ = ["Association", "gate_threshold", "innovation_terms", "joint", "likely_rivals", "nearest"]

CLUTTER = -1
"""Identity given to a detection outside every gate."""
AMBIGUOUS = -2
"""Identity given (by :func:`nearest`) to a detection that two robots explain almost equally well."""


def gate_threshold(dof: int, probability: float = 0.99) -> float:
    """The chi-square gate on a squared Mahalanobis distance with ``dof`` degrees of freedom that a true association
    passes with ``probability``."""
    if not 0.0 < probability < 1.0:
        raise ValueError(f"gate probability must be in (0, 1), got {probability}")
    return chi2_ppf(probability, dof)


def innovation_terms(
    kind: str,
    z: np.ndarray,
    R: np.ndarray,
    x_obs: np.ndarray,
    P_obs: np.ndarray,
    x_targets: np.ndarray,
    P_targets: np.ndarray,
    cross: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Squared Mahalanobis distances ``(m, n)`` of ``m`` detections of kind ``kind`` (``z`` ``(m, k)``, noise ``R``
    ``(m, k, k)`` in the model's coordinates) made by one observer (state ``x_obs`` ``(3,)``, covariance ``P_obs``
    ``(3, 3)``, world frame ``(x, y, theta)`` [m, rad]) from each of ``n`` candidate robots (``x_targets`` ``(n, 3)``,
    ``P_targets`` ``(n, 3, 3)``), with the innovation covariance ``H_i P_obs H_i^T + H_j P_j H_j^T + R``, plus
    ``H_i C_j H_j^T + H_j C_j^T H_i^T`` with ``cross`` ``C (n, 3, 3)``, the covariances of observer and candidate
    (None: independent). A candidate on top of the observer (a range/bearing model undefined there) costs ``inf``.
    Returns them and ``ln det S_ij`` ``(m, n)`` (the innovation's spread, for the likelihood
    ``-2 ln p(z | j) = d2_ij + ln det S_ij + k ln 2 pi``; 0 where the cost is ``inf``)."""
    model = MODELS.get(kind)
    if model is None or model.targets == "self":
        raise ValueError(f"association needs a detection of another robot, not kind {kind!r}")
    z = np.asarray(z, dtype=float).reshape(-1, model.size)
    R = np.asarray(R, dtype=float).reshape(-1, model.size, model.size)
    xt = np.asarray(x_targets, dtype=float).reshape(-1, 3)
    Pt = np.asarray(P_targets, dtype=float).reshape(-1, 3, 3)
    if R.shape[0] != z.shape[0] or Pt.shape[0] != xt.shape[0]:
        raise ValueError(f"{z.shape[0]} detections with {R.shape[0]} noise matrices, {xt.shape[0]} robots with "
                         f"{Pt.shape[0]} covariances")  # fmt: skip
    if z.shape[0] == 0 or xt.shape[0] == 0:
        return np.zeros((z.shape[0], xt.shape[0])), np.zeros((z.shape[0], xt.shape[0]))
    xo = np.asarray(x_obs, dtype=float)
    bad = np.broadcast_to(model.degenerate(xo[None, :], xt), (xt.shape[0],))
    xt = np.where(bad[:, None], xt + [1.0, 0.0, 0.0], xt)  # a finite stand-in; its cost is set to inf below
    h, Hi, Hj = model.predict(xo[None, :], xt)  # (n, k), (n, k, 3), (n, k, 3)
    assert Hj is not None  # noqa: S101  (a relative model: a Jacobian for the target)
    S_state = Hi @ np.asarray(P_obs, dtype=float) @ np.swapaxes(Hi, -1, -2) + Hj @ Pt @ np.swapaxes(Hj, -1, -2)
    if cross is not None:
        Hc = Hi @ np.asarray(cross, dtype=float).reshape(xt.shape[0], 3, 3) @ np.swapaxes(Hj, -1, -2)
        S_state = S_state + Hc + np.swapaxes(Hc, -1, -2)
    S = S_state[None, :, :, :] + model.noise(z, R)[:, None, :, :]  # (m, n, k, k)
    r = model.residual(z[:, None, :], h[None, :, :])  # (m, n, k)
    d2 = mahalanobis2(r, S)
    logdet = np.linalg.slogdet(S)[1]
    d2[:, bad] = np.inf
    logdet[:, bad] = 0.0
    return d2, logdet


@dataclass(frozen=True)
class Association:
    """What a policy decided for one scan: ``identity[i]`` the robot index (column) given to detection ``i``, or
    :data:`CLUTTER` / :data:`AMBIGUOUS`; ``cost[i]`` its squared Mahalanobis distance (``nan`` if none);
    ``missed`` the robot indices expected in view and given no detection."""

    identity: np.ndarray
    cost: np.ndarray
    missed: np.ndarray

    def counts(self) -> dict[str, int]:
        """The outcome counters: associated, clutter, ambiguous, missed."""
        return {
            "associated": int(np.sum(self.identity >= 0)),
            "clutter": int(np.sum(self.identity == CLUTTER)),
            "ambiguous": int(np.sum(self.identity == AMBIGUOUS)),
            "missed": int(self.missed.size),
        }


def _missed(identity: np.ndarray, expected: np.ndarray | None, n: int) -> np.ndarray:
    if expected is None:
        return np.zeros(0, dtype=int)
    exp = np.flatnonzero(np.asarray(expected, dtype=bool).reshape(n))
    return np.setdiff1d(exp, identity[identity >= 0])


def _check_costs(costs: np.ndarray, gate: float) -> np.ndarray:
    c = np.asarray(costs, dtype=float)
    if c.ndim != 2:
        raise ValueError(f"costs must be (detections, robots), got shape {c.shape}")
    if np.isnan(c).any() or (c < 0).any():
        raise ValueError("costs must be squared distances: non-negative, no NaN (inf for impossible)")
    if not gate > 0:
        raise ValueError(f"gate must be positive, got {gate}")
    return c


def nearest(costs: np.ndarray, gate: float, ambiguity: float = 0.0, expected: np.ndarray | None = None,
            logdet: np.ndarray | None = None) -> Association:  # fmt: skip
    """Eq. 8, each detection on its own: the robot of least cost inside the ``gate``; :data:`CLUTTER` if none.
    With ``ambiguity > 0`` a detection whose second-best robot inside the gate costs less than ``ambiguity`` more
    is :data:`AMBIGUOUS` (a likelihood ratio below ``exp(ambiguity / 2)`` where the two innovations' spreads are
    alike); with ``logdet`` as well, so is one that another robot explains almost as well by the likelihood
    (:func:`likely_rivals`). Two detections may get one robot (the slides' "relaxed" solution); ``expected``:
    robots ``(n,)`` in view, for the ``missed`` count."""
    c = _check_costs(costs, gate)
    m, n = c.shape
    if n == 0:
        return Association(np.full(m, CLUTTER), np.full(m, np.nan), np.zeros(0, dtype=int))
    order = np.argsort(c, axis=1)
    best = c[np.arange(m), order[:, 0]]
    ident = np.where(best <= gate, order[:, 0], CLUTTER)
    if ambiguity > 0 and n > 1:
        second = c[np.arange(m), order[:, 1]]
        ident = np.where((ident >= 0) & (second <= gate) & (second - best < ambiguity), AMBIGUOUS, ident)
    ident = likely_rivals(c, logdet, ident, ambiguity)
    cost = np.where(ident >= 0, best, np.nan)
    return Association(ident, cost, _missed(ident, expected, n))


def joint(costs: np.ndarray, gate: float, expected: np.ndarray | None = None, ambiguity: float = 0.0,
          logdet: np.ndarray | None = None) -> Association:  # fmt: skip
    """Eq. 9 with a gate: distinct robots for the detections of one scan, minimising the total cost, where a
    detection may also be declared clutter at the cost ``gate`` (so no pair outside the gate is ever made, and a
    pair inside it is made whenever that lowers the total). Solved exactly as a rectangular assignment over the
    robots plus one clutter column per detection. ``expected``: robots ``(n,)`` in view, for the ``missed`` count.

    With ``ambiguity > 0`` (beyond the slides) a detection ``i`` given robot ``j`` is :data:`AMBIGUOUS` when the
    best assignment that gives ``i`` *another robot* costs less than ``ambiguity`` more in total (a likelihood ratio
    of the two joint hypotheses below ``exp(ambiguity / 2)`` where the spreads are alike): the joint analogue of
    :func:`nearest`'s margin, one more assignment per associated detection; with ``logdet`` as well, so is one that
    another robot alone explains almost as well by the likelihood (:func:`likely_rivals`)."""
    c = _check_costs(costs, gate)
    m, n = c.shape
    big = gate * (m + 1) + 1.0  # dearer than declaring every detection clutter: never chosen
    pair = np.where(c <= gate, c, big)
    clutter = np.full((m, m), big)
    np.fill_diagonal(clutter, gate)
    full = np.hstack([pair, clutter])
    rows, cols = linear_sum_assignment(full)
    best = float(full[rows, cols].sum())
    ident = np.full(m, CLUTTER)
    real = cols < n
    ident[rows[real]] = cols[real]
    ident[(ident >= 0) & (c[np.arange(m), np.maximum(ident, 0)] > gate)] = CLUTTER
    if ambiguity > 0:
        final = ident.copy()
        for i in np.flatnonzero(ident >= 0):
            alt = full.copy()
            alt[i, ident[i]] = alt[i, n + i] = big * 2  # i gets another robot (clutter is the gate's business)
            r2, c2 = linear_sum_assignment(alt)
            if float(alt[r2, c2].sum()) - best < ambiguity:
                final[i] = AMBIGUOUS
        ident = final
    ident = likely_rivals(c, logdet, ident, ambiguity)
    cost = np.where(ident >= 0, c[np.arange(m), np.maximum(ident, 0)], np.nan)
    return Association(ident, cost, _missed(ident, expected, n))


def likely_rivals(costs: np.ndarray, logdet: np.ndarray | None, identity: np.ndarray, ambiguity: float) -> np.ndarray:
    """``identity`` with :data:`AMBIGUOUS` for each detection ``i`` given robot ``j`` where another robot ``k``, in
    the gate or not, has the likelihood cost ``costs[i, k] + logdet[i, k]`` (``-2 ln p(z_i | k)`` up to a constant)
    below ``costs[i, j] + logdet[i, j] + ambiguity``: robot ``k`` explains the detection at least ``exp(-ambiguity
    / 2)`` times as well as ``j``. The squared distance alone favours a robot whose belief is spread wide: it lets
    a detection of a well-known robot just outside its gate go to a lost one (on MRCLAM dataset 1, to a robot whose
    start was 1.5 m uncertain, which jumped 3 m). Unchanged with ``logdet`` None or ``ambiguity`` 0."""
    if logdet is None or not ambiguity > 0:
        return identity
    ld = np.asarray(logdet, dtype=float)
    if ld.shape != costs.shape or not np.isfinite(ld).all():
        raise ValueError(f"logdet must be finite, shaped as the costs {costs.shape}, got {ld.shape}")
    nll = np.where(np.isfinite(costs), costs + ld, np.inf)
    out = identity.copy()
    for i in np.flatnonzero(identity >= 0):
        j = identity[i]
        rival = np.delete(nll[i], j)
        if rival.size and rival.min() < nll[i, j] + ambiguity:
            out[i] = AMBIGUOUS
    return out
