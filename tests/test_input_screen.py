"""The bulk screen of detections (:func:`swarmloc.node.inputs.clearly_valid`) never passes one that
:func:`~swarmloc.node.inputs.validate_detection` would refuse, passes clean sensor data, and the engine's checks
built on it file and count exactly what the detection-by-detection check does. A covariance too large to square,
a stamp of inf, 1e12 s or 10**400, an id of 5000 digits: refused or accepted with a reason, never a crash, and no
record of the in-process runner changes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmloc.engine.checks import Checked
from swarmloc.engine.codes import UNKNOWN_ROBOT
from swarmloc.events import Detection, Odometry
from swarmloc.node.inputs import clearly_valid, validate_detection

pytestmark = pytest.mark.unit


KINDS = ("range_bearing", "range", "bearing", "pose", "absolute", "rbe3", "sonar", 3)
SIZE = {"range_bearing": 2, "range": 1, "bearing": 1, "pose": 3, "absolute": 3, "rbe3": 3}


def _good(rng: np.random.Generator, kind: str, observer: int = 0) -> Detection:
    m = SIZE[kind]
    z = rng.normal(size=m)
    if kind in ("range_bearing", "range", "rbe3"):
        z[0] = abs(z[0]) + 0.1
    A = rng.normal(size=(m, m))
    target = None if kind == "absolute" else int(rng.integers(0, 4))
    return Detection(observer, float(rng.uniform(0, 10)), kind, z, A @ A.T + 0.1 * np.eye(m), target)


ODD_NUMBERS = [math.nan, math.inf, -math.inf, -1.0, 0.0, 1e200, 1e-300, 3, True, "1.0", None, np.float32(2.0)]


@st.composite
def _detections(draw: st.DrawFn) -> Detection:
    """Detections mostly well formed, each field sometimes odd: wrong kinds, sizes, types, NaN, huge or indefinite
    covariances, stamps and ids of odd types."""
    kind = draw(st.sampled_from(KINDS))
    m = SIZE.get(kind, 2) if isinstance(kind, str) else 2
    m_z = draw(st.sampled_from([m, m, m, m + 1, 1]))
    z = np.array(draw(st.lists(st.floats(-5, 5) | st.sampled_from(ODD_NUMBERS[:6]), min_size=m_z, max_size=m_z)))
    if draw(st.booleans()):
        z = np.abs(z) + 0.5 if np.issubdtype(z.dtype, np.floating) else z
    if draw(st.integers(0, 9)) == 0:
        with np.errstate(invalid="ignore"):  # NaN or inf cast to int: an odd input on purpose
            odd = z.astype(int)
        z = draw(st.sampled_from([z.tolist(), "far", None, odd, z.reshape(1, -1)]))
    m_c = draw(st.sampled_from([m, m, m, m + 1]))
    vals = draw(st.lists(st.floats(-1, 1), min_size=m_c * m_c, max_size=m_c * m_c))
    A = np.array(vals).reshape(m_c, m_c)
    cov = A @ A.T + draw(st.sampled_from([0.0, 1e-3, 1.0])) * np.eye(m_c)
    twist = draw(st.integers(0, 7))
    if twist == 1:
        cov[0, -1] += 1e-6  # not symmetric (size > 1)
    elif twist == 2:
        cov = -cov
    elif twist == 3:
        with np.errstate(invalid="ignore"):  # inf * 0 entries: NaN, an odd input on purpose
            cov = cov * draw(st.sampled_from([1e200, 1e300, math.nan, math.inf]))
    elif twist == 4:
        cov = cov.tolist()
    t = draw(st.floats(0, 10) | st.sampled_from([*ODD_NUMBERS, np.array(1.0), np.int64(4)]))
    ids = st.integers(-2, 5) | st.sampled_from(
        [None, True, 1.0, "1", np.int64(2), np.int32(1), 2**63, -(2**63) - 1, 10**30, 2**63 - 1]
    )
    return Detection(draw(ids), t, kind, z, cov, draw(ids), draw(st.booleans()))


@settings(max_examples=300, deadline=None)
@given(st.lists(_detections(), min_size=1, max_size=12))
def test_the_screen_passes_nothing_the_full_check_refuses(ds: list[Detection]) -> None:
    sure = clearly_valid(ds)
    assert sure.shape == (len(ds),) and sure.dtype == bool
    for d, ok in zip(ds, sure.tolist(), strict=True):
        why = validate_detection(d)  # never raises
        assert why is None or not ok, (d, why)


def test_the_screen_passes_clean_sensor_data_and_refuses_each_flaw() -> None:
    rng = np.random.default_rng(3)
    clean = [_good(rng, k) for k in ("range_bearing", "range", "bearing") for _ in range(200)]
    assert clearly_valid(clean).all()
    flawed = [
        Detection(0, 1.0, "range_bearing", np.array([-1.0, 0.1]), np.eye(2), 1),  # negative range
        Detection(0, 1.0, "range", np.array([0.0]), np.eye(1), 1),  # zero range
        Detection(0, 1.0, "bearing", np.array([math.nan]), np.eye(1), 1),
        Detection(0, math.inf, "bearing", np.array([0.1]), np.eye(1), 1),
        Detection(0, "1.0", "bearing", np.array([0.1]), np.eye(1), 1),  # type: ignore[arg-type]
        Detection(0, 1.0, "range_bearing", np.array([1.0, 0.1]), np.array([[1.0, 0.1], [0.0, 1.0]]), 1),
        Detection(0, 1.0, "range_bearing", np.array([1.0, 0.1]), np.array([[1.0, 1.0], [1.0, 1.0]]), 1),
        Detection(0, 1.0, "range_bearing", np.array([1.0, 0.1]), np.eye(2), True),  # a bool is not an id
        Detection(1.0, 1.0, "range_bearing", np.array([1.0, 0.1]), np.eye(2), 1),  # type: ignore[arg-type]
        Detection(0, 1.0, "range_bearing", np.array([1.0, 0.1, 0.0]), np.eye(2), 1),  # z of the wrong size
    ]
    mixed = [*clean[:7], *flawed, *clean[7:20]]
    sure = clearly_valid(mixed)
    assert not sure[7 : 7 + len(flawed)].any() and sure[:7].all() and sure[7 + len(flawed) :].all()
    assert all(validate_detection(d) is not None for d in flawed)


@pytest.mark.parametrize("scale", [1e200, 1e300, 1e308])
def test_a_covariance_too_large_to_square_is_checked_not_a_crash(scale: float) -> None:
    """``(a + d) ** 2`` of Python floats raises OverflowError; the check must answer instead."""
    with np.errstate(over="ignore"):  # 2 * 1e308 is inf: an odd input on purpose
        covs = (scale * np.eye(2), scale * np.array([[2.0, 1.0], [1.0, 2.0]]))
    for cov in covs:
        d = Detection(0, 1.0, "range_bearing", np.array([1.0, 0.1]), cov, 1)
        why = validate_detection(d)
        assert why is None or "cov" in why
        assert clearly_valid([d]).tolist() == [False] or why is None


def test_the_engine_checks_detections_in_bulk_as_one_by_one() -> None:
    """:meth:`Checked.add_all` (screen first) and :meth:`Checked.add` on each: the same counts, reasons, filed
    groups and start times, on clean detections mixed with every flaw (and duplicates, an observer outside the
    team)."""
    rng = np.random.default_rng(11)
    events: list[Detection] = []
    for k in range(300):
        d = _good(rng, ("range_bearing", "range", "bearing", "pose", "absolute")[k % 5], observer=k % 4)
        events.append(d)
        if k % 17 == 0:
            events.append(d)  # a duplicate
    events += [
        Detection(9, 0.5, "range", np.array([1.0]), np.eye(1), 1),
        Detection(0, 0.25, "range", np.array([-1.0]), np.eye(1), 1),
        Detection(1, math.nan, "bearing", np.array([0.1]), np.eye(1), 2),
        Detection(2, 0.75, "range_bearing", np.array([1.0, 0.1]), np.array([[1.0, 0.2], [0.0, 1.0]]), 3),
        Detection(3, 0.1, "range_bearing", np.array([1.0, 0.1]), 1e300 * np.eye(2), 0),
        Detection(3, 0.2, "range_bearing", np.array([1.0, 0.1]), np.eye(2), 0, target_is_robot=False),
        Detection(3, 0.05, "sonar", np.array([1.0, 0.1]), np.eye(2), 0),
    ]
    rng.shuffle(events)  # type: ignore[arg-type]
    col = {r: r for r in range(4)}
    one, bulk = Checked(col, lambda lid: UNKNOWN_ROBOT), Checked(col, lambda lid: UNKNOWN_ROBOT)
    for e in events:
        one._first(e.observer, float(e.t) if math.isfinite(e.t) else None)
        one.add(e)
    bulk.add_all(events)
    assert one.counts == bulk.counts and one.reasons == bulk.reasons
    assert one.counts["detections"] == len(events) and sum(one.reasons.values()) == 18 + 5
    for why in ("range must be positive", "not a finite number", "symmetric", "duplicate", "not in the team"):
        assert any(why in k for k in one.reasons), why
    filed = [{t: {o: {k: (id(e), c) for k, (e, c) in g.items()} for o, g in by.items()} for t, by in x.groups.items()}
             for x in (one, bulk)]  # fmt: skip
    assert filed[0] == filed[1] and sum(len(g) for by in filed[0].values() for g in by.values()) >= 200
    np.testing.assert_array_equal(one.start_times(), bulk.start_times())


def _team_events() -> list:
    ev: list = []
    for k in range(100):
        t = 0.1 * k
        ev += [Odometry(0, t, t + 0.1, 0.2, 0.05), Odometry(1, t, t + 0.1, 0.1, 0.0)]
        if k % 10 == 5:
            ev.append(Detection(0, t, "range", np.array([1.0]), 0.01 * np.eye(1), 1))
    return ev


BAD_INPUT = {
    "stamp inf": Detection(0, math.inf, "range", np.array([1.0]), 0.01 * np.eye(1), 1),
    "stamp 1e12 s": Detection(0, 1e12, "range", np.array([1.0]), 0.01 * np.eye(1), 1),
    "stamp 10**400": Detection(0, 10**400, "range", np.array([1.0]), 0.01 * np.eye(1), 1),
    "target 10**5000": Detection(0, 1.0, "range", np.array([1.0]), 0.01 * np.eye(1), 10**5000),
    "observer 10**5000": Detection(10**5000, 1.0, "range", np.array([1.0]), 0.01 * np.eye(1), 1),
    "target 2**63": Detection(0, 1.0, "range", np.array([1.0]), 0.01 * np.eye(1), 2**63),
    "odometry stamps 10**400": Odometry(0, 10**400, 10**401, 0.1, 0.0),
}


@pytest.mark.parametrize("estimator", ["dekf", "cekf", "rdl"])
@pytest.mark.parametrize("case", list(BAD_INPUT))
def test_one_bad_stamp_or_id_is_counted_and_changes_no_record(estimator: str, case: str) -> None:
    """A stamp of inf or far in the future used to make the in-process runner record every belief at once, before
    the inputs after it (1.17 m off); an int too large for a float or for a repr crashed the node. Now: refused with
    a reason, and every record as without it."""
    from swarmloc.estimators import make_team, options_for
    from swarmloc.gaussian import GroupGaussian
    from swarmloc.lie import SE2
    from swarmloc.motion import UnicycleNoise
    from swarmloc.runner import run

    init = {r: GroupGaussian(SE2, SE2.from_xytheta([float(r), 0.0, 0.0]), 1e-2 * np.eye(3)) for r in (0, 1)}
    ev = _team_events()
    res = [
        run(make_team(estimator, init, **options_for(estimator, t0=0.0, noise=UnicycleNoise())), events,
            record_times=np.arange(0.0, 10.0, 0.5))
        for events in (ev, [*ev[:40], BAD_INPUT[case], *ev[40:]])
    ]  # fmt: skip
    for r in (0, 1):
        np.testing.assert_array_equal(res[1].tracks[r].mean, res[0].tracks[r].mean)
        np.testing.assert_array_equal(res[1].tracks[r].cov, res[0].tracks[r].cov)
    extra = res[1].reasons - res[0].reasons
    assert sum(extra.values()) == 1 and res[1].accounted(), extra
    assert len(next(iter(extra))) < 160


def test_a_node_started_at_an_int_too_large_for_a_float_gets_a_clear_error() -> None:
    from swarmloc.estimators import make_team, options_for
    from swarmloc.gaussian import GroupGaussian
    from swarmloc.lie import SE2
    from swarmloc.motion import UnicycleNoise

    init = {0: GroupGaussian(SE2, SE2.from_xytheta([0.0, 0.0, 0.0]), 1e-2 * np.eye(3))}
    node = make_team("dekf", init, **options_for("dekf", noise=UnicycleNoise()))[0]
    with pytest.raises(ValueError, match="t0 must be a finite time in seconds, got 1000"):
        node.start(10**400)
