"""Drivers of nodes. :func:`run` is the in-process one (tests, simulation, datasets); the network process and the
batched engine drive the same nodes and kernels."""

from swarmloc.runner.inprocess import TruthFn, run, truth_table
from swarmloc.runner.result import RobotTrack, RunResult

__all__ = ["RobotTrack", "RunResult", "TruthFn", "run", "truth_table"]
