"""The lecture's static sensor-network localization from ranges (:mod:`swarmloc.estimators.sensor_network`).

    python examples/sensor_network.py

Three anchors know where they are; five nodes measure ranges to some neighbours (5 cm std). ``rigidity_report``
says whether the measurement graph fixes every node (and names the nodes when it does not); ``localize_network``
solves the weighted least squares and gives each node's position with its covariance. Its start is MDS-MAP
(``mds_initialization``: classical MDS of the shortest-path distances, fitted onto the anchors), which alone is
already near but the least squares improves on.
"""

import numpy as np

from swarmloc.estimators.sensor_network import (
    RangeMeasurement,
    localize_network,
    mds_initialization,
    rigidity_report,
)

anchors = {0: (0.0, 0.0), 1: (10.0, 0.0), 2: (0.0, 10.0)}
nodes = {10: (2.0, 3.0), 11: (7.0, 2.0), 12: (4.0, 7.0), 13: (8.0, 8.0), 14: (5.0, 4.5)}
where = {**anchors, **nodes}
pairs = [(0, 10), (0, 11), (0, 14), (1, 11), (1, 13), (1, 14), (2, 10), (2, 12), (2, 13), (10, 11), (10, 12),
         (10, 14), (11, 13), (11, 14), (12, 13), (12, 14), (13, 14)]  # fmt: skip
rng = np.random.default_rng(0)
ranges = [RangeMeasurement(i, j, float(np.hypot(*np.subtract(where[i], where[j])) + rng.normal(0, 0.05)), 0.05)
          for i, j in pairs]  # fmt: skip

print("localizable:", rigidity_report(ranges, anchors).localizable)
solution = localize_network(ranges, anchors)
for node in solution.node_ids:
    std = np.sqrt(np.diag(solution.marginal(node)))
    print(f"node {node}: {solution.positions[node].round(3)} m (true {nodes[node]}), std {std.round(3)} m")
print(f"chi-square {solution.chi2:.1f} for {solution.dof} degrees of freedom")
true = np.array([nodes[node] for node in solution.node_ids])
start = mds_initialization(ranges, anchors)  # node -> (2,) [m], the least squares' start
start_rms = np.sqrt(np.mean([np.sum((start[node] - nodes[node]) ** 2) for node in nodes]))
rms = np.sqrt(np.mean(np.sum((solution.position_array() - true) ** 2, axis=1)))
print(f"position RMS error: MDS-MAP start {start_rms:.3f} m, least squares {rms:.3f} m")

# without its ranges to anchors 1 and 2 and to node 14, node 13 hangs on two neighbours: refused, and named
weak = [m for m in ranges if (m.i, m.j) not in ((1, 13), (2, 13), (13, 14))]
for problem in rigidity_report(weak, anchors).problems:
    print("refused:", problem)
