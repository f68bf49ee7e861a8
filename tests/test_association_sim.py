"""Anonymous detections in the simulator (ids removed, clutter, misses, range limit), the Khepera III kidnapping
scenario of slides 64-69, the nodes' refusal of anonymous detections, and PMR + the particle-filter bank on it."""

from __future__ import annotations

import numpy as np
import pytest

from swarmloc import make_team, run
from swarmloc.association.tracker import anonymous_scans, track_anonymous
from swarmloc.estimators import ESTIMATORS, options_for
from swarmloc.events import Detection, Odometry, Truth
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, between_xyt
from swarmloc.motion import UnicycleNoise
from swarmloc.sim import RelativeSensor, random_team
from swarmloc.sim.anonymous import CLUTTER_TRUTH, AnonymousSensor, anonymize_sim, is_anonymous, khepera_kidnap

pytestmark = pytest.mark.unit


def team(duration: float = 20.0, seed: int = 0):
    sensor = RelativeSensor(rate=5.0, max_range=3.0, kinds=("pose", "range_bearing"))
    return random_team(5, duration=duration, seed=seed, sensor=sensor)


def test_anonymize_drops_ids_keeps_truth_and_adds_clutter_and_misses_at_the_requested_rates():
    sim = team(40.0)
    tagged = [e for e in sim.events if isinstance(e, Detection) and e.kind == "range_bearing"]
    scans = {(e.t, e.observer) for e in tagged}
    anon = anonymize_sim(sim, AnonymousSensor(p_detect=0.8, clutter_rate=0.5, max_range=2.5), seed=1)
    dets = [e for e in anon.events if isinstance(e, Detection)]
    assert dets and all(is_anonymous(e) for e in dets)  # no pose detections, no ids left
    real = [e for e in dets if e.truth_target != CLUTTER_TRUTH]
    clutter = [e for e in dets if e.truth_target == CLUTTER_TRUTH]
    in_range = [e for e in tagged if e.z[0] <= 2.5]
    rate = len(real) / len(in_range)
    assert abs(rate - 0.8) < 4 * np.sqrt(0.8 * 0.2 / len(in_range)), rate
    n_scans = int(round(40.0 * 5.0)) * 5
    assert len(scans) <= n_scans
    assert abs(len(clutter) / n_scans - 0.5) < 4 * np.sqrt(0.5 / n_scans)
    assert max(e.z[0] for e in dets) <= 2.5
    # each real anonymous detection is the tagged one with its id moved to truth_target
    by_key = {(e.t, e.observer, e.target): e for e in tagged}
    for e in real[:50]:
        assert np.array_equal(by_key[(e.t, e.observer, e.truth_target)].z, e.z)
    # odometry and truth unchanged, in time order, deterministic for a seed
    assert [e for e in anon.events if isinstance(e, Odometry)] == [e for e in sim.events if isinstance(e, Odometry)]
    assert all(a.t <= b.t for a, b in zip(anon.events, anon.events[1:], strict=False))
    again = anonymize_sim(sim, AnonymousSensor(p_detect=0.8, clutter_rate=0.5, max_range=2.5), seed=1)
    assert [(e.t, e.observer, tuple(e.z)) for e in dets] == [
        (e.t, e.observer, tuple(e.z)) for e in again.events if isinstance(e, Detection)
    ]


def test_a_detection_of_a_robot_outside_the_team_is_clutter_to_it():
    """MRCLAM dataset 3 has no robot 4 in its team, yet its cameras see robot 4's barcode 1,395 times: with the ids
    hidden those detections are false ones to the team, so refusing them is right (scored so), and giving them to a
    teammate is wrong."""
    from swarmloc.experiments.association import association_events
    from swarmloc.sim.anonymous import anonymize

    sim = team(10.0)
    dets = [e for e in sim.events if isinstance(e, Detection) and e.target_is_robot]
    assert {e.target for e in dets} >= {3, 4}
    out = [e for e in anonymize(sim.events, team={0, 1, 2, 3}) if isinstance(e, Detection) and e.target_is_robot]
    assert len(out) == len(dets) and all(e.target is None for e in out)
    for a, b in zip(dets, out, strict=True):
        assert b.truth_target == (a.target if a.target != 4 else CLUTTER_TRUTH)
    everyone = [e for e in anonymize(sim.events) if isinstance(e, Detection) and e.target_is_robot]
    assert [e.truth_target for e in everyone] == [e.target for e in dets]
    joint, _ = association_events(sim.events, "joint", [0, 1, 2, 3], UnicycleNoise())
    truths = {e.truth_target for e in joint if isinstance(e, Detection) and e.target_is_robot}
    assert CLUTTER_TRUTH in truths and 4 not in truths


def test_anonymous_scans_reveal_nothing_by_their_order():
    anon = anonymize_sim(team(10.0), AnonymousSensor())
    by_scan: dict = {}
    for e in anon.events:
        if isinstance(e, Detection):
            by_scan.setdefault((e.t, e.observer), []).append(float(e.z[0]))
    assert all(r == sorted(r) for r in by_scan.values())


