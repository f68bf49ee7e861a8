"""Anonymous detections, misses and clutter, applied to simulated events (lecture slides 32-40).

:func:`anonymize` turns a team's tagged robot detections into what a detector of identical robots reports:

* **anonymous**: each robot detection loses its ``target`` (set to None); its true identity is kept in
  ``truth_target`` for scoring only (estimators never read it);
* **misses**: each robot detection is kept with probability ``p_detect``;
* **clutter**: each scan (an observer's robot detections at one instant, before misses) gains ``Poisson(clutter)``
  false detections of the scan's kind, uniform in range ``[min_range, max_range]`` [m] and bearing within
  ``+-fov/2`` [rad] (a relative pose's heading uniform too), with the scan's noise covariance and
  ``truth_target = -1``.

Landmark detections, absolute fixes, odometry and truth pass unchanged. Same seed, same result.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from swarmloc.events import Detection, Event

__all__ = ["anonymize"]

CLUTTER_TRUTH = -1
"""``truth_target`` of a false detection."""


def _z_clutter(rng: np.random.Generator, kind: str, n: int, lo: float, hi: float, fov: float) -> np.ndarray:
    rho = rng.uniform(lo, hi, n)
    beta = rng.uniform(-fov / 2, fov / 2, n)
    if kind == "range_bearing":
        return np.stack([rho, beta], axis=-1)
    if kind == "range":
        return rho[:, None]
    if kind == "bearing":
        return beta[:, None]
    return np.stack([rho * np.cos(beta), rho * np.sin(beta), rng.uniform(-np.pi, np.pi, n)], axis=-1)  # pose


def anonymize(
    events: Sequence[Event],
    *,
    p_detect: float = 1.0,
    clutter: float = 0.0,
    max_range: float = 5.0,
    min_range: float = 0.3,
    fov: float = 2 * np.pi,
    hide_ids: bool = True,
    seed: int = 0,
) -> list[Event]:
    """The events with robot detections made anonymous (``hide_ids``), missed and cluttered as the module says."""
    if not 0.0 <= p_detect <= 1.0:
        raise ValueError(f"p_detect must be in [0, 1], got {p_detect}")
    if not (np.isfinite(clutter) and 0.0 <= clutter <= 100.0):
        raise ValueError(f"clutter must be a mean count per scan in [0, 100], got {clutter}")
    if not 0.0 <= min_range < max_range or not np.isfinite(max_range):
        raise ValueError(f"need 0 <= min_range < max_range (finite), got {min_range}, {max_range}")
    if not 0.0 < fov <= 2 * np.pi:
        raise ValueError(f"fov must be in (0, 2 pi], got {fov}")
    rng = np.random.default_rng(seed)
    out: list[Event] = []
    scan: tuple[int, float] | None = None
    for e in events:
        robot_det = isinstance(e, Detection) and e.target_is_robot and e.kind != "absolute" and e.target is not None
        if not robot_det:
            out.append(e)
            continue
        if (e.observer, e.t) != scan:  # a new scan: its clutter first, drawn once
            scan = (e.observer, e.t)
            k = int(rng.poisson(clutter)) if clutter > 0 else 0
            for z in _z_clutter(rng, e.kind, k, min_range, max_range, fov):
                z.setflags(write=False)
                out.append(Detection(e.observer, e.t, e.kind, z, e.cov, None, True, CLUTTER_TRUTH))
        if p_detect < 1.0 and rng.random() >= p_detect:
            continue
        target = None if hide_ids else e.target
        out.append(Detection(e.observer, e.t, e.kind, e.z, e.cov, target, True, e.target))
    return out
