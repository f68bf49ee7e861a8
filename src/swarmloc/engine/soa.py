"""Structure-of-arrays forms of the distributed EKF's kernels, generic over the array namespace ``xp``.

:mod:`swarmloc.kernels.cartesian` has two forms of each kernel: floats for one robot (what a node calls) and
stacked ``(..., 3, 3)`` matrices (``np.linalg.inv`` and ``matmul`` on 3x3 stacks: a few microseconds per robot).
Here the same formulas act on one array per matrix entry (``x = (x0, x1, x2)``, ``P = (p00, p01, p02, p11, p12,
p22)``, each ``(B,)``), written once for ``xp = numpy`` and ``xp = jax.numpy`` (under ``jax.jit`` the whole update
fuses into one loop). They follow the kernels term by term (same expressions, same order), so results agree to
rounding (tests/test_engine.py checks 1e-12 against the kernels and 1e-10 against the nodes):

* :func:`predict`: :func:`swarmloc.kernels.cartesian.predict_one` (increment of
  :func:`swarmloc.motion.odometry_increment_terms`, Taylor branches ``swarmloc.motion.SERIES``);
* :func:`pose_update`, :func:`absolute_update`, :func:`landmark_update`: a relative pose (``kind="pose"``), a GPS-like
  absolute fix or the range and bearing of a map landmark, predicted by the models the nodes use
  (:mod:`swarmloc.sensors.planar`, on ``xp``), with :func:`swarmloc.kernels.cartesian.kalman_update` (Joseph form),
  plus the gate's normalized innovation squared and the positive-definiteness test of the nodes.

Small matrices are nested lists of entries; an entry is an array or a Python float, and the products skip the
exact zeros and ones of the Jacobians (adding ``0 * a`` changes nothing for finite ``a``).
Units: metres, radians, seconds; angles wrapped to (-pi, pi].
"""

from __future__ import annotations

from typing import Any

from swarmloc.kernels.cartesian import shifted_cov, world_cov
from swarmloc.motion import UnicycleNoise
from swarmloc.motion.closed_form import series_terms, unicycle_terms
from swarmloc.sensors.planar import build

Entry = Any
"""A matrix entry: an array ``(B,)`` of the namespace in use, or a Python float constant."""
Mat = list[list[Entry]]
Vec = tuple[Entry, ...]
"""A vector of entries, one a component: a state ``(x, y, theta)``, a measurement, or a packed upper triangle."""
Updated = tuple[Vec, Vec, Entry, Entry]
"""What an update returns: ``(x+, P+ upper triangle, nis, ok)``."""
UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
"""The entries of a packed upper triangle ``(p00, p01, p02, p11, p12, p22)``, in order."""


# ------------------------------------------------------------------------------------------------ entry algebra
def _is(a: Entry, c: float) -> bool:
    return isinstance(a, float) and a == c


def mul(a: Entry, b: Entry) -> Entry:
    """``a * b`` skipping exact zeros and ones of constant entries."""
    if _is(a, 0.0) or _is(b, 0.0):
        return 0.0
    if _is(a, 1.0):
        return b
    if _is(b, 1.0):
        return a
    if _is(a, -1.0):
        return -b
    if _is(b, -1.0):
        return -a
    return a * b


def add(a: Entry, b: Entry) -> Entry:
    if _is(a, 0.0):
        return b
    if _is(b, 0.0):
        return a
    return a + b


def sub(a: Entry, b: Entry) -> Entry:
    if _is(b, 0.0):
        return a
    if _is(a, 0.0):
        return -b
    return a - b


def mm(A: Mat, B: Mat) -> Mat:
    """Matrix product, the sum over the inner index in increasing order (as ``matmul``)."""
    n, k, m = len(A), len(B), len(B[0])
    out = []
    for i in range(n):
        row = []
        for j in range(m):
            acc: Entry = 0.0
            for q in range(k):
                acc = add(acc, mul(A[i][q], B[q][j]))
            row.append(acc)
        out.append(row)
    return out


def tr(A: Mat) -> Mat:
    return [list(r) for r in zip(*A, strict=True)]


def madd(A: Mat, B: Mat) -> Mat:
    return [[add(a, b) for a, b in zip(ra, rb, strict=True)] for ra, rb in zip(A, B, strict=True)]


