"""The outcome of every detection of a stamp, as codes (:mod:`swarmloc.engine.codes`): the checks made before any
fusion (:func:`screen`), the batched chi-square gate (:func:`gate_rows`), and the tally the nodes keep
(:func:`tally`).

``status`` and ``reason`` are ``(M,)`` int8 arrays over a stamp's detections, in canonical order; a detection is
``PENDING`` until one of these functions or a fusion decides it.
"""

from __future__ import annotations

from collections import Counter
from typing import NamedTuple, TypedDict

import numpy as np

from swarmloc.engine.codes import (
    FUSED,
    GATED,
    MODEL,
    OUTCOMES,
    R_NONFINITE,
    REASONS,
    REJECTED,
    UNKNOWN,
)
from swarmloc.engine.detections import Detections
from swarmloc.engine.formulas import build
from swarmloc.node.update import Gate

Replayed = tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
"""What a compiled replay returns: each detection's outcome and reason code ``(M,)`` (int8, rows of the timeline's
detections) and its records ``(robot row, stamp index, x (K, 3), P (K, 3, 3))`` (Cartesian)."""


class Switches(TypedDict, total=False):
    """The nodes' switches every compiled replay takes as keywords (``replay_joint``, ``replay_rdl``, their JAX forms,
    ...): the gate probability (None: no gate), relative and landmark measurements on, the map as
    :func:`swarmloc.engine.core.landmark_table` gives it, ``(xy (L, 2), cov (L, 2, 2))`` (None: none)."""

    gate: float | None
    use_relative: bool
    use_landmarks: bool
    landmarks: tuple[np.ndarray, np.ndarray] | None


class Constants(NamedTuple):
    """:class:`Switches` as the compiled loops and scans read them (:func:`constants`)."""

    thr: np.ndarray
    """The gate's threshold by measurement kind (code)."""
    gate_on: np.bool_
    relative: np.bool_
    lm_on: np.bool_
    lxy: np.ndarray
    """The landmarks' positions ``(L, 2)`` (one zero row when there are none)."""
    lcov: np.ndarray
    """Their covariances ``(L, 2, 2)``."""


def constants(gate: float | None = None, use_relative: bool = True, use_landmarks: bool = True,
              landmarks: tuple[np.ndarray, np.ndarray] | None = None) -> Constants:  # fmt: skip
    """The :class:`Constants` of a replay's :class:`Switches` (their defaults: no gate, everything on, no map)."""
    g = Gate(gate)
    thr = np.array([g.threshold(MODEL[code].size) for code in range(len(MODEL))])
    lxy, lcov = landmarks if landmarks is not None and len(landmarks[0]) else (np.zeros((1, 2)), np.zeros((1, 2, 2)))
    return Constants(thr, np.bool_(g.p is not None), np.bool_(use_relative), np.bool_(use_landmarks),
                     np.ascontiguousarray(lxy, dtype=float), np.ascontiguousarray(lcov, dtype=float))  # fmt: skip


def mark(status: np.ndarray, reason: np.ndarray, where: np.ndarray, outcome: int, why: int) -> None:
    """Outcome and reason of the detections ``where`` (a mask or indices)."""
    status[where] = outcome
    reason[where] = why


def screen(
    det: Detections, t: float, t0: np.ndarray, use_relative: bool, use_landmarks: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What is decided before any fusion, as the nodes decide it: observers that had not started, relative or
    landmark measurements switched off, unusable or self-addressed targets, neighbours that cannot answer (outside
    the team or not started; clocks ``t0``) and landmarks not in the map.

    Returns ``(status, reason, obs_ok, needs)``: ``obs_ok`` the detections whose observer runs at ``t``, ``needs``
    the pending ones that need their target's answer (robots; a landmark's state is the map's)."""
    n = t0.shape[0]
    obs_ok = t >= t0[det.observer]
    status, reason, needs = build(np).screen_stamp(det.kind, det.observer, det.target, obs_ok,
                                                   t >= t0[np.clip(det.target, 0, n - 1)], use_relative,
                                                   use_landmarks)  # fmt: skip
    return np.asarray(status, dtype=np.int8), np.asarray(reason, dtype=np.int8), obs_ok, needs


def gate_rows(
    status: np.ndarray,
    reason: np.ndarray,
    rows: np.ndarray,
    nis: np.ndarray,
    gate: Gate,
    m: int,
    nonfinite: int = R_NONFINITE,
) -> np.ndarray:
    """:meth:`Gate.verdict <swarmloc.node.update.Gate.verdict>` on the detections ``rows`` (normalized innovations
    squared ``nis`` of dimension ``m``), batched: beyond :meth:`Gate.threshold` they are ``GATED``, non-finite ones
    ``REJECTED`` with reason ``nonfinite``. Returns the mask of the rows that pass (all of them without a gate)."""
    if gate.p is None:
        return np.ones(rows.size, dtype=bool)
    bad = ~np.isfinite(nis)
    with np.errstate(invalid="ignore"):
        gated = ~bad & (nis > gate.threshold(m))
    mark(status, reason, rows[bad], REJECTED, nonfinite)
    status[rows[gated]] = GATED
    return ~(bad | gated)


def tally(counts: Counter[str], reasons: Counter[str], status: np.ndarray, reason: np.ndarray) -> None:
    """Add a stamp's outcomes to ``counts`` (detections in, ``fused``, ``gated``, ``rejected``, ``unknown``) and
    ``reasons`` (``"<outcome>: <reason>"``), as the nodes count."""
    counts["detections"] += int(status.size)
    per = np.bincount(status, minlength=len(OUTCOMES))
    for code in (FUSED, GATED, REJECTED, UNKNOWN):
        counts[OUTCOMES[code]] += int(per[code])
    if reason.any():
        pairs, n = np.unique(np.stack([status[reason > 0], reason[reason > 0]]), axis=1, return_counts=True)
        for (s, r), k in zip(pairs.T, n, strict=True):
            reasons[f"{OUTCOMES[s]}: {REASONS[r]}"] += int(k)
