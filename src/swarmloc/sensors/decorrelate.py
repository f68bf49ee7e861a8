"""Time-correlated detection errors: a truth-free calibration and an information-equivalent weighting.

A camera that reads the same target a few times a second makes nearly the same error each time (on MRCLAM the
errors of consecutive readings of one target are strongly correlated). A filter that treats the readings as
independent counts the same error many times and becomes over-confident. This module is a pre-processor of the
detection stream, independent of the estimator: it gives every range-bearing :class:`~swarmloc.events.Detection`
a covariance such that the readings of one target, fused as if independent, carry the information they really
carry under a correlated-error model whose constants are estimated from the detections themselves.

**Error model.** Each ``(observer, target)`` pair is a *stream*; each component ``c`` (range, bearing) of its error
is a stationary Gauss-Markov process plus white noise, independent across streams and components::

    e_c(t) = s_c(t) + n_c(t),   Var e_c = std_c^2,   s_c: Ornstein-Uhlenbeck, variance phi_c std_c^2, time
    constant tau_c;  n_c white, variance (1 - phi_c) std_c^2;  so  corr(e_c(t), e_c(t + lag)) = phi_c exp(-lag/tau_c).

**Information weights** (:func:`information_weights`). For ``n`` readings of a static quantity ``mu`` with this
error, the generalized-least-squares (best linear unbiased) estimate of ``mu`` has information
``I_n = 1' Sigma^-1 1`` (``Sigma`` the readings' error covariance). Reading ``k`` of a stream is given the share
``w_k = std^2 (I_k - I_{k-1})`` in units of one independent reading, computed exactly, for any spacing, by the
prediction-error decomposition of ``Sigma`` (a scalar Kalman filter of ``s_c`` fed with a sequence of ones), and
its variance becomes ``std^2 / w_k``. The weights of a stream add up to ``I_n std^2``: the filter that fuses them
as independent then claims exactly the information the correlated readings hold. Special cases: a reading with no
predecessor (or one far older than ``tau``) gets ``w = 1``; a pure AR(1) error (``phi = 1``) at lag ``dt`` gives
``w = (1 - rho) / (1 + rho)`` with ``rho = exp(-dt / tau)``, so ``n`` equally spaced readings carry
``(n (1 - rho) + 2 rho) / (1 + rho)`` readings' worth (:func:`ar1_information`; ``~ n (1 - rho) / (1 + rho)``).
Assumptions and what they cost: the error model above, and a target that moves little relative to the observer
within ``tau`` (for a moving geometry the weights are an approximation). The weights are causal (a reading's weight
depends on the earlier readings of its stream only, so a live node can apply them), and they make the *total*
information right, not the combination: a filter that fuses the readings as independent forms the mean weighted
by ``w``, whose variance ``w' Sigma w / (sum w)^2`` exceeds the claimed ``1 / sum w`` by a few percent for errors
that decorrelate within a few readings, about 15% for ``tau`` ~ 5 s and up to about 30% for ``tau`` ~ 20 s, read
two to four times a second (the white-noise model claims ``1 / n``, often a tenth of the true variance).

**Calibration without ground truth** (:func:`calibrate`). It uses the landmark map and the landmark detections:

1. *snapshots*: every instant at which one observer reads two or more distinct landmarks; the observer's pose
   ``(x, y, theta)`` is fitted to that instant's readings by weighted Gauss-Newton (started from a 2-D Procrustes
   fit), leaving residuals ``v_i`` with redundancy numbers ``r_i = 1 - (A N^-1 A' W)_ii`` (``sum r_i = 2k - 3``);
   a fit that has not converged (:data:`swarmloc.sensors.snapshots.STEP_TOL`) is dropped and counted (the
   model's diagnostic ``unconverged_fits``);
2. *variance components* (Helmert/Foerstner): ``std_c^2 = sum_i v_i^2 / (kappa sum_i r_i)`` over the range (or
   bearing) residuals with ``|v_i| <= 3 std_c sqrt(r_i)``, ``kappa = 0.9733`` the variance of a standard normal cut
   at 3 (a convention against the heavy tails, not a fitted number); iterated from the a-priori std to a fixed
   point (relative change below 1e-3);
3. *correlation*: the standardized residuals ``v_i / sqrt(r_i)`` of one (observer, landmark) stream, paired at
   lags in the bins :data:`LAG_EDGES`, give ``rho(lag) = sum u_i u_j / sum (u_i^2 + u_j^2) / 2`` pooled over the
   streams; ``phi_c`` and ``tau_c`` are the least-squares fit of ``phi exp(-lag / tau)`` to these bins.

Limits, stated rather than hidden: a bearing error common to all targets of one image acts like a heading error
and is absorbed by the snapshot's fitted heading, so the estimated bearing std is that of the per-target part; a
snapshot residual mixes the errors of the instant's landmarks, which lowers the estimated short-lag correlation
``phi``; errors that persist for minutes (a per-target bias) are outside the model. With fewer than
:data:`MIN_INSTANTS` snapshots the calibration falls back to the a-priori std and white noise, and says so
(``CameraModel.source``). Every constant of this module is a statistical convention or a bound named here; none
was chosen from a dataset's ground truth.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarmloc.arrays import readonly
from swarmloc.events import Detection, Event, Kind
from swarmloc.sensors.snapshots import (
    DetectionSet,
    fit_residuals,
    snapshot_poses,
)

__all__ = [
    "KAPPA_3SIGMA",
    "LAG_EDGES",
    "MIN_INSTANTS",
    "PRIOR_BEARING_STD",
    "PRIOR_RANGE_STD",
    "CameraModel",
    "DetectionSet",
    "ErrorComponent",
    "ar1_information",
    "calibrate",
    "calibrate_pooled",
    "decorrelate",
    "fit_correlation",
    "heldout_residuals",
    "heldout_score",
    "information_weights",
    "lag_correlation",
    "snapshot_poses",
    "stream_nll",
    "truncated_variance",
]

KAPPA_3SIGMA = 0.9733
"""Variance of a standard normal variable cut at +-3 (the inlier rule of the variance-component estimate)."""

LAG_EDGES: tuple[float, ...] = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0)
"""Lag bins [s] of the residual autocorrelation (a log-spaced analysis grid, not fitted)."""

PRIOR_RANGE_STD = 0.1
"""[m] The a-priori range std of MRCLAM's camera (a generic value, not fitted to any data): the start of the
calibration, its fallback, and the default wherever the camera's noise is not given."""

