"""Truth-free calibration of the yaw diffusion from a robot's own pose snapshots.

A *snapshot* is the robot's pose fitted at one instant from two or more landmarks read together
(:func:`swarmloc.sensors.snapshots.snapshot_poses` gives them, with the fit's covariance). For two snapshots of one
robot ``t_a < t_b``, the fitted heading change minus the integral of the odometry's yaw rate over ``[t_a, t_b]``
(each command held until the next record, as the filters do) is a residual

    r = wrap(theta_b - theta_a - int w dt),      Var r = c (f_a + f_b) + s int q_yaw(v, w) dt

with ``f`` the fits' heading variances [rad^2], ``q_yaw`` the model's yaw diffusion per second
(:class:`~swarmloc.motion.unicycle.UnicycleNoise`) and two unknown scales: ``c`` for the fits (their std need not be
right) and ``s`` for the yaw diffusion. :func:`fit_yaw_scale` finds both as the maximum of their posterior over the
pairs whose residual is within ``cut`` (a turn commanded and not made, or made and not commanded, is an outlier of
a different kind: the model's tails, not its width), the residuals normal truncated at the cut, with weak
log-normal priors on ``c`` and ``s`` centred at 1 (the fits and the model as given). The two scales share the
residuals' variance and the posterior can have two modes (the fits explain the spread, or the diffusion does; seen
on MRCLAM 9 with a third of its landmarks held out, where maximum likelihood also drove ``s`` to 0 with fewer
pairs): the search starts from the best point of a grid over both. :func:`scale_yaw` applies ``s`` to every yaw
term of a noise model. No ground truth is used: only the recording's landmark readings and odometry.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import special
from scipy.optimize import minimize

from swarmloc.lie import wrap_angle
from swarmloc.motion.unicycle import UnicycleNoise

__all__ = ["FIT_PRIOR_STD", "YawScale", "fit_yaw_scale", "heading_increments", "held_integral", "scale_yaw"]


FIT_PRIOR_STD = 2.0
"""Std of the log-normal prior on the fits' variance scale ``c`` (centred at 1: the fits' covariances as given), the
default of the yaw scale's too: weak (a factor 7.4 at one std); it keeps both defined where the data do not tell
them apart, so the posterior has a curvature to report."""


def held_integral(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The integral of a piecewise-constant signal ``x`` held from each stamp of ``t`` [s] to the next, at every
    stamp (0 at the first); ``t`` increasing."""
    return np.concatenate([[0.0], np.cumsum(x[:-1] * np.diff(t))])


def heading_increments(
    odometry: Mapping[int, np.ndarray],
    snapshots: Mapping[str, np.ndarray],
    noise: UnicycleNoise,
    min_gap: float = 1.0,
    max_gap: float = 8.0,
    exclude: tuple[float, float] | None = None,
) -> dict[str, np.ndarray]:
    """Per pair of consecutive snapshots of one robot ``min_gap`` to ``max_gap`` s apart (module docstring).

    ``odometry``: robot id -> ``(n, 3)`` records ``(t [s], v [m/s], w [rad/s])``, time-increasing; ``snapshots``:
    ``observer``, ``t`` [s], ``pose`` ``(m, 3)`` ``(x, y, theta)``, ``cov`` ``(m, 3, 3)`` sorted by time (as
    :func:`~swarmloc.sensors.snapshots.snapshot_poses` returns them). Pairs with either end in ``exclude``
    ``(t0, t1)`` are left out, as are pairs outside a robot's odometry span. Returns ``robot``, ``t`` (the pair's
    end), ``res`` [rad], ``fit`` (the two fits' heading variances summed) [rad^2], ``model`` (the yaw diffusion
    over the interval) [rad^2] and ``turn`` (commanded turn, ``int |w| dt``) [rad].
    """
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("robot", "t", "res", "fit", "model", "turn")}
    obs = np.asarray(snapshots["observer"])
    for r, od in sorted(odometry.items()):
        od = np.asarray(od, dtype=float)
        if od.ndim != 2 or od.shape[0] < 2 or od.shape[1] != 3:
            continue
        t, v, w = od[:, 0], od[:, 1], od[:, 2]
        if not (np.all(np.diff(t) >= 0) and np.isfinite(od).all()):
            raise ValueError(f"heading_increments: odometry of robot {r} must be finite and time-ordered")
        q_yaw = noise.diag(v, w)[2] * np.ones_like(t)
        sel = np.flatnonzero(obs == r)
        ts = np.asarray(snapshots["t"])[sel]
        ps, cs = np.asarray(snapshots["pose"])[sel], np.asarray(snapshots["cov"])[sel]
        if ts.size < 2:
            continue
        yaw, diff, turn = (np.interp(ts, t, held_integral(t, x)) for x in (w, q_yaw, np.abs(w)))
        gap = np.diff(ts)
        ok = (gap >= min_gap) & (gap <= max_gap) & (ts[:-1] >= t[0]) & (ts[1:] <= t[-1])
        if exclude is not None:
            a, b = exclude
            inside = (ts >= a) & (ts <= b)
            ok &= ~inside[:-1] & ~inside[1:]
        out["robot"].append(np.full(int(ok.sum()), r))
        out["t"].append(ts[1:][ok])
        out["res"].append(wrap_angle(np.diff(ps[:, 2]) - np.diff(yaw))[ok])
        out["fit"].append((cs[:-1, 2, 2] + cs[1:, 2, 2])[ok])
        out["model"].append(np.diff(diff)[ok])
        out["turn"].append(np.diff(turn)[ok])
    return {k: (np.concatenate(v) if v else np.empty(0)) for k, v in out.items()}


