"""The book chapter's serial and parallel fusion (Song, Tsai and Chiu Huang 2010; :mod:`swarmloc.fusion_book`).

    python examples/book_fusion.py

Serial fusion: robot 1 at ``(x, y, theta)`` with its covariance sees robot 2 at a relative pose in its own frame;
the result is robot 2's pose in the world with the observer's uncertainty carried into it (eqs 7-8). Parallel
fusion merges every estimate of robot 2 (its own and each observer's) into one (eqs 34-35); it never grows a
covariance. ``serial_jacobian`` is the Jacobian of eq. (4) with its third row corrected: serial fusion's covariance
is ``J diag(C_r, C_e) J^T``. Last, the chapter's two-robot experiment: dead reckoning alone against the cooperative
team.
"""

import numpy as np

from swarmloc.fusion_book import (
    book_two_robot_scenario,
    parallel_fusion,
    run_book_fusion,
    serial_fusion,
    serial_jacobian,
)

# robot 1 at (1 m, 2 m, 0.7 rad) sees robot 2 1.5 m ahead and 0.8 m to its right, turned by 0.3 rad
observer, observer_cov = np.array([1.0, 2.0, 0.7]), np.diag([0.01, 0.02, 0.003])
z, z_cov = np.array([1.5, -0.8, 0.3]), np.diag([0.004, 0.006, 0.002])
seen_mean, seen_cov = serial_fusion(observer, observer_cov, z, z_cov)
print("robot 2 as robot 1 sees it:", np.round(seen_mean, 3), "std", np.round(np.sqrt(np.diag(seen_cov)), 3))
J = serial_jacobian(observer, z)  # (3, 6): d(robot 2's pose) / d(observer's pose, relative pose)
print("Jacobian's heading row (corrected; printed [0, 1, 0, 0, 0, 1]):", J[2])

own_mean, own_cov = np.array([2.7, 2.4, 1.05]), np.diag([0.04, 0.04, 0.01])  # robot 2's own dead reckoning
fused_mean, fused_cov = parallel_fusion([(own_mean, own_cov), (seen_mean, seen_cov)])
print("robot 2 fused:", np.round(fused_mean, 3), "std", np.round(np.sqrt(np.diag(fused_cov)), 3))

scenario = book_two_robot_scenario(seed=0, n_moves=60)
alone, alone_cov = run_book_fusion(scenario, cooperative=False)
team, team_cov = run_book_fusion(scenario, cooperative=True)
truth = scenario.truth[-1, :, :2]
for name, m, c in (("dead reckoning", alone, alone_cov), ("cooperative", team, team_cov)):
    error = np.linalg.norm(m[-1] - truth, axis=-1)
    std = np.sqrt(np.trace(c[-1], axis1=-2, axis2=-1))
    print(f"{name}: final position error {np.round(error, 3)} m, std {np.round(std, 3)} m (H1, H2)")
