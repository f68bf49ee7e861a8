"""The fused truth-free start (:func:`~swarmloc.experiments.truthfree.fuse_fixes`): a robot its gate locked out of
its own absolute fixes is re-acquired after k fixes in a row gated, a single outlier fix is not taken, and every
fix ends counted once."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from swarmloc.config import DEFAULTS
from swarmloc.events import Detection, Kind, Odometry
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2

FIX_COV = np.diag([0.01, 0.01, 0.001])
GATED = DEFAULTS.with_filter(gate=0.99)


def _drive(outliers: dict[int, float] | None = None) -> list[Odometry | Detection]:
    """20 s straight at 0.5 m/s along x from the origin, odometry every 0.1 s, a fix at the true pose every 1 s
    (fix ``i``'s x moved by ``outliers[i]`` m)."""
    odo: list[Odometry | Detection] = [Odometry(0, t, t + 0.1, 0.5, 0.0) for t in np.arange(0.0, 20.0, 0.1)]
    fixes = [Detection(0, float(t), Kind.ABSOLUTE, np.array([0.5 * t + (outliers or {}).get(i, 0.0), 0.0, 0.0]),
                       FIX_COV, target=None) for i, t in enumerate(np.arange(1.0, 20.0, 1.0))]  # fmt: skip
    return sorted([*odo, *fixes], key=lambda e: e.stamp)


def _start(x: float) -> GroupGaussian:
    return GroupGaussian(SE2, SE2.from_xytheta([x, 0.0, 0.0]), np.diag([1e-4, 1e-4, 1e-5]))


def _accounted(counts: dict[str, int], fixes: int = 19) -> bool:
    return counts["fused"] + counts["gated"] + counts["rejected"] + counts["unknown"] + counts["restart_fixes"] == fixes


@pytest.mark.unit
def test_a_robot_locked_out_of_its_fixes_stays_out_without_restarts_and_is_reacquired_with_them():
    from swarmloc.experiments.truthfree import fuse_fixes

    events = _drive()
    stuck, n0 = fuse_fixes(0, _start(3.0), 0.0, 20.0, events, GATED, restart=None)
    assert n0["fused"] == 0 and n0["gated"] == 19 and n0["restarts"] == 0 and _accounted(n0)
    assert abs(SE2.to_xytheta(stuck.mean)[0] - 13.0) < 0.5  # 3 m off, as it started
    back, n3 = fuse_fixes(0, _start(3.0), 0.0, 20.0, events, GATED, restart=3)
    assert n3["restarts"] == 1 and n3["restart_fixes"] == 3 and n3["fused"] == 16 and _accounted(n3)
    err = SE2.to_xytheta(back.mean) - np.array([10.0, 0.0, 0.0])
    assert abs(err[0]) < 0.1 and np.sqrt(back.cov[0, 0]) < 0.3


@pytest.mark.unit
def test_a_single_outlier_fix_is_gated_not_taken_as_a_restart():
    from swarmloc.experiments.truthfree import fuse_fixes

    events = _drive({5: 3.0})  # fix 5 is 3 m off: its run of one never reaches k
    out, n = fuse_fixes(0, _start(0.0), 0.0, 20.0, events, GATED, restart=1)
    assert n["restarts"] == 2 and _accounted(n)  # with k = 1 the outlier restarts it, and the next fix back
    out, n = fuse_fixes(0, _start(0.0), 0.0, 20.0, events, GATED, restart=2)
    assert n["restarts"] == 0 and n["gated"] == 1 and n["fused"] == 18 and _accounted(n)
    assert abs(SE2.to_xytheta(out.mean)[0] - 10.0) < 0.1


@pytest.mark.unit
@pytest.mark.parametrize("bad", [{"restart": 0}, {"inflate": 0.5}, {"inflate": float("nan")}])
def test_fuse_fixes_refuses_a_restart_below_one_fix_or_a_deflation(bad: dict[str, float]):
    from swarmloc.experiments.truthfree import fuse_fixes

    with pytest.raises(ValueError, match="fuse_fixes"):
        fuse_fixes(0, _start(0.0), 0.0, 20.0, _drive(), GATED, **bad)  # type: ignore[arg-type]


@pytest.mark.data
def test_the_fused_start_reacquires_dataset_9s_robots_and_counts_every_fix(mrclam_dataset: Callable[[int], Path]):
    from swarmloc.datasets.mrclam import load_mrclam
    from swarmloc.experiments.mrclam import detection_set
    from swarmloc.experiments.truthfree import fused_from_snapshots, initial_from_snapshots

    data = load_mrclam(mrclam_dataset(9))
    ds = detection_set(data)
    t0, _, locked = fused_from_snapshots(data, ds, restart=None)
    t1, beliefs, counts = fused_from_snapshots(data, ds)
    assert t0 == t1 == initial_from_snapshots(data, ds)[0] and set(beliefs) == set(data.robots)
    assert locked[1]["gated"] == 40 and counts[1]["restarts"] == 1 and counts[1]["fused"] == 38
    assert all(_accounted(n, n["fixes"]) for n in counts.values())  # the robot that defines t0 too (no fixes)


@pytest.mark.data
def test_a_recording_without_truth_starts_from_the_fused_snapshots(mrclam_dataset: Callable[[int], Path]):
    """``swarmloc evaluate``'s start without truth is the fused one, its fixes' counts in the start."""
    from swarmloc.datasets.mrclam import load_mrclam
    from swarmloc.experiments.mrclam import detection_set, mrclam_start
    from swarmloc.experiments.truthfree import fused_from_snapshots

    data = load_mrclam(mrclam_dataset(9))
    start = mrclam_start(data)
    t0, beliefs, counts = fused_from_snapshots(data, detection_set(data))
    assert not start.truth and start.t0 == t0 and start.fixes == counts and counts[1]["restarts"] == 1
    assert all(np.array_equal(start.beliefs[r].mean, b.mean) for r, b in beliefs.items())


@pytest.mark.data
def test_the_start_is_the_same_whatever_the_teams_association_and_clusters(mrclam_dataset: Callable[[int], Path]):
    """The start filters each robot alone on its own fixes, so ``--association`` and clusters leave it as it is:
    with ``association = "joint"`` its one-robot ``diekf`` refused to be built (a policy needs the team), and the
    run fell back to robots at ``(id, 0, 0)`` with 10 m std, from which ``anonymous`` on dataset 9 gave 20.6% of
    its 948 hand-offs the right robot in 200 s."""
    from swarmloc.config import DEFAULTS
    from swarmloc.datasets.mrclam import load_mrclam
    from swarmloc.experiments.mrclam import mrclam_start

    data = load_mrclam(mrclam_dataset(9))
    base = mrclam_start(data)
    for kw in ({"association": "joint"}, {"association": "nearest", "diekf_cluster": 2, "diekf_reform": 10.0}):
        s = mrclam_start(data, DEFAULTS.with_filter(**kw))
        assert s.how == base.how and s.t0 == base.t0 and s.fixes == base.fixes, (kw, s.how)
        for r, b in base.beliefs.items():
            np.testing.assert_array_equal(s.beliefs[r].mean, b.mean)
            np.testing.assert_array_equal(s.beliefs[r].cov, b.cov)


@pytest.mark.data
def test_only_the_datas_fault_falls_back_to_the_placeholder(mrclam_dataset: Callable[[int], Path], monkeypatch):
    """A recording that gives no truth-free start falls back to the placeholder and says why; anything else the
    start raises (a configuration its filters cannot run) is an error, not a start 10 m off."""
    import swarmloc.experiments.truthfree as tf
    from swarmloc.datasets.mrclam import load_mrclam
    from swarmloc.experiments.mrclam import mrclam_start

    data = load_mrclam(mrclam_dataset(9))

    def no_start(*_: object, **__: object) -> None:
        raise tf.NoStart("robot 3 never reads two landmarks at once")

    def bad_config(*_: object, **__: object) -> None:
        raise ValueError("diekf: some option it refuses")

    monkeypatch.setattr(tf, "_first_snapshots", no_start)
    s = mrclam_start(data)
    assert not s.truth and s.t0 == data.t_start and "robot 3 never reads" in s.how and "not poses" in s.how
    monkeypatch.setattr(tf, "_first_snapshots", bad_config)
    with pytest.raises(ValueError, match="some option it refuses"):
        mrclam_start(data)


@pytest.mark.unit
def test_a_fix_that_moves_no_counter_is_a_clear_error(monkeypatch: pytest.MonkeyPatch):
    import swarmloc.experiments.truthfree as tf

    class Silent:  # a node that takes every input and counts none
        def step(self, _: object) -> None:
            pass

        def stats(self) -> dict[str, int]:
            return dict.fromkeys(("fused", "gated", "rejected", "unknown"), 0)

    monkeypatch.setattr(tf, "make_team", lambda *a, **k: [Silent()])
    with pytest.raises(RuntimeError, match=r"fuse_fixes: the fix at 1.0 s moved the counters \[\]"):
        tf.fuse_fixes(0, _start(0.0), 0.0, 20.0, _drive(), GATED)
