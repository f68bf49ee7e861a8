"""The outcome of every detection of a stamp, as codes (:mod:`swarmloc.engine.codes`): the checks made before any
fusion (:func:`screen`), the batched chi-square gate (:func:`gate_rows`), and the tally the nodes keep
(:func:`tally`).

``status`` and ``reason`` are ``(M,)`` int8 arrays over a stamp's detections, in canonical order; a detection is
``PENDING`` until one of these functions or a fusion decides it.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from swarmloc.arrays import BoolArray, FloatArray
from swarmloc.engine.codes import (
    FUSED,
    GATED,
    OUTCOMES,
    R_NONFINITE,
    REASONS,
    REJECTED,
    UNKNOWN,
)
from swarmloc.engine.detections import Detections
from swarmloc.engine.formulas import build
from swarmloc.node.update import Gate


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
    nis: FloatArray,
    gate: Gate,
    m: int,
    nonfinite: int = R_NONFINITE,
) -> BoolArray:
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
    pair = status.astype(np.int64) * len(REASONS) + reason
    tally_table(counts, reasons, np.bincount(pair, minlength=len(OUTCOMES) * len(REASONS)).reshape(len(OUTCOMES), -1))


def tally_table(counts: Counter[str], reasons: Counter[str], table: np.ndarray) -> None:
    """:func:`tally` of a stamp whose outcomes are counted already: ``table[s, r]`` detections of outcome ``s`` and
    reason ``r`` (:data:`~swarmloc.engine.codes.OUTCOMES` by :data:`~swarmloc.engine.codes.REASONS`; the device
    stamp counts them on the device)."""
    counts["detections"] += int(table.sum())
    per = table.sum(axis=1)
    for code in (FUSED, GATED, REJECTED, UNKNOWN):
        counts[OUTCOMES[code]] += int(per[code])
    for s, r in zip(*np.nonzero(table[:, 1:]), strict=True):  # (outcome, reason) in order, as np.unique gave them
        reasons[f"{OUTCOMES[s]}: {REASONS[r + 1]}"] += int(table[s, r + 1])
