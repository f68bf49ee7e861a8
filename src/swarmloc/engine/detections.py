"""One stamp's detections as arrays (:class:`Detections`), robots as row indices; a run of stamps as arrays
(:class:`Timeline`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarmloc.engine.codes import NO_LANDMARK, POSE

_LANDMARKS_LAST = 1 << 40
"""Sort key offset of landmark targets: after every robot row, in the order of the map's ids (the nodes' order)."""


@dataclass(frozen=True)
class Detections:
    """Detections at one stamp, as arrays of length ``M``.

    ``observer`` ``(M,)``: robot row; ``target`` ``(M,)``: robot row, :data:`~swarmloc.engine.codes.NO_TARGET`
    (absolute fix), :data:`~swarmloc.engine.codes.UNKNOWN_ROBOT`, a landmark's code
    (:func:`~swarmloc.engine.codes.landmark_code` of its row in the engine's map, :meth:`Engine.landmark_code
    <swarmloc.engine.Engine.landmark_code>`) or :data:`~swarmloc.engine.codes.NO_LANDMARK`; ``kind`` ``(M,)``: code of
    :data:`~swarmloc.engine.codes.KINDS`; ``z`` ``(M, 3)``: the measurement in its first ``m`` entries (``m`` the
    kind's :attr:`~swarmloc.sensors.models.MeasurementModel.size`: pose ``(x [m], y [m], theta [rad])``, range [m]
    / bearing [rad]); ``R`` ``(M, 3, 3)``: its noise covariance in the leading ``m x m`` block (conventions of
    :class:`swarmloc.events.Detection`). An SE(3) team's detections are 6 wide: ``z`` ``(M, 6)``, ``R``
    ``(M, 6, 6)`` (``"pose3"``: translation [m] and rotation vector [rad]).
    """

    observer: np.ndarray
    target: np.ndarray
    kind: np.ndarray
    z: np.ndarray
    R: np.ndarray

    def __len__(self) -> int:
        return int(self.observer.shape[0])

    def take(self, idx: np.ndarray) -> Detections:
        return Detections(self.observer[idx], self.target[idx], self.kind[idx], self.z[idx], self.R[idx])

    @classmethod
    def concat(cls, *parts: Detections) -> Detections:
        """The detections of ``parts`` one after the other (not sorted: :meth:`canonical` sorts them)."""
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("observer", "target", "kind", "z", "R")))

    def canonical(self, first: np.ndarray | None = None) -> Detections:
        """Sorted by observer, then the nodes' canonical order within a group (kind, robots before landmarks,
        target, z); with ``first`` ``(M,)`` (e.g. a stamp index), by ``first`` before all of these."""
        z = self.z
        tgt = np.where(self.target <= NO_LANDMARK, _LANDMARKS_LAST + NO_LANDMARK - self.target, self.target)
        keys = (*(z[:, k] for k in range(z.shape[1] - 1, -1, -1)), tgt, self.kind, self.observer)
        return self.take(np.lexsort(keys if first is None else (*keys, first)))

    @classmethod
    def poses(cls, observer: np.ndarray, target: np.ndarray, z: np.ndarray, R: np.ndarray) -> Detections:
        """Relative-pose detections (``R`` ``(3, 3)`` or ``(M, 3, 3)``)."""
        m = observer.shape[0]
        kind = np.full(m, POSE, dtype=np.int64)
        return cls(observer, target, kind, z, np.broadcast_to(R, (m, 3, 3)))


@dataclass(frozen=True)
class Timeline:
    """A run of ``S`` stamps as arrays, for a compiled replay (:meth:`swarmloc.engine.Engine.replay_timeline`).

    ``stamps`` ``(S,)``: increasing [s]. Stamp ``s``'s detections are rows ``d0[s]:d0[s + 1]`` of ``det``
    (canonical order within the stamp, :meth:`Detections.canonical`); its commands rows ``c0[s]:c0[s + 1]`` of
    ``robot`` (row), ``v`` [m/s] and ``w`` [rad/s], in force from ``s`` on; ``record`` ``(S,)``: whether every
    started robot's belief is recorded after the stamp's input.
    """

    stamps: np.ndarray
    det: Detections
    d0: np.ndarray
    c0: np.ndarray
    robot: np.ndarray
    v: np.ndarray
    w: np.ndarray
    record: np.ndarray

    def __len__(self) -> int:
        return int(self.stamps.shape[0])
