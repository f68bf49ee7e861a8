"""Association policies (swarmloc.association.policies) against independent computations: finite-difference
innovation covariances, Monte Carlo chi-square statistics of true associations, and brute-force enumeration of the
joint assignment (lecture slides 38-39, eqs. 8-9)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.stats import chi2, multivariate_normal

from swarmloc.association import AMBIGUOUS, CLUTTER, gate_threshold, innovation_terms, joint, likely_rivals, nearest
from swarmloc.sensors.models import MODELS

pytestmark = pytest.mark.unit


def _h(kind: str, xo: np.ndarray, xt: np.ndarray) -> np.ndarray:
    """The measurement written out by hand (independent of sensors.models)."""
    dx, dy = xt[0] - xo[0], xt[1] - xo[1]
    c, s = np.cos(xo[2]), np.sin(xo[2])
    bx, by = c * dx + s * dy, -s * dx + c * dy
    if kind == "range_bearing":
        return np.array([np.hypot(bx, by), np.arctan2(by, bx)])
    if kind == "pose":
        return np.array([bx, by, np.angle(np.exp(1j * (xt[2] - xo[2])))])
    if kind == "range":
        return np.array([np.hypot(bx, by)])
    return np.array([np.arctan2(by, bx)])


def _wrap(kind: str, r: np.ndarray) -> np.ndarray:
    ang = np.array(MODELS[kind].angular)
    return np.where(ang, np.angle(np.exp(1j * r)), r)


def _jac(kind: str, xo: np.ndarray, xt: np.ndarray, which: int, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for j in range(3):
        d = np.zeros(3)
        d[j] = eps
        a, b = (xo + d, xt) if which == 0 else (xo, xt + d)
        a2, b2 = (xo - d, xt) if which == 0 else (xo, xt - d)
        cols.append(_wrap(kind, _h(kind, a, b) - _h(kind, a2, b2)) / (2 * eps))
    return np.stack(cols, axis=-1)


def _spd(rng: np.random.Generator, scale: np.ndarray) -> np.ndarray:
    A = rng.normal(size=(3, 3)) * 0.3
    return np.diag(scale) + A @ A.T * scale.min()


@pytest.mark.parametrize("kind", ["range_bearing", "range", "bearing", "pose"])
def test_innovation_distances_equal_a_finite_difference_computation(kind):
    rng = np.random.default_rng(1)
    k = MODELS[kind].size
    xo, Po = np.array([0.3, -0.2, 0.4]), _spd(rng, np.array([0.02, 0.03, 0.01]))
    xt = rng.uniform(-4, 4, size=(5, 3))
    Pt = np.stack([_spd(rng, np.array([0.05, 0.04, 0.02])) for _ in range(5)])
    z = rng.normal(size=(4, k)) * 0.5 + np.stack([_h(kind, xo, xt[i]) for i in range(4)])
    z[:, 0] = np.abs(z[:, 0]) if kind in ("range", "range_bearing") else z[:, 0]
    R = np.stack([np.eye(k) * 0.01 * (i + 1) for i in range(4)])
    got = innovation_terms(kind, z, R, xo, Po, xt, Pt)[0]
    want = np.empty((4, 5))
    for i, j in itertools.product(range(4), range(5)):
        Hi, Hj = _jac(kind, xo, xt[j], 0), _jac(kind, xo, xt[j], 1)
        Rc = MODELS[kind].noise(z[i], R[i])  # a pose's noise is given in exponential coordinates
        S = Hi @ Po @ Hi.T + Hj @ Pt[j] @ Hj.T + Rc
        r = _wrap(kind, z[i] - _h(kind, xo, xt[j]))
        want[i, j] = r @ np.linalg.solve(S, r)
    np.testing.assert_allclose(got, want, rtol=1e-6)


@pytest.mark.parametrize("kind", ["range_bearing", "pose"])
def test_innovation_distances_with_cross_covariances_are_the_joint_innovations(kind):
    """With ``cross`` (a joint filter's observer-candidate covariances) a cost is ``r^T S^-1 r`` with ``S = H P H^T +
    R``, ``H = [H_i, H_j]`` and ``P`` the pair's joint covariance (finite-difference Jacobians); the blocks are not
    symmetric, so a transposed ``cross`` would fail."""
    rng = np.random.default_rng(2)
    k = MODELS[kind].size
    A = rng.normal(size=(18, 18)) * 0.1
    P = A @ A.T + np.eye(18) * 0.01  # observer, then 5 candidates: one joint covariance
    xo, xt = np.array([0.3, -0.2, 0.4]), rng.uniform(-4, 4, size=(5, 3))
    Pt = np.stack([P[3 * j + 3 : 3 * j + 6, 3 * j + 3 : 3 * j + 6] for j in range(5)])
    C = np.stack([P[:3, 3 * j + 3 : 3 * j + 6] for j in range(5)])
    z = rng.normal(size=(3, k)) * 0.3 + np.stack([_h(kind, xo, xt[i]) for i in range(3)])
    R = np.stack([np.eye(k) * 0.01 * (i + 1) for i in range(3)])
    got = innovation_terms(kind, z, R, xo, P[:3, :3], xt, Pt, cross=C)[0]
    for i, j in itertools.product(range(3), range(5)):
        H = np.hstack([_jac(kind, xo, xt[j], 0), _jac(kind, xo, xt[j], 1)])
        Pj = P[np.r_[0:3, 3 * j + 3 : 3 * j + 6]][:, np.r_[0:3, 3 * j + 3 : 3 * j + 6]]
        r = _wrap(kind, z[i] - _h(kind, xo, xt[j]))
        S = H @ Pj @ H.T + MODELS[kind].noise(z[i], R[i])
        np.testing.assert_allclose(got[i, j], r @ np.linalg.solve(S, r), rtol=1e-6)
    assert not np.allclose(got, innovation_terms(kind, z, R, xo, P[:3, :3], xt, Pt)[0])  # the cross terms count here


def test_the_true_associations_cost_is_chi_square_with_the_measurements_dof():
    """Monte Carlo: draw the observer's and the target's true states from their beliefs and a noisy range-bearing
    detection; the squared distance to the true target is chi-square(2) (mean 2, 99% gate passed 99% of the time).
    With the slides' P_jj alone (mapped into measurement space) it is not: it leaves out the observer's uncertainty
    and the sensor noise, and its mean is far above 2, so a chi-square gate on it refuses true associations."""
    rng = np.random.default_rng(7)
    xo, Po = np.array([0.0, 0.0, 0.1]), np.diag([0.01, 0.01, 0.002])
    xt, Pt = np.array([[3.0, 1.0, 0.5]]), np.diag([0.02, 0.03, 0.01])[None]
    R = np.diag([0.05**2, 0.02**2])
    n = 20000
    d2, d2_pjj = np.empty(n), np.empty(n)
    Hj = _jac("range_bearing", xo, xt[0], 1)
    for s in range(n):
        o = rng.multivariate_normal(xo, Po)
        t = rng.multivariate_normal(xt[0], Pt[0])
        z = _h("range_bearing", o, t) + rng.multivariate_normal(np.zeros(2), R)
        d2[s] = innovation_terms("range_bearing", z[None], R[None], xo, Po, xt, Pt)[0][0, 0]
        r = _wrap("range_bearing", z - _h("range_bearing", xo, xt[0]))
        d2_pjj[s] = r @ np.linalg.solve(Hj @ Pt[0] @ Hj.T, r)  # eq. 8 as printed: the target's covariance only
    se = np.sqrt(2 * 2 / n)  # standard error of the mean of chi2(2)
    assert abs(d2.mean() - 2.0) < 5 * se + 0.03  # 0.03: first-order linearization
    assert abs(np.mean(d2 <= gate_threshold(2, 0.99)) - 0.99) < 0.005
    assert d2_pjj.mean() > 3.0


def _brute_force(c: np.ndarray, gate: float) -> float:
    """The least total cost over every partial injective assignment, clutter at ``gate`` each."""
    m, n = c.shape
    best = np.inf
    for ident in itertools.product([-1, *range(n)], repeat=m):
        used = [j for j in ident if j >= 0]
        if len(used) != len(set(used)) or any(c[i, j] > gate for i, j in enumerate(ident) if j >= 0):
            continue
        best = min(best, sum(gate if j < 0 else c[i, j] for i, j in enumerate(ident)))
    return best


def test_joint_assignment_is_the_optimum_of_eq_9_with_clutter():
    rng = np.random.default_rng(3)
    gate = 9.21
    for _ in range(200):
        m, n = rng.integers(1, 5), rng.integers(1, 5)
        c = rng.exponential(6.0, size=(m, n))
        c[rng.random(size=(m, n)) < 0.1] = np.inf
        a = joint(c, gate)
        used = a.identity[a.identity >= 0]
        assert len(used) == len(set(used.tolist()))
        total = sum(gate if j < 0 else c[i, j] for i, j in enumerate(a.identity))
        assert total == pytest.approx(_brute_force(c, gate), abs=1e-9)
        assert np.all(np.isnan(a.cost[a.identity < 0]))


def test_nearest_gates_and_refuses_ambiguity_joint_resolves_the_conflict():
    # two detections both nearest to robot 0; robot 1 explains the second almost as well
    c = np.array([[0.5, 30.0, 50.0], [1.0, 1.5, 40.0], [20.0, 25.0, 30.0]])
    gate = gate_threshold(2, 0.99)  # 9.21
    a = nearest(c, gate)
    assert a.identity.tolist() == [0, 0, CLUTTER]  # the relaxed solution: robot 0 twice
    assert nearest(c, gate, ambiguity=1.0).identity.tolist() == [0, AMBIGUOUS, CLUTTER]
    b = joint(c, gate, expected=np.array([True, True, True]))
    assert b.identity.tolist() == [0, 1, CLUTTER]
    assert b.counts() == {"associated": 2, "clutter": 1, "ambiguous": 0, "missed": 1}
    assert b.missed.tolist() == [2]


@pytest.mark.parametrize("kind", ["range_bearing", "pose"])
def test_innovation_terms_are_the_gaussian_likelihood_of_each_robot(kind):
    """``d2 + ln det S`` is ``-2 ln p(z | j) - k ln 2 pi``, the innovation's Gaussian density (scipy's, with ``S``
    built from finite-difference Jacobians as above)."""
    rng = np.random.default_rng(3)
    k = MODELS[kind].size
    xo, Po = np.array([0.3, -0.2, 0.4]), _spd(rng, np.array([0.02, 0.03, 0.01]))
    xt = rng.uniform(-4, 4, size=(4, 3))
    Pt = np.stack([_spd(rng, np.array([0.05, 0.04, 0.02]) * (1 + 20 * j)) for j in range(4)])  # spreads apart
    z = rng.normal(size=(3, k)) * 0.3 + np.stack([_h(kind, xo, xt[i]) for i in range(3)])
    R = np.stack([np.eye(k) * 0.01 * (i + 1) for i in range(3)])
    d2, logdet = innovation_terms(kind, z, R, xo, Po, xt, Pt)
    for i, j in itertools.product(range(3), range(4)):
        Hi, Hj = _jac(kind, xo, xt[j], 0), _jac(kind, xo, xt[j], 1)
        S = Hi @ Po @ Hi.T + Hj @ Pt[j] @ Hj.T + MODELS[kind].noise(z[i], R[i])
        r = _wrap(kind, z[i] - _h(kind, xo, xt[j]))
        logpdf = multivariate_normal(np.zeros(k), S).logpdf(r)
        np.testing.assert_allclose(d2[i, j] + logdet[i, j], -2 * logpdf - k * np.log(2 * np.pi), rtol=1e-6)


def test_a_detection_a_well_known_robot_explains_better_is_not_given_a_lost_one():
    """Dataset 1's case: a robot 1.2 m uncertain is inside the gate (8.4), the robot truly seen, known to 5 cm,
    just outside it (10.9). By the squared distance alone the lost robot gets the detection (and jumps metres); by
    the likelihood the known robot explains it e^1.4 times better, so the detection is refused as ambiguous. The
    rule is the density ratio (scipy) against ``exp(-ambiguity / 2)``, whichever robot is given."""
    kind, rng = "range_bearing", np.random.default_rng(4)
    xo, Po = np.array([0.0, 0.0, 0.0]), np.diag([0.05, 0.05, 0.02]) ** 2
    xt = np.array([[3.0, -1.6, 0.0], [2.25, -2.25, 0.0]])  # robot 0 seen (known), robot 1 lost
    Pt = np.stack([np.diag([0.06, 0.05, 0.04]) ** 2, np.diag([0.12, 1.2, 0.17]) ** 2])
    z, R = np.array([[3.25, -0.6]]), np.diag([0.1, 0.02])[None] ** 2
    d2, logdet = innovation_terms(kind, z, R, xo, Po, xt, Pt)
    gate = gate_threshold(2, 0.99)
    assert d2[0, 1] < gate < d2[0, 0], d2  # the lost robot in the gate, the seen one out
    for policy in (nearest(d2, gate, 2.0), joint(d2, gate, ambiguity=2.0)):
        assert policy.identity.tolist() == [1]
    for policy in (nearest(d2, gate, 2.0, logdet=logdet), joint(d2, gate, ambiguity=2.0, logdet=logdet)):
        assert policy.identity.tolist() == [AMBIGUOUS]
    for _ in range(200):  # random costs and spreads: refused exactly when a rival's density is within the ratio
        c, ld = rng.uniform(0, 12, size=(1, 3)), rng.uniform(-8, 2, size=(1, 3))
        ident = nearest(c, gate).identity
        got = likely_rivals(c, ld, ident, 2.0)
        if ident[0] < 0:
            assert got.tolist() == ident.tolist()
            continue
        dens = np.exp(-(c[0] + ld[0]) / 2)  # proportional to each robot's density of z
        rivals = np.delete(dens, ident[0])
        assert (got[0] == AMBIGUOUS) == bool(np.any(rivals > dens[ident[0]] * np.exp(-1.0))), (c, ld)
    with pytest.raises(ValueError, match="logdet must be finite"):
        likely_rivals(d2, logdet[:, :1], np.array([1]), 2.0)


def test_bad_input_is_refused_with_a_reason():
    with pytest.raises(ValueError, match="non-negative, no NaN"):
        joint(np.array([[np.nan]]), 9.0)
    with pytest.raises(ValueError, match="gate must be positive"):
        nearest(np.zeros((1, 1)), 0.0)
    with pytest.raises(ValueError, match="not kind 'absolute'"):
        innovation_terms("absolute", np.zeros((1, 3)), np.eye(3)[None], np.zeros(3), np.eye(3), np.zeros((1, 3)),
                         np.eye(3)[None])  # fmt: skip
    with pytest.raises(ValueError, match="gate probability"):
        gate_threshold(2, 1.0)
    on_top, spread = innovation_terms("range_bearing", np.array([[1.0, 0.0]]), np.eye(2)[None] * 0.01, np.zeros(3),
                                      np.eye(3) * 0.01, np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
                                      np.stack([np.eye(3) * 0.01] * 2))  # fmt: skip
    assert spread[0, 0] == 0.0 and np.isfinite(spread).all()  # the robot on top: no spread, its cost inf
    assert on_top[0, 0] == np.inf and on_top[0, 1] == pytest.approx(0.0)
    assert joint(on_top, 9.0).identity.tolist() == [1]
    assert joint(np.zeros((0, 3)), 9.0).identity.size == 0
    assert nearest(np.zeros((2, 0)), 9.0).identity.tolist() == [CLUTTER, CLUTTER]
    assert chi2.ppf(0.99, 2) == pytest.approx(gate_threshold(2))


# ---------------------------------------------------------------------------------------- anonymous detections
def _source(robots: int, duration: float, seed: int):
    from swarmloc.experiments.sources import load_source

    return load_source("sim:random", robots=robots, duration=duration, seed=seed)


def _run(src, events, **opts):
    from swarmloc.estimators import make_team, node_options
    from swarmloc.runner import run

    base = node_options("cekf", src.config, src.landmarks, src.t_start)
    return run(make_team("cekf", src.initial, **{**base, **opts}), events, src.record_times(), src.truth)


def _accuracy(res) -> tuple[int, int]:
    right = sum(v for k, v in res.reasons.items() if "association right" in k or "(right)" in k)
    wrong = sum(v for k, v in res.reasons.items() if "association wrong" in k or "(wrong)" in k)
    return right, wrong


def test_anonymize_hides_ids_misses_and_clutters_as_told():
    from swarmloc.events import Detection
    from swarmloc.sim.anonymous import anonymize

    src = _source(4, 30.0, 0)
    tagged = [e for e in src.events if isinstance(e, Detection)]
    scans = {(d.observer, d.t) for d in tagged}
    out = anonymize(src.events, p_detect=0.8, clutter=2.0, seed=3)
    again = anonymize(src.events, p_detect=0.8, clutter=2.0, seed=3)  # same seed, same events
    assert len(again) == len(out)
    assert all(a is b or np.array_equal(a.z, b.z) for a, b in zip(out, again, strict=True))
    dets = [e for e in out if isinstance(e, Detection)]
    assert all(d.target is None for d in dets)
    real = [d for d in dets if d.truth_target != -1]
    clutter = [d for d in dets if d.truth_target == -1]
    assert {(d.observer, d.t, d.truth_target) for d in real} <= {(d.observer, d.t, d.target) for d in tagged}
    n = len(tagged)
    assert abs(len(real) / n - 0.8) < 4 * np.sqrt(0.8 * 0.2 / n)
    assert abs(len(clutter) / len(scans) - 2.0) < 4 * np.sqrt(2.0 / len(scans))
    assert len(out) - len(dets) == len(src.events) - n  # odometry (and anything else) unchanged
    for bad in ({"p_detect": 1.5}, {"clutter": -1.0}, {"max_range": np.inf}, {"fov": 0.0}):
        with pytest.raises(ValueError):
            anonymize(src.events, **bad)


def test_joint_association_of_anonymous_detections_equals_the_tagged_run_when_every_identity_is_right():
    """cekf with ``association="joint"`` on the same detections without their ids: where every association is right
    the beliefs are the tagged run's, bit for bit (the choice predicts a copy of the state, not the filter's own).
    A wide association gate, so that none is refused: at 0.99 the joint's innovations leave out 3 of 190 true ones,
    about the 1 % the gate is for (the filter's own gate, 0.997, refuses one of them in both runs)."""
    from swarmloc.sim.anonymous import anonymize

    src = _source(3, 30.0, 0)
    tagged = _run(src, src.events)
    anon = _run(src, anonymize(src.events), association="joint", association_gate=1 - 1e-12)
    assert _accuracy(anon) == (190, 0)
    for r in tagged.tracks:
        np.testing.assert_array_equal(anon.tracks[r].mean, tagged.tracks[r].mean)
        np.testing.assert_array_equal(anon.tracks[r].cov, tagged.tracks[r].cov)


@pytest.mark.parametrize("est", ["cekf", "iekf", "fej"])
def test_a_centralized_filter_weighs_the_choice_with_the_covariance_of_its_update(est):
    """Robot 1 has ranged robot 2 precisely five times: their relative pose is known far better than their marginals
    say (a strong cross-covariance). A detection of robot 3 (believed 1.1 m off) then looks like robot 2 from the
    marginals, by more than the ambiguity margin; the cost with the joint's cross-covariances -- the innovation
    covariance the update weighs -- rules robot 2 out and gives robot 3, which the update then fuses. (Marginals
    alone: robot 2 is chosen and the filter's own gate refuses it: the choice and the update disagreed.)"""
    from swarmloc.config import DEFAULTS
    from swarmloc.estimators import make_team, node_options
    from swarmloc.events import Detection
    from swarmloc.gaussian import GroupGaussian
    from swarmloc.lie import SE2
    from swarmloc.runner import run

    def rb(x: float, y: float) -> np.ndarray:  # range and bearing from robot 1 at the origin, heading 0
        return np.array([np.hypot(x, y), np.arctan2(y, x)])

    cov = np.eye(3) * 0.3**2
    believed = {1: (0.0, 0.0), 2: (2.0, 0.0), 3: (2.0, 1.9)}
    initial = {r: GroupGaussian(SE2, SE2.from_xytheta(*xy, 0.0), cov) for r, xy in believed.items()}
    R = np.diag([0.02**2, 0.01**2])
    events = [Detection(1, 0.1 * k, "range_bearing", rb(2.0, 0.0), R, target=2) for k in range(1, 6)]
    events.append(Detection(1, 0.6, "range_bearing", rb(2.0, 0.8), R, truth_target=3))  # robot 3 is at (2, 0.8)
    res = run(make_team(est, initial, **node_options(est, DEFAULTS, None, 0.0), association="nearest"), events, [0.7])
    assert dict(res.reasons) == {"fused: association right": 1} and res.stats["fused"] == 6


def test_under_clutter_and_misses_the_policies_keep_identities_and_consistency():
    from swarmloc.evaluation.metrics import anees_bounds, evaluate
    from swarmloc.sim.anonymous import anonymize

    src = _source(5, 40.0, 1)
    events = anonymize(src.events, p_detect=0.9, clutter=1.0, seed=2)
    refused = _run(src, events)  # tags: an anonymous detection is refused, never fused as if tagged
    assert refused.stats["fused"] == 0
    assert refused.reasons["rejected: robot detection without a target id"] == refused.stats["detections"]
    for policy in ("nearest", "joint"):
        res = _run(src, events, association=policy)
        s = res.stats
        assert s["detections"] == s["fused"] + s["gated"] + s["rejected"] + s["unknown"]
        right, wrong = _accuracy(res)
        assert right + wrong + res.reasons.get("rejected: association: ambiguous", 0) == s["detections"]
        assert right / (right + wrong) > 0.98, (policy, right, wrong)
        team = evaluate(res)["team"]
        lo, hi = anees_bounds(team["n"])
        assert 0.5 < team["anees"] < 2.0, (policy, team["anees"], lo, hi)


def test_association_options_are_checked():
    src = _source(2, 5.0, 0)
    with pytest.raises(ValueError, match="association must be one of"):
        _run(src, src.events, association="psychic")
    with pytest.raises(ValueError, match="gate probability"):
        _run(src, src.events, association="joint", association_gate=1.0)
    from swarmloc.estimators import DistributedEKF, make_team, node_options

    class Tagged(DistributedEKF):  # an estimator that declares it cannot associate (none of ESTIMATORS does)
        name = "tagged"
        associates = False

    with pytest.raises(ValueError, match="not supported by tagged"):
        make_team(Tagged, src.initial, **node_options("dekf", src.config, None), association="joint")
    assert make_team("rdl", src.initial, **node_options("rdl", src.config, None), association="joint")[0].association \
        == "joint"  # fmt: skip
    with pytest.raises(ValueError, match="association_gate"):
        make_team("dekf", src.initial, **{**node_options("dekf", src.config, None), "association": "nearest",
                                          "association_gate": 0.0})  # fmt: skip
    iekf = make_team("iekf", src.initial, **node_options("iekf", src.config, None), association="joint")
    assert iekf[0].association == "joint"  # any centralized filter: the choice reads beliefs, not coordinates