@dataclass(frozen=True)
class YawScale:
    """The fitted yaw-diffusion scale ``scale`` (multiplies the model's yaw terms) and the std of its logarithm
    ``log_std`` (marginal, from the posterior's curvature), the fits' variance scale ``fit_scale``, the pairs used
    (``pairs``, residuals within ``cut`` [rad]) and left out (``outliers``)."""

    scale: float
    log_std: float
    fit_scale: float
    pairs: int
    outliers: int
    cut: float


def fit_yaw_scale(
    inc: Mapping[str, np.ndarray], cut: float = 0.5, prior_std: float = 2.0, min_pairs: int = 30
) -> YawScale:
    """Maximum a-posteriori ``(s, c)`` of ``Var r = c fit + s model`` over the pairs of :func:`heading_increments`
    with ``|r| < cut`` [rad], the residuals Gaussian truncated at the cut, ``log s ~ N(0, prior_std^2)`` (``inf``:
    maximum likelihood in ``s``) and ``log c ~ N(0, FIT_PRIOR_STD^2)``. ``log_std`` is the curvature's at the mode
    found and takes the pairs as independent (consecutive pairs share a snapshot: it overstates the spread somewhat
    where the fits' error matters). ``outliers`` counts the pairs left out (beyond the cut, or without a positive
    variance). Raises ValueError with fewer than ``min_pairs`` pairs kept (too little to calibrate)."""
    if not (cut > 0 and prior_std > 0):
        raise ValueError(f"fit_yaw_scale: cut and prior_std must be > 0, got {cut!r}, {prior_std!r}")
    res, fit, model = (np.asarray(inc[k], dtype=float) for k in ("res", "fit", "model"))
    ok = (np.abs(res) < cut) & (fit > 0) & (model > 0)
    if int(ok.sum()) < min_pairs:
        raise ValueError(f"fit_yaw_scale: {int(ok.sum())} snapshot pairs within {cut} rad, {min_pairs} needed")
    r2, f, m = res[ok] ** 2, fit[ok], model[ok]

    def nll(p: np.ndarray) -> float:
        var = math.exp(p[0]) * f + math.exp(p[1]) * m
        kept = special.erf(cut / np.sqrt(2.0 * var))  # each residual's normal truncated at the cut
        prior = 0.5 * (p[1] / prior_std) ** 2 + 0.5 * (p[0] / FIT_PRIOR_STD) ** 2
        return float(np.sum(0.5 * (np.log(var) + r2 / var) + np.log(kept))) + prior

    grid = [np.array([a, b]) for a in np.linspace(-8.0, 4.0, 25) for b in np.linspace(-9.0, 4.0, 27)]
    start = min(grid, key=nll)  # the global mode's basin (two modes are common, module docstring)
    best = minimize(nll, start, method="Nelder-Mead", options={"xatol": 1e-6, "fatol": 1e-9, "maxiter": 4000})
    c, s = np.exp(best.x)
    h, e = 1e-3, np.eye(2) * 1e-3  # the posterior's Hessian in (log c, log s) at its optimum, by differences
    hess = np.array([[(nll(best.x + e[i] + e[j]) - nll(best.x + e[i] - e[j]) - nll(best.x - e[i] + e[j])
                       + nll(best.x - e[i] - e[j])) / (4 * h * h) for j in range(2)] for i in range(2)])  # fmt: skip
    cov = np.linalg.inv(hess) if np.all(np.linalg.eigvalsh(hess) > 0) else np.full((2, 2), np.inf)
    log_std = math.sqrt(cov[1, 1])  # marginal: c and s share the residuals' variance
    return YawScale(float(s), log_std, float(c), int(ok.sum()), int(res.size - ok.sum()), float(cut))


def scale_yaw(noise: UnicycleNoise, s: float) -> UnicycleNoise:
    """``noise`` with every yaw term (``q_w0``, ``q_w1``, ``q_w2``, ``q_wv``) multiplied by ``s`` > 0."""
    if not (s > 0 and math.isfinite(s)):
        raise ValueError(f"scale_yaw: scale must be finite and > 0, got {s!r}")
    return dataclasses.replace(
        noise, q_w0=noise.q_w0 * s, q_w1=noise.q_w1 * s, q_w2=noise.q_w2 * s, q_wv=noise.q_wv * s
    )
