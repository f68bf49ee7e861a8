"""Planar trajectories in the TUM format (readable and writable by ``evo``).

A TUM file holds one pose per line, eight numbers separated by blanks::

    # timestamp tx ty tz qx qy qz qw
    0.000000000 1.000000000 2.000000000 0.000000000 0.000000000 0.000000000 0.000000000 1.000000000

``timestamp`` in seconds (any origin, e.g. Unix epoch), ``tx ty tz`` the position in metres in the world frame and
``qx qy qz qw`` the orientation as a unit quaternion (scalar last, Hamilton convention, body to world). Lines
starting with ``#`` and blank lines are ignored. Times must be strictly increasing.

swarmloc is planar: a pose is ``(x [m], y [m], theta [rad])`` with the yaw ``theta`` in ``(-pi, pi]``.
:func:`write_tum` writes ``z = 0`` and the yaw quaternion ``(0, 0, sin(theta/2), cos(theta/2))``; times and
positions with nine decimals (``%.9f``), the quaternion with twelve (``%.12f``: nine would limit the yaw to about
1.4e-9 rad, since the yaw is twice the angle of ``(qw, qz)``), so that a round trip is exact to 1e-9.
:func:`read_tum` accepts a quaternion of any norm within ``QUAT_NORM_TOL`` of one (it is normalized) and rejects a
pose that is not planar: ``|z| > PLANAR_TOL_Z`` metres or a tilt (combined roll and pitch, the angle between the
body and world z axes) above ``PLANAR_TOL_TILT`` radians.

3-D teams (SE(3)) write full poses with :func:`write_tum3` (``(x, y, z, qx, qy, qz, qw)`` rows, :func:`pose7`
converts a ``4 x 4`` pose; the quaternion's sign is chosen with ``qw >= 0``).

Every problem raises :class:`TUMError` (a ``ValueError``) naming the file and, for bad lines, every bad line
number with its content.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from swarmloc.datasets.bounds import shorten
from swarmloc.lie import wrap_angle

__all__ = [
    "PLANAR_TOL_TILT",
    "PLANAR_TOL_Z",
    "QUAT_NORM_TOL",
    "TUMError",
    "interpolate",
    "pose7",
    "pose_from7",
    "read_tum",
    "write_tum",
    "write_tum3",
]

PLANAR_TOL_Z = 1e-6
"""Largest ``|z|`` [m] of a planar pose."""

PLANAR_TOL_TILT = 1e-6
"""Largest tilt [rad] (angle between the body z axis and the world z axis) of a planar pose."""

QUAT_NORM_TOL = 1e-3
"""Largest ``| |q| - 1 |`` accepted for a quaternion (it is normalized after the check)."""

HEADER = "timestamp tx ty tz qx qy qz qw"

_MAX_LISTED = 20


class TUMError(ValueError):
    """A problem with a TUM trajectory file: missing file, malformed line, non-planar pose, time order."""


def _summary(label: str, problems: list[str]) -> str:
    head = f"{label}: {len(problems)} bad line{'s' if len(problems) != 1 else ''}:"
    body = [f"  {p}" for p in problems[:_MAX_LISTED]]
    if len(problems) > _MAX_LISTED:
        body.append(f"  ... and {len(problems) - _MAX_LISTED} more")
    return "\n".join([head, *body])


def _pose_of(vals: list[float]) -> tuple[float, float, float, str | None]:
    """``(x, y, yaw, problem)`` from ``[t, tx, ty, tz, qx, qy, qz, qw]``; ``problem`` is None for a planar pose."""
    _, x, y, z, qx, qy, qz, qw = vals
    norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        return x, y, 0.0, f"quaternion (qx, qy, qz, qw) must have unit norm, its norm is {norm:.6g}"
    qx, qy, qz, qw = qx / norm, qy / norm, qz / norm, qw / norm
    tilt = 2.0 * math.asin(min(1.0, math.hypot(qx, qy)))
    if abs(z) > PLANAR_TOL_Z or tilt > PLANAR_TOL_TILT:
        why = f"pose is not planar (|z| = {abs(z):.3g} m, tilt = {tilt:.3g} rad; at most {PLANAR_TOL_Z:g} m and "
        return x, y, 0.0, why + f"{PLANAR_TOL_TILT:g} rad)"
    # yaw of R = R(q): atan2(R[1, 0], R[0, 0]), written so that it stays accurate near +-pi
    yaw = math.atan2(2.0 * (qw * qz + qx * qy), qw * qw + qx * qx - qy * qy - qz * qz)
    if yaw <= -math.pi:
        yaw += 2.0 * math.pi
    return x, y, yaw, None


def read_tum(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """Read a planar TUM trajectory: ``times (N,)`` [s] and ``poses (N, 3)`` as ``(x [m], y [m], yaw [rad])``.

    The yaw is taken from the quaternion and lies in ``(-pi, pi]``. Raises :class:`TUMError` listing every bad
    line (not 8 finite numbers, non-unit quaternion, non-planar pose, time not after the previous line's), or when
    the file is missing or holds no pose.
    """
    p = Path(path).expanduser()
    label = p.name
    if not p.is_file():
        raise TUMError(f"TUM file not found: {p}" if not p.exists() else f"TUM path {p} is not a file")
    times: list[float] = []
    poses: list[tuple[float, float, float]] = []
    problems: list[str] = []
    prev_t: tuple[float, int] | None = None
    try:
        with open(p, encoding="utf-8", errors="replace") as fh:
            for lineno, raw in enumerate(fh, start=1):
                content = raw.strip()
                if not content or content.startswith("#"):
                    continue

                def bad(problem: str, lineno: int = lineno, content: str = content) -> None:
                    problems.append(f"{label} line {lineno}: {problem}, got {shorten(content)!r}")

                parts = content.split()
                if len(parts) != 8:
                    bad(f"expected 8 numbers (timestamp tx ty tz qx qy qz qw), found {len(parts)} columns")
                    continue
                try:
                    vals = [float(s) for s in parts]
                except ValueError:
                    bad("expected 8 numbers (timestamp tx ty tz qx qy qz qw), found a non-numeric column")
                    continue
                if not all(math.isfinite(v) for v in vals):
                    bad("expected 8 finite numbers, found NaN or inf")
                    continue
                x, y, yaw, problem = _pose_of(vals)
                if problem is not None:
                    bad(problem)
                    continue
                t = vals[0]
                if prev_t is not None and t <= prev_t[0]:
                    bad(f"times must be strictly increasing, {t!r} is not after {prev_t[0]!r} (line {prev_t[1]})")
                    continue
                prev_t = (t, lineno)
                times.append(t)
                poses.append((x, y, yaw))
    except OSError as exc:
        raise TUMError(f"{label}: cannot read file ({exc.strerror or exc})") from None
    if problems:
        raise TUMError(_summary(label, problems))
    if not times:
        raise TUMError(f"{label}: no poses (every line is blank or a '#' comment)")
    return np.array(times, dtype=float), np.array(poses, dtype=float).reshape(-1, 3)


def write_tum(path: str | os.PathLike[str], times: np.ndarray, xytheta: np.ndarray) -> Path:
    """Write a planar trajectory as a TUM file (header ``# timestamp tx ty tz qx qy qz qw``).

    ``times (N,)`` [s] strictly increasing; ``xytheta (N, 3)`` as ``(x [m], y [m], theta [rad])``. Writes ``z = 0``
    and the yaw quaternion ``(0, 0, sin(theta/2), cos(theta/2))``; ``%.9f`` for times and positions, ``%.12f``
    for the quaternion (see the module doc). Returns the path written.
    """
    t = np.asarray(times, dtype=float)
    xyt = np.asarray(xytheta, dtype=float)
    if t.ndim != 1:
        raise ValueError(f"write_tum: argument 'times' must have shape (N,), got {t.shape}")
    if xyt.shape != (t.size, 3):
        raise ValueError(f"write_tum: argument 'xytheta' must have shape ({t.size}, 3), got {xyt.shape}")
    if not (np.isfinite(t).all() and np.isfinite(xyt).all()):
        raise ValueError("write_tum: 'times' and 'xytheta' must be finite")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise ValueError(f"write_tum: 'times' must be strictly increasing, times[{i}] = {t[i]!r} <= {t[i - 1]!r}")
    half = 0.5 * xyt[:, 2]
    zeros = np.zeros(t.size)
    rows = np.column_stack([t, xyt[:, 0], xyt[:, 1], zeros, zeros, zeros, np.sin(half), np.cos(half)])
    out = Path(path)
    np.savetxt(out, rows, fmt=["%.9f"] * 4 + ["%.12f"] * 4, header=HEADER, comments="# ")
    return out


def interpolate(times: np.ndarray, xytheta: np.ndarray, query: np.ndarray | float) -> np.ndarray:
    """Poses ``(len(query), 3)`` at ``query`` times [s]: ``x``, ``y`` linear, the heading linear on the unwrapped
    angle and wrapped back to ``(-pi, pi]``. Raises ValueError for a time outside ``[times[0], times[-1]]``."""
    tq = np.atleast_1d(np.asarray(query, dtype=float)).ravel()
    outside = (tq < times[0]) | (tq > times[-1]) | ~np.isfinite(tq)
    if outside.any():
        bad = float(tq[np.flatnonzero(outside)[0]])
        raise ValueError(f"time {bad:.6f} is outside the trajectory's span [{times[0]:.6f}, {times[-1]:.6f}]")
    out = np.empty((tq.size, 3))
    out[:, 0] = np.interp(tq, times, xytheta[:, 0])
    out[:, 1] = np.interp(tq, times, xytheta[:, 1])
    th = np.interp(tq, times, np.unwrap(xytheta[:, 2]))
    out[:, 2] = wrap_angle(th)
    return out


def pose7(g: np.ndarray) -> np.ndarray:
    """SE(3) pose(s) ``(..., 4, 4)`` -> ``(..., 7)`` ``(x, y, z, qx, qy, qz, qw)`` (unit quaternion, ``qw >= 0``)."""
    from scipy.spatial.transform import Rotation

    g = np.asarray(g, dtype=float)
    q = Rotation.from_matrix(g[..., :3, :3].reshape(-1, 3, 3)).as_quat().reshape(*g.shape[:-2], 4)
    q = np.where(q[..., 3:] < 0, -q, q)
    return np.concatenate([g[..., :3, 3], q], axis=-1)


def pose_from7(p: np.ndarray) -> np.ndarray:
    """``(..., 7)`` ``(x, y, z, qx, qy, qz, qw)`` -> SE(3) pose(s) ``(..., 4, 4)`` (the quaternion is normalized)."""
    from scipy.spatial.transform import Rotation

    p = np.asarray(p, dtype=float)
    R = Rotation.from_quat(p[..., 3:].reshape(-1, 4)).as_matrix().reshape(*p.shape[:-1], 3, 3)
    g = np.zeros((*p.shape[:-1], 4, 4))
    g[..., :3, :3] = R
    g[..., :3, 3] = p[..., :3]
    g[..., 3, 3] = 1.0
    return g


def write_tum3(path: str | os.PathLike[str], times: np.ndarray, poses: np.ndarray) -> Path:
    """Write a 3-D trajectory as a TUM file: ``times (N,)`` [s] strictly increasing, ``poses (N, 7)``
    ``(x, y, z, qx, qy, qz, qw)`` or ``(N, 4, 4)``. Returns the path written (what ``evo_ape tum`` reads)."""
    t = np.asarray(times, dtype=float)
    P = np.asarray(poses, dtype=float)
    if P.ndim == 3 and P.shape[1:] == (4, 4):
        P = pose7(P)
    if t.ndim != 1 or P.shape != (t.size, 7):
        raise ValueError(f"write_tum3: want times (N,) and poses (N, 7) or (N, 4, 4), got {t.shape} and {P.shape}")
    if not (np.isfinite(t).all() and np.isfinite(P).all()):
        raise ValueError("write_tum3: 'times' and 'poses' must be finite")
    if np.any(np.diff(t) <= 0):
        raise ValueError("write_tum3: 'times' must be strictly increasing")
    out = Path(path)
    np.savetxt(out, np.column_stack([t, P]), fmt=["%.9f"] * 4 + ["%.12f"] * 4, header=HEADER, comments="# ")
    return out
