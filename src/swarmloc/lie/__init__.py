"""Lie groups SE(2) and SE(3): hat, vee, exp, log, Ad, ad, Jacobians, BCH (batched numpy); planar poses as rows
``(x, y, theta)`` (:mod:`~swarmloc.lie.planar`)."""

from swarmloc.lie.base import SEGroup
from swarmloc.lie.planar import between_xyt, compose_xyt, exp_xyt, invert_xyt, log_xyt
from swarmloc.lie.se2 import SE2, wrap_angle
from swarmloc.lie.se3 import SE3

__all__ = ["SE2", "SE3", "SEGroup", "between_xyt", "compose_xyt", "exp_xyt", "invert_xyt", "log_xyt", "wrap_angle"]
