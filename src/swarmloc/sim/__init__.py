"""Simulation: differential-drive teams with odometry, relative/absolute sensors, and ready-made scenarios."""

from swarmloc.sim.anonymous import AnonymousSensor, anonymize, anonymize_sim, khepera_kidnap
from swarmloc.sim.scenarios import (
    THESIS_ROS_D,
    THESIS_START,
    random_team,
    thesis_ground_truth_neighbour,
    thesis_schedule,
    thesis_two_robot,
)
from swarmloc.sim.simulator import (
    AbsoluteSensor,
    RelativeSensor,
    SimConfig,
    SimResult,
    WheelSchedule,
    simulate,
    wrap_angle,
)

__all__ = [
    "THESIS_ROS_D",
    "THESIS_START",
    "AbsoluteSensor",
    "AnonymousSensor",
    "RelativeSensor",
    "SimConfig",
    "SimResult",
    "WheelSchedule",
    "anonymize",
    "anonymize_sim",
    "khepera_kidnap",
    "random_team",
    "simulate",
    "thesis_ground_truth_neighbour",
    "thesis_schedule",
    "thesis_two_robot",
    "wrap_angle",
]
