"""Data association: which robot (or landmark) an anonymous detection saw.

``policies``: gated nearest neighbour (lecture slide 38, eq. 8) and joint assignment of a scan's detections
(slide 39, eq. 9) on squared Mahalanobis distances of the innovations, with clutter, ambiguous and missed outcomes.
"""

from swarmloc.association.policies import (
    AMBIGUOUS,
    CLUTTER,
    Association,
    gate_threshold,
    innovation_costs,
    joint,
    nearest,
)

__all__ = ["AMBIGUOUS", "CLUTTER", "Association", "gate_threshold", "innovation_costs", "joint", "nearest"]
