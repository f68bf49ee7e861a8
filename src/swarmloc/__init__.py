"""swarmloc: multi-robot cooperative localization on SE(2)/SE(3) in exponential coordinates."""

from swarmloc.lie import SE2, SE3

__all__ = ["SE2", "SE3"]
__version__ = "0.1.0"
