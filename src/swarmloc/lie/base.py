"""Common machinery of the special Euclidean groups SE(2) and SE(3).

Conventions (fixed by ``DESIGN.md``):

* elements are homogeneous matrices ``(..., n+1, n+1)``; tangent vectors (exponential coordinates) are
  ``(..., d)`` with the translational part first: SE(2) ``(v1, v2, alpha)``, SE(3) ``(v1, v2, v3, w1, w2, w3)``;
* ``exp`` and ``log`` are the matrix exponential and its principal inverse (rotation angle in (-pi, pi]);
* ``Ad(g) y = (g y^ g^-1)^v`` and ``ad(x) y = [x^, y^]^v``;
* left Jacobian ``Jl(x)``: ``exp(x + dx) = exp(Jl(x) dx) exp(x)`` to first order;
  right Jacobian ``Jr(x)``: ``exp(x + dx) = exp(x) exp(Jr(x) dx)``; ``Jr(x) = Jl(-x)``.

Subclasses are namespaces of pure, batched functions (classmethods); no instance is ever created.
"""

from __future__ import annotations

from abc import abstractmethod

import numpy as np

from swarmloc.arrays import FloatArray
from swarmloc.lie.checks import as_element, as_square, as_tangent


class SEGroup:
    """Base class: SE(n) as a namespace of batched functions."""

    n: int = 0  # dimension of the space the group acts on
    dim: int = 0  # dimension of the group (degrees of freedom)
    name: str = "SE(n)"

    # ----------------------------------------------------------------- validation
    @classmethod
    def check_tangent(cls, x: object, where: str = "", name: str = "x") -> FloatArray:
        """Validate exponential coordinates ``(..., dim)``; raise ValueError naming ``name``."""
        return as_tangent(x, cls.dim, where or cls.__name__, name)

    @classmethod
    def check_element(cls, g: object, where: str = "", name: str = "g") -> FloatArray:
        """Validate group elements ``(..., n+1, n+1)``; raise ValueError naming ``name``."""
        return as_element(g, cls.n, where or cls.__name__, name)

    @classmethod
    def _tangent_arg(cls, x: object, validate: bool, op: str) -> FloatArray:
        """``x`` as a float array; validated first (errors naming ``<Group>.<op>``) when ``validate``."""
        return cls.check_tangent(x, f"{cls.__name__}.{op}") if validate else np.asarray(x, dtype=float)

    @classmethod
    def _element_arg(cls, g: object, validate: bool, op: str) -> FloatArray:
        """``g`` as a float array; validated first (errors naming ``<Group>.<op>``) when ``validate``."""
        return cls.check_element(g, f"{cls.__name__}.{op}") if validate else np.asarray(g, dtype=float)

    # ----------------------------------------------------------------- to be provided by subclasses
    @staticmethod
    @abstractmethod
    def rotation_hat(w: FloatArray) -> FloatArray:
        """``(..., dim - n) -> (..., n, n)``: the rotation block of :meth:`hat`, from the angular part."""

    @staticmethod
    @abstractmethod
    def rotation_vee(W: FloatArray) -> FloatArray:
        """``(..., n, n) -> (..., dim - n)``: inverse of :meth:`rotation_hat` (uses the antisymmetric part)."""

    @classmethod
    @abstractmethod
    def exp(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """``(..., dim) -> (..., n+1, n+1)``: the matrix exponential of ``x^``, in closed form."""

    @classmethod
    @abstractmethod
    def log(cls, g: FloatArray, validate: bool = True) -> FloatArray:
        """``(..., n+1, n+1) -> (..., dim)``: the principal logarithm (rotation angle in (-pi, pi])."""

    @classmethod
    @abstractmethod
    def Ad(cls, g: FloatArray, validate: bool = True) -> FloatArray:
        """``(..., n+1, n+1) -> (..., dim, dim)``: the adjoint, ``Ad(g) y = (g y^ g^-1)^v``."""

    @classmethod
    @abstractmethod
    def ad(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """``(..., dim) -> (..., dim, dim)``: the algebra's adjoint, ``ad(x) y = [x^, y^]^v``."""

    @classmethod
    @abstractmethod
    def left_jacobian(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """``(..., dim) -> (..., dim, dim)``: ``Jl(x)``, ``exp(x + dx) = exp(Jl(x) dx) exp(x)`` to first order."""

    @classmethod
    @abstractmethod
    def left_jacobian_inv(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """``(..., dim) -> (..., dim, dim)``: the inverse of :meth:`left_jacobian`."""

    # ----------------------------------------------------------------- generic
    @classmethod
    def hat(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """``(..., dim) -> (..., n+1, n+1)`` Lie-algebra matrix: :meth:`rotation_hat` of the angular part, and the
        translational part as the last column."""
        x = cls._tangent_arg(x, validate, "hat")
        n = cls.n
        X = np.zeros((*x.shape[:-1], n + 1, n + 1))
        X[..., :n, :n] = cls.rotation_hat(x[..., n:])
        X[..., :n, n] = x[..., :n]
        return X

    @classmethod
    def vee(cls, X: FloatArray, validate: bool = True) -> FloatArray:
        """``(..., n+1, n+1) -> (..., dim)``; inverse of :meth:`hat` (uses the antisymmetric part of the rotation
        block)."""
        n = cls.n
        X = as_square(X, n + 1, f"{cls.__name__}.vee", "X") if validate else np.asarray(X, dtype=float)
        return np.concatenate([X[..., :n, n], cls.rotation_vee(X[..., :n, :n])], axis=-1)

    @classmethod
    def identity(cls, batch_shape: tuple[int, ...] = ()) -> FloatArray:
        """Identity element(s) of shape ``batch_shape + (n+1, n+1)``."""
        return np.broadcast_to(np.eye(cls.n + 1), (*batch_shape, cls.n + 1, cls.n + 1)).copy()

    @classmethod
    def inverse(cls, g: FloatArray, validate: bool = True) -> FloatArray:
        """Group inverse ``[[R^T, -R^T t], [0, 1]]`` (exact, batched)."""
        if validate:
            g = cls.check_element(g, f"{cls.__name__}.inverse", "g")
        n = cls.n
        R = g[..., :n, :n]
        t = g[..., :n, n]
        out = np.zeros(g.shape)
        Rt = np.swapaxes(R, -1, -2)
        out[..., :n, :n] = Rt
        out[..., :n, n] = -np.einsum("...ij,...j->...i", Rt, t)
        out[..., n, n] = 1.0
        return out

    @classmethod
    def compose(cls, a: FloatArray, b: FloatArray, validate: bool = True) -> FloatArray:
        """Group product ``a @ b`` with broadcasting over leading axes."""
        if validate:
            a = cls.check_element(a, f"{cls.__name__}.compose", "a")
            b = cls.check_element(b, f"{cls.__name__}.compose", "b")
        out: FloatArray = np.matmul(a, b)
        return out

    @classmethod
    def between(cls, a: FloatArray, b: FloatArray, validate: bool = True) -> FloatArray:
        """Relative pose ``a^-1 b`` (pose of b in a's frame)."""
        if validate:
            a = cls.check_element(a, f"{cls.__name__}.between", "a")
            b = cls.check_element(b, f"{cls.__name__}.between", "b")
        out: FloatArray = np.matmul(cls.inverse(a, validate=False), b)
        return out

    @classmethod
    def right_jacobian(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """Right Jacobian ``Jr(x) = Jl(-x)``: ``exp(x + dx) = exp(x) exp(Jr(x) dx)`` to first order."""
        if validate:
            x = cls.check_tangent(x, f"{cls.__name__}.right_jacobian")
        return cls.left_jacobian(-np.asarray(x, dtype=float), validate=False)

    @classmethod
    def right_jacobian_inv(cls, x: FloatArray, validate: bool = True) -> FloatArray:
        """Inverse of the right Jacobian."""
        if validate:
            x = cls.check_tangent(x, f"{cls.__name__}.right_jacobian_inv")
        return cls.left_jacobian_inv(-np.asarray(x, dtype=float), validate=False)

    @classmethod
    def bch(cls, x: FloatArray, y: FloatArray, order: int = 2, validate: bool = True) -> FloatArray:
        """Baker-Campbell-Hausdorff approximation of ``log(exp(x) exp(y))``.

        ``order=1``: ``x + y``; ``order=2``: ``+ ad(x) y / 2``;
        ``order=3``: ``+ (ad(x)^2 y + ad(y)^2 x) / 12`` (thesis eq. 3.18).
        """
        where = f"{cls.__name__}.bch"
        if validate:
            x = cls.check_tangent(x, where, "x")
            y = cls.check_tangent(y, where, "y")
        if order not in (1, 2, 3):
            raise ValueError(f"{where}: argument 'order' must be 1, 2 or 3, got {order!r}")
        z = x + y
        if order >= 2:
            adx = cls.ad(x, validate=False)
            z = z + 0.5 * np.einsum("...ij,...j->...i", adx, y)
        if order >= 3:
            ady = cls.ad(y, validate=False)
            z = (
                z
                + (np.einsum("...ij,...jk,...k->...i", adx, adx, y) + np.einsum("...ij,...jk,...k->...i", ady, ady, x))
                / 12.0
            )
        return z

    @classmethod
    def basis(cls) -> FloatArray:
        """Lie-algebra basis ``E_i = hat(e_i)``, shape ``(dim, n+1, n+1)``."""
        return _basis(cls)

    @classmethod
    def ad_basis(cls) -> FloatArray:
        """``ad(E_i)`` for each basis vector, shape ``(dim, dim, dim)``."""
        return _ad_basis(cls)

    @classmethod
    def sample_tangent(cls, rng: np.random.Generator, size: tuple[int, ...] | int, scale: float = 1.0) -> FloatArray:
        """Random tangent vectors: standard normal times ``scale``."""
        size = (size,) if isinstance(size, int) else tuple(size)
        return scale * rng.standard_normal((*size, cls.dim))

    @classmethod
    def random(cls, rng: np.random.Generator, size: tuple[int, ...] | int = (), scale: float = 1.0) -> FloatArray:
        """Random elements ``exp(scale * N(0, I))``."""
        return cls.exp(cls.sample_tangent(rng, size, scale), validate=False)

    @classmethod
    def normalize(cls, g: FloatArray) -> FloatArray:
        """Project a nearly-valid element back onto the group (rotation block by SVD)."""
        g = np.array(g, dtype=float)
        n = cls.n
        U, _, Vt = np.linalg.svd(g[..., :n, :n])
        d = np.sign(np.linalg.det(U @ Vt))
        U[..., :, -1] *= d[..., None]
        g[..., :n, :n] = U @ Vt
        g[..., n, :n] = 0.0
        g[..., n, n] = 1.0
        return g


_BASES: dict[tuple[type[SEGroup], str], FloatArray] = {}  # (group, "hat" or "ad"): its basis, computed once


def _basis(group: type[SEGroup]) -> FloatArray:
    if (group, "hat") not in _BASES:
        _BASES[group, "hat"] = group.hat(np.eye(group.dim), validate=False)
    return _BASES[group, "hat"].copy()


def _ad_basis(group: type[SEGroup]) -> FloatArray:
    if (group, "ad") not in _BASES:
        _BASES[group, "ad"] = group.ad(np.eye(group.dim), validate=False)
    return _BASES[group, "ad"].copy()
