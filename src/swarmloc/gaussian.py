"""Gaussians on SE(2)/SE(3) in exponential coordinates ("banana distributions").

A :class:`GroupGaussian` with mean ``mu`` and covariance ``Sigma`` is the law of ``g = mu exp(hat(y))``,
``y ~ N(0, Sigma)`` (right perturbation; thesis eq. 3.19 with ``y = log(mu^-1 g)``). Its density with respect
to the Haar measure is approximated, as in the thesis, by
``f(g) = exp(-1/2 y^T Sigma^-1 y) / ((2 pi)^(d/2) |Sigma|^(1/2))`` with ``y = log(mu^-1 g)``.

Second-order convolution (Wang & Chirikjian 2008; thesis eqs. 3.22-3.28): if ``g1 ~ (mu1, Sigma1)`` and
``g2 ~ (mu2, Sigma2)`` are independent then ``g1 g2`` is, to second order, Gaussian with mean ``mu1 mu2`` and
covariance ``A + B + F(A, B)``, ``A = Ad(mu2^-1) Sigma1 Ad(mu2^-1)^T``, ``B = Sigma2`` and

    F(A, B) = 1/4  sum_ij ad(E_i) B ad(E_j)^T A_ij
            + 1/12 (A'' B + (A'' B)^T) + 1/12 (B'' A + (B'' A)^T),   A'' = sum_ij ad(E_i) ad(E_j) A_ij.

The printed eq. (3.26) writes ``B^T A''``; the derivation (A.14) and the Monte Carlo test both need the
transpose ``(A'' B)^T = B^T A''^T``, which keeps the result symmetric.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from swarmloc.lie import SE2, SE3
from swarmloc.lie.base import SEGroup
from swarmloc.lie.checks import as_element, as_square, first_bad
from swarmloc.text import numbers

MAX_SAMPLE_ENTRIES = 10**9
"""Most numbers one :meth:`GroupGaussian.sample` draws (8 GB of tangent vectors, before the group elements)."""

_GROUPS: dict[str, type[SEGroup]] = {"SE2": SE2, "SE(2)": SE2, "se2": SE2, "SE3": SE3, "SE(3)": SE3, "se3": SE3}

SYM_TOL = 1e-9
"""Relative tolerance for a covariance to count as symmetric: ``max|C - C^T| <= SYM_TOL * max(1, max|C|)``."""


def resolve_group(group: type[SEGroup] | str) -> type[SEGroup]:
    """Accept ``SE2``/``SE3`` classes or their names."""
    if isinstance(group, str):
        if group not in _GROUPS:
            raise ValueError(f"argument 'group' must be SE2 or SE3 (class or name), got unknown name {group!r}")
        return _GROUPS[group]
    if isinstance(group, type) and issubclass(group, SEGroup) and group.dim > 0:
        return group
    raise ValueError(f"argument 'group' must be SE2 or SE3 (class or name), got {group!r}")


def check_covariance(cov: object, dim: int, where: str, name: str = "cov") -> np.ndarray:
    """Validate a covariance ``(..., dim, dim)``: finite, symmetric, positive definite; raise ValueError."""
    C = as_square(cov, dim, where, name)
    asym = np.abs(C - np.swapaxes(C, -1, -2)).max(axis=(-1, -2))
    scale = np.maximum(1.0, np.abs(C).max(axis=(-1, -2)))
    bad = asym > SYM_TOL * scale
    if bad.any():
        i = first_bad(bad)
        Ci = C[i] if i else C
        r, c = np.unravel_index(np.argmax(np.abs(Ci - Ci.T)), Ci.shape)
        raise ValueError(
            f"{where}: argument '{name}' is not symmetric: entry ({r}, {c}) is {Ci[r, c]:.6g} but ({c}, {r}) is "
            f"{Ci[c, r]:.6g}" + (f" at batch index {i}" if i else "") + "; symmetrize it, e.g. (C + C.T) / 2"
        )
    eig = np.linalg.eigvalsh(C)
    bad = eig[..., 0] <= 0
    if bad.any():
        i = first_bad(bad)
        raise ValueError(
            f"{where}: argument '{name}' is not positive definite: smallest eigenvalue {eig[i][0]:.3g}"
            + (f" at batch index {i}" if i else "")
        )
    return C


def bvec(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``M v`` batched over leading axes (``M (..., m, n)``, ``v (..., n)``)."""
    out: np.ndarray = np.einsum("...ij,...j->...i", M, v)
    return out