PRIOR_BEARING_STD = 0.035
"""[rad] The a-priori bearing std (about 2 degrees, the camera's spec); as :data:`PRIOR_RANGE_STD`."""

MIN_INSTANTS = 100
"""Fewest snapshots (instants with two or more landmarks) for an estimate; fewer: a-priori std, white noise."""

MIN_PAIRS = 50
"""Fewest residual pairs for a lag bin to enter the correlation fit."""

PHI_MAX = 0.999
"""Largest correlated fraction ``phi`` (keeps a white part, so that a reading never carries zero information)."""

W_MIN = 1e-6
"""Smallest information weight (a covariance at most 1e6 times the marginal one)."""

MEDIAN_CHI2_1 = 0.454936
"""Median of a chi-square variable with 1 degree of freedom."""

MIN_REDUNDANCY = 0.05
"""Residuals with a smaller redundancy number say too little about their own error and are left out."""


# ----------------------------------------------------------------------------------------------------------------
# the information of correlated readings


def _check_corr(phi: float, tau: float) -> tuple[float, float]:
    if not (isinstance(phi, int | float) and math.isfinite(phi) and 0.0 <= phi <= 1.0):
        raise ValueError(f"phi (correlated fraction of the error variance) must lie in [0, 1], got {phi!r}")
    if not (isinstance(tau, int | float) and math.isfinite(tau) and tau > 0.0):
        raise ValueError(f"tau (correlation time [s]) must be finite and > 0, got {tau!r}")
    return float(phi), float(tau)


