"""Lie groups SE(2) and SE(3): hat, vee, exp, log, Ad, ad, Jacobians, BCH (batched numpy)."""

from swarmloc.lie.base import SEGroup
from swarmloc.lie.se2 import SE2, wrap_angle
from swarmloc.lie.se3 import SE3

__all__ = ["SE2", "SE3", "SEGroup", "wrap_angle"]
