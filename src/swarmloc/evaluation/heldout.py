"""A truth-free consistency score: the normalized innovation squared (NIS) of landmark readings that never entered
the belief they are scored against.

At each landmark reading the observer's belief an instant before it (:data:`RECORD_LEAD`) is pushed through the
range-bearing model, ``NIS = r' (H P H' + R + L)^-1 r`` (``R`` the reading's variance, ``L`` the landmark's map
std), and compared with chi-square of 2 dof. The headline is the robust ratio ``median(NIS) / 1.386`` (1:
consistent, above: over-confident, below: under-confident); ``mean(NIS) / 2`` (ANIS per dof) counts the tails too.
A reading already fused would score the belief against itself: with landmarks fused, the landmarks are split into
folds (:func:`landmark_folds`) and each fold's readings are scored against a run without that fold
(:func:`without_landmarks`). Used by ``swarmloc evaluate`` on recordings without ground truth and by the
leave-one-dataset-out study (the repository's ``swarmloc_studies.lodo``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from swarmloc.events import Detection, Event
from swarmloc.gaussian import mahalanobis2
from swarmloc.lie import wrap_angle
from swarmloc.runner import RobotTrack

__all__ = [
    "BAND",
    "GATE_2DOF",
    "LandmarkInnovations",
    "MEDIAN_CHI2_2",
    "RECORD_LEAD",
    "band_verdict",
    "landmark_folds",
    "landmark_innovations",
    "landmark_nis",
    "nis_summary",
    "reading_times",
    "tracks_nis",
    "without_landmarks",
]

GATE_2DOF = 11.618  # chi-square 0.997 quantile, 2 dof
MEDIAN_CHI2_2 = 1.386294  # 2 ln 2
RECORD_LEAD = 1e-6  # [s] beliefs are recorded this long before each landmark reading
BAND = (0.5, 2.0)
"""The band a per-dof consistency figure (ANEES/dof against the truth, or the held-out NIS ratio) must fall in to
call an estimator consistent: within a factor 2 of the ideal 1 either way (the project's goal; the chi-square band
of independent records is far narrower than records one after another, which are correlated, can meet)."""


def band_verdict(value: float, band: tuple[float, float] = BAND) -> str:
    """``"in band"`` when ``band[0] <= value <= band[1]``, else ``"out of band"`` (NaN included)."""
    return "in band" if band[0] <= value <= band[1] else "out of band"


class LandmarkInnovations(NamedTuple):
    """The innovations of landmark readings against the beliefs recorded just before them
    (:func:`landmark_innovations`), one row per reading: ``r`` ``(n, 2)`` (range [m], bearing [rad], the bearing
    wrapped), the belief's share of their covariance ``belief = H P H'`` ``(n, 2, 2)``, the rest ``noise = R + L``
    (the reading's variance and the landmark's map std pushed through the model), the Jacobian ``H`` ``(n, 2, 3)``
    in the belief's right perturbation, the belief's covariance ``P`` ``(n, 3, 3)`` it was formed with, and ``ok``:
    whether a belief was recorded just before the reading (the other rows are not meaningful)."""

    r: np.ndarray
    belief: np.ndarray
    noise: np.ndarray
    H: np.ndarray
    P: np.ndarray
    ok: np.ndarray

    def nis(self) -> np.ndarray:
        """The normalized innovation squared ``r' (belief + noise)^-1 r`` of each row (NaN where not ``ok``)."""
        return np.where(self.ok, mahalanobis2(self.r, self.belief + self.noise), np.nan)