def msub(A: Mat, B: Mat) -> Mat:
    return [[sub(a, b) for a, b in zip(ra, rb, strict=True)] for ra, rb in zip(A, B, strict=True)]


def eye(n: int) -> Mat:
    return [[1.0 if i == j else 0.0 for j in range(n)] for i in range(n)]


def inv(A: Mat) -> Mat:
    """Inverse of a 1x1, 2x2 or 3x3 matrix by cofactors (inf/NaN where singular: the caller's ``ok`` is False)."""
    n = len(A)
    if n == 1:
        return [[1.0 / A[0][0]]]
    if n == 2:
        a, b, c, d = A[0][0], A[0][1], A[1][0], A[1][1]
        det = a * d - b * c
        return [[d / det, -b / det], [-c / det, a / det]]
    a, b, c = A[0]
    d, e, f = A[1]
    g, h, k = A[2]
    c00, c01, c02 = e * k - f * h, f * g - d * k, d * h - e * g
    det = a * c00 + b * c01 + c * c02
    r = 1.0 / det
    return [
        [c00 * r, (c * h - b * k) * r, (b * f - c * e) * r],
        [c01 * r, (a * k - c * g) * r, (c * d - a * f) * r],
        [c02 * r, (b * g - a * h) * r, (a * e - b * d) * r],
    ]


def sym3(p: Vec) -> Mat:
    """Full 3x3 matrix from its upper triangle ``(p00, p01, p02, p11, p12, p22)``."""
    p00, p01, p02, p11, p12, p22 = p
    return [[p00, p01, p02], [p01, p11, p12], [p02, p12, p22]]


def wrap(xp: Any, a: Entry) -> Entry:
    """Angle wrapped to (-pi, pi] (:func:`swarmloc.lie.wrap_angle`; :mod:`swarmloc.sensors.planar`'s)."""
    return build(xp).wrap(a)


# ------------------------------------------------------------------------------------------------ prediction
def increment_terms(xp: Any, v: Entry, w: Entry, dt: Entry, noise: UnicycleNoise) -> Vec:
    """``(cos, sin, tx, ty, S11, S12, S13, S22, S23, S33)`` of the odometry increment over ``dt`` [s] for ``(v [m/s],
    w [rad/s])``: :func:`swarmloc.motion.odometry_increment_terms`, batched (the series terms of
    :func:`swarmloc.motion.closed_form.series_terms`)."""
    q_v, q_lat, q_w = noise.diag(v, w)
    x = w * dt
    sin_x, *terms = series_terms(xp, x)
    return (xp.cos(x), sin_x, *unicycle_terms(x, dt, v, q_v, q_w, q_lat, *terms))


def predict(xp: Any, x: Vec, p: Vec, v: Entry, w: Entry, dt: Entry, noise: UnicycleNoise) -> tuple[Vec, Vec]:
    """EKF prediction of ``x = (x, y, theta)`` and ``P`` (upper triangle) over ``dt`` [s] with the command ``(v, w)``
    (:func:`swarmloc.kernels.cartesian.predict_one`); entries with ``dt <= 0`` are returned unchanged."""
    c, s, tx, ty, S11, S12, S13, S22, S23, S33 = increment_terms(xp, v, w, dt, noise)
    x0, y0, th0 = x
    ct, st = xp.cos(th0), xp.sin(th0)
    dx, dy = ct * tx - st * ty, st * tx + ct * ty
    th = wrap(xp, th0 + xp.arctan2(s, c))
    new_p = shifted_cov(p, dx, dy, world_cov(xp.cos(th), xp.sin(th), (S11, S12, S13, S22, S23, S33)))
    move = dt > 0
    new_x = (x0 + dx, y0 + dy, th)
    return (
        tuple(xp.where(move, a, b) for a, b in zip(new_x, x, strict=True)),
        tuple(xp.where(move, a, b) for a, b in zip(new_p, p, strict=True)),
    )