def _check_times(times: Sequence[float] | np.ndarray, what: str = "times") -> np.ndarray:
    t = np.asarray(times, dtype=np.float64)
    if t.ndim != 1:
        raise ValueError(f"{what} must be one-dimensional, got shape {t.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise ValueError(f"{what}[{bad[0]}] is {t[bad[0]]}: times must be finite")
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        k = int(back[0]) + 1
        raise ValueError(
            f"{what} must be sorted (non-decreasing): "
            f"{what}[{k}] = {float(t[k])!r} < {what}[{k - 1}] = {float(t[k - 1])!r}"
        )
    return t


def information_weights(times: Sequence[float] | np.ndarray, phi: float, tau: float) -> np.ndarray:
    """Share of the information of each reading of one stream, in units of one independent reading.

    ``times`` [s] (sorted, finite) of the readings of one (observer, target) stream; ``phi`` in ``[0, 1]`` the
    correlated fraction of the error variance; ``tau`` [s] its correlation time. Returns ``w`` with
    ``sum(w[:k]) == 1' Sigma_k^-1 1`` (unit variance) for every ``k``: the generalized-least-squares information
    of the first ``k`` readings about a constant (see the module docstring). ``w[0] == 1``; ``0 < w <= 1`` for
    this model; values are floored at :data:`W_MIN`.
    """
    phi, tau = _check_corr(phi, tau)
    t = _check_times(times)
    out = np.empty(t.size)
    white = 1.0 - phi
    p, s_hat, t_prev = phi, 0.0, None  # variance and estimate of s (unit marginal variance), fed with ones
    for k, tk in enumerate(t.tolist()):
        if t_prev is not None:
            a = math.exp(-(tk - t_prev) / tau)
            s_hat *= a
            p = a * a * p + phi * (1.0 - a * a)
        s = p + white
        t_prev = tk
        if s <= 1e-300:  # phi = 1 and a repeated time: the reading repeats the last one exactly
            out[k] = 0.0
            continue
        eps = 1.0 - s_hat
        out[k] = eps * eps / s
        gain = p / s
        s_hat += gain * eps
        p -= gain * p
    return np.maximum(out, W_MIN)


def ar1_information(n: int, rho: float) -> float:
    """Information of ``n`` equally spaced readings with AR(1) errors of lag-1 correlation ``rho``, in units of one
    independent reading: ``(n (1 - rho) + 2 rho) / (1 + rho)`` (``1' Sigma^-1 1``; ``~ n (1 - rho) / (1 + rho)``).
    """
    if not (isinstance(n, int | np.integer) and n >= 1):
        raise ValueError(f"n must be a positive integer, got {n!r}")
    if not (math.isfinite(rho) and -1.0 < rho < 1.0):
        raise ValueError(f"rho must lie in (-1, 1), got {rho!r}")
    return (n * (1.0 - rho) + 2.0 * rho) / (1.0 + rho)


# ----------------------------------------------------------------------------------------------------------------
# autocorrelation of residual streams


def _check_streams(stream: np.ndarray, times: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, ...]:
    """Residual streams as arrays (``times`` and ``values`` as floats): ValueError unless ``stream``, ``times`` and
    ``values`` are 1-D arrays of equal length."""
    stream = np.asarray(stream)
    t = np.asarray(times, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if not (stream.ndim == t.ndim == v.ndim == 1 and stream.size == t.size == v.size):
        raise ValueError("stream, times and values must be 1-D arrays of equal length")
    return stream, t, v


def lag_correlation(
    stream: np.ndarray, times: np.ndarray, values: np.ndarray, edges: Sequence[float] = LAG_EDGES
) -> dict[str, np.ndarray]:
    """Pooled autocorrelation of ``values`` within streams, by lag bin.

    ``stream`` (integer labels), ``times`` [s] and ``values`` are 1-D arrays of equal length (NaN values are left
    out). Pairs ``i < j`` of the same stream with lag ``t_j - t_i`` in ``[edges[b], edges[b + 1])`` give
    ``rho[b] = sum v_i v_j / sum (v_i^2 + v_j^2) / 2`` (values taken as zero-mean). Returns ``lag`` (mean lag of
    the pairs of each bin), ``rho`` and ``pairs`` (NaN ``rho`` where a bin has none).
    """
    stream, t, v = _check_streams(stream, times, values)
    if not np.isfinite(t).all():
        raise ValueError("times must be finite")
    e = np.asarray(edges, dtype=np.float64)
    if e.ndim != 1 or e.size < 2 or not np.all(np.diff(e) > 0) or e[0] < 0:
        raise ValueError(f"edges must be increasing and >= 0, got {list(edges)}")
    keep = np.isfinite(v)
    order = np.lexsort((t[keep], stream[keep]))
    s, t, v = stream[keep][order], t[keep][order], v[keep][order]
    nb = e.size - 1
    num, den, cnt, lag_sum = np.zeros(nb), np.zeros(nb), np.zeros(nb, dtype=np.int64), np.zeros(nb)
    for m in range(1, s.size):
        same = s[m:] == s[:-m]
        lag = t[m:] - t[:-m]
        ok = same & (lag < e[-1])
        if not ok.any():  # rows sorted by (stream, time): no pair at offset m means none at any larger offset
            break
        b = np.searchsorted(e, lag[ok], side="right") - 1
        a, c = v[:-m][ok], v[m:][ok]
        np.add.at(num, b, a * c)
        np.add.at(den, b, 0.5 * (a * a + c * c))
        np.add.at(cnt, b, 1)
        np.add.at(lag_sum, b, lag[ok])
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.where(cnt > 0, num / den, np.nan)
        mean_lag = np.where(cnt > 0, lag_sum / cnt, 0.5 * (e[:-1] + e[1:]))
    return {"lag": mean_lag, "rho": rho, "pairs": cnt}


def fit_correlation(
    lag: np.ndarray, rho: np.ndarray, pairs: np.ndarray, min_pairs: int = MIN_PAIRS
) -> tuple[float, float]:
    """Least-squares fit of ``rho(lag) = phi exp(-lag / tau)`` to the bins with at least ``min_pairs`` pairs.

    ``tau`` on a log grid over [0.05 s, 1000 s], ``phi`` in closed form for each ``tau``, clipped to
    ``[0, PHI_MAX]``. Returns ``(phi, tau)``; ``(0.0, 1.0)`` (white noise) when fewer than three bins qualify.
    """
    lag, rho, pairs = (np.asarray(x, dtype=np.float64) for x in (lag, rho, pairs))
    ok = (pairs >= min_pairs) & np.isfinite(rho)
    if ok.sum() < 3:
        return 0.0, 1.0
    x_lag, y = lag[ok], rho[ok]
    best = (np.inf, 0.0, 1.0)
    for tau in np.geomspace(0.05, 1000.0, 600):
        x = np.exp(-x_lag / tau)
        phi = float(np.clip(np.dot(x, y) / np.dot(x, x), 0.0, PHI_MAX))
        sse = float(np.sum((y - phi * x) ** 2))
        if sse < best[0]:
            best = (sse, phi, float(tau))
    return best[1], best[2]


# ----------------------------------------------------------------------------------------------------------------
# calibration


@dataclass(frozen=True)
class ErrorComponent:
    """The error model of one measurement component: marginal ``std``, correlated fraction ``phi`` and correlation
    time ``tau`` [s] (``phi = 0``: white noise)."""

    std: float
    phi: float = 0.0
    tau: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.std) and self.std > 0):
            raise ValueError(f"std must be finite and > 0, got {self.std!r}")
        _check_corr(self.phi, self.tau)