def landmark_innovations(
    track_times: np.ndarray, mean: np.ndarray, cov: np.ndarray, dets: Sequence[Detection],
    landmarks: Mapping[int, Sequence[float]], std: tuple[float, float], lead: float = RECORD_LEAD,
) -> LandmarkInnovations:  # fmt: skip
    """The :class:`LandmarkInnovations` of landmark readings ``dets`` of one observer against its beliefs recorded
    ``lead`` s before each (``mean`` ``(T, 3)``, right-perturbation ``cov`` ``(T, 3, 3)``; default
    :data:`RECORD_LEAD`; 0: at the reading's stamp, as a smoother's delayed output has its poses), with the reading's
    error std ``std`` = (range [m], bearing [rad]) and each landmark's map std."""
    t = np.array([d.t for d in dets], dtype=float).reshape(-1)
    idx = np.clip(np.searchsorted(track_times, t - lead - 1e-9), 0, max(len(track_times) - 1, 0))
    ok = np.abs(track_times[idx] - (t - lead)) < 1e-7 if len(track_times) else np.zeros(len(t), bool)
    x, P = mean[idx], cov[idx]
    ids = [d.target for d in dets if d.target is not None]
    if len(ids) < len(dets):
        raise ValueError("landmark_innovations: a reading without its landmark's id (target)")
    lm = np.array([landmarks[k][:4] for k in ids], dtype=float).reshape(-1, 4)
    z = np.array([d.z for d in dets], dtype=float).reshape(-1, 2)
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    dx, dy = lm[:, 0] - x[:, 0], lm[:, 1] - x[:, 1]
    q = np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)  # landmark in the body frame
    rng = np.maximum(np.hypot(q[:, 0], q[:, 1]), 1e-6)
    r = np.stack([z[:, 0] - rng, wrap_angle(z[:, 1] - np.arctan2(q[:, 1], q[:, 0]))], axis=-1)
    jq = np.stack([q / rng[:, None], np.stack([-q[:, 1], q[:, 0]], -1) / (rng**2)[:, None]], axis=1)  # d(rb)/dq
    dq = np.zeros((len(dets), 2, 3))  # dq / d(right perturbation): -I for the translation, (q_y, -q_x) for theta
    dq[:, 0, 0] = dq[:, 1, 1] = -1.0
    dq[:, 0, 2], dq[:, 1, 2] = q[:, 1], -q[:, 0]
    H = jq @ dq
    rot_t = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], axis=1)  # d q / d landmark
    jl = jq @ rot_t
    L = jl @ (np.eye(2)[None] * np.square(lm[:, 2:4])[:, :, None]) @ np.swapaxes(jl, 1, 2)
    noise = np.diag([std[0] ** 2, std[1] ** 2])[None] + L
    return LandmarkInnovations(r, H @ P @ np.swapaxes(H, 1, 2), noise, H, P, ok)


def landmark_nis(track_times: np.ndarray, mean: np.ndarray, cov: np.ndarray, dets: Sequence[Detection],
                 landmarks: Mapping[int, Sequence[float]], std: tuple[float, float],
                 lead: float = RECORD_LEAD) -> np.ndarray:  # fmt: skip
    """Predictive NIS (2 dof) of landmark readings ``dets`` of one observer against its beliefs recorded ``lead`` s
    before each (:func:`landmark_innovations`: ``r' (H P H' + R + L)^-1 r``); NaN where no belief was recorded
    then."""
    if not dets:
        return np.empty(0)
    return landmark_innovations(track_times, mean, cov, dets, landmarks, std, lead).nis()


def tracks_nis(tracks: Mapping[int, RobotTrack], readings: Sequence[Detection],
               landmarks: Mapping[int, Sequence[float]], std: tuple[float, float],
               lead: float = RECORD_LEAD) -> np.ndarray:  # fmt: skip
    """The finite predictive NIS of landmark ``readings`` against the beliefs of ``tracks`` (every observer's own
    track, recorded at :func:`reading_times`, or with ``lead`` 0 at the readings' stamps; readings without a belief
    then are left out)."""
    nis = np.concatenate([np.empty(0)] + [
        landmark_nis(tr.times, tr.mean, tr.cov, [d for d in readings if d.observer == rb], landmarks, std, lead)
        for rb, tr in tracks.items()
    ])  # fmt: skip
    return nis[np.isfinite(nis)]


def nis_summary(nis: np.ndarray, suffix: str = "") -> dict[str, Any]:
    """The scores of 2-dof NIS values (keys end in ``suffix``): ``nis_ratio`` median / 1.386, ``anis`` mean / 2,
    ``beyond_gate`` the share above the 0.997 quantile, ``readings`` the count (NaN scores for none)."""
    return {
        f"nis_ratio{suffix}": float(np.median(nis) / MEDIAN_CHI2_2) if nis.size else float("nan"),
        f"anis{suffix}": float(np.mean(nis) / 2.0) if nis.size else float("nan"),
        f"beyond_gate{suffix}": float(np.mean(nis > GATE_2DOF)) if nis.size else float("nan"),
        f"readings{suffix}": int(nis.size),
    }


def landmark_folds(ids: Iterable[int], k: int) -> list[frozenset[int]]:
    """``k`` folds of the landmark ids (every ``k``-th of the sorted ids, so that each fold spreads over the map)."""
    order = sorted(ids)
    return [frozenset(order[f::k]) for f in range(k)]


def without_landmarks(events: Sequence[Event], fold: frozenset[int]) -> list[Event]:
    """``events`` less the landmark readings of the landmarks in ``fold`` (a run that never sees them)."""
    return [e for e in events if not (isinstance(e, Detection) and not e.target_is_robot and e.target in fold)]


def reading_times(readings: Sequence[Detection]) -> np.ndarray:
    """The record times that :func:`landmark_nis` scores ``readings`` at: :data:`RECORD_LEAD` s before each
    (sorted, unique)."""
    return np.unique(np.array([d.t for d in readings]) - RECORD_LEAD)
