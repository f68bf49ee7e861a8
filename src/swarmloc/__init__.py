"""swarmloc: multi-robot cooperative localization on SE(2)/SE(3) in exponential coordinates.

What a user needs is here: the groups (:class:`SE2`, :class:`SE3`), Gaussians on them (:class:`GroupGaussian`),
the fusion functions, the estimators as nodes (one per robot; :func:`make_team` builds a team) and the in-process
runner (:func:`run`). Importing swarmloc loads numpy, scipy and msgspec only: figures, tables and progress bars
live with the experiments and the command line.

The names are loaded on first use (``from swarmloc import run`` or ``swarmloc.run``), not by ``import swarmloc``
itself: a program that only needs a part of the package (the command line, which parses its arguments before
anything else; a network process, which must be able to end with its launcher from its first moment) does not wait
for the whole numerical core to load.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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

_HOME = {
    "estimators": ("ESTIMATORS", "CentralizedEKF", "DeadReckoning", "DistributedEKF", "ExpCI", "ExpFusion", "Node",
                   "RecursiveDecentralized", "RobotNode", "make_team"),
    "events": ("Detection", "Odometry", "Truth"),
    "fusion": ("fuse_absolute", "fuse_point_measurement", "fuse_relative"),
    "gaussian": ("GroupGaussian", "world_covariance"),
    "lie": ("SE2", "SE3"),
    "motion": ("UnicycleNoise",),
    "runner": ("RobotTrack", "RunResult", "run"),
}  # fmt: skip
"""The subpackage each public name is defined in (the imports above, which type checkers read)."""
_MODULE_OF = {name: module for module, names in _HOME.items() for name in names}

if not TYPE_CHECKING:  # type checkers read the imports above, and flag a name that is not there

    def __getattr__(name: str) -> Any:
        """A public name, imported from its subpackage on first use and kept (PEP 562)."""
        if name not in _MODULE_OF:
            raise AttributeError(f"module 'swarmloc' has no attribute {name!r}")
        value = globals()[name] = getattr(import_module(f"swarmloc.{_MODULE_OF[name]}"), name)
        return value

    def __dir__() -> list[str]:
        return sorted({*globals(), *__all__})
