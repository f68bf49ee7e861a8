"""Whether a static range network with anchors is localizable (lecture slides on multi-robot localization, slide
29): the rigidity and anchor checks behind :func:`swarmloc.estimators.sensor_network.rigidity_report`.

The network is uniquely localizable iff the *grounded* graph (the measurement graph plus edges between all anchors)
is globally rigid with at least 3 non-collinear anchors (Aspnes et al., IEEE TMC 2006). In the plane, for generic
positions, global rigidity <=> 3-connected and redundantly rigid (Jackson & Jordan 2005), and rigidity <=> the
rigidity matrix has rank ``2N - 3`` (``N`` nodes, anchors included). The ranks are computed at a configuration (the
initial one, then again at the solution), so a degenerate geometry (e.g. nodes measured only from collinear nodes)
is refused as well and told apart from a flexible graph.

This module knows only the graph (which pairs of nodes are measured) and positions; the ranges, their validation
and the estimate are :mod:`swarmloc.estimators.sensor_network`'s.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["COLLINEAR_RTOL", "RANK_RTOL", "RigidityReport", "localizability"]

RANK_RTOL = 1e-8
"""Singular values below ``RANK_RTOL`` times the largest count as zero (rows are unit vectors, so well scaled)."""
COLLINEAR_RTOL = 1e-6
"""Anchors are collinear when their second principal spread is below ``COLLINEAR_RTOL`` times the first."""


@dataclass(frozen=True)
class RigidityReport:
    """Whether a network is (uniquely) localizable, and if not why, naming the nodes.

    ``problems`` are human-readable sentences; ``localizable`` is True when there are none. The named fields list the
    offending nodes per check: ``unconnected`` (no path of measurements to an anchor), ``low_degree`` (free nodes
    with fewer than 3 distinct measured neighbours, ``{id: count}``), ``flexible`` (free nodes that can move
    infinitesimally with all ranges and anchors fixed), ``separating_pairs`` (``(a, b, nodes)``: ``nodes`` reach
    the anchors only through ``a`` and ``b`` and can be reflected across the line through them),
    ``non_redundant`` (node pairs whose measurement is needed for rigidity: without it the network flexes, so one
    range can be satisfied by two shapes). ``rank``/``expected_rank``: rank of the grounded rigidity matrix and
    ``2N - 3``; ``configuration``: positions (all nodes) where the ranks were evaluated (None when not evaluated).
    """

    localizable: bool
    problems: tuple[str, ...]
    anchor_ids: tuple[int, ...]
    free_ids: tuple[int, ...]
    unconnected: tuple[int, ...] = ()
    low_degree: Mapping[int, int] = field(default_factory=dict)
    flexible: tuple[int, ...] = ()
    separating_pairs: tuple[tuple[int, int, tuple[int, ...]], ...] = ()
    non_redundant: tuple[tuple[int, int], ...] = ()
    rank: int | None = None
    expected_rank: int | None = None
    configuration: Mapping[int, np.ndarray] | None = None

    @property
    def rank_deficient(self) -> bool:
        """True when the rank was evaluated and is below ``2N - 3`` (no finite covariance at ``configuration``)."""
        return self.rank is not None and self.expected_rank is not None and self.rank < self.expected_rank

    def raise_if_unlocalizable(self) -> None:
        """Raise ValueError listing every problem when the network is not localizable."""
        if not self.localizable:
            raise ValueError("sensor network not localizable: " + "; ".join(self.problems))


def _adjacency(pairs: Iterable[tuple[int, int]], ids: Iterable[int]) -> dict[int, set[int]]:
    adj: dict[int, set[int]] = {k: set() for k in ids}
    for i, j in pairs:
        adj[i].add(j)
        adj[j].add(i)
    return adj


def _reach(adj: Mapping[int, set[int]], start: Iterable[int], removed: frozenset[int] = frozenset()) -> set[int]:
    seen = {s for s in start if s not in removed}
    todo = deque(seen)
    while todo:
        u = todo.popleft()
        for v in adj[u]:
            if v not in seen and v not in removed:
                seen.add(v)
                todo.append(v)
    return seen


def _articulation_points(adj: Mapping[int, set[int]], removed: int) -> set[int]:
    """Cut vertices of the graph without node ``removed`` (iterative Tarjan)."""
    disc: dict[int, int] = {}
    low: dict[int, int] = {}
    cut: set[int] = set()
    t = 0
    for root in adj:
        if root == removed or root in disc:
            continue
        disc[root] = low[root] = t
        t += 1
        children = 0
        stack = [(root, -1, iter(adj[root]))]
        while stack:
            u, parent, it = stack[-1]
            advanced = False
            for v in it:
                if v == removed:
                    continue
                if v not in disc:
                    disc[v] = low[v] = t
                    t += 1
                    if u == root:
                        children += 1
                    stack.append((v, u, iter(adj[v])))
                    advanced = True
                    break
                if v != parent:
                    low[u] = min(low[u], disc[v])
            if advanced:
                continue
            stack.pop()
            if stack:
                p = stack[-1][0]
                low[p] = min(low[p], low[u])
                if p != root and low[u] >= disc[p]:
                    cut.add(p)
        if children > 1:
            cut.add(root)
    return cut


def _rigidity_rows(
    pairs: Sequence[tuple[int, int]], conf: Mapping[int, np.ndarray], col: Mapping[int, int], ncol: int
) -> np.ndarray:
    """Rigidity matrix with unit-vector rows (columns 2*col[k], 2*col[k]+1 for nodes in ``col``)."""
    R = np.zeros((len(pairs), ncol))
    for r, (i, j) in enumerate(pairs):
        d = conf[j] - conf[i]
        n = np.linalg.norm(d)
        u = d / n if n > 0 else np.zeros(2)
        if i in col:
            R[r, 2 * col[i] : 2 * col[i] + 2] = -u
        if j in col:
            R[r, 2 * col[j] : 2 * col[j] + 2] = u
    return R


def _svd_rank(R: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    U, s, Vt = np.linalg.svd(R, full_matrices=True)
    rank = int(np.sum(s > RANK_RTOL * s[0])) if s.size and s[0] > 0 else 0
    return rank, U, s, Vt


def _flexible_nodes(
    pairs: Sequence[tuple[int, int]], conf: Mapping[int, np.ndarray], free: tuple[int, ...]
) -> tuple[int, ...]:
    """Free nodes that move in some infinitesimal motion keeping ranges and anchors fixed."""
    col = {k: n for n, k in enumerate(free)}
    R = _rigidity_rows(pairs, conf, col, 2 * len(free))
    rank, _, _, Vt = _svd_rank(R)
    null = Vt[rank:].T.reshape(len(free), 2, -1)
    move = np.sqrt(np.sum(null**2, axis=(1, 2)))
    return tuple(k for k, m in zip(free, move, strict=True) if m > 1e-6)


# ---------------------------------------------------------------------------------------------------------------
# the checks


def localizability(
    pairs: Sequence[tuple[int, int]],
    anchors: Mapping[int, np.ndarray],
    free: tuple[int, ...],
    configuration: Mapping[int, np.ndarray] | Callable[[], Mapping[int, np.ndarray]],
    unique: bool = True,
) -> RigidityReport:
    """The checks of :func:`swarmloc.estimators.sensor_network.rigidity_report` on validated input.

    ``pairs``: the measured node pairs ``(i, j)``, ``i < j``, sorted, each once; ``anchors``: id -> ``(2,)``;
    ``free``: the other node ids, sorted; ``configuration``: positions of all nodes (anchors included) at which the
    ranks are evaluated, or a function returning them, called only once the anchors are usable and every node is
    connected to them (an initialization such as MDS-MAP needs that).
    """
    anc = anchors
    problems: list[str] = []
    anchor_ids = tuple(sorted(anc))
    ids = anchor_ids + free
    pairs = list(pairs)
    anchors_ok, unconnected, low = _anchor_and_degree_checks(_adjacency(pairs, ids), anc, free, unique, problems)
    if not anchors_ok or unconnected:
        return RigidityReport(False, tuple(problems), anchor_ids, free, low_degree=low, unconnected=unconnected)

    conf = configuration() if callable(configuration) else configuration
    akeys = sorted(anc)
    virtual = [(a, b) for n, a in enumerate(akeys) for b in akeys[n + 1 :]]
    grounded = pairs + virtual
    rank, expected, U, flexible = _rank_checks(pairs, grounded, conf, ids, free, problems)
    seps: list[tuple[int, int, tuple[int, ...]]] = []
    nonred: tuple[tuple[int, int], ...] = ()
    if unique and not flexible:
        seps = _separating_pairs(_adjacency(grounded, ids), ids, anc, free, low)
        for a, b, cut in seps:
            problems.append(
                f"node(s) {list(cut)} reach the anchors only through nodes {a} and {b}: they can be reflected "
                "across the line through them (the graph is not 3-connected)"
            )
        if not seps and rank == expected:
            stresses = U[:, rank:]
            nonred = tuple(
                grounded[r]
                for r in range(len(grounded))
                if stresses.shape[1] == 0 or np.max(np.abs(stresses[r])) < 1e-8
            )
            if nonred:
                problems.append(
                    f"not redundantly rigid: the range(s) between node pairs {[list(p) for p in nonred]} are each "
                    "needed for rigidity (anchor pairs count as known ranges), so the network may have another shape "
                    "that fits all ranges"
                )
    return RigidityReport(
        not problems,
        tuple(problems),
        anchor_ids,
        free,
        unconnected=unconnected,
        low_degree=low,
        flexible=flexible,
        separating_pairs=tuple(seps),
        non_redundant=nonred,
        rank=rank,
        expected_rank=expected,
        configuration={k: np.array(v) for k, v in conf.items()},
    )


def _anchor_and_degree_checks(
    adj: Mapping[int, set[int]],
    anc: Mapping[int, np.ndarray],
    free: tuple[int, ...],
    unique: bool,
    problems: list[str],
) -> tuple[bool, tuple[int, ...], dict[int, int]]:
    """``(anchors usable, unconnected free nodes, {low-degree free node: degree})``; problems appended."""
    anchors_ok = True
    if len(anc) < 3:
        anchors_ok = False
        problems.append(
            f"too few anchors: {len(anc)} (ids {sorted(anc)}); a unique planar frame needs at least 3 non-collinear"
        )
    else:
        A = np.array(list(anc.values()))
        s = np.linalg.svd(A - A.mean(axis=0), compute_uv=False)
        if s[0] == 0 or s[1] <= COLLINEAR_RTOL * s[0]:
            anchors_ok = False
            problems.append(
                f"anchors {sorted(anc)} are collinear (or coincide): the network can be reflected across their line"
            )

    unconnected: tuple[int, ...] = ()
    if anc:
        reached = _reach(adj, anc)
        unconnected = tuple(k for k in free if k not in reached)
        if unconnected:
            problems.append(f"node(s) {list(unconnected)} not connected to any anchor by measurements")
    need = 3 if unique else 2
    low = {k: len(adj[k]) for k in free if len(adj[k]) < need and k not in unconnected}
    if low:
        listed = ", ".join(f"{k} ({n})" for k, n in low.items())
        problems.append(
            f"node(s) with fewer than {need} distinct measured neighbours: {listed}"
            + ("; 2 ranges leave a mirror ambiguity" if unique else "")
        )
    return anchors_ok, unconnected, low


def _rank_checks(
    pairs: Sequence[tuple[int, int]], grounded: Sequence[tuple[int, int]], conf: Mapping[int, np.ndarray],
    ids: tuple[int, ...], free: tuple[int, ...], problems: list[str],
) -> tuple[int, int, np.ndarray, tuple[int, ...]]:  # fmt: skip
    """``(rank, 2N - 3, U of the SVD, flexible free nodes)`` of the grounded rigidity matrix at ``conf``; a rank
    deficit is told apart as a flexible graph or a degenerate geometry (problems appended)."""
    col = {k: n for n, k in enumerate(ids)}
    Rg = _rigidity_rows(grounded, conf, col, 2 * len(ids))
    rank, U, _, _ = _svd_rank(Rg)
    expected = 2 * len(ids) - 3
    flexible: tuple[int, ...] = ()
    if rank < expected:
        flexible = _flexible_nodes(pairs, conf, free)
        generic = _generic_rank(grounded, ids)
        if generic < expected:
            problems.append(
                f"the network is not rigid (rank {rank} of the rigidity matrix < 2N-3 = {expected}): node(s) "
                f"{list(flexible)} are not rigidly attached to the anchors (they can move keeping all ranges)"
            )
        else:
            problems.append(
                f"degenerate geometry: the rigidity matrix has rank {rank} < 2N-3 = {expected} at this configuration "
                f"(the graph is generically rigid; e.g. collinear neighbours); node(s) {list(flexible)} are not "
                "determined to first order"
            )
    return rank, expected, U, flexible


def _separating_pairs(
    gadj: Mapping[int, set[int]], ids: tuple[int, ...], anc: Mapping[int, np.ndarray], free: tuple[int, ...],
    low: Mapping[int, int],
) -> list[tuple[int, int, tuple[int, ...]]]:  # fmt: skip
    """``(a, b, nodes)``: ``nodes`` (not all of low degree, reported already) reach the anchors only through the
    nodes ``a`` and ``b`` of the grounded graph ``gadj``."""
    seps: list[tuple[int, int, tuple[int, ...]]] = []
    for v in ids:
        for a in _articulation_points(gadj, v):
            pair = (min(v, a), max(v, a))
            if any(p[:2] == pair for p in seps):
                continue
            rest = _reach(gadj, anc, frozenset(pair))
            cut = tuple(k for k in free if k not in rest and k not in pair)
            if cut and not set(cut) <= set(low):
                seps.append((pair[0], pair[1], cut))
    return seps


def _generic_rank(pairs: Sequence[tuple[int, int]], ids: tuple[int, ...]) -> int:
    rng = np.random.default_rng(12345)
    conf = {k: rng.uniform(-1.0, 1.0, 2) for k in ids}
    col = {k: n for n, k in enumerate(ids)}
    return _svd_rank(_rigidity_rows(pairs, conf, col, 2 * len(ids)))[0]
