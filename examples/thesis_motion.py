"""The thesis' closed forms of the motion increment (chapter 5; :mod:`swarmloc.motion`) against the general forms
the estimators use.

    python examples/thesis_motion.py

A differential-drive robot with constant wheel speeds drives a straight line or an arc. The mean of its increment
has a closed form (eqs 5.5, 5.7) and so has the covariance (eq. 5.6, and eq. 5.9 as corrected, in the general
notation and in the thesis' own). The estimators use the general ``increment_mean`` (the group exponential) and
``increment_cov`` (quadrature of eq. 5.4): every closed form agrees with them to rounding. The thesis' second-order
mean (eq. 5.11) is an approximation for short steps: on this arc's 1 rad turn an entry is off by 0.16.
"""

import numpy as np

from swarmloc.motion import (
    circular_cov,
    circular_mean,
    increment_cov,
    increment_mean,
    increment_mean_second_order,
    straight_line_mean,
    thesis_circular_cov,
    thesis_straight_cov,
)

D, r, l = 5.0, 0.033, 0.2  # the thesis' robot: diffusion D, wheel radius r and track l [m]
Q = D * np.diag([r**2 / 2, 0.0, 2 * r**2 / l**2])  # its diffusion per second, diag(q_v, q_lat, q_w)
t = 2.0  # [s]

w = 10.0  # straight: both wheels at 10 rad/s
line = np.array([r * w, 0.0, 0.0])  # the body twist (v, 0, omega)
a, alpha_dot = 1.0, 0.5  # an arc of radius 1 m at 0.5 rad/s
arc = np.array([a * alpha_dot, 0.0, alpha_dot])
forms = {  # closed form, general form
    "straight mean (5.5)": (straight_line_mean(r * w, t), increment_mean(line, t)),
    "straight covariance (5.6)": (thesis_straight_cov(D, r, l, w, t), increment_cov(line, Q, t)),
    "arc mean (5.7)": (circular_mean(a * alpha_dot, alpha_dot, t), increment_mean(arc, t)),
    "arc covariance (5.9)": (circular_cov(a * alpha_dot, alpha_dot, t, Q[0, 0], Q[2, 2]), increment_cov(arc, Q, t)),
    "arc covariance (5.9, thesis notation)": (thesis_circular_cov(D, r, l, a, alpha_dot, t), increment_cov(arc, Q, t)),
    "arc mean, second order (5.11)": (increment_mean_second_order(arc, t), increment_mean(arc, t)),
}
difference = {name: np.abs(closed - general).max() / np.abs(general).max() for name, (closed, general) in forms.items()}
for name, d in difference.items():
    print(f"{name}: largest difference {d:.1e} (relative)")