def test_anonymize_rejects_bad_settings():
    with pytest.raises(ValueError, match="p_detect"):
        AnonymousSensor(p_detect=1.5)
    with pytest.raises(ValueError, match="clutter_rate"):
        AnonymousSensor(clutter_rate=-1)
    sim = random_team(3, duration=2.0, seed=0)  # pose detections only
    with pytest.raises(ValueError, match="range_bearing"):
        anonymize_sim(sim, AnonymousSensor())


@pytest.mark.parametrize("name", list(ESTIMATORS))
def test_every_estimator_refuses_anonymous_detections_and_counts_them(name: str):
    anon = anonymize_sim(team(3.0), AnonymousSensor(clutter_rate=0.3))
    n_anon = sum(is_anonymous(e) for e in anon.events)
    assert n_anon > 20
    init = {r: GroupGaussian(SE2, SE2.from_xytheta(p), 1e-4 * np.eye(3)) for r, p in anon.initial_poses.items()}
    nodes = make_team(name, init, **options_for(name, noise=anon.unicycle_noise(), gate=0.997, horizon=2.0))
    res = run(nodes, anon.events)
    assert res.stats["fused"] == 0 and res.stats["rejected"] == n_anon
    why = [k for k in res.reasons if "without a target id" in k or (name == "dr" and "does not use" in k)]
    assert sum(res.reasons[k] for k in why) == n_anon, res.reasons
    assert res.accounted()


def test_khepera_scenario_has_four_robots_two_metre_range_and_one_documented_kidnapping():
    sc = khepera_kidnap(seed=0)
    sim = sc.sim
    assert sim.robot_ids == (1, 2, 3, 4) and sc.kidnapped == 4 and sc.kidnap_time == 60.0
    dets = [e for e in sim.events if isinstance(e, Detection)]
    assert all(is_anonymous(e) for e in dets)
    assert max(e.z[0] for e in dets) <= 2.0 + 0.05 and max(abs(e.z[1]) for e in dets) <= np.deg2rad(120) + 0.05
    assert np.allclose(dets[0].cov, np.diag([0.01**2, np.deg2rad(1.0) ** 2]))
    truth4 = [(e.t, e.pose) for e in sim.events if isinstance(e, Truth) and e.robot == 4]
    jumps = [(t1, np.hypot(*(p1[:2] - p0[:2]))) for (_, p0), (t1, p1) in zip(truth4, truth4[1:], strict=False)]
    big = [(t, d) for t, d in jumps if d > 0.05]
    assert len(big) == 1 and big[0][0] == pytest.approx(60.0) and big[0][1] > 1.0  # the kidnapping, once
    others = [e for e in sim.events if isinstance(e, Truth) and e.robot != 4]
    assert len(others) == 3 * len(truth4)
    xy = sim.truth[..., :2]
    assert xy.min() > 0 and xy[..., 0].max() < 3.5 and xy[..., 1].max() < 1.5  # inside the arena
    odo4 = [e for e in sim.events if isinstance(e, Odometry) and e.robot == 4]
    assert len({(e.v, e.w) for e in odo4}) == 1  # its odometry never notices


@pytest.mark.parametrize("clutter", [False, True])
def test_pmr_and_the_bank_localize_the_khepera_team_and_recover_the_kidnapped_robot(clutter: bool):
    """Slides 66-69 in simulation: robot 1 localizes 2, 3, 4 from anonymous scans; after the kidnapping of 4 at
    60 s its filter resets and converges again -- also with 10% misses and 0.2 false positives per scan."""
    fov = np.deg2rad(240.0)
    sensor = AnonymousSensor(p_detect=0.9, clutter_rate=0.2, max_range=2.0, fov=fov) if clutter else None
    sc = khepera_kidnap(seed=0, sensor=sensor)
    sim = sc.sim
    noise = UnicycleNoise.from_diff_drive(sim.config.drive)
    track = track_anonymous(
        sim.events, 1, sim.robot_ids, noise, 0.035, max_range=2.0, fov=fov, sigma_range=0.01,
        max_unmatched=int(clutter), n_particles=300, rng=0,
    )  # fmt: skip
    assert track.counts["scans"] == 600 and track.counts["bank_reset"] >= 1
    col = {r: c for c, r in enumerate(sim.robot_ids)}
    k = np.searchsorted(sim.times, np.array(track.times) - 1e-9)
    for j in (2, 3, 4):
        truth = between_xyt(sim.truth[k, col[1]], sim.truth[k, col[j]])
        t, pos, ang = track.errors(j, truth)
        early = (t > 1) & (t <= 10)
        late = t > 75
        assert np.nanmedian(pos[early]) < 0.05 and np.nanmedian(pos[late]) < 0.05, j
        assert np.nanmedian(ang[late]) < 0.1, j
        if j == 4:
            before = (t > 60) & (t <= 61)  # just after the kidnapping: the filter still believes the old place
            assert np.nanmin(pos[before]) > 0.5
            after = (t > 65) & (t <= 120)
            assert np.nanmedian(pos[after]) < 0.05


def test_anonymous_scans_group_points_per_robot():
    sc = khepera_kidnap(seed=1, duration=4.0, kidnap_time=2.0)
    scans = anonymous_scans(sc.sim.events, sc.sim.robot_ids)
    assert len(scans) == 20
    for scan in scans.values():
        assert set(scan) == {1, 2, 3, 4} and all(p.shape[1] == 2 for p in scan.values())
