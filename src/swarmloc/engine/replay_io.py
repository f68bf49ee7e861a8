"""What every compiled replay (the numba loops) takes and returns: the nodes' switches (:class:`Switches`) and the
noise model's coefficients (:func:`noise_tuple`), read as :class:`Constants`, the team's start as a joint state
(:func:`joint_start`) and the result (:data:`Replayed`). Units: metres, radians, seconds.
"""

from __future__ import annotations

from dataclasses import fields
from typing import NamedTuple, TypedDict

import numpy as np

from swarmloc.engine.codes import MODEL
from swarmloc.kernels.invariant import cartesian_to_world_cov
from swarmloc.motion import UnicycleNoise
from swarmloc.node.update import Gate

Replayed = tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
"""What a compiled replay returns: each detection's outcome and reason code ``(M,)`` (int8, rows of the timeline's
detections) and its records ``(robot row, stamp index, x (K, 3), P (K, 3, 3))`` (Cartesian)."""


class Switches(TypedDict, total=False):
    """The nodes' switches every compiled replay takes as keywords (``replay_joint``, ``replay_rdl``,
    ``replay_clusters``): the gate probability (None: no gate), relative and landmark measurements on, the map as
    :func:`swarmloc.engine.core.landmark_table` gives it, ``(xy (L, 2), cov (L, 2, 2))`` (None: none)."""

    gate: float | None
    use_relative: bool
    use_landmarks: bool
    landmarks: tuple[np.ndarray, np.ndarray] | None


Noise = tuple[float, ...]
"""A noise model's coefficients as the compiled prediction takes them (:func:`noise_tuple`)."""


def noise_tuple(noise: UnicycleNoise) -> Noise:
    """``noise``'s coefficients as floats in the order of its fields: the argument ``q`` of the compiled prediction
    (:func:`swarmloc.engine.scalar.predict_source`), which traces them in that order."""
    return tuple(float(getattr(noise, f.name)) for f in fields(noise))  # not astuple: it deep-copies every field


class Constants(NamedTuple):
    """:class:`Switches` and the noise model as the compiled loops read them (:func:`constants`)."""

    thr: np.ndarray
    """The gate's threshold by measurement kind (code)."""
    gate_on: np.bool_
    relative: np.bool_
    lm_on: np.bool_
    lxy: np.ndarray
    """The landmarks' positions ``(L, 2)`` (one zero row when there are none)."""
    lcov: np.ndarray
    """Their covariances ``(L, 2, 2)``."""
    noise: Noise
    """The noise model's coefficients (:func:`noise_tuple`): an argument of the compiled prediction, not constants
    compiled in, so one compiled loop serves every noise model."""


def constants(noise: Noise | None = None, gate: float | None = None, use_relative: bool = True,
              use_landmarks: bool = True, landmarks: tuple[np.ndarray, np.ndarray] | None = None
              ) -> Constants:  # fmt: skip
    """The :class:`Constants` of a replay's noise model (its :func:`noise_tuple`, made once by the caller; None:
    :class:`~swarmloc.motion.UnicycleNoise`'s defaults) and :class:`Switches` (their defaults: no gate, everything
    on, no map)."""
    g = Gate(gate)
    thr = np.array([g.threshold(MODEL[code].size) for code in range(len(MODEL))])
    lxy, lcov = landmarks if landmarks is not None and len(landmarks[0]) else (np.zeros((1, 2)), np.zeros((1, 2, 2)))
    return Constants(thr, np.bool_(g.p is not None), np.bool_(use_relative), np.bool_(use_landmarks),
                     np.ascontiguousarray(lxy, dtype=float), np.ascontiguousarray(lcov, dtype=float),
                     noise_tuple(UnicycleNoise()) if noise is None else noise)  # fmt: skip


def joint_start(x: np.ndarray, P: np.ndarray, t0: float | np.ndarray, invariant: bool, K: int = 0
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The joint state at the start from Cartesian beliefs ``x (n, 3)``, ``P (n, 3, 3)`` (uncorrelated) and the
    starts ``t0`` [s] (one float, or each robot's ``(n,)``; ``inf``: never starts): ``(X (n, 3), blocks (B, 3K, 3K),
    clocks (n,), starts (n,))``, the covariance block-diagonal in clusters of ``K`` robots in row order (0: one
    cluster of all; the last cluster possibly smaller), world-frame errors with ``invariant``."""
    n = x.shape[0]
    K = K or n
    starts = np.array(np.broadcast_to(np.asarray(t0, dtype=float), (n,)))
    X = np.array(x, dtype=float)
    blocks = cartesian_to_world_cov(X, np.asarray(P, dtype=float)) if invariant else P
    J = np.zeros((-(-n // K), 3 * K, 3 * K))
    for k in range(n):
        c = 3 * (k % K)
        J[k // K, c : c + 3, c : c + 3] = blocks[k]
    return X, J, np.where(np.isfinite(starts), starts, 0.0), starts
