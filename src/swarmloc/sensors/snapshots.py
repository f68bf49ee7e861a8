"""Landmark snapshots: the observer's pose fitted at each instant it reads two or more distinct landmarks.

Step 1 of the camera calibration (:mod:`swarmloc.sensors.decorrelate`) and the poses the yaw-diffusion calibration
(:mod:`swarmloc.motion.calibrate`) pairs up: each snapshot's pose ``(x, y, theta)`` is fitted to that instant's
range-bearing readings by weighted Gauss-Newton (started from a 2-D Procrustes fit), leaving residuals ``v_i`` with
redundancy numbers ``r_i = 1 - (A N^-1 A' W)_ii`` (``sum r_i = 2k - 3``) and the fit's covariance ``N^-1``.

A fit runs 20 Gauss-Newton steps (a well-spread geometry converges in a few; two landmarks weighted by a tight
bearing std need more) and is used only when it has converged: its last step ``dx`` is below :data:`STEP_TOL` of
its own standard deviations, ``sqrt(dx' N dx) <= STEP_TOL``. One that has not is dropped and counted
(``unconverged``), as a fit that is not finite is: such fits oscillate or diverge (on MRCLAM nearly all of them
two-landmark fits, some still moving by metres per step), an ulp of difference in their start moves them by
metres, and neither their poses nor their residuals describe the robot or the camera.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarmloc.lie import wrap_angle

__all__ = ["STEP_TOL", "DetectionSet", "fit_residuals", "snapshot_poses"]

STEP_TOL = 1e-3
"""A snapshot fit has converged when its last Gauss-Newton step is at most this many of its own standard deviations
(the step's Mahalanobis size under the fit's covariance); otherwise it is dropped and counted, not used."""


def _fit_group(z: np.ndarray, p: np.ndarray, range_std: float, bearing_std: float, iterations: int = 20):  # noqa: ANN202
    """Weighted Gauss-Newton pose fits of ``m`` instants with ``k`` landmarks each: ``z`` ``(m, k, 2)`` range and
    bearing, ``p`` ``(m, k, 2)`` landmark positions. Returns residuals and redundancy numbers ``(m, 2k)`` (ranges
    first), a mask of the instants whose fit is finite and has converged (:data:`STEP_TOL`), the poses ``(m, 3)``,
    the fits' covariances ``(m, 3, 3)`` and the number of finite fits that have not converged."""
    m, k, _ = z.shape
    r, b = z[..., 0], z[..., 1]
    q = np.stack([r * np.cos(b), r * np.sin(b)], axis=-1)
    qd = q - q.mean(axis=1, keepdims=True)
    pd = p - p.mean(axis=1, keepdims=True)
    th = np.arctan2(
        np.sum(qd[..., 0] * pd[..., 1] - qd[..., 1] * pd[..., 0], axis=1),
        np.sum(qd[..., 0] * pd[..., 0] + qd[..., 1] * pd[..., 1], axis=1),
    )
    qc, pc = q.mean(axis=1), p.mean(axis=1)
    c, s = np.cos(th), np.sin(th)
    x = np.stack([pc[:, 0] - (c * qc[:, 0] - s * qc[:, 1]), pc[:, 1] - (s * qc[:, 0] + c * qc[:, 1]), th], axis=1)
    w = np.concatenate([np.full(k, range_std**-2), np.full(k, bearing_std**-2)])
    eye = np.eye(3)

    def linearize(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dx, dy = p[..., 0] - x[:, :1], p[..., 1] - x[:, 1:2]
        d2 = np.maximum(dx * dx + dy * dy, 1e-12)
        d = np.sqrt(d2)
        v = np.concatenate([r - d, wrap_angle(b - (np.arctan2(dy, dx) - x[:, 2:3]))], axis=1)
        zero = np.zeros_like(d)
        a_r = np.stack([-dx / d, -dy / d, zero], axis=-1)
        a_b = np.stack([dy / d2, -dx / d2, zero - 1.0], axis=-1)
        return v, np.concatenate([a_r, a_b], axis=1)

    step = np.zeros_like(x)
    for _ in range(iterations):
        v, a = linearize(x)
        n = np.einsum("mik,i,mil->mkl", a, w, a)
        n += 1e-12 * np.trace(n, axis1=1, axis2=2)[:, None, None] * eye
        g = np.einsum("mik,i,mi->mk", a, w, v)
        step = np.linalg.solve(n, g[..., None])[..., 0]
        x = x + step
    v, a = linearize(x)
    n = np.einsum("mik,i,mil->mkl", a, w, a)
    n += 1e-12 * np.trace(n, axis1=1, axis2=2)[:, None, None] * eye
    ninv = np.linalg.inv(n)
    red = 1.0 - np.einsum("mik,mkl,mil->mi", a, ninv, a) * w
    ok = np.isfinite(v).all(axis=1) & np.isfinite(red).all(axis=1) & np.isfinite(x).all(axis=1)
    converged = np.einsum("mk,mkl,ml->m", step, n, step) <= STEP_TOL**2
    return v, red, ok & converged, x, ninv, int((ok & ~converged).sum())


@dataclass
class _Snapshots:
    """Instants with two or more distinct landmarks, grouped by their landmark count ``k``."""

    groups: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]  # k -> (z (m,k,2), p (m,k,2), row index (m,k))

    @property
    def instants(self) -> int:
        return sum(g[0].shape[0] for g in self.groups.values())


