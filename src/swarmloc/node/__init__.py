"""The node: one robot's (or, centralized, the team's) filter as a sans-I/O state machine, in parts.

:class:`Node` (:mod:`~swarmloc.node.base`) composes the parts; :class:`RobotNode` is the base of the distributed
estimators (:mod:`swarmloc.estimators`). Parts: :mod:`~swarmloc.node.clock` (present, horizon, tolerance, clock
jumps), :mod:`~swarmloc.node.inputs` (the input contract, odometry timelines), :mod:`~swarmloc.node.intake` (the
robot's own inputs taken), :mod:`~swarmloc.node.history` (entries, states), :mod:`~swarmloc.node.filing` (entries
filed, replayed, pruned), :mod:`~swarmloc.node.protocol` (messages accepted, answered, refused, revised),
:mod:`~swarmloc.node.accounting` (counters that add up), :mod:`~swarmloc.node.update` (the one Kalman update
with its gate), :mod:`~swarmloc.node.keys` (history keys, entries, detection groups), :mod:`~swarmloc.node.trust`
(teammates' messages checked, suspects, quarantine).
"""

from swarmloc.node.accounting import OUTCOMES, STAT_KEYS, Accounting
from swarmloc.node.base import Node, belief_of
from swarmloc.node.clock import DEFAULT_CONFIRM, DEFAULT_HORIZON, DEFAULT_TOLERANCE, Clock
from swarmloc.node.inputs import Landmarks, OdometryTimeline, landmark_state, odometry_problem, validate_detection
from swarmloc.node.keys import P_GROUP, P_ODOMETRY, Entry, Group, Key, detection_key
from swarmloc.node.protocol import belief_answer, refusal, same
from swarmloc.node.robot import RobotNode, check_model
from swarmloc.node.team import TeamNode
from swarmloc.node.trust import DEFAULT_QUARANTINE, broadcast_nis, correction_nis, fits
from swarmloc.node.update import (
    FUSED,
    NUMERICAL,
    Gate,
    Outcome,
    applied,
    chi2_ppf,
    gated_kalman,
    positive_definite,
    usable_covariance,
)

__all__ = [
    "DEFAULT_CONFIRM",
    "DEFAULT_HORIZON",
    "DEFAULT_QUARANTINE",
    "DEFAULT_TOLERANCE",
    "FUSED",
    "NUMERICAL",
    "OUTCOMES",
    "P_GROUP",
    "P_ODOMETRY",
    "STAT_KEYS",
    "Accounting",
    "Clock",
    "Entry",
    "Gate",
    "Group",
    "Key",
    "Landmarks",
    "Node",
    "OdometryTimeline",
    "Outcome",
    "applied",
    "RobotNode",
    "TeamNode",
    "belief_answer",
    "belief_of",
    "broadcast_nis",
    "check_model",
    "chi2_ppf",
    "correction_nis",
    "detection_key",
    "fits",
    "gated_kalman",
    "landmark_state",
    "odometry_problem",
    "positive_definite",
    "refusal",
    "same",
    "usable_covariance",
    "validate_detection",
]
