"""Motion models: the differential-drive SDE on SE(2), increment mean/covariance, closed forms, sampling, odometry.

Conventions: SE(2) exponential coordinates ``(v1, v2, alpha)``, right perturbation ``g = mu exp(y^)``, body twist
``h = (forward speed, lateral speed, yaw rate)``, diffusion ``Q = H H^T`` per second; all batched over leading axes.
:mod:`swarmloc.motion.calibrate` fits the yaw diffusion's scale to a recording's own pose snapshots (no truth).
"""

from swarmloc.motion._stable import SERIES, SERIES_BELOW
from swarmloc.motion.closed_form import (
    circular_cov,
    circular_mean,
    constant_twist_cov,
    increment_mean_closed,
    straight_line_cov,
    straight_line_mean,
    thesis_circular_cov,
    thesis_straight_cov,
    unicycle_cov,
)
from swarmloc.motion.diffdrive import DiffDrive
from swarmloc.motion.propagation import increment_cov, increment_mean, increment_mean_second_order
from swarmloc.motion.sde import euler_maruyama
from swarmloc.motion.unicycle import UnicycleNoise, odometry_increment, odometry_increment_terms

__all__ = [
    "SERIES",
    "SERIES_BELOW",
    "DiffDrive",
    "UnicycleNoise",
    "circular_cov",
    "circular_mean",
    "constant_twist_cov",
    "euler_maruyama",
    "increment_cov",
    "increment_mean",
    "increment_mean_closed",
    "increment_mean_second_order",
    "odometry_increment",
    "odometry_increment_terms",
    "straight_line_cov",
    "straight_line_mean",
    "thesis_circular_cov",
    "thesis_straight_cov",
    "unicycle_cov",
]