def _snapshots(
    observer: np.ndarray, t: np.ndarray, target: np.ndarray, z: np.ndarray, lm: Mapping[int, Any]
) -> _Snapshots:
    ids = np.array(sorted(int(k) for k in lm), dtype=np.int64)
    pos = np.array([[float(lm[k][0]), float(lm[k][1])] for k in ids.tolist()]).reshape(-1, 2)
    is_lm = np.isin(target, ids)
    rows = np.flatnonzero(is_lm & (z[:, 0] > 0))
    if rows.size == 0:
        return _Snapshots({})
    order = rows[np.lexsort((target[rows], t[rows], observer[rows]))]
    o, tt = observer[order], t[order]
    new = np.r_[True, (o[1:] != o[:-1]) | (tt[1:] != tt[:-1])]
    start = np.flatnonzero(new)
    size = np.diff(np.r_[start, order.size])
    groups: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for k in np.unique(size[size >= 2]).tolist():
        st = start[size == k]
        idx = order[st[:, None] + np.arange(k)[None, :]]  # (m, k) rows
        tg = target[idx]
        distinct = np.all(np.diff(np.sort(tg, axis=1), axis=1) != 0, axis=1)
        idx, tg = idx[distinct], tg[distinct]
        if idx.shape[0] == 0:
            continue
        p = pos[np.searchsorted(ids, tg)]
        groups[k] = (z[idx], p, idx)
    return _Snapshots(groups)


def snapshot_poses(ds: DetectionSet, range_std: float, bearing_std: float) -> dict[str, np.ndarray]:
    """The observer's pose fitted at every snapshot of ``ds`` (two or more landmarks at one instant), weighted by
    the given std [m], [rad]: ``observer``, ``t`` [s], ``pose`` ``(m, 3)`` as ``(x, y, theta)`` and ``cov``
    ``(m, 3, 3)`` (the fit's covariance of ``(x, y, theta)`` under those std), sorted by time, and ``unconverged``
    the number of fits dropped for not having converged (module docstring)."""
    snaps, obs, tt, _ = ds.snapshots()
    parts: dict[str, list[np.ndarray]] = {"observer": [], "t": [], "pose": [], "cov": []}
    unconverged = 0
    for z, p, idx in snaps.groups.values():
        _, _, ok, x, ninv, dropped = _fit_group(z, p, range_std, bearing_std)
        unconverged += dropped
        parts["observer"].append(obs[idx[ok, 0]])
        parts["t"].append(tt[idx[ok, 0]])
        parts["pose"].append(np.column_stack([x[ok, :2], wrap_angle(x[ok, 2])]))
        parts["cov"].append(ninv[ok])
    if not parts["t"]:
        return {
            "observer": np.empty(0, np.int64),
            "t": np.empty(0),
            "pose": np.empty((0, 3)),
            "cov": np.empty((0, 3, 3)),
            "unconverged": np.array(unconverged),
        }
    out = {k: np.concatenate(v) for k, v in parts.items()}
    order = np.argsort(out["t"], kind="stable")
    return {**{k: v[order] for k, v in out.items()}, "unconverged": np.array(unconverged)}


