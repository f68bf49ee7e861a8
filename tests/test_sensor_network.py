"""Static sensor-network localization (range-only, anchors fixed): accuracy at the noise floor, consistency of the
Jacobian covariance (NEES, chi-square, Monte Carlo) and refusal of unlocalizable networks with the nodes named."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from swarmloc.estimators.sensor_network import (
    RangeMeasurement,
    localize_network,
    mds_initialization,
    rigidity_report,
)

pytestmark = pytest.mark.unit


N_NODES, SIDE, RMAX, STD, N_ANCHORS = 15, 10.0, 4.0, 0.05, 4
FREE = range(N_ANCHORS, N_NODES)


def _network(seed: int, noise: bool = True):
    """15 nodes uniform in 10 x 10 m (at least 0.5 m apart), ranges between all pairs within 4 m with std 0.05 m,
    nodes 0-3 anchors."""
    rng = np.random.default_rng(seed)
    pts: list[np.ndarray] = []
    while len(pts) < N_NODES:
        p = rng.uniform(0.0, SIDE, 2)
        if all(np.linalg.norm(p - q) >= 0.5 for q in pts):
            pts.append(p)
    P = np.array(pts)
    meas = []
    for i in range(N_NODES):
        for j in range(i + 1, N_NODES):
            d = float(np.linalg.norm(P[i] - P[j]))
            if d <= RMAX:
                meas.append(RangeMeasurement(i, j, d + (rng.normal(0.0, STD) if noise else 0.0), STD))
    return P, {k: P[k] for k in range(N_ANCHORS)}, meas


def _well_conditioned(seed: int) -> bool:
    """Globally rigid (rigidity_report at the truth) and well conditioned at the truth: every free node's measured
    neighbours spread at least 0.3 m (rms) across their best line (no near flip) and predicted position std at most
    0.15 m (linearization valid). Uses only the noiseless geometry."""
    P, anc, meas = _network(seed, noise=False)
    truth = {k: P[k] for k in FREE}
    if not rigidity_report(meas, anc, truth, nodes=range(N_NODES)).localizable:
        return False
    for k in FREE:
        Q = np.array([P[m.j if m.i == k else m.i] for m in meas if k in (m.i, m.j)])
        if np.linalg.svd(Q - Q.mean(axis=0), compute_uv=False)[1] / np.sqrt(len(Q)) < 0.3:
            return False
    sol = localize_network(meas, anc, truth, nodes=range(N_NODES))
    return max(np.linalg.eigvalsh(sol.marginal(k))[-1] for k in sol.node_ids) <= 0.15**2


def _seeds(n: int) -> list[int]:
    out, seed = [], 0
    while len(out) < n:
        if _well_conditioned(seed):
            out.append(seed)
        seed += 1
    return out


@pytest.fixture(scope="module")
def seeds() -> list[int]:
    return _seeds(30)


def test_noise_floor_nees_and_chi2(seeds):
    """30 random rigid networks solved from the default initialization: joint NEES, chi-square of the fits and the
    squared position error against the trace of the predicted covariance, each in its two-sided 99.9% band."""
    nees, fit, dof, err2, tr, tr2 = 0.0, 0.0, 0, 0.0, 0.0, 0.0
    for seed in seeds:
        P, anc, meas = _network(seed)
        sol = localize_network(meas, anc, nodes=range(N_NODES))
        assert sol.success and sol.node_ids == tuple(FREE)
        e = (sol.position_array() - P[N_ANCHORS:]).ravel()
        nees += float(e @ np.linalg.solve(sol.covariance, e))
        fit += sol.chi2
        dof += sol.dof
        err2 += float(e @ e)
        tr += float(np.trace(sol.covariance))
        tr2 += float(np.trace(sol.covariance @ sol.covariance))
        assert np.allclose(sol.residuals, [m.range for m in meas] - _ranges(sol, anc, meas))
        assert sol.chi2 == pytest.approx(float(np.sum(sol.normalized_residuals**2)))
    n = 2 * len(FREE) * len(seeds)
    lo, hi = chi2.ppf([0.0005, 0.9995], n)
    assert lo < nees < hi, (nees, lo, hi)
    lo, hi = chi2.ppf([0.0005, 0.9995], dof)
    assert lo < fit < hi, (fit, dof, lo, hi)
    # sum |e|^2 is a weighted sum of chi2(1) with mean tr(P) and variance 2 tr(P^2) (summed over networks)
    assert abs(err2 - tr) < 3.3 * np.sqrt(2.0 * tr2), (err2, tr, np.sqrt(2.0 * tr2))
    assert np.sqrt(err2 / n) < 2 * STD  # noise floor: rms coordinate error comparable with the range std


def _ranges(sol, anc, meas):
    pos = {**anc, **sol.positions}
    return np.array([np.linalg.norm(pos[m.j] - pos[m.i]) for m in meas])


def test_noiseless_recovers_truth(seeds):
    for seed in seeds[:5]:
        P, anc, meas = _network(seed, noise=False)
        sol = localize_network(meas, anc, nodes=range(N_NODES))
        assert np.max(np.abs(sol.position_array() - P[N_ANCHORS:])) < 1e-6
        assert sol.chi2 < 1e-12


def test_covariance_matches_monte_carlo(seeds):
    """The Jacobian covariance against the sample covariance of 1000 noise draws on one network. Whitened by the
    predicted covariance, the sample covariance is I up to sampling error: std sqrt(2/N) on the diagonal and
    sqrt(1/N) off it; the sample mean is 0 with std sqrt(1/N). Bounds at 5 of those stds (484 entries tested)."""
    P, anc, meas0 = _network(seeds[0], noise=False)
    truth = {k: P[k] for k in FREE}
    ref = localize_network(meas0, anc, truth, nodes=range(N_NODES))
    rng = np.random.default_rng(7)
    N = 1000
    errs = np.empty((N, 2 * len(FREE)))
    for n in range(N):
        meas = [m._replace(range=m.range + rng.normal(0.0, m.std)) for m in meas0]
        sol = localize_network(meas, anc, truth, nodes=range(N_NODES))
        errs[n] = (sol.position_array() - P[N_ANCHORS:]).ravel()
    L = np.linalg.cholesky(ref.covariance)
    W = np.linalg.solve(L, errs.T).T
    S = W.T @ W / N  # about the true mean 0
    assert np.max(np.abs(np.diag(S) - 1.0)) < 5 * np.sqrt(2.0 / N)
    assert np.max(np.abs(S - np.diag(np.diag(S)))) < 5 * np.sqrt(1.0 / N)
    assert np.max(np.abs(W.mean(axis=0))) < 5 * np.sqrt(1.0 / N)
    # a solution's own covariance (at its noisy estimate) is close to the one at the truth
    rel = np.linalg.norm(sol.covariance - ref.covariance) / np.linalg.norm(ref.covariance)
    assert rel < 0.1


# ---------------------------------------------------------------------------------------------------------------
# hand-made networks for the checks

ANCHORS = {0: (0.0, 0.0), 1: (6.0, 0.0), 2: (0.0, 6.0), 3: (6.0, 6.0)}
BASE = {10: (2.0, 2.0), 11: (4.0, 2.5), 12: (3.0, 4.0)}


def _ranges_between(pos: dict[int, tuple[float, float]], pairs, std=0.01):
    return [RangeMeasurement(i, j, float(np.hypot(*np.subtract(pos[j], pos[i]))), std) for i, j in pairs]


def _base_pairs():
    pairs = [(a, f) for a in ANCHORS for f in BASE]
    return pairs + [(10, 11), (10, 12), (11, 12)]


def _pos(extra=None):
    return {**ANCHORS, **BASE, **(extra or {})}


def test_base_network_is_localizable():
    meas = _ranges_between(_pos(), _base_pairs())
    rep = rigidity_report(meas, ANCHORS)
    assert rep.localizable and rep.problems == ()
    assert rep.rank == rep.expected_rank == 2 * 7 - 3
    sol = localize_network(meas, ANCHORS)
    for k, p in BASE.items():
        assert np.allclose(sol.positions[k], p, atol=1e-8)
    init = mds_initialization(meas, ANCHORS)
    assert set(init) == set(BASE)


def test_node_with_two_links_refused():
    pos = _pos({20: (5.0, 4.5)})
    meas = _ranges_between(pos, _base_pairs() + [(20, 11), (20, 12)])
    with pytest.raises(ValueError, match=r"fewer than 3 distinct measured neighbours: 20 \(2\)"):
        localize_network(meas, ANCHORS)
    # two ranges fix the node locally (not its mirror image): accepted when only local uniqueness is asked
    sol = localize_network(meas, ANCHORS, {**BASE, 20: (5.2, 4.4)}, unique=False)
    assert np.allclose(sol.positions[20], pos[20], atol=1e-8)


def test_chain_refused_naming_nodes():
    pos = _pos({20: (5.0, 4.5), 21: (5.5, 6.5)})
    meas = _ranges_between(pos, _base_pairs() + [(20, 11), (20, 21), (21, 12)])
    rep = rigidity_report(meas, ANCHORS)
    assert not rep.localizable
    assert set(rep.low_degree) == {20, 21}
    assert set(rep.flexible) == {20, 21}
    with pytest.raises(ValueError, match=r"node\(s\) \[20, 21\] are not rigidly attached"):
        localize_network(meas, ANCHORS)


def test_hinge_refused_naming_nodes():
    """A rigid triangle 20-21-22 (plus 12: a K4) attached to the rigid base only at node 12 rotates about it."""
    pos = _pos({20: (3.0, 6.0), 21: (4.5, 5.0), 22: (2.0, 5.5)})
    part = [(12, 20), (12, 21), (12, 22), (20, 21), (20, 22), (21, 22)]
    meas = _ranges_between(pos, _base_pairs() + part)
    rep = rigidity_report(meas, ANCHORS)
    assert rep.low_degree == {}  # every node has 3 neighbours: only the rank finds it
    assert rep.flexible == (20, 21, 22)
    assert rep.rank == rep.expected_rank - 1
    with pytest.raises(ValueError, match=r"not rigid \(rank 16 .* node\(s\) \[20, 21, 22\] are not rigidly"):
        localize_network(meas, ANCHORS)


def test_separating_pair_refused():
    """20-21 with 11-12 form a K4 attached through 11 and 12 only: rigid, but it can be reflected across 11-12."""
    pos = _pos({20: (5.0, 4.5), 21: (5.5, 3.0)})
    part = [(20, 11), (20, 12), (21, 11), (21, 12), (20, 21)]
    meas = _ranges_between(pos, _base_pairs() + part)
    rep = rigidity_report(meas, ANCHORS)
    assert rep.flexible == () and rep.rank == rep.expected_rank
    assert rep.separating_pairs == ((11, 12, (20, 21)),)
    with pytest.raises(ValueError, match=r"\[20, 21\] reach the anchors only through nodes 11 and 12"):
        localize_network(meas, ANCHORS)
    # with one more range to an anchor it is uniquely localizable
    meas += _ranges_between(pos, [(3, 20)])
    sol = localize_network(meas, ANCHORS)
    assert np.allclose(sol.positions[21], pos[21], atol=1e-8)


def test_not_redundantly_rigid_refused():
    """The triangular prism: anchor triangle 0-1-2 and free triangle 10-11-12 joined by 0-10, 1-11, 2-12. Every node
    has 3 neighbours, the graph is 3-connected and (minimally) rigid, but no range is redundant: it has a second
    realization (not globally rigid)."""
    anc = {0: (0.0, 0.0), 1: (6.0, 0.0), 2: (0.0, 6.0)}
    pos = {**anc, 10: (2.0, 1.5), 11: (3.5, 2.0), 12: (1.5, 3.5)}
    pairs = [(10, 11), (11, 12), (10, 12), (0, 10), (1, 11), (2, 12)]
    meas = _ranges_between(pos, pairs)
    rep = rigidity_report(meas, anc)
    assert rep.rank == rep.expected_rank == 9 and rep.flexible == () and rep.separating_pairs == ()
    assert set(rep.non_redundant) == set(pairs) | {(0, 1), (0, 2), (1, 2)}
    assert not rep.localizable
    with pytest.raises(ValueError, match=r"not redundantly rigid: the range\(s\) between node pairs .*\[0, 10\]"):
        localize_network(meas, anc)
    # one more range (a diagonal of the prism) makes it globally rigid
    meas += _ranges_between(pos, [(0, 11)])
    assert rigidity_report(meas, anc).localizable


def test_anchor_problems():
    meas = _ranges_between(_pos(), _base_pairs())
    two = {0: ANCHORS[0], 1: ANCHORS[1]}
    with pytest.raises(ValueError, match=r"too few anchors: 2 \(ids \[0, 1\]\)"):
        localize_network(meas, two)
    line = {0: (0.0, 0.0), 1: (3.0, 0.0), 2: (6.0, 0.0)}
    pos = {**line, **BASE}
    meas = _ranges_between(pos, [(a, f) for a in line for f in BASE] + [(10, 11), (10, 12), (11, 12)])
    with pytest.raises(ValueError, match=r"anchors \[0, 1, 2\] are collinear"):
        localize_network(meas, line)


def test_disconnected_nodes_named():
    pos = _pos({30: (9.0, 9.0), 31: (9.5, 8.0)})
    meas = _ranges_between(pos, _base_pairs() + [(30, 31)])
    with pytest.raises(ValueError, match=r"node\(s\) \[30, 31\] not connected to any anchor"):
        localize_network(meas, ANCHORS)
    # a declared node without any measurement
    meas = _ranges_between(_pos(), _base_pairs())
    rep = rigidity_report(meas, ANCHORS, nodes=[10, 11, 12, 40])
    assert rep.unconnected == (40,) and not rep.localizable


def test_input_validation():
    good = _ranges_between(_pos(), _base_pairs())
    with pytest.raises(ValueError, match=r"unknown node id\(s\) \[12\]"):
        localize_network(good, ANCHORS, nodes=[10, 11])
    for bad, msg in [
        ((10, 11, float("nan"), 0.1), "range nan must be finite"),
        ((10, 11, 1.0, float("nan")), "std nan must be finite and positive"),
        ((10, 11, 1.0, 0.0), "std 0.0 must be finite and positive"),
        ((10, 11, 1.0, -0.1), "std -0.1 must be finite and positive"),
        ((10, 10, 1.0, 0.1), "node 10 measures itself"),
        ((10.5, 11, 1.0, 0.1), "node id 10.5 is not an integer"),
        ((10, 11, -1.0, 0.1), "range -1.0 must be finite and non-negative"),
        ((10, 11, 1.0), "is not \\(i, j, range, std\\)"),
    ]:
        with pytest.raises(ValueError, match=msg):
            localize_network([*good, bad], ANCHORS)
    with pytest.raises(ValueError, match="duplicate anchor id 1"):
        localize_network(good, [(0, (0.0, 0.0)), (1, (6.0, 0.0)), (1, (0.0, 6.0)), (3, (6.0, 6.0))])
    with pytest.raises(ValueError, match="anchor 2: position .* not finite"):
        localize_network(good, {**ANCHORS, 2: (np.nan, 6.0)})
    with pytest.raises(ValueError, match=r"initial: no position for node\(s\) \[12\]"):
        localize_network(good, ANCHORS, {10: (2.0, 2.0), 11: (4.0, 2.5)})
    with pytest.raises(ValueError, match="initial: unknown node id 99"):
        localize_network(good, ANCHORS, {**BASE, 99: (0.0, 0.0)})
    with pytest.raises(ValueError, match="nothing to localize"):
        localize_network(_ranges_between(ANCHORS, [(0, 1)]), ANCHORS)
