"""Kernels of the world-frame (invariant) error convention on SE(2), batched over leading axes.

A pose ``g`` with estimate ``g^`` has the *world-frame* (left) error ``xi`` with ``g = exp(hat(xi)) g^`` (Barrau &
Bonnabel's right-invariant error ``eta = g g^-1``). A rigid motion ``T`` of the whole team maps every ``g_i`` to
``T g_i``, so every robot's error moves by the same ``xi`` (to first order, ``xi_i -> log(T) + xi_i``): the team's
unobservable directions without absolute information are the constant columns ``[I; I; ...; I]``, whatever the
estimate. With the thesis' right perturbation ``g = g^ exp(y)`` (body frame) or with Cartesian errors the same
directions depend on the estimate, and an EKF that evaluates its Jacobians at moving estimates gains false
information along them (Huang, Mourikis & Roumeliotis 2011).

Relations used (``x = (x, y, theta)`` Cartesian, first order; all verified numerically in tests/test_invariant.py):

* a Cartesian perturbation is ``dx = N(x) xi`` with ``N(x) = [[1, 0, -y], [0, 1, x], [0, 0, 1]]``, the generator of
  a rigid motion of the world at ``x`` (:func:`world_basis`); so a Cartesian Jacobian ``H_c`` becomes ``H_c N(x)``
  and a Cartesian covariance ``P_c = N P_w N^T``;
* the thesis' body-frame coordinates are ``y = Ad(g^-1) xi`` (:func:`world_to_body`);
* the odometry step ``g+ = g Delta exp(w)`` gives ``xi+ = xi + Ad(g+) w``: the error transition is the identity and
  the process noise ``Q_w = N(x+)^-1 Q_c N(x+)^-T`` for the Cartesian process covariance ``Q_c`` of the same step
  (:func:`cartesian_to_world_cov`);
* the update's correction ``delta`` moves the estimate to ``exp(hat(delta)) g^`` (:func:`left_correct`).
"""

from __future__ import annotations

import numpy as np

from swarmloc.arrays import FloatArray
from swarmloc.lie import SE2, wrap_angle


def _T(a: FloatArray, i: int, j: int) -> FloatArray:
    """``np.swapaxes`` as the array method (the same view, without the function's dispatch)."""
    return a.swapaxes(i, j)


__all__ = [
    "cartesian_to_world_cov",
    "left_correct",
    "world_basis",
    "world_basis_inv",
    "world_delta",
    "world_to_body",
]


def world_basis(x: FloatArray) -> FloatArray:
    """``N(x) (..., 3, 3)``: Cartesian change ``dx`` of the pose ``x (..., 3)`` under the world-frame error ``xi``."""
    x = np.asarray(x, dtype=float)
    if x.shape == (3,):  # one pose: the same matrix, built directly
        return np.array([[1.0, 0.0, -x[1]], [0.0, 1.0, x[0]], [0.0, 0.0, 1.0]])
    N = np.broadcast_to(np.eye(3), (*x.shape[:-1], 3, 3)).copy()
    N[..., 0, 2] = -x[..., 1]
    N[..., 1, 2] = x[..., 0]
    return N


def world_basis_inv(x: FloatArray) -> FloatArray:
    """``N(x)^-1``."""
    x = np.asarray(x, dtype=float)
    if x.shape == (3,):
        return np.array([[1.0, 0.0, x[1]], [0.0, 1.0, -x[0]], [0.0, 0.0, 1.0]])
    N = np.broadcast_to(np.eye(3), (*x.shape[:-1], 3, 3)).copy()
    N[..., 0, 2] = x[..., 1]
    N[..., 1, 2] = -x[..., 0]
    return N


def cartesian_to_world_cov(x: FloatArray, P: FloatArray) -> FloatArray:
    """Covariance of the world-frame error from a Cartesian covariance at ``x``: ``N^-1 P N^-T``."""
    Ni = world_basis_inv(x)
    return Ni @ P @ _T(Ni, -1, -2)


def world_to_body(g: FloatArray, P: FloatArray) -> FloatArray:
    """Covariance of the body-frame (right-perturbation) error ``y = Ad(g^-1) xi`` at the pose matrix ``g``."""
    A = SE2.Ad(SE2.inverse(g, validate=False))
    return A @ P @ _T(A, -1, -2)


def left_correct(x: FloatArray, delta: FloatArray) -> FloatArray:
    """Cartesian pose of ``exp(hat(delta)) g(x)``: the estimate ``x (..., 3)`` corrected by a world-frame ``delta``."""
    g = SE2.exp(np.asarray(delta, dtype=float)) @ SE2.from_xytheta(np.asarray(x, dtype=float))
    th = wrap_angle(np.arctan2(g[..., 1, 0], g[..., 0, 0]))
    return np.stack([g[..., 0, 2], g[..., 1, 2], th], axis=-1)


def world_delta(x0: FloatArray, x1: FloatArray) -> FloatArray:
    """The world-frame correction ``delta (3,)`` with ``exp(hat(delta)) g(x0) = g(x1)`` (:func:`left_correct`'s
    inverse) of two Cartesian poses ``(3,)``."""
    return SE2.log(SE2.from_xytheta(x1) @ SE2.inverse(SE2.from_xytheta(x0), validate=False))
