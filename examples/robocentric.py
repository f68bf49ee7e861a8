"""The lecture's robocentric filters: relative and absolute mutual localization (``swarmloc.estimators.robocentric``).

    python examples/robocentric.py

Robot 1 tracks where its two teammates are *in its own moving frame*: it knows each robot's odometry displacement
and every robot measures every other's relative pose. :class:`JointRobocentricEKF` keeps the joint covariance;
:class:`SeparateRobocentricEKF` one filter per teammate, which turns a teammate-to-teammate measurement into robot
1's frame with an estimate and so grows over-confident. ``robocentric_monte_carlo`` measures both by NEES against
the chi-square band; ``absolute_mutual`` gives the pose of a teammate's fixed frame in robot 1's fixed frame.
"""

import numpy as np

from swarmloc.estimators.robocentric import (
    JointRobocentricEKF,
    SeparateRobocentricEKF,
    absolute_mutual,
    compose,
    inverse,
)
from swarmloc_studies.robocentric import robocentric_monte_carlo

rng = np.random.default_rng(1)
poses = np.array([[0.0, 0.0, 0.0], [2.0, 1.0, 0.5], [1.0, -2.0, -1.0]])  # the three robots in the world [m, rad]


def relative(a: int, b: int) -> np.ndarray:
    """The true pose of robot ``b`` in robot ``a``'s frame (robots indexed 0, 1, 2 here)."""
    return compose(inverse(poses[a])[0], poses[b])[0]


Q, R = np.diag([1e-4, 1e-4, 1e-4]), np.diag([0.05, 0.05, 0.02]) ** 2  # odometry and measurement noise
q0 = np.array([relative(0, 1), relative(0, 2)])  # robot 1's start knowledge of its teammates (index 0 and 1)
P0 = np.eye(6) * 1e-4
filters = {"joint": JointRobocentricEKF(q0, P0, Q, np.stack([Q, Q])),
           "separate": SeparateRobocentricEKF(q0, P0, Q, np.stack([Q, Q]))}  # fmt: skip
for _ in range(30):  # 30 steps
    u = np.column_stack([rng.uniform(0.05, 0.15, 3), np.zeros(3), rng.uniform(-0.1, 0.1, 3)])  # true moves
    poses = np.array([compose(poses[i], u[i])[0] for i in range(3)])
    u_read = u + rng.multivariate_normal(np.zeros(3), Q, size=3)  # odometry as the robots read it
    for f in filters.values():
        f.predict(u_read[0], u_read[1:])
    for a in range(3):
        for b in range(3):
            if a != b:
                z = relative(a, b) + rng.multivariate_normal(np.zeros(3), R)
                for f in filters.values():
                    f.update(a - 1, b - 1, z, R)  # robot 1 is index -1 in the filters, its teammates 0 and 1
truth = np.array([relative(0, 1), relative(0, 2)])
for name, f in filters.items():
    print(f"{name}: position error {np.linalg.norm(f.q[:, :2] - truth[:, :2], axis=1).round(3)} m,"
          f" x std {np.sqrt(np.diag(f.P)[[0, 3]]).round(3)} m (teammates 2 and 3)")  # fmt: skip

# absolute mutual localization: robot 2's fixed frame in robot 1's, from the relative pose of their moving frames
# and each robot's pose in its own fixed frame (odometry since its start)
frame, frame_cov = absolute_mutual(filters["joint"].q[0], filters["joint"].P[:3, :3], np.array([3.0, 0.2, 0.1]),
                                   np.eye(3) * 1e-3, np.array([2.5, -0.4, 0.3]), np.eye(3) * 1e-3)  # fmt: skip
print("robot 2's fixed frame in robot 1's:", frame.round(3), "std", np.sqrt(np.diag(frame_cov)).round(3))

mc = robocentric_monte_carlo(runs=20, steps=30, robots=4, seed=0)  # 4 robots, 20 runs of 30 steps
lo, hi = mc["band"]
for name in ("joint", "separate"):
    print(f"{name}: ANEES {mc[name + '_mean_anees']:.2f}, inside the 95% band {lo:.2f}-{hi:.2f} at"
          f" {100 * mc[name + '_in_band']:.0f}% of the steps")  # fmt: skip
