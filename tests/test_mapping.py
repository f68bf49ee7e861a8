"""Line maps (issue 20): range sensing, line extraction and its covariance, world-frame propagation against Monte
Carlo, information-form fusion, one line per wall from two robots, and the ``swarmloc map`` experiment."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import chi2

from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, wrap_angle
from swarmloc.mapping import LineMap, LineObservation, MapLine, extract_lines, fit_line, line_to_world, map_error
from swarmloc.sim.walls import RangeFinder, Walls, cast_rays, office_walls

pytestmark = pytest.mark.unit


def _scan(pose: tuple[float, float, float], walls: Walls, finder: RangeFinder, rng: np.random.Generator):
    """One noisy scan from ``pose`` (no other robots)."""
    th = pose[2] + finder.angles
    d = np.stack([np.cos(th), np.sin(th)], -1)
    r = cast_rays(np.broadcast_to(pose[:2], d.shape), d, walls.segments)
    r = r + finder.sigma * rng.standard_normal(r.shape)
    r[~(r <= finder.max_range)] = np.nan
    return r


def _line_of(seg: np.ndarray) -> tuple[float, float]:
    """(rho, alpha) of the infinite line through a segment ``(2, 2)``."""
    e = seg[1] - seg[0]
    n = np.array([e[1], -e[0]]) / np.hypot(*e)
    rho = float(n @ seg[0])
    if rho < 0:
        n, rho = -n, -rho
    return rho, float(np.arctan2(n[1], n[0]))


def test_rays_stop_at_the_first_wall_or_robot_and_miss_past_the_range() -> None:
    walls = Walls.from_polylines([(-1, -1), (1, -1), (1, 1), (-1, 1), (-1, -1)])
    o = np.zeros((4, 2))
    d = np.array([[1, 0], [0, 1], [-1, 0], [0, -1.0]])
    np.testing.assert_allclose(cast_rays(o, d, walls.segments), 1.0)
    disc = np.full((4, 1, 2), np.nan)
    disc[0, 0] = (0.5, 0.0)  # a robot of radius 0.2 in front of the first beam only
    np.testing.assert_allclose(cast_rays(o, d, walls.segments, disc, 0.2), [0.3, 1, 1, 1])
    far = Walls(np.array([[[5.0, -1], [5.0, 1]]]))
    assert np.isinf(cast_rays(o[:1], np.array([[-1.0, 0]]), far.segments)).all()  # behind the ray: no hit


def test_line_extraction_recovers_known_walls_within_the_noise() -> None:
    rng = np.random.default_rng(1)
    walls = office_walls()
    finder = RangeFinder(n_beams=181, fov=np.deg2rad(180), max_range=4.0, sigma=0.01)
    m2s, found = [], 0
    for pose in [(1.5, 1.2, 0.3), (5.0, 3.0, 0.0), (8.0, 1.0, 2.0), (2.5, 4.8, -1.0)]:
        g = SE2.from_xytheta(pose)
        for f in extract_lines(_scan(pose, walls, finder, rng), finder.angles, finder.sigma):
            ends = f.endpoints @ g[:2, :2].T + g[:2, 2]
            # the true wall: the one both end points lie nearest to
            from swarmloc.mapping.metrics import point_segment_distance

            w = int(np.argmin(point_segment_distance(ends, walls.segments).sum(axis=0)))
            assert point_segment_distance(ends, walls.segments[w : w + 1]).max() < 0.05
            # true line in the sensor frame
            local = (walls.segments[w] - g[:2, 2]) @ g[:2, :2]
            rho, alpha = _line_of(local)
            d = np.array([f.rho - rho, wrap_angle(f.alpha - alpha)])
            m2s.append(float(d @ np.linalg.solve(f.cov, d)))
            found += 1
    assert found >= 8
    # Mahalanobis distances of the fits from the true walls are chi-square(2): every one below the 99.9% quantile
    # and their mean near 2 (a wrong covariance or a biased fit would fail one of these)
    assert max(m2s) < chi2.ppf(0.999, 2), m2s
    assert 1.0 < np.mean(m2s) < 3.5, np.mean(m2s)


def test_line_fit_covariance_matches_monte_carlo_within_5_percent() -> None:
    rng = np.random.default_rng(2)
    phi = np.linspace(-0.6, 0.4, 51)
    r_true = 2.0 / np.cos(phi - 0.2)  # a wall at rho = 2 m, alpha = 0.2 rad
    sigma = 0.02
    ref = fit_line(r_true, phi, sigma)
    assert ref.rho == pytest.approx(2.0) and ref.alpha == pytest.approx(0.2)
    X = np.array(
        [
            [f.rho, f.alpha]
            for f in (fit_line(r, phi, sigma) for r in r_true + sigma * rng.standard_normal((6000, phi.size)))
        ]
    )
    mc = np.cov(X.T)
    np.testing.assert_allclose(np.diag(ref.cov), np.diag(mc), rtol=0.05)
    assert ref.cov[0, 1] == pytest.approx(mc[0, 1], rel=0.08)


def _world_mc(rho, alpha, C, mu, S, rng, M=400_000):
    g = SE2.to_xytheta(GroupGaussian(SE2, mu, S).sample(M, rng))
    e = rng.standard_normal((M, 2)) @ np.linalg.cholesky(C).T
    a = alpha + e[:, 1] + g[:, 2]
    r = rho + e[:, 0] + g[:, 0] * np.cos(a) + g[:, 1] * np.sin(a)
    return np.where(r < 0, -r, r), np.where(r < 0, a + np.pi, a)


@pytest.mark.parametrize("heading_std", [0.05, 0.25])
def test_world_line_covariance_matches_monte_carlo(heading_std: float) -> None:
    """A line 3 m away seen from a belief with heading std ``heading_std``: the second-order propagation matches
    Monte Carlo within 5% (measured: < 0.5%); at 0.25 rad the first order overstates the variance of rho by ~5%."""
    rng = np.random.default_rng(3)
    rho, alpha, C = 3.0, 0.3, np.diag([1e-4, 1e-4])
    mu = SE2.from_xytheta(1.0, -2.0, 0.7)
    sxy = 0.14 * heading_std / 0.25
    S = np.diag([sxy**2, sxy**2 / 2, heading_std**2])
    S[0, 2] = S[2, 0] = 0.3 * sxy * heading_std
    rw, aw = _world_mc(rho, alpha, C, mu, S, rng)
    rel = {}
    for order in (1, 2):
        r, a, Cw = line_to_world(rho, alpha, C, mu, S, order)
        mc = np.cov(np.stack([rw - r, wrap_angle(aw - a)]))
        rel[order] = np.abs(np.diag(Cw) / np.diag(mc) - 1)
    assert rel[2].max() < 0.05, rel
    if heading_std == 0.25:
        assert rel[1][0] > 0.03 and rel[2][0] < 0.01, rel  # the difference the second order makes


def test_first_order_equals_the_jacobian_on_x_y_theta() -> None:
    """Order 1 is the plain Jacobian propagation: rho_w = rho + x cos(alpha + th) + y sin(alpha + th)."""
    rho, alpha, C = 2.0, -0.4, np.array([[2e-4, 1e-5], [1e-5, 3e-4]])
    mu = SE2.from_xytheta(0.5, 1.0, 0.9)
    S = np.array([[0.01, 0.002, 0.001], [0.002, 0.02, -0.003], [0.001, -0.003, 0.01]])
    r, a, Cw = line_to_world(rho, alpha, C, mu, S, 1)
    x, y, th = SE2.to_xytheta(mu)
    aw = alpha + th
    R = mu[:2, :2]
    n, t = np.array([np.cos(aw), np.sin(aw)]), np.array([-np.sin(aw), np.cos(aw)])
    J_pose = np.array([[*(n @ R), t @ [x, y]], [0, 0, 1]])  # d(rho_w, alpha_w) / d(xi) at xi = 0
    J_line = np.array([[1, t @ [x, y]], [0, 1]])
    np.testing.assert_allclose(Cw, J_pose @ S @ J_pose.T + J_line @ C @ J_line.T, rtol=1e-9, atol=1e-15)
    assert r == pytest.approx(rho + x * np.cos(aw) + y * np.sin(aw)) and a == pytest.approx(wrap_angle(aw))


def _obs(rho, alpha, cov, x0, x1, robot=0):
    n, t = np.array([np.cos(alpha), np.sin(alpha)]), np.array([-np.sin(alpha), np.cos(alpha)])
    return LineObservation(rho, alpha, np.asarray(cov), rho * n + np.outer([x0, x1], t), robot)


def test_fusing_two_observations_follows_the_information_form() -> None:
    lm = LineMap()
    C1 = np.array([[4e-4, 1e-5], [1e-5, 1e-4]])
    C2 = np.array([[1e-4, -2e-5], [-2e-5, 3e-4]])
    lm.add(_obs(1.00, 0.10, C1, -1.0, 0.5, robot=1))
    k = lm.add(_obs(1.02, 0.11, C2, 0.0, 1.5, robot=2))
    assert k == 0 and len(lm.lines) == 1
    I1, I2 = np.linalg.inv(C1), np.linalg.inv(C2)
    C = np.linalg.inv(I1 + I2)
    x = C @ (I1 @ [1.00, 0.10] + I2 @ [1.02, 0.11])
    ln = lm.lines[0]
    np.testing.assert_allclose(ln.cov, C, rtol=1e-12)
    np.testing.assert_allclose([ln.rho, ln.alpha], x, rtol=1e-12)
    assert np.linalg.det(ln.cov) < min(np.linalg.det(C1), np.linalg.det(C2))
    assert ln.robots == {1, 2} and ln.n_obs == 2
    assert ln.s0 < -0.95 and ln.s1 > 1.45  # the extent is the union
    # a far line (Mahalanobis) and a collinear one 2 m further along (no overlap) stay separate
    lm.add(_obs(1.5, 0.10, C1, -1.0, 0.5))
    lm.add(_obs(1.01, 0.105, C1, 3.5, 5.0))
    assert len(lm.lines) == 3


def test_a_line_through_the_origin_fuses_across_the_rho_sign_flip() -> None:
    lm = LineMap()
    C = np.diag([1e-4, 1e-4])
    lm.add(_obs(0.005, 0.5, C, -1, 1))
    lm.add(_obs(0.005, 0.5 + np.pi, C, -1, 1))  # the same line, normal the other way
    assert len(lm.lines) == 1 and lm.lines[0].rho < 0.01


def _corridor_map(merge: bool) -> LineMap:
    """Two robots drive towards each other along a corridor 1 m wide and 8 m long (walls y = 0 and y = 1), from
    its two ends: at first each sees only its own end of the walls; beliefs with a 2 cm / 1 deg error."""
    rng = np.random.default_rng(4)
    walls = Walls(np.array([[[0.0, 0.0], [8.0, 0.0]], [[0.0, 1.0], [8.0, 1.0]]]))
    finder = RangeFinder(n_beams=91, fov=np.deg2rad(180), max_range=2.5, sigma=0.01)
    S = np.diag([0.02**2, 0.02**2, np.deg2rad(1.0) ** 2])
    lm = LineMap()
    if not merge:
        lm._merge_from = lambda k: k  # type: ignore[method-assign]
    for step in range(25):
        for robot, pose in ((1, (0.5 + 0.1 * step, 0.5, 0.0)), (2, (7.5 - 0.1 * step, 0.5, np.pi))):
            mu = SE2.from_xytheta(pose) @ SE2.exp(rng.multivariate_normal(np.zeros(3), S))  # belief mean, off truth
            for f in extract_lines(_scan(pose, walls, finder, rng), finder.angles, finder.sigma):
                r, a, C = line_to_world(f.rho, f.alpha, f.cov, mu, S)
                lm.add(LineObservation(float(r), float(a), C, f.endpoints @ mu[:2, :2].T + mu[:2, 2], robot))
    return lm


def test_two_robots_mapping_one_corridor_produce_one_line_per_wall() -> None:
    lm = _corridor_map(merge=True)
    assert len(lm.lines) == 2, [(ln.rho, ln.alpha, ln.s0, ln.s1) for ln in lm.lines]
    assert all(ln.robots == {1, 2} for ln in lm.lines)
    err = map_error(lm.segments(), np.array([[[0.0, 0.0], [8.0, 0.0]], [[0.0, 1.0], [8.0, 1.0]]]))
    assert err["endpoint_mean"] < 0.05 and err["covered"] > 0.8
    # without the merge pass each wall stays two lines: the merge is what makes them one
    assert len(_corridor_map(merge=False).lines) == 4


def test_bad_observations_are_refused_or_counted() -> None:
    lm = LineMap()
    with pytest.raises(ValueError, match="positive definite"):
        lm.add(_obs(1.0, 0.0, [[1e-4, 0], [0, -1e-4]], 0, 1))
    assert lm.offer(_obs(float("nan"), 0.0, np.eye(2) * 1e-4, 0, 1)) is None
    assert lm.offer(_obs(1.0, 0.0, np.eye(2) * 1e-4, 0.5, 0.5)) is None  # zero-length segment
    assert lm.counts["rejected"] == 2 and not lm.lines
    assert lm.offer(_obs(1.0, 0.0, np.eye(2) * 1e-4, 0, 1)) == 0
    gj = lm.to_geojson()
    np.testing.assert_allclose(gj["features"][0]["geometry"]["coordinates"], [[1, 0], [1, 1]], atol=1e-12)


def test_map_command_writes_a_table_figure_and_maps(tmp_path, capsys, terminal_progress) -> None:
    """...and shows its progress on stderr, one step per estimator run (before, it printed nothing until the end:
    2.5 minutes with its defaults)."""
    from swarmloc.cli import main

    assert main(["map", "--seeds", "1", "--estimators", "expfusion", "--out", str(tmp_path)]) == 0
    rep = json.loads((tmp_path / "map.json").read_text())
    m = rep["mean"]
    assert m["true poses"]["endpoint_mean"] < 0.02  # sensing and extraction alone
    assert m["team, expfusion"]["endpoint_mean"] < m["team, dr"]["endpoint_mean"]
    assert m["team, expfusion"]["covered"] > 0.4
    for f in ("map.md", "map.png", "team_expfusion.geojson", "H1_alone.dxf"):
        assert (tmp_path / f).stat().st_size > 0
    assert json.loads((tmp_path / "team_expfusion.geojson").read_text())["features"]
    out, err = capsys.readouterr()
    assert "team, expfusion" in out and "2/2" not in out  # the table on stdout, the bar on stderr
    assert "map: seed 0, expfusion" in err and "2/2" in err  # dead reckoning, then expfusion


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--seeds", "0"], "seeds must be an integer in [1, 10000], got 0"),
        (["--seeds", "20000"], "seeds must be an integer in [1, 10000], got 20000"),
        (["--seeds", "2", "--first-seed", str(2**32 - 1)], "the first seed must be an integer in [0, 2^32 - seeds]"),
        (["--estimators", "foo"], "unknown estimator(s) ['foo']"),
        (["--D", "-1"], "D (the wheel-speed diffusion) must be a finite number >= 0"),
        (["--sigma", "-1"], "RangeFinder: need"),
    ],
)
def test_map_command_refuses_bad_input_in_one_line_before_any_run(argv, says, capsys) -> None:
    """Each of these raised a traceback (an IndexError for no seeds, a KeyError for an unknown estimator, a
    configuration error naming ``q_v0`` for a negative ``--D``, numpy's for seeds past 2^32) after or before runs;
    now one line, status 2."""
    from swarmloc.cli import main

    assert main(["map", "--quiet", *argv]) == 2
    out, err = capsys.readouterr()
    assert err.startswith("swarmloc map: ") and says in err and err.count("\n") == 1 and not out


def test_line_ends_are_closed_at_corners_and_wall_ends_open_at_the_fov_and_behind_occluders() -> None:
    rng = np.random.default_rng(5)
    # a corner ahead-left (walls x = 2 and y = 1.5 meeting at (2, 1.5)), and a short wall x = 1 for y in [-0.9, -0.3]
    # in front of the far wall x = 2 on the right
    walls = Walls(np.array([[[2.0, -3.0], [2.0, 1.5]], [[2.0, 1.5], [-1.0, 1.5]], [[1.0, -0.9], [1.0, -0.3]]]))
    finder = RangeFinder(n_beams=121, fov=np.deg2rad(120), max_range=5.0, sigma=0.005)
    fits = extract_lines(_scan((0.0, 0.0, 0.0), walls, finder, rng), finder.angles, finder.sigma)

    def ends_near(f, x=None, y=None):
        return [bool((x is None or abs(p[0] - x) < 0.02) and (y is None or abs(p[1] - y) < 0.02)) for p in f.endpoints]

    short = [f for f in fits if abs(f.rho - 1.0) < 0.02]
    assert len(short) == 1 and short[0].closed == (True, True)  # beams past both its ends hit the far wall
    # its ends were put half a beam spacing outwards: within 2 cm of the true ends (a beam spacing here is 3.5 cm)
    assert sorted(np.round(short[0].endpoints[:, 1], 1)) == [-0.9, -0.3]
    top = [f for f in fits if abs(f.rho - 1.5) < 0.02]
    assert len(top) == 1
    assert [c for c, near in zip(top[0].closed, ends_near(top[0], x=2.0), strict=True) if near] == [True]  # corner
    assert [c for c, near in zip(top[0].closed, ends_near(top[0], x=2.0), strict=True) if not near] == [False]  # FOV
    far = [f for f in fits if abs(f.rho - 2.0) < 0.02]
    # the far wall: pieces below and above the occluder; every end next to the occluder or the FOV edge is open,
    # the one at the corner closed
    assert len(far) == 2
    flags = {(round(float(p[1]), 1), c) for f in far for p, c in zip(f.endpoints, f.closed, strict=True)}
    assert (1.5, True) in flags and all(not c for y, c in flags if y != 1.5), flags
    assert all(v > 0 for f in fits for v in f.end_var)


def test_closed_ends_are_averaged_where_the_union_of_extents_would_overshoot() -> None:
    """200 sightings of the whole wall y = 1, x in [0, 4], each with a 5 cm pose error along the wall: the union of
    their extents is the farthest sighting (about 2.7 standard deviations out); averaging closed ends is not."""
    rng = np.random.default_rng(6)
    C = np.diag([1e-4, 1e-4])

    def build(closed: bool) -> MapLine:
        lm = LineMap()
        for _ in range(200):
            dx = 0.05 * rng.standard_normal()
            lm.add(LineObservation(1.0, np.pi / 2, C, np.array([[dx, 1.0], [4.0 + dx, 1.0]]), 1, 0.0,
                                   (closed, closed), (0.05**2, 0.05**2)))  # fmt: skip
        assert len(lm.lines) == 1
        return lm.lines[0]

    ends = np.sort(build(True).endpoints()[:, 0])
    np.testing.assert_allclose(ends, [0.0, 4.0], atol=0.015)
    union = np.sort(build(False).endpoints()[:, 0])  # open ends: the union, as before ends were classified
    assert union[0] < -0.08 and union[1] > 4.08
    # an open sighting further out than the closed ends' spread extends the line; one within it does not
    lm = LineMap()
    lm.add(LineObservation(1.0, np.pi / 2, C, np.array([[0.0, 1.0], [4.0, 1.0]]), 1, 0.0, (True, True), (1e-4, 1e-4)))
    lm.add(LineObservation(1.0, np.pi / 2, C, np.array([[3.0, 1.0], [4.02, 1.0]]), 2, 0.0, (True, False), (1e-4, 1e-4)))
    assert np.sort(lm.lines[0].endpoints()[:, 0]).tolist() == pytest.approx([0.0, 4.0])
    lm.add(LineObservation(1.0, np.pi / 2, C, np.array([[3.0, 1.0], [4.5, 1.0]]), 2, 0.0, (True, False), (1e-4, 1e-4)))
    assert np.sort(lm.lines[0].endpoints()[:, 0]).tolist() == pytest.approx([0.0, 4.5])
    with pytest.raises(ValueError, match="end_var"):
        lm.add(LineObservation(1.0, np.pi / 2, C, np.array([[0.0, 1.0], [4.0, 1.0]]), 1, 0.0, (True, True), (-1, 0)))
