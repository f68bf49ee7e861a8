"""The codes every module of the engine shares, its compiled kernels included: detection kinds, target codes,
outcomes and their reasons. The bottom layer of :mod:`swarmloc.engine`: it imports no other engine module.

Kinds are numbered by their rank in a detection group's canonical order and described by the shared measurement
models (:data:`swarmloc.sensors.models.MODELS`: size, angles, prediction, residual, noise): the engine keeps no
table of kinds of its own.
"""

from __future__ import annotations

from swarmloc.estimators.rdl import UNKNOWN_CORRELATION
from swarmloc.events import Kind
from swarmloc.node.update import NONFINITE, NUMERICAL
from swarmloc.sensors.models import DEGENERATE, KIND_ORDER, MODELS, MeasurementModel
from swarmloc.sensors.models3 import MODELS3

KINDS: dict[int, str] = {code: kind for kind, code in KIND_ORDER.items()}
"""Kind code (the canonical order :data:`swarmloc.sensors.models.KIND_ORDER`) -> name."""
MODEL: dict[int, MeasurementModel] = {KIND_ORDER[kind]: m for kind, m in MODELS.items()}
"""Kind code -> its :class:`~swarmloc.sensors.models.MeasurementModel`."""
ABSOLUTE, POSE = KIND_ORDER[Kind.ABSOLUTE], KIND_ORDER[Kind.POSE]
POSE3 = MODELS3[Kind.POSE3].order
"""Kind code of an SE(3) relative pose (``"pose3"``, :data:`swarmloc.sensors.models3.MODELS3`): the one kind an SE(3)
team's engine fuses."""
KIND_NAMES: dict[int, str] = {**KINDS, POSE3: Kind.POSE3}
"""Kind code -> name, the planar kinds and ``"pose3"``."""

NO_TARGET = -1
"""Target code of an absolute fix."""
UNKNOWN_ROBOT = -2
"""Target code of a robot outside the team or a landmark not in the map (the detection is counted ``unknown``)."""
UNUSABLE = -3
"""Target code of a detection its group holds but no filter can use (no target id, the pose of a landmark):
counted ``rejected``."""

NO_LANDMARK = -4
"""Target code of a landmark detection whose landmark is not in the engine's map (counted ``unknown``). A landmark
in the map, at row ``k`` of the map's sorted ids, has code ``NO_LANDMARK - 1 - k`` (:func:`landmark_code`)."""


def landmark_code(k: int) -> int:
    """Target code of the landmark at row ``k`` of the engine's map (``-5, -6, ...``)."""
    return NO_LANDMARK - 1 - k


PENDING, FUSED, GATED, REJECTED, UNKNOWN = range(5)
OUTCOMES = ("pending", "fused", "gated", "rejected", "unknown")
"""Outcome code -> the name the nodes count it under."""
REASONS = (
    "",
    "the target is the observer itself",
    "relative measurements are switched off",
    "no answer: the robot is not in the team",
    "no answer: the robot had not started",
    "the observer had not started",
    "no usable target (a robot detection without a target id, or the pose of a landmark)",
    NONFINITE,
    DEGENERATE,
    NUMERICAL,
    "landmark measurements are switched off",
    "the landmark is not in the map",
    UNKNOWN_CORRELATION,
)
"""Reason code -> the nodes' text (0: none)."""
R_SELF, R_OFF, R_TEAM, R_NOT_STARTED, R_OBSERVER, R_UNUSABLE, R_NONFINITE, R_DEGENERATE, R_NUMERICAL = range(1, 10)
R_LANDMARKS_OFF, R_NO_LANDMARK, R_CORRELATION = 10, 11, 12
