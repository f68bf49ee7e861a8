"""The public names of :mod:`swarmloc`, each from the subpackage that defines it (loaded on first use)."""

from .estimators import ESTIMATORS as ESTIMATORS
from .estimators import CentralizedEKF as CentralizedEKF
from .estimators import DeadReckoning as DeadReckoning
from .estimators import DistributedEKF as DistributedEKF
from .estimators import ExpCI as ExpCI
from .estimators import ExpFusion as ExpFusion
from .estimators import Node as Node
from .estimators import RecursiveDecentralized as RecursiveDecentralized
from .estimators import RobotNode as RobotNode
from .estimators import make_team as make_team
from .events import Detection as Detection
from .events import Odometry as Odometry
from .events import Truth as Truth
from .fusion import fuse_absolute as fuse_absolute
from .fusion import fuse_point_measurement as fuse_point_measurement
from .fusion import fuse_relative as fuse_relative
from .gaussian import GroupGaussian as GroupGaussian
from .gaussian import world_covariance as world_covariance
from .lie import SE2 as SE2
from .lie import SE3 as SE3
from .motion import UnicycleNoise as UnicycleNoise
from .runner import RobotTrack as RobotTrack
from .runner import RunResult as RunResult
from .runner import run as run

__all__: list[str]
__version__: str
