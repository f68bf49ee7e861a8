"""swarmloc: multi-robot cooperative localization on SE(2)/SE(3) in exponential coordinates.

What a user needs is here: the groups (:class:`SE2`, :class:`SE3`), Gaussians on them (:class:`GroupGaussian`),
the fusion functions, the estimators as nodes (one per robot; :func:`make_team` builds a team) and the in-process
runner (:func:`run`). Importing swarmloc loads numpy, scipy and msgspec only: figures, tables and progress bars
live with the experiments and the command line.
"""

from swarmloc.estimators import (
    ESTIMATORS,
    CentralizedEKF,
    DeadReckoning,
    DistributedEKF,
    ExpCI,
    ExpFusion,
    Node,
    RecursiveDecentralized,
    RobotNode,
    make_team,
)
from swarmloc.events import Detection, Odometry, Truth
from swarmloc.fusion import fuse_absolute, fuse_point_measurement, fuse_relative
from swarmloc.gaussian import GroupGaussian, world_covariance
from swarmloc.lie import SE2, SE3
from swarmloc.motion import UnicycleNoise
from swarmloc.runner import RobotTrack, RunResult, run

__all__ = [
    "ESTIMATORS",
    "SE2",
    "SE3",
    "CentralizedEKF",
    "DeadReckoning",
    "Detection",
    "DistributedEKF",
    "ExpCI",
    "ExpFusion",
    "GroupGaussian",
    "Node",
    "Odometry",
    "RecursiveDecentralized",
    "RobotNode",
    "RobotTrack",
    "RunResult",
    "Truth",
    "UnicycleNoise",
    "fuse_absolute",
    "fuse_point_measurement",
    "fuse_relative",
    "make_team",
    "run",
    "world_covariance",
]
__version__ = "0.1.0"
