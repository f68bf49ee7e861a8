"""Line fusion: a map of wall segments built from the robots' world-frame line observations.

:class:`LineMap` is small, pure and stateful (lists of floats and 2x2 matrices; no I/O, no clock) so that a belief
server can own one and answer map queries (the chapter's Fig. 1: "all detected lines are fused through the line data
fusion block" on the server). Each observation (:class:`LineObservation`, world frame) is

1. **associated** with the map line that passes both tests and has the smallest Mahalanobis distance: the squared
   Mahalanobis distance of ``(rho, alpha)`` (``d^T (C_obs + C_map)^-1 d``, angle difference wrapped, ``rho``
   compared in both representations ``(rho, alpha)`` and ``(-rho, alpha + pi)``) at most the chi-square quantile
   ``gate`` with 2 degrees of freedom, *and* extents that overlap or leave a gap of at most ``max_gap`` [m] along
   the line;
2. **fused** in information form: ``I = C_map^-1 + C_obs^-1``, ``x = I^-1 (C_map^-1 x_map + C_obs^-1 x_obs)``
   (the two treated as independent, as in the chapter's parallel fusion; observations that share a robot's pose
   error are correlated, so the fused covariance is optimistic: the association gate keeps ``C_obs`` in);
3. **extended**, end by end (projected onto the fused line): two *closed* ends (where the scan saw the wall end,
   :func:`swarmloc.mapping.extract_lines`) within 3 standard deviations of each other are averaged, weighted by
   their inverse variances along the line (the variance kept is the smaller one, not the fused one: successive
   ends seen by one robot share its pose error); an *open* end (the wall may go on unseen) moves the end outwards
   only where it lies more than 3 standard deviations beyond a closed one; two open ends: the farther. Without end
   information (all ends open) this is the union of both segments' projections. Why: the union of many noisy
   extents is their farthest, biased outwards by the largest pose error along the wall (measured on ``swarmloc map``:
   docs/maps.md);
4. otherwise **added** as a new line. After a fusion the grown line is tested against the other lines with the
   same two tests and merged with any that pass (two robots seeing two ends of one wall end as one line).

Every line keeps its covariance, the robots that saw it and its number of observations. Bad input (not finite,
covariance not symmetric positive definite, degenerate extent) raises ValueError from :meth:`LineMap.add`;
:meth:`LineMap.offer` counts it as rejected instead (for a server that must not stop on one bad message).
"""

from __future__ import annotations

import json
import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from swarmloc.gaussian import symmetric
from swarmloc.lie import wrap_angle
from swarmloc.mapping.lines import normal_tangent

__all__ = ["LineMap", "LineObservation", "MapLine"]


@dataclass(frozen=True)
class LineObservation:
    """A line seen by ``robot`` at time ``t`` [s], in the world frame: ``rho`` [m], ``alpha`` [rad], ``cov``
    ``(2, 2)`` of ``(rho, alpha)`` and the segment's ``endpoints`` ``(2, 2)`` [m]."""

    rho: float
    alpha: float
    cov: np.ndarray
    endpoints: np.ndarray
    robot: int = 0
    t: float = 0.0
    closed: tuple[bool, bool] = (False, False)
    end_var: tuple[float, float] = (0.0, 0.0)
    """Whether each end point is where the wall ends (``closed``) and its variance along the line [m^2]."""

    def check(self) -> None:
        """ValueError naming what is wrong."""
        C = np.asarray(self.cov, dtype=float)
        E = np.asarray(self.endpoints, dtype=float)
        if not (np.isfinite(self.rho) and np.isfinite(self.alpha)):
            raise ValueError(f"LineObservation: rho {self.rho!r} and alpha {self.alpha!r} must be finite")
        if C.shape != (2, 2) or not np.isfinite(C).all() or abs(C[0, 1] - C[1, 0]) > 1e-9 * max(1.0, abs(C).max()):
            raise ValueError("LineObservation: cov must be a finite symmetric 2x2 matrix")
        if np.linalg.eigvalsh(C)[0] <= 0:
            raise ValueError("LineObservation: cov must be positive definite")
        if E.shape != (2, 2) or not np.isfinite(E).all() or np.hypot(*(E[1] - E[0])) <= 0:
            raise ValueError("LineObservation: endpoints must be two distinct finite points, shape (2, 2)")
        v = np.asarray(self.end_var, dtype=float)
        if v.shape != (2,) or not np.isfinite(v).all() or (v < 0).any():
            raise ValueError("LineObservation: end_var must be two finite variances >= 0")
        if np.shape(self.closed) != (2,):
            raise ValueError("LineObservation: closed must be two flags")


