"""Estimators behind one protocol (predict / update / belief): dead reckoning, the thesis estimator,
the distributed EKF, the centralized CL-EKF and consistent distributed fusion."""

from swarmloc.estimators.base import CallbackChannel, Channel, Estimator, NoChannel
from swarmloc.estimators.consistent import ExpCI, RecursiveDecentralized
from swarmloc.estimators.ekf import CentralizedEKF, DistributedEKF
from swarmloc.estimators.expfusion import DeadReckoning, ExpFusion

__all__ = [
    "CallbackChannel",
    "CentralizedEKF",
    "Channel",
    "DeadReckoning",
    "DistributedEKF",
    "Estimator",
    "ExpCI",
    "ExpFusion",
    "RecursiveDecentralized",
    "NoChannel",
    "ESTIMATORS",
]

ESTIMATORS = {
    "dr": DeadReckoning,
    "expfusion": ExpFusion,
    "dekf": DistributedEKF,
    "cekf": CentralizedEKF,
    "ci": ExpCI,
    "rdl": RecursiveDecentralized,
}
"""Estimator classes by their command-line name."""
