"""One robot's range scans as a series, and the world-frame line observations of one scan given a belief.

:class:`ScanSeries` is what a robot's node reads of its range finder (times, ranges, beam angles, range noise);
:func:`scan_observations` extracts a scan's lines (:func:`~swarmloc.mapping.extract_lines`) and carries them into
the world with the robot's belief at the scan (:func:`~swarmloc.mapping.line_to_world`): the observations that
``swarmloc map`` fuses in-process and a networked robot sends to the belief server.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarmloc.mapping.linemap import LineObservation
from swarmloc.mapping.lines import LineFit, extract_lines
from swarmloc.mapping.transform import line_to_world

__all__ = ["ScanSeries", "scan_observations"]


@dataclass(frozen=True)
class ScanSeries:
    """Scans of one robot: ``times`` ``(S,)`` [s], ``ranges`` ``(S, B)`` [m] (NaN: no return) at beam ``angles``
    ``(B,)`` [rad, robot frame], range noise std ``sigma`` [m]."""

    times: np.ndarray
    ranges: np.ndarray
    angles: np.ndarray
    sigma: float

    def __post_init__(self) -> None:
        t, r, a = (np.asarray(x, dtype=float) for x in (self.times, self.ranges, self.angles))
        if t.ndim != 1 or a.ndim != 1 or r.shape != (t.size, a.size):
            raise ValueError(f"ScanSeries: times (S,), ranges (S, B), angles (B,); got {t.shape}, {r.shape}, {a.shape}")
        if not (np.isfinite(t).all() and np.isfinite(a).all() and np.all(np.diff(t) > 0)):
            raise ValueError("ScanSeries: times must be finite and increasing, angles finite")
        if not (np.isfinite(self.sigma) and self.sigma >= 0):
            raise ValueError(f"ScanSeries: sigma must be a finite std >= 0 m, got {self.sigma!r}")
        for name, v in (("times", t), ("ranges", r), ("angles", a)):
            v.setflags(write=False)
            object.__setattr__(self, name, v)


def scan_observations(
    ranges: np.ndarray,
    angles: np.ndarray,
    sigma: float,
    pose_mean: np.ndarray,
    pose_cov: np.ndarray,
    robot: int,
    t: float,
    order: int = 2,
) -> list[LineObservation]:
    """The lines of one scan (``ranges`` ``(B,)`` [m] at ``angles`` [rad], noise ``sigma`` [m]) in the world frame
    of a robot whose belief is ``pose_mean`` (SE(2) matrix ``(3, 3)``) with exponential-coordinate covariance
    ``pose_cov`` ``(3, 3)``, in extraction order; ``order``: of the propagation (1 or 2)."""
    fits = extract_lines(ranges, angles, sigma)
    if not fits:
        return []
    g = np.asarray(pose_mean, dtype=float)
    S = np.asarray(pose_cov, dtype=float)
    rho, alpha, C = line_to_world(np.array([f.rho for f in fits]), np.array([f.alpha for f in fits]),
                                  np.array([f.cov for f in fits]), g, S, order)  # fmt: skip
    return [
        LineObservation(
            float(rho[k]),
            float(alpha[k]),
            C[k],
            f.endpoints @ g[:2, :2].T + g[:2, 2],
            robot,
            float(t),
            f.closed,
            _end_var(f, S),
        )  # fmt: skip
        for k, f in enumerate(fits)
    ]


def _end_var(f: LineFit, pose_cov: np.ndarray) -> tuple[float, float]:
    """Variance [m^2] of each end of ``f`` along its line, in the world: the fit's own (beam spacing, range noise)
    plus the pose's, first order: an end ``p`` (robot frame) is at ``mu (p + xi_xy + xi_th J p)``, ``J p = (-p_y,
    p_x)``, so along the line's tangent ``t`` (robot frame; the world rotation keeps lengths) its variance is
    ``a^T Sigma a`` with ``a = (t_x, t_y, t . J p)``."""
    t = np.array([-np.sin(f.alpha), np.cos(f.alpha)])
    out = []
    for e in range(2):
        p = f.endpoints[e]
        a = np.array([t[0], t[1], t[0] * -p[1] + t[1] * p[0]])
        out.append(float(f.end_var[e] + a @ pose_cov @ a))
    return out[0], out[1]
