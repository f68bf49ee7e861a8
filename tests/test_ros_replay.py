"""The offline replay of ROS input messages leaves out the input events a live node refused
(:func:`swarmloc.ros.replay.replay_messages` ``refused``): a late detection is as if its message never came; a late
odometry message keeps its sample (the next interval starts there) and loses only the interval it closes."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.lie import SE2
from swarmloc.ros.params import load_params
from swarmloc.ros.replay import leave_out, replay_messages
from swarmloc.ros.simulate import team_messages
from swarmloc.ros.timeline import InputTimeline, refused_key, refused_record

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def team():
    src = load_source("sim:random", robots=3, duration=4.0, seed=1)
    params = {}
    for r in src.robots:
        xyt = SE2.to_xytheta(np.asarray(src.initial[r].mean))
        over = {"robot_id": r, "team_robots": list(src.robots), "no_auth": True, "frequency": 5.0,
                "initial_state": [float(v) for v in xyt], "initial_covariance": [1e-4] * 3,
                "odom_frame": f"robot{r}/odom", "base_link_frame": f"robot{r}/base_link"}  # fmt: skip
        params[r] = load_params([], over, "swarmloc", f"/robot{r}")
    messages = {r: [(kind, m) for _, rr, kind, m in team_messages(src, 0.0) if rr == r] for r in src.robots}
    return messages, params


def events_of(messages, params, r):
    """Robot ``r``'s events, per message, as the node's timeline makes them."""
    p = params[r]
    tl = InputTimeline(r, base_frame=p.base_link_frame, robots=frozenset(p.team_ids))
    return [getattr(tl, kind)(m) for kind, m in messages[r]]


def beliefs(res, r):
    return np.array([np.concatenate([SE2.to_xytheta(b.mean), b.cov.ravel()]) for b in res.beliefs[r]])


def test_a_refused_detection_is_left_out_as_if_its_message_never_came(team):
    messages, params = team
    r = 2
    per_msg = events_of(messages, params, r)
    k = next(i for i, evs in enumerate(per_msg) if len(evs) == 1 and isinstance(evs[0], Detection) and i > 10)
    rec = refused_record(per_msg[k][0], "stale")
    assert rec["kind"] == "detection" and rec["robot"] == r and rec["reason"] == "stale"
    full = replay_messages(messages, params)
    got = replay_messages(messages, params, refused=[rec])
    without = replay_messages({**messages, r: messages[r][:k] + messages[r][k + 1 :]}, params)
    assert got.stats["fused"] == full.stats["fused"] - 1 == without.stats["fused"]
    for q in messages:
        np.testing.assert_array_equal(got.times[q], without.times[q])
        np.testing.assert_array_equal(beliefs(got, q), beliefs(without, q))
    assert np.abs(beliefs(got, r) - beliefs(full, r)).max() > 1e-6  # the detection mattered


def test_a_refused_odometry_message_loses_its_interval_and_keeps_its_sample(team):
    messages, params = team
    r = 1
    per_msg = events_of(messages, params, r)
    k = next(i for i, evs in enumerate(per_msg) if evs and isinstance(evs[0], Odometry) and i > 10)
    lost = per_msg[k][0]
    rec = refused_record(lost, "stale")
    assert (rec["kind"], rec["t0"], rec["t1"]) == ("odometry", lost.t0, lost.t1)
    every = [e for evs in per_msg for e in evs]
    kept = leave_out(every, Counter([refused_key(rec)]))
    assert kept == [e for e in every if e is not lost]  # only that interval; the next one starts at its end
    after = next(e for e in every[every.index(lost) + 1 :] if isinstance(e, Odometry))
    assert after.t0 == lost.t1
    full = replay_messages(messages, params)
    got = replay_messages(messages, params, refused=[rec])
    np.testing.assert_array_equal(got.times[r], full.times[r])
    before = full.times[r] <= lost.t0
    np.testing.assert_array_equal(beliefs(got, r)[before], beliefs(full, r)[before])
    assert np.abs(beliefs(got, r)[~before] - beliefs(full, r)[~before]).max() > 1e-6
    np.testing.assert_array_equal(got.timelines[r].odom_at(lost.t1)[0], full.timelines[r].odom_at(lost.t1)[0])


def test_a_refused_input_the_messages_do_not_make_is_an_error(team):
    messages, params = team
    rec = {"kind": "odometry", "robot": 0, "stamp": -5.0, "t0": -5.0, "t1": -4.9, "reason": "stale"}
    with pytest.raises(ValueError, match="do not make"):
        replay_messages(messages, params, refused=[rec])