@dataclass(frozen=True)
class CameraModel:
    """Range and bearing error models of a camera, where they come from, and the evidence of the estimate."""

    range: ErrorComponent
    bearing: ErrorComponent
    source: str = "a priori"
    instants: int = 0
    residuals: int = 0
    diagnostics: dict[str, list[float]] = field(default_factory=dict, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (for reports)."""
        return {
            "source": self.source,
            "range": dataclasses.asdict(self.range),
            "bearing": dataclasses.asdict(self.bearing),
            "instants": self.instants,
            "residuals": self.residuals,
            **self.diagnostics,
        }


def truncated_variance(cut: float) -> float:
    """Variance of a standard normal variable cut at ``+-cut`` (``KAPPA_3SIGMA`` at 3; 1 for ``inf``)."""
    if not (cut > 0):
        raise ValueError(f"cut must be > 0, got {cut!r}")
    if math.isinf(cut):
        return 1.0
    mass = math.erf(cut / math.sqrt(2.0))
    return 1.0 - 2.0 * cut * math.exp(-0.5 * cut * cut) / math.sqrt(2.0 * math.pi) / mass


def _vce(values: np.ndarray, red: np.ndarray, std: float, cut: float = 3.0) -> tuple[float, np.ndarray]:
    inl = np.abs(values) <= cut * std * np.sqrt(np.maximum(red, 0.0))
    den = truncated_variance(cut) * float(np.sum(red[inl]))
    if den <= 0:
        return std, inl
    return math.sqrt(float(np.sum(values[inl] ** 2)) / den), inl


def calibrate(
    observer: np.ndarray,
    t: np.ndarray,
    target: np.ndarray,
    z: np.ndarray,
    landmarks: Mapping[int, Any],
    range_std: float = PRIOR_RANGE_STD,
    bearing_std: float = PRIOR_BEARING_STD,
    estimate_std: bool = True,
    max_iterations: int = 100,
) -> CameraModel:
    """Estimate the camera's :class:`CameraModel` from its detections and the landmark map (no ground truth).

    ``observer``, ``t`` [s], ``target``, ``z`` ``(n, 2)`` (range [m], bearing [rad]) are the detections (robot
    targets are ignored here); ``landmarks`` maps landmark id to ``(x, y, ...)`` [m]. ``range_std`` and
    ``bearing_std`` are the a-priori std: the start of the variance-component iteration, the std kept when
    ``estimate_std`` is false, and the fallback (with white noise) when fewer than :data:`MIN_INSTANTS` snapshots
    exist. Raises ValueError on non-finite or mis-shaped input. :func:`calibrate_pooled` of one set.
    """
    return calibrate_pooled(
        [DetectionSet(observer, t, target, z, landmarks)], range_std, bearing_std, estimate_std, max_iterations
    )


def calibrate_pooled(
    sets: Sequence[DetectionSet],
    range_std: float = PRIOR_RANGE_STD,
    bearing_std: float = PRIOR_BEARING_STD,
    estimate_std: bool = True,
    max_iterations: int = 100,
    cut: float = 3.0,
) -> CameraModel:
    """One :class:`CameraModel` for several recordings of the same kind of camera (each with its own map).

    The snapshot fits run per set; the variance components pool the residuals of all sets, and the lag
    correlation pools the pairs of all sets' streams (a stream never spans two sets). ``cut`` is the inlier rule
    of the variance components, ``|v| <= cut std sqrt(r)``, with the variance of a normal cut there as its
    correction (:func:`truncated_variance`; 3 is the default convention; a larger cut lets more of the heavy tail
    into the std). Otherwise as :func:`calibrate`.
    """
    if not (range_std > 0 and bearing_std > 0 and math.isfinite(range_std) and math.isfinite(bearing_std)):
        raise ValueError(f"a-priori std must be finite and > 0, got {range_std!r}, {bearing_std!r}")
    if not sets:
        raise ValueError("calibrate_pooled: no detection sets")
    prepared = [ds.snapshots() for ds in sets]
    instants = sum(p[0].instants for p in prepared)
    if instants < MIN_INSTANTS:
        return CameraModel(
            ErrorComponent(range_std),
            ErrorComponent(bearing_std),
            source=f"a priori, white (only {instants} instants with two or more landmarks, {MIN_INSTANTS} needed)",
            instants=instants,
        )
    sr, sb = float(range_std), float(bearing_std)
    iterations = 0

    def pooled(sr: float, sb: float) -> dict[str, np.ndarray]:
        parts = [fit_residuals(p[0], sr, sb) for p in prepared]
        out = {k: np.concatenate([q[k] for q in parts]) for k in ("v_range", "r_range", "v_bearing", "r_bearing")}
        out["set"] = np.concatenate([np.full(q["row"].size, i) for i, q in enumerate(parts)])
        out["row"] = np.concatenate([q["row"] for q in parts])
        out["unconverged"] = np.sum([q["unconverged"] for q in parts])
        return out

    res = pooled(sr, sb)
    if estimate_std:
        for iterations in range(1, max_iterations + 1):  # noqa: B007
            nr, _ = _vce(res["v_range"], res["r_range"], sr, cut)
            nb, _ = _vce(res["v_bearing"], res["r_bearing"], sb, cut)
            done = abs(nr - sr) <= 1e-3 * sr and abs(nb - sb) <= 1e-3 * sb  # the inlier set can cycle below that
            sr, sb = nr, nb
            res = pooled(sr, sb)
            if done:
                break
    obs = np.concatenate([p[1][res["row"][res["set"] == i]] for i, p in enumerate(prepared)])
    tt = np.concatenate([p[2][res["row"][res["set"] == i]] for i, p in enumerate(prepared)])
    tg = np.concatenate([p[3][res["row"][res["set"] == i]] for i, p in enumerate(prepared)])
    stream = (res["set"] * 1_000_003 + obs) * 1_000_003 + tg  # a stream never spans two sets
    comps = {}
    diag: dict[str, Any] = {}
    for name, std in (("range", sr), ("bearing", sb)):
        v, red = res[f"v_{name}"], res[f"r_{name}"]
        use = (red >= MIN_REDUNDANCY) & (np.abs(v) <= cut * std * np.sqrt(np.maximum(red, 0.0)))
        u = np.where(use, v / np.sqrt(np.maximum(red, MIN_REDUNDANCY)), np.nan)
        lc = lag_correlation(stream, tt, u)
        phi, tau = fit_correlation(lc["lag"], lc["rho"], lc["pairs"])
        comps[name] = ErrorComponent(std, phi, tau)
        diag["lag_s"] = [round(float(x), 3) for x in lc["lag"]]
        diag[f"rho_{name}"] = [None if not np.isfinite(x) else round(float(x), 4) for x in lc["rho"]]
        diag["pairs"] = [int(x) for x in lc["pairs"]]
    diag["vce_iterations"] = iterations
    diag["unconverged_fits"] = int(res["unconverged"])  # snapshot fits dropped at the final std
    if len(sets) > 1 or cut != 3.0:
        diag["sets"] = [ds.name for ds in sets]
        diag["cut"] = cut
    source = "estimated (std and correlation)" if estimate_std else "a-priori std, estimated correlation"
    return CameraModel(
        comps["range"],
        comps["bearing"],
        source=source if len(sets) == 1 else f"{source}, pooled over {len(sets)} recordings",
        instants=instants,
        residuals=int(res["row"].size),
        diagnostics=diag,
    )


def stream_nll(
    stream: np.ndarray, times: np.ndarray, values: np.ndarray, component: ErrorComponent
) -> tuple[float, int]:
    """Exact Gaussian negative log-likelihood of residual streams under ``component``'s error model.

    ``stream`` (integer labels), ``times`` [s] and ``values`` (residuals, NaN: missing) are 1-D arrays of equal
    length; within a stream the values are ``component``'s error process (Ornstein-Uhlenbeck of variance ``phi
    std^2`` and time constant ``tau`` plus white noise), streams independent. The likelihood is computed by the
    prediction-error decomposition (a scalar Kalman filter per stream, all streams advanced together). Returns
    ``(sum of -log p, number of values)``; the per-value mean is comparable between models on the same values.
    """
    stream, t, v = _check_streams(stream, times, values)
    keep = np.isfinite(v) & np.isfinite(t)
    stream, t, v = stream[keep], t[keep], v[keep]
    if v.size == 0:
        return 0.0, 0
    order = np.lexsort((t, stream))
    stream, t, v = stream[order], t[order], v[order]
    sid = np.r_[0, np.cumsum(stream[1:] != stream[:-1])]
    first = np.r_[0, np.flatnonzero(np.diff(sid)) + 1]
    rank = np.arange(sid.size) - first[sid]
    var, phi, tau = component.std**2, component.phi, component.tau
    white = (1.0 - phi) * var
    p = np.full(first.size, phi * var)
    s_hat = np.zeros(first.size)
    t_prev = np.full(first.size, np.nan)
    total = 0.0
    by_rank = np.argsort(rank, kind="stable")
    bounds = np.searchsorted(rank[by_rank], np.arange(int(rank.max()) + 2))
    for k in range(int(rank.max()) + 1):
        rows = by_rank[bounds[k] : bounds[k + 1]]
        j = sid[rows]
        if k > 0:
            a = np.exp(-np.maximum(t[rows] - t_prev[j], 0.0) / tau)
            s_hat[j] *= a
            p[j] = a * a * p[j] + phi * var * (1.0 - a * a)
        sv = p[j] + white
        e = v[rows] - s_hat[j]
        total += float(np.sum(0.5 * (np.log(2.0 * np.pi * sv) + e * e / sv)))
        gain = p[j] / sv
        s_hat[j] += gain * e
        p[j] -= gain * p[j]
        t_prev[j] = t[rows]
    return total, int(v.size)


def heldout_residuals(
    ds: DetectionSet, range_std: float = PRIOR_RANGE_STD, bearing_std: float = PRIOR_BEARING_STD, trim: float = 5.0
) -> dict[str, np.ndarray]:
    """Standardized snapshot residuals of ``ds`` for scoring camera models on data they were not fitted to.

    The snapshot fits are weighted by fixed std (``range_std`` [m], ``bearing_std`` [rad]; every model is then
    scored on the same values, so pass std that do not depend on the model scored);
    ``u = v / sqrt(r)`` for residuals with redundancy at least :data:`MIN_REDUNDANCY`; values beyond ``trim``
    times the set's own robust scale (``1.4826`` median ``|u|``) are set to NaN (outliers, the same for every
    model). Returns ``stream``, ``t`` [s], ``u_range`` [m], ``u_bearing`` [rad] and ``instants``.
    """
    snaps, obs, tt, tg = ds.snapshots()
    res = fit_residuals(snaps, range_std, bearing_std)
    rows = res["row"]
    out: dict[str, np.ndarray] = {"stream": obs[rows] * 1_000_003 + tg[rows], "t": tt[rows]}
    for name in ("range", "bearing"):
        v, red = res[f"v_{name}"], res[f"r_{name}"]
        u = np.where(red >= MIN_REDUNDANCY, v / np.sqrt(np.maximum(red, MIN_REDUNDANCY)), np.nan)
        scale = 1.4826 * float(np.nanmedian(np.abs(u))) if np.isfinite(u).any() else 0.0
        out[f"u_{name}"] = np.where(np.abs(u) <= trim * scale, u, np.nan)
    out["instants"] = np.array(snaps.instants)
    return out


def heldout_score(model: CameraModel, held: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Truth-free scores of ``model`` on :func:`heldout_residuals` ``held`` of a recording it was not fitted to.

    Per component: ``nll_<c>`` the mean negative log-likelihood per residual under the model's correlated error
    process (:func:`stream_nll`; lower is better; comparable between models on the same ``held``), and
    ``ratio_<c>`` the robust variance ratio ``median(u^2) / (0.4549 std^2)`` (1 when the model's std is right;
    0.4549 is the median of chi-square with 1 dof). ``nll`` is the sum of the two components' means.
    """
    out: dict[str, float] = {}
    for name in ("range", "bearing"):
        comp: ErrorComponent = getattr(model, name)
        u = held[f"u_{name}"]
        total, n = stream_nll(held["stream"], held["t"], u, comp)
        out[f"nll_{name}"] = total / max(n, 1)
        out[f"ratio_{name}"] = float(np.nanmedian(u * u)) / (MEDIAN_CHI2_1 * comp.std**2) if n else float("nan")
        out[f"n_{name}"] = n
    out["nll"] = out["nll_range"] + out["nll_bearing"]
    return out