def convolution_F_reference(group: type[SEGroup], A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``F(A, B)`` written term by term as in eq. 3.26 (corrected); batched. Slow but plain."""
    G = group.ad_basis()  # G[i] = ad(E_i)
    term1 = np.einsum("...ij,iab,...bc,jdc->...ad", A, G, B, G, optimize=True)
    A2 = np.einsum("...ij,iab,jbc->...ac", A, G, G, optimize=True)
    B2 = np.einsum("...ij,iab,jbc->...ac", B, G, G, optimize=True)
    A2B = A2 @ B
    B2A = B2 @ A
    return 0.25 * term1 + (A2B + np.swapaxes(A2B, -1, -2) + B2A + np.swapaxes(B2A, -1, -2)) / 12.0


_F_TENSORS: dict[type[SEGroup], np.ndarray] = {}  # group: its convolution_F_tensor, computed once


def convolution_F_tensor(group: type[SEGroup]) -> np.ndarray:
    """Read-only ``K`` with ``vec(F(A, B)) = kron(vec A, vec B) @ K``: F is bilinear, so it is one matrix product."""
    K = _F_TENSORS.get(group)
    if K is None:
        d = group.dim
        E = np.eye(d * d).reshape(d * d, d, d)
        K = convolution_F_reference(group, E[:, None], E[None, :])  # (d^2, d^2, d, d)
        K = K.reshape(d**4, d * d)
        K.setflags(write=False)
        _F_TENSORS[group] = K
    return K


def convolution_F(group: type[SEGroup], A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Second-order term ``F(A, B)`` of the convolution covariance (thesis eq. 3.26, corrected), batched.

    Evaluated as one matrix product with a precomputed bilinear tensor (equal to
    :func:`convolution_F_reference` to rounding; tested).
    """
    d = group.dim
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    shape = np.broadcast_shapes(A.shape[:-2], B.shape[:-2])
    outer = A.reshape(*A.shape[:-2], d * d, 1) * B.reshape(*B.shape[:-2], 1, d * d)
    return (outer.reshape(*shape, d**4) @ convolution_F_tensor(group)).reshape(*shape, d, d)


def symmetric(C: np.ndarray) -> np.ndarray:
    """``(C + C^T) / 2`` over the last two axes (batched): the symmetric part of a covariance, which rounding in a
    product such as ``A P A^T`` leaves slightly asymmetric."""
    return 0.5 * (C + np.swapaxes(C, -1, -2))


def positive_definite(P: np.ndarray) -> bool:
    """Finite and positive definite as ``numpy.linalg.cholesky`` decides (no margin). Numba compiles it as it is
    (:mod:`swarmloc.kernels.pairs`)."""
    if not np.isfinite(P).all():
        return False
    try:
        np.linalg.cholesky(P)
    except Exception:  # numpy raises LinAlgError; numba, which compiles this for the rdl replay, catches no narrower
        return False
    return True


@lru_cache(maxsize=1024)
def chi2_ppf(p: float, dof: int) -> float:
    """The ``p`` quantile of the chi-square law with ``dof`` degrees of freedom: the bound a squared Mahalanobis
    distance of a consistent ``dof``-dimensional Gaussian stays under with probability ``p`` (gates, NEES bands;
    cached, with a bound: a gate asks for the same few ``(p, dof)`` pairs at every update, while the ANEES bands'
    ``dof`` grows with the number of records scored)."""
    from scipy.stats import chi2

    return float(chi2.ppf(p, dof))


def mahalanobis2(y: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distance ``y^T cov^-1 y`` of vectors ``y (..., k)`` under covariances ``cov (..., k, k)``
    (batched, broadcast): a NEES of an error, a NIS of an innovation ``r`` under its covariance ``S``."""
    return np.einsum("...i,...i->...", y, np.linalg.solve(cov, y[..., None])[..., 0])


def convolve_moments(
    group: type[SEGroup], mu1: np.ndarray, S1: np.ndarray, mu2: np.ndarray, S2: np.ndarray, order: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of ``g1 g2`` for independent ``g1 ~ (mu1, S1)``, ``g2 ~ (mu2, S2)`` (batched, no checks)."""
    Ad = group.Ad(group.inverse(mu2, validate=False), validate=False)
    A = Ad @ S1 @ np.swapaxes(Ad, -1, -2)
    cov = A + S2
    if order == 2:
        cov = cov + convolution_F(group, A, S2)
    return mu1 @ mu2, symmetric(cov)


@dataclass(frozen=True, init=False)
class GroupGaussian:
    """Gaussian on SE(2)/SE(3) in exponential coordinates (right perturbation), optionally batched.

    Parameters
    ----------
    group: ``SE2`` or ``SE3`` (class or name).
    mean: element(s) of the group, ``(..., n+1, n+1)``.
    cov: covariance(s) of the exponential coordinates, ``(..., d, d)``; symmetric positive definite.
    """

    group: type[SEGroup]
    mean: np.ndarray
    cov: np.ndarray

    def __init__(self, group: type[SEGroup] | str, mean: object, cov: object, validate: bool = True) -> None:
        G = resolve_group(group)
        if validate:
            mean = G.check_element(mean, "GroupGaussian", "mean")
            cov = check_covariance(cov, G.dim, "GroupGaussian", "cov")
        mean = np.array(mean, dtype=float)
        cov = np.array(cov, dtype=float)
        if mean.shape[:-2] != cov.shape[:-2]:
            try:
                shape = np.broadcast_shapes(mean.shape[:-2], cov.shape[:-2])
            except ValueError:
                raise ValueError(
                    f"GroupGaussian: batch shapes of 'mean' {mean.shape[:-2]} and 'cov' {cov.shape[:-2]} differ"
                ) from None
            mean = np.broadcast_to(mean, (*shape, *mean.shape[-2:])).copy()
            cov = np.broadcast_to(cov, (*shape, *cov.shape[-2:])).copy()
        mean.setflags(write=False)
        cov.setflags(write=False)
        object.__setattr__(self, "group", G)
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", cov)

    # ------------------------------------------------------------------ basics
    @property
    def dim(self) -> int:
        return self.group.dim

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.mean.shape[:-2]

    def __getitem__(self, idx: Any) -> GroupGaussian:
        return GroupGaussian(self.group, self.mean[idx], self.cov[idx], validate=False)

    def __repr__(self) -> str:
        """The mean as ``(x, y, theta)`` [m, rad] (SE(3): translation [m] and rotation vector [rad]) and ``std``,
        the standard deviations of the exponential coordinates (square roots of the covariance's diagonal); of a
        batch, its shape and its first element. At most a line of about 120 characters."""
        first = (0,) * len(self.batch_shape)
        mean, cov = self.mean[first], self.cov[first]
        if self.dim == 3:
            where = f"mean (x, y, theta)={numbers(SE2.to_xytheta(mean))}"
        else:
            rot = self.group.log(mean, validate=False)[3:]
            where = f"mean xyz={numbers(mean[:3, 3])} rotvec={numbers(rot)}"
        batch = f"batch {self.batch_shape}, first: " if self.batch_shape else ""
        std = numbers(np.sqrt(np.clip(np.diagonal(cov), 0.0, None)))
        return f"GroupGaussian({self.group.__name__}, {batch}{where}, std={std})"

    def sample(self, n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """``n`` draws ``mean @ exp(hat(y))``, shape ``(n, *batch_shape, n+1, n+1)``; ``n`` an integer from 0 to
        :data:`MAX_SAMPLE_ENTRIES` over the batch size times the dimension (ValueError, before any allocation)."""
        most = MAX_SAMPLE_ENTRIES // (int(np.prod(self.batch_shape, dtype=np.int64)) * self.dim)
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or not 0 <= n <= most:
            raise ValueError(f"GroupGaussian.sample: n must be an integer in [0, {most}], got {n!r}")
        rng = np.random.default_rng(rng)
        L = np.linalg.cholesky(self.cov)
        z = rng.standard_normal((n, *self.batch_shape, self.dim))
        y = bvec(L, z)
        return self.mean @ self.group.exp(y, validate=False)

    def tangent_of(self, g: np.ndarray, validate: bool = True) -> np.ndarray:
        """Exponential coordinates ``log(mean^-1 g)`` of element(s) ``g`` about the mean."""
        if validate:
            g = self.group.check_element(g, "GroupGaussian.tangent_of", "g")
        return self.group.log(self.group.inverse(self.mean, validate=False) @ g, validate=False)

    def mahalanobis2(self, g: np.ndarray, validate: bool = True) -> np.ndarray:
        """Squared Mahalanobis distance ``y^T Sigma^-1 y`` with ``y = log(mean^-1 g)`` (the NEES of an estimate)."""
        return mahalanobis2(self.tangent_of(g, validate), self.cov)

    def logpdf(self, g: np.ndarray, validate: bool = True) -> np.ndarray:
        """Log density (thesis eq. 3.19, small-covariance normalizer) at element(s) ``g``."""
        m2 = self.mahalanobis2(g, validate)
        _, logdet = np.linalg.slogdet(self.cov)
        return -0.5 * (m2 + logdet + self.dim * np.log(2 * np.pi))

    # ------------------------------------------------------------------ operations
    def convolve(self, other: GroupGaussian, order: int = 2) -> GroupGaussian:
        """Law of ``g1 g2`` with ``g1 ~ self``, ``g2 ~ other`` independent (thesis 3.22-3.28).

        ``order=2`` includes ``F(A, B)``; ``order=1`` drops it (``A + B``).
        """
        if not isinstance(other, GroupGaussian):
            raise ValueError(f"GroupGaussian.convolve: argument 'other' must be a GroupGaussian, got {type(other)}")
        if other.group is not self.group:
            raise ValueError(f"GroupGaussian.convolve: groups differ ({self.group.__name__} vs {other.group.__name__})")
        if order not in (1, 2):
            raise ValueError(f"GroupGaussian.convolve: argument 'order' must be 1 or 2, got {order!r}")
        mu, cov = convolve_moments(self.group, self.mean, self.cov, other.mean, other.cov, order)
        return GroupGaussian(self.group, mu, cov, validate=False)

    def inverse(self) -> GroupGaussian:
        """Law of ``g^-1``: mean ``mu^-1``, covariance ``Ad(mu) Sigma Ad(mu)^T``.

        Exact for the right perturbation: ``(mu exp(y))^-1 = mu^-1 exp(-Ad(mu) y)``.
        """
        Ad = self.group.Ad(self.mean, validate=False)
        return GroupGaussian(
            self.group, self.group.inverse(self.mean, validate=False), Ad @ self.cov @ np.swapaxes(Ad, -1, -2), False
        )

    def left_multiply(self, h: np.ndarray) -> GroupGaussian:
        """Law of ``h g`` for a fixed element ``h`` (exact: the covariance is unchanged)."""
        h = self.group.check_element(h, "GroupGaussian.left_multiply", "h")
        return GroupGaussian(self.group, h @ self.mean, self.cov, validate=False)

    def right_multiply(self, h: np.ndarray) -> GroupGaussian:
        """Law of ``g h`` for a fixed element ``h`` (exact: covariance ``Ad(h^-1) Sigma Ad(h^-1)^T``)."""
        h = self.group.check_element(h, "GroupGaussian.right_multiply", "h")
        Ad = self.group.Ad(self.group.inverse(h, validate=False), validate=False)
        return GroupGaussian(self.group, self.mean @ h, Ad @ self.cov @ np.swapaxes(Ad, -1, -2), validate=False)

    # ------------------------------------------------------------------ planar marginal ("banana") contour
    def xy_marginal_density(self, xs: np.ndarray, ys: np.ndarray, n_theta: int = 181) -> np.ndarray:
        """Marginal density of the position ``(x, y)`` on the grid ``xs x ys`` (SE(2) only, unbatched).

        ``p(x, y) = int f(g(x, y, theta)) dtheta`` by the trapezoidal rule over ``n_theta`` headings spanning
        +-6 standard deviations of the heading around the mean heading (clipped to a full turn). Returns
        an array of shape ``(len(ys), len(xs))``.
        """
        if self.group is not SE2 or self.batch_shape:
            raise ValueError("xy_marginal_density: only for an unbatched SE(2) Gaussian")
        th0 = SE2.to_xytheta(self.mean)[2]
        half = min(np.pi, 6.0 * np.sqrt(self.cov[2, 2]))
        ths = th0 + np.linspace(-half, half, n_theta)
        X, Y, T = np.meshgrid(xs, ys, ths, indexing="xy")
        g = SE2.from_xytheta(X, Y, T)
        dens = np.exp(self.logpdf(g, validate=False))
        return np.trapezoid(dens, ths, axis=-1)

    def xy_contour(self, mass: float = 0.95, grid: int = 161, n_theta: int = 181) -> list[np.ndarray]:
        """Contour of the marginal x-y density that encloses probability ``mass`` (the thesis' banana contour).

        The grid spans the samples' extent; the density level is chosen so that the grid cells above it hold
        ``mass`` of the total. Returns a list of ``(k, 2)`` polylines (usually one closed loop).
        """
        if not 0 < mass < 1:
            raise ValueError(f"xy_contour: argument 'mass' must be in (0, 1), got {mass}")
        pts = SE2.to_xytheta(self.sample(4000, rng=0))[:, :2]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        pad = 0.25 * (hi - lo) + 1e-9
        xs = np.linspace(lo[0] - pad[0], hi[0] + pad[0], grid)
        ys = np.linspace(lo[1] - pad[1], hi[1] + pad[1], grid)
        P = self.xy_marginal_density(xs, ys, n_theta)
        flat = np.sort(P.ravel())[::-1]
        cum = np.cumsum(flat)
        level = flat[min(np.searchsorted(cum, mass * cum[-1]), flat.size - 1)]
        import contourpy

        lines = contourpy.contour_generator(xs, ys, P).lines(level)
        return [np.asarray(seg) for seg in lines]


def world_covariance(mean: object, cov: object) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y, theta)`` of SE(2) poses ``mean`` ``(..., 3, 3)`` and the first-order covariance ``(..., 3, 3)`` of
    ``(x, y, theta)`` in the world frame, for beliefs whose covariance ``cov`` is of the right-perturbation
    exponential coordinates (``g = mean exp(xi^)``).

    ``(x, y, theta)(mean exp(xi)) = (t + R v, theta + omega) + O(|xi|^2)``, so the Jacobian is ``J = blockdiag(R,
    1)`` and the result ``J cov J^T`` (symmetrized; theta in (-pi, pi]). What ROS's ``PoseWithCovariance`` and the
    filterpy-style ``node.P`` report. Raises ValueError for a mean outside SE(2) or a covariance of the wrong shape.
    """
    M = as_element(mean, 2, "world_covariance", "mean")
    S = as_square(cov, 3, "world_covariance", "cov")
    xyt = SE2.to_xytheta(M)
    J = np.zeros(np.broadcast_shapes(M.shape, S.shape))
    J[..., :2, :2], J[..., 2, 2] = SE2.rotation(xyt[..., 2]), 1.0
    C = J @ S @ np.swapaxes(J, -1, -2)
    return xyt, symmetric(C)