@dataclass
class MapLine:
    """A fused line: ``rho`` [m] ``>= 0``, ``alpha`` [rad], ``cov`` ``(2, 2)``, extent ``[s0, s1]`` [m] along the
    tangent ``(-sin alpha, cos alpha)`` from the foot point, the ``robots`` that saw it, ``n_obs`` observations."""

    rho: float
    alpha: float
    cov: np.ndarray
    s0: float
    s1: float
    robots: set[int] = field(default_factory=set)
    n_obs: int = 1
    ends: tuple[_End, _End] | None = field(default=None, repr=False)
    """The low and high end's estimates (None: both open at ``s0``, ``s1``, variance 0)."""

    def endpoints(self) -> np.ndarray:
        """The segment's end points ``(2, 2)`` [m]."""
        n, t = normal_tangent(self.alpha)
        return self.rho * n + np.outer([self.s0, self.s1], t)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Tangential coordinates [m] of ``points`` ``(k, 2)`` on this line."""
        return np.asarray(points, dtype=float) @ normal_tangent(self.alpha)[1]


@dataclass(frozen=True)
class _End:
    """One end of a map line: a world point ``(2,)`` [m]; ``closed`` (the wall ends there); ``var`` along the line
    [m^2]; for a closed end the sums of the weights ``w`` and weighted points ``wp`` that ``point`` averages."""

    point: np.ndarray
    closed: bool
    var: float
    w: float = 0.0
    wp: np.ndarray | None = None

    @staticmethod
    def of(point: np.ndarray, closed: bool, var: float) -> _End:
        v = max(float(var), 1e-12)
        return _End(point, closed, v, 1 / v, point / v) if closed else _End(point, False, v)


def _combine(a: _End, b: _End, s: Any, out: float) -> _End:
    """The end of a line from ends ``a`` and ``b`` (module docstring, step 3); ``s`` projects a point onto the line,
    ``out`` is -1 for the low end and +1 for the high end."""
    beyond = out * (s(b.point) - s(a.point))  # > 0: b lies further out than a
    gate = 3.0 * np.sqrt(a.var + b.var)
    if a.closed and b.closed:
        assert a.wp is not None and b.wp is not None  # a closed end carries its sums
        if abs(beyond) <= gate:
            w, wp = a.w + b.w, a.wp + b.wp
            return _End(wp / w, True, min(a.var, b.var), w, wp)
        return b if beyond > 0 else a
    if a.closed != b.closed:
        c, o = (a, b) if a.closed else (b, a)
        return o if out * (s(o.point) - s(c.point)) > gate else c
    return b if beyond > 0 else a


def _flip(cov: np.ndarray) -> np.ndarray:
    """Covariance of ``(-rho, alpha + pi)`` from that of ``(rho, alpha)``: the cross term changes sign."""
    return cov * np.array([[1.0, -1.0], [-1.0, 1.0]])


def _innovation(rho: float, alpha: float, cov: np.ndarray, line: MapLine) -> tuple[np.ndarray, np.ndarray]:
    """``(rho, alpha) - (line.rho, line.alpha)`` and the covariance of ``(rho, alpha)``, in whichever
    representation, ``(rho, alpha)`` or the flipped ``(-rho, alpha + pi)``, has the smaller angle difference."""
    d1 = np.array([rho - line.rho, wrap_angle(alpha - line.alpha)])
    d2 = np.array([-rho - line.rho, wrap_angle(alpha + np.pi - line.alpha)])
    return (d1, cov) if abs(d1[1]) <= abs(d2[1]) else (d2, _flip(cov))


def _obs_ends(obs: LineObservation) -> tuple[_End, _End]:
    E = np.asarray(obs.endpoints, dtype=float)
    return (_End.of(E[0], bool(obs.closed[0]), obs.end_var[0]), _End.of(E[1], bool(obs.closed[1]), obs.end_var[1]))


def _ends_of(line: MapLine) -> tuple[_End, _End]:
    """``line``'s ends, or open ones at its extent when it has none."""
    if line.ends is not None:
        return line.ends
    E = line.endpoints()
    return _End.of(E[0], False, 0.0), _End.of(E[1], False, 0.0)