# ----------------------------------------------------------------------------------------------------------------
# the pre-processor


def decorrelate(events: Sequence[Event], model: CameraModel) -> list[Event]:
    """``events`` with every range-bearing :class:`Detection` given ``cov = diag(std_r^2 / w_r, std_b^2 / w_b)``,
    ``w`` its :func:`information_weights` within its (observer, target) stream; other events unchanged, order
    kept. Raises ValueError naming the detection when a stream's times go backwards or a reading is not finite.
    """
    streams: dict[tuple[int, int | None, bool], list[tuple[int, Detection]]] = {}  # (observer, target, robot?)
    for i, e in enumerate(events):
        if isinstance(e, Detection) and e.kind == Kind.RANGE_BEARING:
            if not (math.isfinite(e.t) and np.isfinite(e.z).all()):
                raise ValueError(f"event {i}: detection by robot {e.observer} of {e.target} at t={e.t} is not finite")
            streams.setdefault((e.observer, e.target, e.target_is_robot), []).append((i, e))
    out = list(events)
    r2, b2 = model.range.std**2, model.bearing.std**2
    for (obs, tgt, _), dets in streams.items():
        times = np.array([d.t for _, d in dets])
        try:
            _check_times(times, f"times of the detections of {tgt} by robot {obs}")
        except ValueError as exc:
            raise ValueError(f"{exc} (events must be in time order)") from None
        wr = information_weights(times, model.range.phi, model.range.tau)
        wb = information_weights(times, model.bearing.phi, model.bearing.tau)
        for (i, d), a, b in zip(dets, wr.tolist(), wb.tolist(), strict=True):
            out[i] = dataclasses.replace(d, cov=readonly(np.diag([r2 / a, b2 / b])))
    return out
