"""Anonymous mutual localization (the lecture's slides 41-63; :mod:`swarmloc.association`).

    python examples/anonymous_localization.py

Four robots see each other as anonymous points (a laser finds *a* robot, not which one) with 1 cm noise. Robot 0
runs probabilistic multiple registration (PMR) on its own points and those its teammates sent: every placement of
the teammates, with identities, that all the registrations agree on. When the robots stand on a square, rotating
the team by a quarter turn changes nothing robot 0 can see: the symmetry metric is 0 and slide 45's count is
``(4 - 1)! = 6`` solutions, which PMR finds. Move one robot 30 cm and the metric is positive, and the solution
unique: each teammate's pose in robot 0's frame, within a few centimetres.
"""

import numpy as np

from swarmloc.association import multiple_registration, solution_count_theory, symmetry_metric
from swarmloc.lie import between_xyt

rng = np.random.default_rng(0)
sigma = 0.01  # the points' noise [m]
square = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
moved = square + [[0.3, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]
for name, where in (("square", square), ("one robot moved", moved)):
    poses = np.column_stack([where, rng.uniform(-np.pi, np.pi, 4)])  # (x, y, heading) in the world
    # what each robot sees: the others' positions in its own frame, shuffled (anonymous), with noise
    observations = {}
    for i in range(4):
        seen = np.delete(between_xyt(poses[i], poses)[:, :2], i, axis=0)
        observations[i] = rng.permutation(seen + sigma * rng.standard_normal(seen.shape))
    result = multiple_registration(observations, 0, sigma)
    if name == "square":
        square_result = result
    print(f"{name}: symmetry metric {symmetry_metric(where):.3f} m, {len(result.solutions)} solution(s) "
          f"(theory {solution_count_theory(where, 0)})")  # fmt: skip
for j, pose in sorted(result.solutions[0].poses.items())[1:]:  # robot 0 itself is at the origin
    error = np.hypot(*(pose[:2] - between_xyt(poses[0], poses[j])[:2]))
    print(f"robot {j} in robot 0's frame: {pose.round(3)} (position error {error:.3f} m)")
