"""swarmloc: multi-robot cooperative localization on SE(2)/SE(3) in exponential coordinates."""

from swarmloc.fusion import fuse_absolute, fuse_relative
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, SE3

__all__ = ["SE2", "SE3", "GroupGaussian", "fuse_relative", "fuse_absolute"]
__version__ = "0.1.0"
