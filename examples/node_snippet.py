"""Two robots' nodes driven by hand: odometry, a detection of a teammate and its answer, and what ``node.x`` says.

    python examples/node_snippet.py

``node.x`` (and ``node.P``) is the pose at the node's *present*: the stamp of the latest input it has filed. An
odometry record is filed at its start ``t0`` (its command is in force from then on), so after the odometry over
[0, 0.5] s alone the present is still 0 and ``x`` the start pose; ``node.belief(0.5)`` is the pose at 0.5 s,
predicted with that command. A detection of a teammate waits for the teammate's answer; once the answer is
stepped in, it is filed and the present moves to its stamp. ``swarmloc.run(nodes, events)`` does the routing
for a whole team.
"""

import numpy as np

from swarmloc import SE2, Detection, ExpFusion, GroupGaussian, Odometry, UnicycleNoise, world_covariance


def start(robot: int, x: float) -> ExpFusion:
    """Robot ``robot``'s node, known to start at ``(x, 0, 0)`` at t = 0 (1 cm, 0.6 deg)."""
    belief = GroupGaussian(SE2, SE2.from_xytheta([x, 0.0, 0.0]), 1e-4 * np.eye(3))
    return ExpFusion(robot, belief, noise=UnicycleNoise(), t0=0.0, gate=0.997)


node, teammate = start(0, 0.0), start(1, 1.2)
node.step(Odometry(0, 0.0, 0.5, 0.4, 0.1))  # command (0.4 m/s, 0.1 rad/s) over [0, 0.5] s
print(node)  # present 0: the odometry is filed at its start t0; x is the start pose
at_half = node.belief(0.5)  # the belief at 0.5 s: 0.2 m driven
print("belief at 0.5 s:", at_half)
x_half, P_half = world_covariance(at_half.mean, at_half.cov)  # (x, y, theta) and its world-frame covariance

(query,) = node.step(Detection(0, 0.3, "pose", np.array([1.0, 0.0, 0.0]), 1e-3 * np.eye(3), target=1))
print(query)  # robot 0 asks robot 1 for its belief at 0.3 s; the detection waits (pending)
(answer,) = teammate.step(query)  # robot 1's node answers (over a network: a message)
node.step(answer)  # the detection is fused and filed: the present is 0.3 s
print(node)  # x: the pose at 0.3 s, pulled toward what robot 1's answer and the detection say
x, P = node.x, node.P  # read-only copies, filterpy's names
stats = node.stats()
print({k: stats[k] for k in ("detections", "fused", "gated", "rejected", "unknown", "pending")})
