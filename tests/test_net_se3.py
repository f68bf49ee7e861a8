"""3-D teams over the network (issue 22): schema 2 carries SE(3) beliefs, states and 6-dof team updates and
validates them on receipt; a live team of three processes on ``sim:3d`` (127.0.0.1) equals the in-process run to
1e-6 for ``expfusion``, ``dekf``, ``ci`` and ``diekf``."""

from __future__ import annotations

import os

import msgspec
import numpy as np
import pytest
from test_net import leftovers, max_diff

from swarmloc.estimators import accepted_options, estimator_class, make_team, node_options
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.lie import SE3
from swarmloc.messages import SCHEMA_VERSION, TeamUpdate, flat
from swarmloc.net.entry import distributed_class, make_node
from swarmloc.net.schema import Belief, Broadcast, Envelope, Rejected, decode, encode
from swarmloc.runner import run

pytestmark = pytest.mark.network


G = SE3.exp(np.array([1.0, 2.0, 3.0, 0.1, -0.2, 0.3]))


def reference3(src, est: str):
    """The in-process run with the options a node process takes (``make_node``: config's, the source's noise)."""
    cls = estimator_class(est, src.initial)
    opts = {k: v for k, v in node_options(est, src.config, src.landmarks).items() if k in accepted_options(cls)}
    return run(make_team(cls, src.initial, **{**opts, "noise": src.noise}), src.events, src.record_times())


def test_schema_version_bumped_and_se3_bodies_validated() -> None:
    assert SCHEMA_VERSION == 2
    ok = Belief(robot=0, stamp=1.0, mean=flat(G), cov=flat(np.eye(6) * 0.01), group="SE3")
    assert decode(encode("t", 0, 0, ok), "t", [0, 1]).body == ok
    bad_mean = list(flat(G))
    bad_mean[0] += 0.5
    bad = {
        "not in SE\\(3\\)": Belief(robot=0, stamp=1.0, mean=tuple(bad_mean), cov=flat(np.eye(6)), group="SE3"),
        "16 and 36": Belief(robot=0, stamp=1.0, mean=flat(G), cov=flat(np.eye(3)), group="SE3"),
        "positive definite": Belief(robot=0, stamp=1.0, mean=flat(G), cov=flat(-np.eye(6)), group="SE3"),
        "9 finite": Belief(robot=0, stamp=1.0, mean=flat(G), cov=flat(np.eye(6))),  # SE(3) numbers named SE2
    }
    for why, body in bad.items():
        with pytest.raises(Rejected, match=why):
            decode(encode("t", 0, 0, body), "t", [0, 1])
    eye = flat(np.eye(6))
    u = TeamUpdate(sender=0, receiver=-1, stamp=1.0, target=1, m=6, n=6, Hi=flat(-np.eye(6)), Hj=eye, Sinv=eye,
                   nu=(0.0,) * 6, Pii=eye, Pjj=eye)  # fmt: skip
    assert decode(encode("t", 0, 0, Broadcast(robot=0, n=0, update=u)), "t", [0, 1]).body.update == u
    short = msgspec.structs.replace(u, Pjj=eye[:9])
    with pytest.raises(Rejected, match="finite numbers"):
        decode(encode("t", 0, 0, Broadcast(robot=0, n=0, update=short)), "t", [0, 1])
    old = msgspec.msgpack.encode(Envelope(v=1, team="t", from_robot=0, seq=0, body=ok))
    with pytest.raises(Rejected, match="schema version 1"):
        decode(old, "t", [0, 1])


def test_make_node_follows_the_beliefs_group() -> None:
    src = load_source("sim:3d", robots=2, duration=1.0, seed=0)
    node = make_node("diekf", 0, src.initial[0], src.config, src.landmarks, team=src.robots, noise=src.noise)
    assert type(node).__name__ == "DistributedInvariantEKF" and node.group.name == "SE(3)" and node.team == (0, 1)
    with pytest.raises(ValueError, match="no SE\\(3\\) form"):
        distributed_class("rdl", src.initial[0])
    with pytest.raises(ValueError, match="not a distributed estimator"):
        distributed_class("cekf", src.initial[0])


@pytest.mark.parametrize("est", ["expfusion", "dekf", "ci", "diekf"])
def test_networked_equals_in_process_on_a_3d_team(est: str) -> None:
    src = load_source("sim:3d", robots=3, duration=6.0, seed=1)
    team = f"eq3d{est}{os.getpid()}"
    tr = run_team(src=src, source="sim:3d", robots=3, duration=6.0, seed=1, estimator=est, team=team, max_wall=120)
    assert not leftovers(team)
    assert all(c == 0 for c in tr.exit_codes.values()), tr.exit_codes
    res = team_result(tr, src, est)
    assert res.stats["reports"] == 3 and res.stats["recorded_provisional_only"] == 0
    ref = reference3(src, est)
    assert res.tracks[0].mean.shape[-1] == 7 and res.tracks[0].cov.shape[-1] == 6
    assert max_diff(res, ref) <= 1e-9  # every recorded mean (x, y, z, quaternion) and 6 x 6 covariance
    assert res.stats["fused"] == ref.stats["fused"] == res.stats["detections"] > 50
