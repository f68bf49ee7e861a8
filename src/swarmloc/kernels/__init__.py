"""Pure batched kernels: the math every driver shares (nodes call them with batch size 1, a batched engine with N).

* :mod:`swarmloc.kernels.group`: exponential-coordinate prediction and updates on the group (thesis estimator,
  covariance intersection);
* :mod:`swarmloc.kernels.cartesian`: EKF prediction, the one Kalman (Joseph) update, Cartesian <-> group beliefs;
* :mod:`swarmloc.kernels.ci`: the covariance-intersection weight search;
* :mod:`swarmloc.kernels.pairs`: ``rdl``'s pair math (factors, joint prior), plain for the nodes, compiled by numba
  for the engine's replay.

Arrays are batched over leading axes: poses ``(..., 3, 3)``, states ``(..., 3)``, covariances ``(..., 3, 3)``.
No kernel validates its input: nodes validate what comes in, once.
"""

from swarmloc.kernels import cartesian, ci, group

__all__ = ["cartesian", "ci", "group"]