class LineMap:
    """The fused map (see the module docstring): ``gate`` is the association probability (chi-square, 2 dof),
    ``max_gap`` [m] the largest gap along a line between two segments that may still be one wall."""

    def __init__(self, gate: float = 0.99, max_gap: float = 0.3) -> None:
        if not 0 < gate < 1:
            raise ValueError(f"LineMap: gate must be a probability in (0, 1), got {gate!r}")
        if not max_gap >= 0:
            raise ValueError(f"LineMap: max_gap must be >= 0 m, got {max_gap!r}")
        self.gate = float(gate)
        self.max_gap = float(max_gap)
        self._chi2 = float(chi2.ppf(gate, 2))
        self.lines: list[MapLine] = []
        self.counts: Counter[str] = Counter()

    # ------------------------------------------------------------------ association
    def _compatible(self, rho: float, alpha: float, cov: np.ndarray, ends: np.ndarray, line: MapLine) -> float:
        """Squared Mahalanobis distance when both tests pass, else ``inf``."""
        d, cov = _innovation(rho, alpha, cov, line)
        m2 = float(d @ np.linalg.solve(cov + line.cov, d))
        if m2 > self._chi2:
            return np.inf
        s = line.project(ends)
        gap = max(s.min() - line.s1, line.s0 - s.max())
        return m2 if gap <= self.max_gap else np.inf

    def associate(self, obs: LineObservation) -> int | None:
        """Index of the map line ``obs`` would be fused with, or None (a new line)."""
        ends = np.asarray(obs.endpoints, dtype=float)
        cov = np.asarray(obs.cov, dtype=float)
        scores = [self._compatible(obs.rho, obs.alpha, cov, ends, ln) for ln in self.lines]
        if not scores or not np.isfinite(min(scores)):
            return None
        return int(np.argmin(scores))

    # ------------------------------------------------------------------ fusion
    @staticmethod
    def _fuse(line: MapLine, rho: float, alpha: float, cov: np.ndarray, ends: tuple[_End, _End]) -> None:
        """Information-form fusion of ``(rho, alpha, cov)`` into ``line``, its ends combined with ``ends`` (a
        segment's, as :class:`_End`: module docstring, step 3) (in place)."""
        old = _ends_of(line)
        d, cov = _innovation(rho, alpha, cov, line)
        x_obs = np.array([line.rho, line.alpha]) + d
        Im, Io = np.linalg.inv(line.cov), np.linalg.inv(cov)
        C = np.linalg.inv(Im + Io)
        x = C @ (Im @ np.array([line.rho, line.alpha]) + Io @ x_obs)
        C = symmetric(C)
        if x[0] >= 0:
            line.rho, line.alpha, line.cov = float(x[0]), wrap_angle(float(x[1])), C
        else:
            line.rho, line.alpha, line.cov = float(-x[0]), wrap_angle(float(x[1]) + np.pi), _flip(C)
        t = normal_tangent(line.alpha)[1]

        def s(p: np.ndarray) -> float:
            return float(p @ t)

        new = sorted(ends, key=lambda e: s(e.point))
        lo, hi = sorted(old, key=lambda e: s(e.point))
        lo, hi = _combine(lo, new[0], s, -1.0), _combine(hi, new[1], s, 1.0)
        if s(lo.point) >= s(hi.point):  # ends crossed (closed ends of a very short line): the union, open
            pts = [e.point for e in (*old, *ends)]
            lo = _End.of(min(pts, key=s), False, 0.0)
            hi = _End.of(max(pts, key=s), False, 0.0)
        line.ends = (lo, hi)
        line.s0, line.s1 = s(lo.point), s(hi.point)
        line.n_obs += 1

    def add(self, obs: LineObservation) -> int:
        """Fuse ``obs`` into the map (module docstring); returns the index of the line it ended in. ValueError for
        a bad observation (nothing changes)."""
        obs.check()
        self.counts["observations"] += 1
        cov = np.asarray(obs.cov, dtype=float)
        ends = np.asarray(obs.endpoints, dtype=float)
        k = self.associate(obs)
        if k is None:
            rho, alpha = (obs.rho, wrap_angle(obs.alpha)) if obs.rho >= 0 else (-obs.rho, wrap_angle(obs.alpha + np.pi))
            cov = cov.copy() if obs.rho >= 0 else _flip(cov)
            s = ends @ normal_tangent(alpha)[1]
            line = MapLine(float(rho), alpha, cov, float(s.min()), float(s.max()), {obs.robot})
            e = sorted(_obs_ends(obs), key=lambda e: float(e.point @ normal_tangent(alpha)[1]))
            line.ends = (e[0], e[1])
            self.lines.append(line)
            self.counts["added"] += 1
            return len(self.lines) - 1
        self._fuse(self.lines[k], obs.rho, obs.alpha, cov, _obs_ends(obs))
        self.lines[k].robots.add(obs.robot)
        self.counts["fused"] += 1
        return self._merge_from(k)

    def offer(self, obs: LineObservation) -> int | None:
        """:meth:`add` that never raises: a bad observation is counted ``rejected`` (and its reason in
        ``counts``) and gives None."""
        try:
            return self.add(obs)
        except (ValueError, TypeError, np.linalg.LinAlgError) as e:
            self.counts["rejected"] += 1
            self.counts[f"rejected: {str(e).split(':')[-1].strip()[:60]}"] += 1
            return None

    def _merge_from(self, k: int) -> int:
        """Merge every line compatible with line ``k`` into it (repeatedly); returns ``k``'s final index."""
        while True:
            line = self.lines[k]
            best, j_best = np.inf, None
            for j, other in enumerate(self.lines):
                if j == k:
                    continue
                m2 = self._compatible(other.rho, other.alpha, other.cov, other.endpoints(), line)
                if m2 < best:
                    best, j_best = m2, j
            if j_best is None:
                return k
            other = self.lines[j_best]
            self._fuse(line, other.rho, other.alpha, other.cov, _ends_of(other))
            line.robots |= other.robots
            line.n_obs += other.n_obs - 1
            del self.lines[j_best]
            self.counts["merged"] += 1
            k = k - 1 if j_best < k else k

    # ------------------------------------------------------------------ output
    def segments(self) -> np.ndarray:
        """Every line's end points, ``(L, 2, 2)`` [m]."""
        return np.array([ln.endpoints() for ln in self.lines]).reshape(-1, 2, 2)

    def to_geojson(self) -> dict[str, Any]:
        """A GeoJSON FeatureCollection: one LineString per line (planar metres, not WGS84: ``crs`` says so),
        properties ``rho``, ``alpha``, ``cov``, ``robots``, ``n_obs``."""
        feats = [
            {
                "type": "Feature",
                "geometry": {"type": "LineString", "coordinates": ln.endpoints().tolist()},
                "properties": {
                    "rho": ln.rho,
                    "alpha": ln.alpha,
                    "cov": np.asarray(ln.cov).tolist(),
                    "robots": sorted(ln.robots),
                    "n_obs": ln.n_obs,
                },  # fmt: skip
            }
            for ln in self.lines
        ]
        return {"type": "FeatureCollection", "crs": {"type": "name", "properties": {"name": "local planar metres"}},
                "features": feats}  # fmt: skip

    def save_geojson(self, path: str | os.PathLike[str]) -> None:
        Path(path).write_text(json.dumps(self.to_geojson(), indent=1))

    def save_dxf(self, path: str | Path) -> None:
        """The segments as a minimal ASCII DXF (LINE entities on layer MAP; AutoCAD R12 subset, written by hand so
        that no DXF library is needed)."""
        out = ["0", "SECTION", "2", "ENTITIES"]
        for (x0, y0), (x1, y1) in self.segments():
            out += ["0", "LINE", "8", "MAP", "10", f"{x0:.6f}", "20", f"{y0:.6f}", "30", "0.0",
                    "11", f"{x1:.6f}", "21", f"{y1:.6f}", "31", "0.0"]  # fmt: skip
        out += ["0", "ENDSEC", "0", "EOF"]
        Path(path).write_text("\n".join(out) + "\n")

    def plot(self, ax: Any, **kw: Any) -> None:
        """Draw the segments on a matplotlib axis (``kw`` to ``ax.plot``)."""
        for seg in self.segments():
            ax.plot(seg[:, 0], seg[:, 1], **{"color": "C0", "lw": 2, **kw})
