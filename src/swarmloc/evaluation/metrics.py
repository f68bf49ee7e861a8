"""Accuracy and consistency: RMSE, NEES, ANEES with chi-square bounds, per robot and team, over time.

NEES of a belief ``(mu, Sigma)`` against the true pose ``g``: ``y^T Sigma^-1 y`` with ``y = log(mu^-1 g)``
(exponential coordinates, right perturbation, 3 degrees of freedom on SE(2)). ANEES is reported *per degree of
freedom* (mean NEES / 3): a consistent filter gives about 1; above the upper chi-square bound it is
over-confident, below the lower bound under-confident.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from swarmloc.gaussian import chi2_ppf, mahalanobis2
from swarmloc.lie import SE2, wrap_angle
from swarmloc.runner import RobotTrack, RunResult

DOF = 3


def errors(track: RobotTrack) -> dict[str, np.ndarray]:
    """Per-record position error [m], heading error [rad] and NEES (SE(3) tracks: :func:`errors_se3`)."""
    if track.mean.shape[-1] == 7:
        return errors_se3(track)
    with np.errstate(invalid="ignore"):  # a row that is not finite has NaN errors (its caller counts it)
        ep = np.linalg.norm(track.mean[:, :2] - track.truth[:, :2], axis=1)
        eh = wrap_angle(track.mean[:, 2] - track.truth[:, 2])
        y = SE2.log(
            SE2.inverse(SE2.from_xytheta(track.mean), validate=False) @ SE2.from_xytheta(track.truth), validate=False
        )
        nees = mahalanobis2(y, track.cov)
    return {"pos": ep, "heading": eh, "nees": nees}


def errors_se3(track: RobotTrack) -> dict[str, np.ndarray]:
    """SE(3) track (means and truth ``(x, y, z, qx, qy, qz, qw)``): position error [m] (3-D), rotation error
    ``|log(R_est^T R_true)|`` [rad] (under the key ``heading``, so that pooled tables read the same) and the NEES
    of the exponential coordinates ``log(mu^-1 g)`` (6 dof)."""
    from swarmloc.datasets.tum import pose_from7
    from swarmloc.lie import SE3

    ep = np.linalg.norm(track.mean[:, :3] - track.truth[:, :3], axis=1)
    y = SE3.log(SE3.inverse(pose_from7(track.mean), validate=False) @ pose_from7(track.truth), validate=False)
    er = np.linalg.norm(y[:, 3:], axis=1)
    return {"pos": ep, "heading": er, "nees": mahalanobis2(y, track.cov)}


def anees_bounds(n: int, dof: int = DOF, p: float = 0.95) -> tuple[float, float]:
    """Two-sided ``p`` bounds of the per-dof ANEES of ``n`` *independent* NEES values."""
    a = (1 - p) / 2
    return chi2_ppf(a, n * dof) / (n * dof), chi2_ppf(1 - a, n * dof) / (n * dof)


def pooled(errs: Iterable[Mapping[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Error arrays of :func:`errors` (or of anything with its keys) concatenated key by key (empty: none)."""
    errs = list(errs)
    return {k: np.concatenate([e[k] for e in errs]) if errs else np.zeros(0) for k in ("pos", "heading", "nees")}


def summarize(errs: Mapping[str, np.ndarray], dof: int = DOF) -> dict[str, float]:
    """RMSE of position and heading (SE(3): rotation angle; also as ``rot_rmse``), per-dof ANEES (``dof`` 3 on
    SE(2), 6 on SE(3)), median NEES per dof and the fraction of NEES inside the two-sided 95% band."""
    n = errs["pos"].size
    if n == 0:
        return {"n": 0}
    lo, hi = chi2_ppf(0.025, dof), chi2_ppf(0.975, dof)
    out = {
        "n": int(n),
        "pos_rmse": float(np.sqrt(np.mean(errs["pos"] ** 2))),
        "heading_rmse": float(np.sqrt(np.mean(errs["heading"] ** 2))),
        "anees": float(np.mean(errs["nees"]) / dof),
        "nees_median": float(np.median(errs["nees"]) / dof),
        "frac_in_95": float(np.mean((errs["nees"] >= lo) & (errs["nees"] <= hi))),
    }
    if dof != DOF:
        out["rot_rmse"] = out["heading_rmse"]
        out["dof"] = dof
    return out


def evaluate(result: RunResult, robots: list[int] | None = None) -> dict:
    """Per-robot and team summaries of one run (team = all records of all robots pooled)."""
    robots = sorted(result.tracks) if robots is None else robots
    per, errs = {}, []
    dof = DOF
    for r in robots:
        tr = result.tracks.get(r)
        if tr is None or tr.times.size == 0:
            continue
        dof = 6 if tr.mean.shape[-1] == 7 else DOF
        errs.append(errors(tr))
        per[r] = summarize(errs[-1], dof)
    team = summarize(pooled(errs), dof)
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
