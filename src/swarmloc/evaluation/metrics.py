"""Accuracy and consistency: RMSE, NEES, ANEES with chi-square bounds, per robot and team, over time.

NEES of a belief ``(mu, Sigma)`` against the true pose ``g``: ``y^T Sigma^-1 y`` with ``y = log(mu^-1 g)``
(exponential coordinates, right perturbation, 3 degrees of freedom on SE(2)). ANEES is reported *per degree of
freedom* (mean NEES / 3): a consistent filter gives about 1; above the upper chi-square bound it is
over-confident, below the lower bound under-confident.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from swarmloc.lie import SE2
from swarmloc.lie import wrap_angle as wrap
from swarmloc.runner import RobotTrack, RunResult

DOF = 3


def errors(track: RobotTrack) -> dict[str, np.ndarray]:
    """Per-record position error [m], heading error [rad] and NEES."""
    ep = np.linalg.norm(track.mean[:, :2] - track.truth[:, :2], axis=1)
    eh = wrap(track.mean[:, 2] - track.truth[:, 2])
    y = SE2.log(
        SE2.inverse(SE2.from_xytheta(track.mean), validate=False) @ SE2.from_xytheta(track.truth), validate=False
    )
    nees = np.einsum("ni,ni->n", y, np.linalg.solve(track.cov, y[..., None])[..., 0])
    return {"pos": ep, "heading": eh, "nees": nees}


def anees_bounds(n: int, dof: int = DOF, p: float = 0.95) -> tuple[float, float]:
    """Two-sided ``p`` bounds of the per-dof ANEES of ``n`` *independent* NEES values."""
    a = (1 - p) / 2
    return float(chi2.ppf(a, n * dof) / (n * dof)), float(chi2.ppf(1 - a, n * dof) / (n * dof))


def summarize(errs: dict[str, np.ndarray]) -> dict[str, float]:
    n = errs["pos"].size
    if n == 0:
        return {"n": 0}
    lo, hi = chi2.ppf([0.025, 0.975], DOF)
    return {
        "n": int(n),
        "pos_rmse": float(np.sqrt(np.mean(errs["pos"] ** 2))),
        "heading_rmse": float(np.sqrt(np.mean(errs["heading"] ** 2))),
        "anees": float(np.mean(errs["nees"]) / DOF),
        "nees_median": float(np.median(errs["nees"]) / DOF),
        "frac_in_95": float(np.mean((errs["nees"] >= lo) & (errs["nees"] <= hi))),
    }


def evaluate(result: RunResult, robots: list[int] | None = None) -> dict:
    """Per-robot and team summaries of one run (team = all records of all robots pooled)."""
    robots = sorted(result.tracks) if robots is None else robots
    per = {}
    pooled: dict[str, list[np.ndarray]] = {"pos": [], "heading": [], "nees": []}
    for r in robots:
        tr = result.tracks.get(r)
        if tr is None or tr.times.size == 0:
            continue
        e = errors(tr)
        per[r] = summarize(e)
        for k in pooled:
            pooled[k].append(e[k])
    team = summarize({k: np.concatenate(v) if v else np.zeros(0) for k, v in pooled.items()})
    return {"estimator": result.estimator, "robots": per, "team": team, "wall_time": result.wall_time}


def over_seeds(results: list[RunResult], robot: int) -> dict[str, np.ndarray]:
    """Error statistics over independent runs (seeds) at common record times, for one robot.

    Returns times, mean and 10/90-percentiles of the position error, the per-dof ANEES over seeds at each time
    and its chi-square bounds for ``len(results)`` independent runs.
    """
    tracks = [r.tracks[robot] for r in results]
    n = min(t.times.size for t in tracks)
    errs = [errors(t) for t in tracks]
    E = np.stack([e["pos"][:n] for e in errs])
    N = np.stack([e["nees"][:n] for e in errs])
    lo, hi = anees_bounds(len(results))
    return {
        "times": tracks[0].times[:n],
        "pos_mean": E.mean(0),
        "pos_p10": np.percentile(E, 10, axis=0),
        "pos_p90": np.percentile(E, 90, axis=0),
        "anees": N.mean(0) / DOF,
        "anees_lo": np.full(n, lo),
        "anees_hi": np.full(n, hi),
    }
