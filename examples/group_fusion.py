"""Beliefs on SE(2) and their fusion (:mod:`swarmloc.gaussian`, :mod:`swarmloc.fusion`), each checked against
sampling (:mod:`swarmloc.evaluation.montecarlo`).

    python examples/group_fusion.py

A belief is a mean pose with a covariance in exponential coordinates (right perturbation: ``g = mu exp(y)``).
Moving it by a known transform is exact (``left_multiply``: the covariance is kept, ``right_multiply``: turned by
the adjoint). Odometry convolves it with the increment's belief to second order; with 0.45 rad of heading spread
the first-order sum ``A + B`` is off by several percent, the second order by a fraction of one. Then the three
updates: a relative pose of an uncertain neighbour (``fuse_relative``), a GPS-like fix of the pose itself
(``fuse_absolute``) and a range and bearing of a landmark known to 2 cm (``fuse_point_measurement``, gated first
by its normalized innovation ``point_innovation``). The relative and range-bearing posteriors are compared with
importance sampling, which never linearizes. The group's own tools: ``SE2.log`` is the matrix logarithm read as a
vector (``SE2.vee``), ``SE2.bch`` approximates ``log(exp(x) exp(y))``, and ``SE2.right_jacobian`` carries a small
change of coordinates into a right perturbation, ``exp(x + d) ~ exp(x) exp(Jr(x) d)``.
"""

import numpy as np
import scipy.linalg

from swarmloc import SE2, GroupGaussian
from swarmloc.evaluation.montecarlo import convolution_mc, importance_posterior, importance_posterior_point
from swarmloc.fusion import fuse_absolute, fuse_point_measurement, fuse_relative, point_innovation, point_measurement

rng = np.random.default_rng(0)
pose = lambda x, y, theta: SE2.from_xytheta([x, y, theta])  # noqa: E731


def off(cov, reference):
    """Relative (Frobenius) difference of two covariances."""
    return np.linalg.norm(cov - reference) / np.linalg.norm(reference)


def apart(mean, reference):
    """Distance between two poses, ``|log(reference^-1 mean)|``."""
    return np.linalg.norm(SE2.log(np.linalg.inv(reference) @ mean))


belief = GroupGaussian(SE2, pose(1.0, 0.5, 0.3), np.diag([0.02, 0.01, 0.25]))
turned = belief.right_multiply(pose(0.0, 0.0, np.pi / 2))  # the same robot, its body frame turned a quarter
print("turned a quarter: x and y variances swap:", np.diag(turned.cov).round(3))
shifted = belief.left_multiply(pose(5.0, 0.0, 0.0))  # the whole world moved 5 m along x
print("world moved: mean", SE2.to_xytheta(shifted.mean).round(3), "covariance kept:", np.diag(shifted.cov))

step = GroupGaussian(SE2, pose(2.0, -0.5, 0.5), np.diag([0.05, 0.02, 0.2]))  # an odometry increment
sampled = convolution_mc(belief, step, 400_000, rng)  # E[y y^T] about the product of the means
first, second = (off(belief.convolve(step, order=k).cov, sampled) for k in (1, 2))
print(f"prediction against sampling: first order {first:.1%} off, second order {second:.1%} off")

# robot 0 at the origin, unsure by 10 cm and 0.1 rad, sees robot 1 (its own belief: 2 m ahead, 5 cm) 2.1 m ahead
prior = GroupGaussian(SE2, pose(0.0, 0.0, 0.0), np.diag([0.01, 0.01, 0.01]))
neighbour = GroupGaussian(SE2, pose(2.0, 0.0, 0.0), np.diag([0.0025, 0.0025, 0.0025]))
seen = GroupGaussian(SE2, pose(2.1, 0.0, 0.0), np.diag([0.001, 0.001, 0.001]))
posterior = fuse_relative(prior, [(neighbour, seen)])
mean, cov, _ = importance_posterior(prior, [(neighbour, seen)], 100_000, rng)
relative = apart(posterior.mean, mean), off(posterior.cov, cov)
print(f"relative pose: posterior x {SE2.to_xytheta(posterior.mean)[0]:.3f} m (pulled toward -0.1 m)")
print("  against sampling: the mean {:.4f} apart, covariance {:.1%} off".format(*relative))

fix = GroupGaussian(SE2, pose(0.05, 0.0, 0.0), np.diag([0.01, 0.01, 1.0]))  # a GPS-like fix: position only
fixed = fuse_absolute(prior, [fix])
print("absolute fix: x", SE2.to_xytheta(fixed.mean)[0].round(4), "m, x variance", fixed.cov[0, 0].round(4))

landmark, landmark_cov = np.array([3.0, 1.0]), np.diag([0.0004, 0.0004])
z, R = np.array([np.hypot(3.0, 1.0) + 0.05, np.arctan2(1.0, 3.0) - 0.02]), np.diag([0.05**2, 0.02**2])
nis = point_innovation(prior.mean, prior.cov, point_measurement("range_bearing", z, R, landmark, landmark_cov))
print(f"range and bearing of the landmark: innovation {nis:.2f}, under the 99% gate of chi-square(2), 9.21")
m, c = fuse_point_measurement(prior.mean, prior.cov, "range_bearing", z, R, landmark, landmark_cov)
mean, cov, _ = importance_posterior_point(prior, "range_bearing", z, R, (landmark, landmark_cov), 100_000, rng)
point = apart(m, mean), off(c, cov)
print("  against sampling: the mean {:.4f} apart, covariance {:.1%} off".format(*point))

x, y = np.array([0.3, -0.2, 0.5]), np.array([-0.1, 0.4, 0.3])
print(f"log against the matrix logarithm: {np.abs(SE2.vee(scipy.linalg.logm(SE2.exp(x)).real) - x).max():.0e}")
exact = SE2.log(SE2.exp(x) @ SE2.exp(y))
bch = [np.abs(SE2.bch(x, y, order=k) - exact).max() for k in (1, 2, 3)]
print("BCH error, first, second and third order: {:.1e}, {:.1e}, {:.1e}".format(*bch))
d = np.array([1e-4, -2e-4, 1e-4])
moved = SE2.log(np.linalg.inv(SE2.exp(x)) @ SE2.exp(x + d))  # the right perturbation that x + d is
print(f"right Jacobian: {np.abs(moved - SE2.right_jacobian(x) @ d).max():.0e} off for |d| = 2.4e-4")