def fit_residuals(snaps: _Snapshots, range_std: float, bearing_std: float) -> dict[str, np.ndarray]:
    """Residuals and redundancy numbers of every snapshot fit of ``snaps`` under the given std [m], [rad]: ``row``
    (index of the detection), ``v_range``, ``r_range``, ``v_bearing``, ``r_bearing``, ``instants`` and
    ``unconverged`` (the fits dropped for not having converged, module docstring)."""
    out: dict[str, list[np.ndarray]] = {"row": [], "v_range": [], "r_range": [], "v_bearing": [], "r_bearing": []}
    unconverged = 0
    for k, (z, p, idx) in sorted(snaps.groups.items()):
        v, red, ok, _, _, dropped = _fit_group(z, p, range_std, bearing_std)
        unconverged += dropped
        out["row"].append(idx[ok].ravel())
        out["v_range"].append(v[ok, :k].ravel())
        out["r_range"].append(red[ok, :k].ravel())
        out["v_bearing"].append(v[ok, k:].ravel())
        out["r_bearing"].append(red[ok, k:].ravel())
    res = {key: (np.concatenate(val) if val else np.empty(0)) for key, val in out.items()}
    res["row"] = res["row"].astype(np.int64)
    res["instants"] = np.array(snaps.instants)
    res["unconverged"] = np.array(unconverged)
    return res


def _check_detections(observer, t, target, z):  # noqa: ANN001, ANN202
    obs = np.asarray(observer)
    tt = np.asarray(t, dtype=np.float64)
    tg = np.asarray(target)
    zz = np.asarray(z, dtype=np.float64)
    n = tt.size
    if not (obs.shape == (n,) and tg.shape == (n,) and tt.shape == (n,) and zz.shape == (n, 2)):
        raise ValueError(
            f"observer, t, target must have shape (n,) and z (n, 2); got {obs.shape}, {tt.shape}, {tg.shape}, "
            f"{zz.shape}"
        )
    for name, arr in (("t", tt), ("z", zz)):
        bad = np.flatnonzero(~np.isfinite(arr).reshape(n, -1).all(axis=1)) if n else np.empty(0, dtype=int)
        if bad.size:
            raise ValueError(f"detection {bad[0]}: {name} is not finite ({arr[bad[0]]})")
    return obs.astype(np.int64), tt, tg.astype(np.int64), zz


@dataclass(frozen=True)
class DetectionSet:
    """One recording's detections as arrays (``observer``, ``t`` [s], ``target``, ``z`` ``(n, 2)`` range [m] and
    bearing [rad]) with its landmark map (id -> ``(x, y, ...)`` [m]); ``name`` labels it in messages."""

    observer: np.ndarray
    t: np.ndarray
    target: np.ndarray
    z: np.ndarray
    landmarks: Mapping[int, Any]
    name: str = ""

    def snapshots(self) -> tuple[_Snapshots, np.ndarray, np.ndarray, np.ndarray]:
        """The instants with two or more landmarks, and the checked observer, time and target arrays."""
        obs, tt, tg, zz = _check_detections(self.observer, self.t, self.target, self.z)
        return _snapshots(obs, tt, tg, zz, self.landmarks), obs, tt, tg