# ------------------------------------------------------------------------------------------------ update
def kalman(xp: Any, x: Vec, p: Vec, r: list[Entry], H: Mat, R: Mat) -> Updated:
    """:func:`swarmloc.kernels.cartesian.kalman_update` on one robot's 3-vector (angle component 2 wrapped).

    Returns ``(x+, P+ upper triangle, nis, ok)`` with ``ok`` False where the update is not finite."""
    P = sym3(p)
    Ht = tr(H)
    PHt = mm(P, Ht)
    S = madd(mm(H, PHt), R)
    Si = inv(S)
    m = len(r)
    nis: Entry = 0.0
    for i in range(m):
        acc: Entry = 0.0
        for j in range(m):
            acc = add(acc, mul(Si[i][j], r[j]))
        nis = add(nis, mul(r[i], acc))
    K = mm(PHt, Si)
    Kr = mm(K, [[a] for a in r])
    xn = [x[i] + Kr[i][0] for i in range(3)]
    xn[2] = wrap(xp, xn[2])
    IKH = msub(eye(3), mm(K, H))
    Pn = madd(mm(mm(IKH, P), tr(IKH)), mm(mm(K, R), tr(K)))
    pn = tuple(0.5 * (Pn[i][j] + Pn[j][i]) for i, j in UPPER)
    ok = xp.isfinite(nis)
    for a in (*xn, *pn):
        ok = ok & xp.isfinite(a)
    return tuple(xn), pn, nis, ok


def positive_definite(xp: Any, p: Vec) -> Entry:
    """Finite and positive definite (leading minors > 0: where a Cholesky factorization exists)."""
    p00, p01, p02, p11, p12, p22 = p
    d2 = p00 * p11 - p01 * p01
    d3 = p00 * (p11 * p22 - p12 * p12) - p01 * (p01 * p22 - p12 * p02) + p02 * (p01 * p12 - p11 * p02)
    ok = (p00 > 0) & (d2 > 0) & (d3 > 0)
    for a in p:
        ok = ok & xp.isfinite(a)
    return ok


def pose_update(xp: Any, x: Vec, p: Vec, xk: Vec, pk: Vec, z: Vec, rz: Vec) -> Updated:
    """Relative-pose update of observer ``(x, P)`` with the neighbour's ``(xk, Pk)`` and the measurement ``z =
    (x, y, theta)`` of the neighbour in the observer's frame, noise ``rz`` (exponential coordinates, upper triangle).

    ``R_eff = B(z) R B(z)^T + Hk Pk Hk^T`` (noise in Cartesian coordinates plus the neighbour's covariance), as the
    node's :func:`swarmloc.estimators.dekf.linearize`. Returns ``(x+, P+, nis, ok)`` (see :func:`kalman`)."""
    P = build(xp)
    h, Hi, Hk = P.pose(*x, *xk)
    Bz = P.rotation(z[2])
    R = mm(mm(Bz, sym3(rz)), tr(Bz))
    R_eff = madd(R, mm(mm(Hk, sym3(pk)), tr(Hk)))
    return kalman(xp, x, p, list(P.pose_residual(z, h)), Hi, R_eff)


def absolute_update(xp: Any, x: Vec, p: Vec, z: Vec, rz: Vec) -> Updated:
    """GPS-like fix ``z = (x, y, theta)`` with additive Cartesian noise ``rz`` (upper triangle): ``H = I``."""
    return kalman(xp, x, p, list(build(xp).pose_residual(z, x)), eye(3), sym3(rz))


def landmark_update(xp: Any, x: Vec, p: Vec, lk: Vec, lp: Vec, z: Vec, rz: Vec) -> Updated:
    """Range-bearing update of observer ``(x, P)`` by a map landmark at ``lk = (x, y)`` [m] with map covariance
    ``lp = (l00, l01, l11)``; ``z = (range [m], bearing [rad])``, noise ``rz = (r00, r01, r11)``: the node's
    :func:`swarmloc.estimators.dekf.linearize` with :func:`swarmloc.sensors.models.range_bearing` of a 2-D target,
    ``R_eff = R + Hk L Hk^T``. A landmark within ``MIN_RANGE`` of the observer is the caller's to reject (the
    Jacobians divide by the range). Returns ``(x+, P+, nis, ok)`` (see :func:`kalman`)."""
    P = build(xp)
    h, Hi, Hk = P.range_bearing(*x, lk[0], lk[1])
    L = [[lp[0], lp[1]], [lp[1], lp[2]]]
    R_eff = madd([[rz[0], rz[1]], [rz[1], rz[2]]], mm(mm(Hk, L), tr(Hk)))
    return kalman(xp, x, p, list(P.range_bearing_residual(z, h)), Hi, R_eff)
