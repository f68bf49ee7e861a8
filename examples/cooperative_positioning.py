"""The lecture's cooperative positioning, move-and-stop in two groups (``swarmloc.sim.scenarios``).

    python examples/cooperative_positioning.py

Group B drives while group A stands, then the other way round; at the end of each phase the robots that moved
measure their pose relative to the ones that stood still, which serve as landmarks. Any estimator runs on the
scenario's events; here the centralized EKF and recursive decentralized fusion against dead reckoning.
"""

import numpy as np

from swarmloc import SE2, GroupGaussian, make_team, run
from swarmloc.estimators import node_options
from swarmloc.sim.scenarios import cooperative_positioning
from swarmloc.sim.source import sim_source

scenario = cooperative_positioning(n_a=2, n_b=2, phases=8, seed=0)
source = sim_source(scenario, "sim:coop")
starts = scenario.initial_pose_matrices()  # the true starts, known to 1 mm / 1 mrad
known = {r: GroupGaussian(SE2, starts[r], np.eye(3) * 1e-6) for r in source.initial}
for estimator in ("dr", "cekf", "rdl"):
    nodes = make_team(estimator, known, **node_options(estimator, source.config, None))
    result = run(nodes, source.events, [39.9], truth=source.truth)
    errors = [np.linalg.norm(track.mean[-1, :2] - track.truth[-1, :2]) for track in result.tracks.values()]
    print(f"{estimator}: final position error {np.sqrt(np.mean(np.square(errors))):.3f} m (RMS of 4 robots)")
