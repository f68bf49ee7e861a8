"""Relative mutual localization as a Monte Carlo scenario (lecture slides 22-28): one joint robocentric EKF against
separate per-teammate EKFs on the same simulated runs, judged by NEES against its chi-square band.

Each run: ``n`` robots start at random poses, each step every robot moves by a random displacement (forward
0.05-0.15 m, sideways 0, turn +-0.1 rad), its odometry reads it with noise ``Q``, and every robot measures every other
robot's relative pose with noise ``R`` (types (a), (b) and (c) of slide 25). Robot 1 runs both filters.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from swarmloc.estimators.robocentric import (
    JointRobocentricEKF,
    SeparateRobocentricEKF,
    compose,
    inverse,
)
from swarmloc.lie import wrap_angle

__all__ = ["robocentric_monte_carlo"]


def _nees(q: np.ndarray, P: np.ndarray, truth: np.ndarray) -> float:
    e = (q - truth).ravel()
    e[2::3] = wrap_angle(e[2::3])
    return float(e @ np.linalg.solve(P, e))


def robocentric_monte_carlo(
    runs: int = 40, steps: int = 60, robots: int = 4, seed: int = 0, sigma_odo=(0.01, 0.01, 0.01),
    sigma_meas=(0.05, 0.05, 0.02),
) -> dict[str, np.ndarray | float | tuple[float, float]]:  # fmt: skip
    """NEES of both filters' full state (``3(robots-1)`` dof) per run and step; the per-step ANEES (per dof) and its
    two-sided 95% band for ``runs`` independent runs."""
    rng = np.random.default_rng(seed)
    m = robots - 1
    Q = np.diag(np.square(sigma_odo))
    R = np.diag(np.square(sigma_meas))
    nees = {"joint": np.zeros((runs, steps)), "separate": np.zeros((runs, steps))}
    for k in range(runs):
        g = np.column_stack([rng.uniform(0, 4, robots), rng.uniform(0, 4, robots), rng.uniform(-np.pi, np.pi, robots)])

        def truth(g: np.ndarray = g) -> np.ndarray:
            inv1, _ = inverse(g[0])
            return np.array([compose(inv1, g[j])[0] for j in range(1, robots)])

        P0 = np.kron(np.eye(m), np.diag([1e-4, 1e-4, 1e-4]))
        q0 = truth() + rng.multivariate_normal(np.zeros(3 * m), P0).reshape(m, 3)
        filters: dict[str, JointRobocentricEKF | SeparateRobocentricEKF] = {
            "joint": JointRobocentricEKF(q0, P0, Q, np.stack([Q] * m)),
            "separate": SeparateRobocentricEKF(q0, P0, Q, np.stack([Q] * m)),
        }
        for t in range(steps):
            u_true = np.column_stack(
                [rng.uniform(0.05, 0.15, robots), np.zeros(robots), rng.uniform(-0.1, 0.1, robots)]
            )
            g = np.array([compose(g[i], u_true[i])[0] for i in range(robots)])
            u = u_true + rng.multivariate_normal(np.zeros(3), Q, size=robots)
            for f in filters.values():
                f.predict(u[0], u[1:])
            for a in range(robots):
                inva, _ = inverse(g[a])
                for b in range(robots):
                    if a == b:
                        continue
                    z = compose(inva, g[b])[0] + rng.multivariate_normal(np.zeros(3), R)
                    for f in filters.values():
                        f.update(a - 1, b - 1, z, R)
            tq = truth(g)
            for name, f in filters.items():
                nees[name][k, t] = _nees(f.q, f.P, tq)
    dof = 3 * m
    lo, hi = chi2.ppf([0.025, 0.975], runs * dof) / (runs * dof)
    out: dict = {"band": (float(lo), float(hi)), "dof": dof}
    for name, v in nees.items():
        anees = v.mean(axis=0) / dof
        out[f"{name}_nees"] = v
        out[f"{name}_anees"] = anees
        out[f"{name}_mean_anees"] = float(anees.mean())
        out[f"{name}_in_band"] = float(np.mean((anees >= lo) & (anees <= hi)))
    return out
