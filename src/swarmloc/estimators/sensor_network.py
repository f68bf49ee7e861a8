"""Static sensor-network localization from ranges (lecture slides on multi-robot localization, slide 29).

Problem: static agents (nodes) measure the distance to some other nodes; a few nodes (anchors) have known positions.
The network is a *measurement graph* (nodes = agents, an edge = one agent measures another). Slide 29 lists the
problems solved here: check whether the graph allows a unique solution (rigidity, :func:`rigidity_report`) and
produce an estimate of the formation (:func:`localize_network`, least squares).

Conventions and units
---------------------
* Planar positions ``(x, y)`` in metres in the anchors' frame; nodes are identified by integer ids.
* A measurement is a range ``z = ||p_j - p_i|| + v`` [m] with ``v ~ N(0, std^2)`` (:class:`RangeMeasurement`, or a
  tuple ``(i, j, range, std)``). Measurements are independent; several of the same pair (``i -> j`` and ``j -> i``)
  are all used. Ranges need no frame, so the direction of the measurement does not matter. Bearings (slides 18-19,
  in the *measuring* node's frame) would add each measuring node's unknown heading; they are not handled here.
* Anchors: known positions, held fixed (not estimated); the unknowns are the positions of all other nodes, ordered
  by increasing id in :attr:`NetworkSolution.node_ids` (x, y per node in :attr:`NetworkSolution.covariance`).

Estimation: weighted nonlinear least squares ``min sum ((||p_j - p_i|| - z) / std)^2`` with
:func:`scipy.optimize.least_squares` (analytic Jacobian), covariance ``(J^T W J)^-1`` at the solution
(``W = diag(std^-2)``), chi-square of the fit with ``M - 2n`` degrees of freedom (``M`` measurements, ``n`` free
nodes). Default initialization: two starts, the fit with the lower cost is kept: MDS-MAP (classical
multidimensional scaling of the shortest-path completion of the range graph, anchor-anchor distances added as
known edges, mapped onto the anchors by the least-squares similarity: rotation, reflection, scale, translation) and
sequential multilateration from the anchors (ambiguities resolved towards the MDS-MAP positions). Either alone
ends in a local minimum (a folded part of the network) on a few per cent of random networks; see the tests.

Localizability (:func:`rigidity_report`): the grounded graph must be globally rigid with at least 3 non-collinear
anchors; the checks (on the graph and a configuration only) are in :mod:`swarmloc.estimators.network_rigidity`.
This module validates the input, initializes and solves; :class:`RigidityReport` is importable from either.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from numbers import Integral
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import shortest_path

from swarmloc.estimators.network_rigidity import RigidityReport, localizability
from swarmloc.gaussian import symmetric

__all__ = [
    "NetworkSolution",
    "RangeMeasurement",
    "RigidityReport",
    "localize_network",
    "mds_initialization",
    "rigidity_report",
]


class RangeMeasurement(NamedTuple):
    """Node ``i`` measured the distance ``range`` [m] to node ``j`` with standard deviation ``std`` [m]."""

    i: int
    j: int
    range: float
    std: float


@dataclass(frozen=True)
class NetworkSolution:
    """Least-squares positions of the non-anchor nodes.

    ``node_ids``: free node ids (increasing); ``positions``: id -> ``(2,)`` [m]; ``covariance``: ``(2n, 2n)`` [m^2]
    ordered ``(x, y)`` per node as in ``node_ids``; ``residuals``: measured minus predicted range [m] per
    measurement (input order); ``normalized_residuals``: the same divided by the std; ``chi2``: their sum of squares;
    ``dof``: ``M - 2n``; ``report``: the rigidity report at the solution; ``nfev``/``success``/``message``: from
    :func:`scipy.optimize.least_squares`.
    """

    node_ids: tuple[int, ...]
    positions: Mapping[int, np.ndarray]
    covariance: np.ndarray
    residuals: np.ndarray
    normalized_residuals: np.ndarray
    chi2: float
    dof: int
    report: RigidityReport
    nfev: int
    success: bool
    message: str

    def position_array(self) -> np.ndarray:
        """Positions ``(n, 2)`` in the order of ``node_ids``."""
        return np.array([self.positions[i] for i in self.node_ids]).reshape(-1, 2)

    def marginal(self, node: int) -> np.ndarray:
        """The ``(2, 2)`` position covariance of one free node [m^2]."""
        k = self.node_ids.index(node)
        return self.covariance[2 * k : 2 * k + 2, 2 * k : 2 * k + 2].copy()


# ---------------------------------------------------------------------------------------------------------------
# validation


def _node_id(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise ValueError(f"{what}: node id {value!r} is not an integer")
    return int(value)


def _point(value: Any, what: str) -> np.ndarray:
    try:
        p = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{what}: position {value!r} is not a pair of numbers") from exc
    if p.shape != (2,):
        raise ValueError(f"{what}: position must have shape (2,), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{what}: position {p.tolist()} is not finite")
    return p


def _anchors(anchors: Mapping[int, Any] | Iterable[tuple[int, Any]]) -> dict[int, np.ndarray]:
    items = anchors.items() if isinstance(anchors, Mapping) else anchors
    out: dict[int, np.ndarray] = {}
    for item in items:
        try:
            key, pos = item
        except (TypeError, ValueError) as exc:
            raise ValueError(f"anchor entry {item!r} is not (id, (x, y))") from exc
        k = _node_id(key, "anchor")
        if k in out:
            raise ValueError(f"duplicate anchor id {k}")
        out[k] = _point(pos, f"anchor {k}")
    return out


def _measurements(measurements: Iterable[Any], known: set[int] | None) -> list[RangeMeasurement]:
    out = []
    for n, m in enumerate(measurements):
        try:
            i, j, z, s = m
        except (TypeError, ValueError) as exc:
            raise ValueError(f"measurement {n} ({m!r}) is not (i, j, range, std)") from exc
        i, j = _node_id(i, f"measurement {n}"), _node_id(j, f"measurement {n}")
        if known is not None:
            unknown = [k for k in (i, j) if k not in known]
            if unknown:
                raise ValueError(f"measurement {n} ({i} -> {j}): unknown node id(s) {unknown}")
        if i == j:
            raise ValueError(f"measurement {n}: node {i} measures itself")
        try:
            z, s = float(z), float(s)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"measurement {n} ({i} -> {j}): range and std must be numbers") from exc
        if not np.isfinite(z) or z < 0.0:
            raise ValueError(f"measurement {n} ({i} -> {j}): range {z} must be finite and non-negative")
        if not np.isfinite(s) or s <= 0.0:
            raise ValueError(f"measurement {n} ({i} -> {j}): std {s} must be finite and positive")
        out.append(RangeMeasurement(i, j, z, s))
    if not out:
        raise ValueError("no measurements")
    return out


def _setup(
    measurements: Iterable[Any], anchors: Mapping[int, Any] | Iterable[tuple[int, Any]], nodes: Iterable[int] | None
) -> tuple[list[RangeMeasurement], dict[int, np.ndarray], tuple[int, ...]]:
    anc = _anchors(anchors)
    if nodes is not None:
        declared = [_node_id(k, "nodes") for k in nodes]
        known = set(declared) | set(anc)
    else:
        known = None
    meas = _measurements(measurements, known)
    ids = set(anc) | {k for m in meas for k in (m.i, m.j)}
    if known is not None:
        ids |= known
    free = tuple(sorted(ids - set(anc)))
    if not free:
        raise ValueError("every node is an anchor: nothing to localize")
    return meas, anc, free


def _configuration(
    positions: Mapping[int, Any], anc: dict[int, np.ndarray], free: Sequence[int], what: str
) -> dict[int, np.ndarray]:
    if not isinstance(positions, Mapping):
        raise ValueError(f"{what} must be a mapping node id -> (x, y)")
    conf: dict[int, np.ndarray] = {}
    allowed = set(free) | set(anc)
    for key, val in positions.items():
        k = _node_id(key, what)
        if k not in allowed:
            raise ValueError(f"{what}: unknown node id {k}")
        if k in anc:
            continue
        conf[k] = _point(val, f"{what} {k}")
    missing = [k for k in free if k not in conf]
    if missing:
        raise ValueError(f"{what}: no position for node(s) {missing}")
    conf.update(anc)
    return conf


# ---------------------------------------------------------------------------------------------------------------
# initialization


def mds_initialization(
    measurements: Iterable[Any],
    anchors: Mapping[int, Any] | Iterable[tuple[int, Any]],
    *,
    nodes: Iterable[int] | None = None,
) -> dict[int, np.ndarray]:
    """MDS-MAP initial positions of the free nodes: classical MDS of the shortest-path distances through the range
    graph (mean range per pair; anchor-anchor distances added as edges), then the least-squares similarity
    (rotation, reflection, scale, translation) onto the anchors. Needs every node connected to an anchor and at
    least 2 distinct anchors. Returns id -> ``(2,)`` [m] for the free nodes."""
    meas, anc, free = _setup(measurements, anchors, nodes)
    return _mds(meas, anc, free)


def _mds(meas: list[RangeMeasurement], anc: dict[int, np.ndarray], free: tuple[int, ...]) -> dict[int, np.ndarray]:
    ids = list(anc) + list(free)
    idx = {k: n for n, k in enumerate(ids)}
    N = len(ids)
    W = np.zeros((N, N))
    for (i, j), r in _mean_ranges(meas).items():
        W[idx[i], idx[j]] = W[idx[j], idx[i]] = max(r, 1e-9)
    akeys = list(anc)
    for a, ka in enumerate(akeys):
        for kb in akeys[a + 1 :]:
            d = float(np.linalg.norm(anc[ka] - anc[kb]))
            if d > 0:
                W[idx[ka], idx[kb]] = W[idx[kb], idx[ka]] = d
    D = shortest_path(csr_matrix(W), directed=False)
    if not np.all(np.isfinite(D)):
        raise ValueError("MDS initialization needs every node connected to the anchors")
    Jc = np.eye(N) - 1.0 / N
    B = -0.5 * Jc @ (D**2) @ Jc
    w, V = np.linalg.eigh(B)
    X = V[:, -2:] * np.sqrt(np.maximum(w[-2:], 0.0))
    A = np.array([anc[k] for k in akeys])
    Xa = X[: len(akeys)]
    ma, mx = A.mean(axis=0), Xa.mean(axis=0)
    H = (Xa - mx).T @ (A - ma)
    U, s, Vt = np.linalg.svd(H)
    Rm = U @ Vt
    sx = float(np.sum((Xa - mx) ** 2))
    scale = float(np.sum(s) / sx) if sx > 0 else 1.0
    Y = scale * (X - mx) @ Rm + ma
    return {k: Y[idx[k]].copy() for k in free}


def _mean_ranges(meas: list[RangeMeasurement]) -> dict[tuple[int, int], float]:
    total: dict[tuple[int, int], list[float]] = {}
    for m in meas:
        total.setdefault((min(m.i, m.j), max(m.i, m.j)), []).append(m.range)
    return {k: float(np.mean(v)) for k, v in total.items()}


def _multilateration(
    meas: list[RangeMeasurement], anc: dict[int, np.ndarray], free: tuple[int, ...], guess: Mapping[int, np.ndarray]
) -> dict[int, np.ndarray]:
    """Sequential multilateration: repeatedly place the free node with the most placed neighbours (anchors first) by
    a small least-squares fit to their ranges, started from the linearized solution (3 or more neighbours) or from
    ``guess``; with 2 placed neighbours the circle intersection nearer ``guess``, with 1 the circle point nearer it."""
    ranges = _mean_ranges(meas)
    nbr: dict[int, dict[int, float]] = {k: {} for k in list(anc) + list(free)}
    for (i, j), rij in ranges.items():
        nbr[i][j] = nbr[j][i] = rij
    placed = {k: np.asarray(v, dtype=float) for k, v in anc.items()}
    todo = set(free)
    while todo:
        k = max(sorted(todo), key=lambda c: sum(n in placed for n in nbr[c]))
        ns = [n for n in sorted(nbr[k]) if n in placed]
        g = np.asarray(guess[k], dtype=float)
        Q = np.array([placed[n] for n in ns]).reshape(-1, 2)
        r = np.array([nbr[k][n] for n in ns])
        if len(ns) >= 3:
            A = 2.0 * (Q[1:] - Q[0])
            b = np.sum(Q[1:] ** 2, axis=1) - np.sum(Q[0] ** 2) - r[1:] ** 2 + r[0] ** 2
            sv = np.linalg.svd(A, compute_uv=False)
            x0 = np.linalg.lstsq(A, b, rcond=None)[0] if sv[-1] > 1e-6 * sv[0] else g
            fit = least_squares(lambda p, Q=Q, r=r: np.linalg.norm(Q - p, axis=1) - r, x0)
            pos = fit.x
        elif len(ns) == 2:
            d = float(np.linalg.norm(Q[1] - Q[0]))
            u = (Q[1] - Q[0]) / d if d > 0 else np.array([1.0, 0.0])
            a = float(np.clip((r[0] ** 2 - r[1] ** 2 + d**2) / (2 * d), -r[0], r[0])) if d > 0 else 0.0
            h = np.sqrt(max(r[0] ** 2 - a**2, 0.0))
            perp = np.array([-u[1], u[0]])
            options = [Q[0] + a * u + h * perp, Q[0] + a * u - h * perp]
            pos = min(options, key=lambda p: float(np.linalg.norm(p - g)))
        elif len(ns) == 1:
            away = g - Q[0]
            n = float(np.linalg.norm(away))
            pos = Q[0] + r[0] * (away / n if n > 0 else np.array([1.0, 0.0]))
        else:
            pos = g
        placed[k] = pos
        todo.remove(k)
    return {k: placed[k] for k in free}


# ---------------------------------------------------------------------------------------------------------------
# rigidity


def rigidity_report(
    measurements: Iterable[Any],
    anchors: Mapping[int, Any] | Iterable[tuple[int, Any]],
    positions: Mapping[int, Any] | None = None,
    *,
    nodes: Iterable[int] | None = None,
    unique: bool = True,
) -> RigidityReport:
    """Check that a range network with anchors is localizable, naming what is wrong.

    ``measurements``: :class:`RangeMeasurement` or ``(i, j, range, std)`` items; ``anchors``: id -> ``(x, y)`` [m]
    (or ``(id, (x, y))`` pairs); ``positions``: a configuration of the free nodes (id -> ``(x, y)``) at which the
    rigidity matrix is evaluated, default :func:`mds_initialization`; ``nodes``: the declared node ids (anchors may
    be left out); a measurement naming another id is an error, and a declared node without measurement is reported
    unconnected. ``unique``: also require global rigidity (a unique solution, not only a locally unique one).

    Checks, in order: at least 3 anchors, not collinear; every free node connected to an anchor; every free node
    with at least 3 distinct measured neighbours (``unique``; 2 otherwise); infinitesimal rigidity (rank of the
    grounded rigidity matrix ``2N - 3``, flexible nodes named); then, with ``unique``, 3-connectivity of the
    grounded graph (separating pairs named) and redundant rigidity (measurements whose loss flexes the network).
    Invalid input (non-integer or unknown id, NaN, non-positive range or std, duplicate anchor) raises ValueError;
    an unlocalizable network is reported (``report.raise_if_unlocalizable()`` turns it into a ValueError).
    """
    meas, anc, free = _setup(measurements, anchors, nodes)
    conf = None if positions is None else _configuration(positions, anc, free, "positions")
    return _report(meas, anc, free, conf, unique)


def _report(
    meas: list[RangeMeasurement], anc: dict[int, np.ndarray], free: tuple[int, ...],
    conf: Mapping[int, np.ndarray] | None, unique: bool,
) -> RigidityReport:  # fmt: skip
    """:func:`localizability` of the measured pairs, at ``conf`` or else at the MDS-MAP configuration."""
    pairs = sorted({(min(m.i, m.j), max(m.i, m.j)) for m in meas})
    if conf is None:  # MDS-MAP, computed only once the early checks pass (it needs every node connected)
        return localizability(pairs, anc, free, lambda: {**_mds(meas, anc, free), **anc}, unique)
    return localizability(pairs, anc, free, conf, unique)


# ---------------------------------------------------------------------------------------------------------------
# least squares


def _residuals(
    meas: list[RangeMeasurement], free: tuple[int, ...], conf: Mapping[int, np.ndarray]
) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray], np.ndarray]:
    """``(fun, jac, w)``: the weighted residuals ``(||p_j - p_i|| - z) / std`` of the free nodes' stacked positions
    ``x`` (order of ``free``; the anchors at ``conf``), their analytic Jacobian, and the weights ``1 / std``."""
    col = {k: n for n, k in enumerate(free)}
    I = np.array([m.i for m in meas])
    J = np.array([m.j for m in meas])
    z = np.array([m.range for m in meas])
    w = 1.0 / np.array([m.std for m in meas])
    fi = np.array([col.get(k, -1) for k in I])
    fj = np.array([col.get(k, -1) for k in J])
    P0 = np.array([conf[k] for k in I])
    Q0 = np.array([conf[k] for k in J])
    rows = np.arange(len(meas))

    def points(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        X = x.reshape(-1, 2)
        P = np.where((fi >= 0)[:, None], X[np.maximum(fi, 0)], P0)
        Q = np.where((fj >= 0)[:, None], X[np.maximum(fj, 0)], Q0)
        return P, Q

    def fun(x: np.ndarray) -> np.ndarray:
        P, Q = points(x)
        r: np.ndarray = (np.linalg.norm(Q - P, axis=1) - z) * w
        return r

    def jac(x: np.ndarray) -> np.ndarray:
        P, Q = points(x)
        d = Q - P
        n = np.linalg.norm(d, axis=1)
        u = d / np.where(n > 0, n, 1.0)[:, None] * w[:, None]
        Jm = np.zeros((len(meas), x.size))
        for f, sign in ((fi, -1.0), (fj, 1.0)):
            ok = f >= 0
            Jm[rows[ok], 2 * f[ok]] += sign * u[ok, 0]
            Jm[rows[ok], 2 * f[ok] + 1] += sign * u[ok, 1]
        return Jm

    return fun, jac, w


def localize_network(
    measurements: Iterable[Any],
    anchors: Mapping[int, Any] | Iterable[tuple[int, Any]],
    initial: Mapping[int, Any] | None = None,
    *,
    nodes: Iterable[int] | None = None,
    unique: bool = True,
    xtol: float = 1e-12,
    ftol: float = 1e-12,
    gtol: float = 1e-12,
    max_nfev: int | None = None,
) -> NetworkSolution:
    """Weighted least-squares positions of the non-anchor nodes of a range network, anchors held fixed.

    Arguments as in :func:`rigidity_report`; ``initial``: id -> ``(x, y)`` [m] for every free node (entries for
    anchors are ignored). Without it, two starts are solved and the lower cost kept: :func:`mds_initialization`
    (MDS-MAP) and sequential multilateration from the anchors (each node placed from its already placed neighbours,
    ambiguities resolved towards the MDS-MAP position). The network is checked first (:func:`rigidity_report` at
    the initial, resp. MDS-MAP, configuration) and refused with a ValueError naming the problem and the nodes; the
    rank is checked again at the solution. Solved with :func:`scipy.optimize.least_squares` (trust region
    reflective, analytic Jacobian, residuals ``(||p_j - p_i|| - z) / std``); the covariance is ``(J^T W J)^-1`` at the
    solution. Tolerances and ``max_nfev`` go to ``least_squares``.
    """
    meas, anc, free = _setup(measurements, anchors, nodes)
    conf: Mapping[int, np.ndarray] | None = None if initial is None else _configuration(initial, anc, free, "initial")
    report = _report(meas, anc, free, conf, unique)
    report.raise_if_unlocalizable()
    conf = report.configuration
    assert conf is not None

    fun, jac, w = _residuals(meas, free, conf)
    starts = [np.concatenate([conf[k] for k in free])]
    if initial is None:
        lat = _multilateration(meas, anc, free, conf)
        starts.append(np.concatenate([lat[k] for k in free]))
    res = None
    for x0 in starts:
        fit = least_squares(fun, x0, jac=jac, method="trf", xtol=xtol, ftol=ftol, gtol=gtol, max_nfev=max_nfev)
        if res is None or fit.cost < res.cost:
            res = fit
    assert res is not None
    X = res.x.reshape(-1, 2)
    sol = {k: X[n].copy() for n, k in enumerate(free)}
    final = _report(meas, anc, free, {**sol, **anc}, unique)
    if final.flexible or final.rank_deficient:
        raise ValueError(
            "sensor network not localizable at the least-squares solution (no finite covariance): "
            + "; ".join(final.problems)
        )
    Jw = jac(res.x)
    _, s, Vt = np.linalg.svd(Jw, full_matrices=False)
    cov = (Vt.T / s**2) @ Vt
    cov = symmetric(cov)
    r = fun(res.x)
    return NetworkSolution(
        node_ids=free,
        positions=sol,
        covariance=cov,
        residuals=-r / w,
        normalized_residuals=-r,
        chi2=float(r @ r),
        dof=len(meas) - 2 * len(free),
        report=final,
        nfev=int(res.nfev),
        success=bool(res.success),
        message=str(res.message),
    )
