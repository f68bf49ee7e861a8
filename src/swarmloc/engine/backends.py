"""Array backends of the engine's fast EKF path: the structure-of-arrays kernels of :mod:`swarmloc.engine.soa`
run by numpy (``"numpy"``) or by ``jax.numpy`` under ``jax.jit`` in float64 (``"jax"``) or float32 (``"jax32"``),
on jax's default device (CPU or GPU); the same formulas compiled as scalar loops by numba (``"numba"``,
:mod:`swarmloc.engine.numba_ops`). :func:`jax_team_step` is the whole step as one jitted function on arrays kept on
the device (no scheduling, Jacobi order): the device's ceiling for it, measured by ``swarmloc-studies bench``. The
engine's jax backends keep the team on the device (:mod:`swarmloc.engine.resident`) and run a stamp of poses, fixes
and range-bearing detections as one device call (:mod:`swarmloc.engine.jax_stamp`, :attr:`JaxOps.stamp`); the
per-batch kernels here take any other stamp, on host arrays.

Both take and return numpy arrays: states ``x (B, 3)`` ``(x [m], y [m], theta [rad])``, covariances
``P (B, 3, 3)``, commands ``v [m/s]``, ``w [rad/s]``, intervals ``dt [s]`` ``(B,)``. The jax backends pad every
batch to a power of two (at least 8) so that a run compiles each function for a handful of sizes only; ``"jax32"``
computes in float32 on the device and returns float64 (the engine's states stay float64 on the host).
"""

from __future__ import annotations

from collections import Counter
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np

from swarmloc.engine import soa
from swarmloc.engine.jax_stamp import bucket, device_stamp, import_jax, pad_rows
from swarmloc.motion import UnicycleNoise

if TYPE_CHECKING:
    from swarmloc.engine.numba_ops import NumbaOps

BACKENDS = ("numpy", "jax", "jax32", "numba")

Arrays = tuple[np.ndarray, ...]


def _up(P: Any) -> tuple[Any, ...]:
    return tuple(P[..., i, j] for i, j in soa.UPPER)


def _up2(L: Any) -> tuple[Any, ...]:
    return L[..., 0, 0], L[..., 0, 1], L[..., 1, 1]


def _full(xp: Any, p: tuple[Any, ...]) -> Any:
    p00, p01, p02, p11, p12, p22 = p
    return xp.stack([xp.stack([p00, p01, p02], -1), xp.stack([p01, p11, p12], -1), xp.stack([p02, p12, p22], -1)], -2)


def _cols(x: Any) -> tuple[Any, ...]:
    return x[..., 0], x[..., 1], x[..., 2]


def _predict(xp: Any, noise: UnicycleNoise, x: Any, P: Any, v: Any, w: Any, dt: Any) -> tuple[Any, Any]:
    xs, ps = soa.predict(xp, _cols(x), _up(P), v, w, dt, noise)
    return xp.stack(xs, -1), _full(xp, ps)


def _finish(xp: Any, res: soa.Updated) -> tuple[Any, ...]:
    xs, ps, nis, ok = res
    return xp.stack(xs, -1), _full(xp, ps), nis, ok, soa.positive_definite(xp, ps)


def _pose(xp: Any, x: Any, P: Any, xk: Any, Pk: Any, z: Any, Rz: Any) -> tuple[Any, ...]:
    return _finish(xp, soa.pose_update(xp, _cols(x), _up(P), _cols(xk), _up(Pk), _cols(z), _up(Rz)))


def _absolute(xp: Any, x: Any, P: Any, z: Any, Rz: Any) -> tuple[Any, ...]:
    return _finish(xp, soa.absolute_update(xp, _cols(x), _up(P), _cols(z), _up(Rz)))


def _landmark(xp: Any, x: Any, P: Any, lk: Any, L: Any, z: Any, Rz: Any) -> tuple[Any, ...]:
    lk2, z2 = (lk[..., 0], lk[..., 1]), (z[..., 0], z[..., 1])
    return _finish(xp, soa.landmark_update(xp, _cols(x), _up(P), lk2, _up2(L), z2, _up2(Rz)))


class NumpyOps:
    """The fast EKF kernels on numpy arrays."""

    name = "numpy"

    def __init__(self, noise: UnicycleNoise) -> None:
        self.noise = noise

    def predict(self, x: np.ndarray, P: np.ndarray, v: np.ndarray, w: np.ndarray, dt: np.ndarray) -> Arrays:
        """Predicted ``(x, P)``; rows with ``dt <= 0`` unchanged."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return _predict(np, self.noise, x, P, v, w, dt)

    def pose_update(
        self, x: np.ndarray, P: np.ndarray, xk: np.ndarray, Pk: np.ndarray, z: np.ndarray, Rz: np.ndarray
    ) -> Arrays:
        """``(x+, P+, nis, ok, positive definite)`` of relative-pose updates (:func:`soa.pose_update`)."""
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            return _pose(np, x, P, xk, Pk, z, Rz)

    def absolute_update(self, x: np.ndarray, P: np.ndarray, z: np.ndarray, Rz: np.ndarray) -> Arrays:
        """``(x+, P+, nis, ok, positive definite)`` of absolute fixes (:func:`soa.absolute_update`)."""
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            return _absolute(np, x, P, z, Rz)

    def landmark_update(
        self, x: np.ndarray, P: np.ndarray, lk: np.ndarray, L: np.ndarray, z: np.ndarray, Rz: np.ndarray
    ) -> Arrays:
        """``(x+, P+, nis, ok, positive definite)`` of range-bearing detections ``z (B, 2)``, noise ``Rz (B, 2, 2)``,
        of map landmarks at ``lk (B, 2)`` with covariance ``L (B, 2, 2)`` (:func:`soa.landmark_update`)."""
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            return _landmark(np, x, P, lk, L, z, Rz)


def _pad(a: np.ndarray, size: int, fill: np.ndarray | float, dtype: Any = np.float64) -> np.ndarray:
    """``a`` as ``dtype`` padded to ``size`` rows with ``fill`` (:func:`~swarmloc.engine.jax_stamp.pad_rows`)."""
    return pad_rows(np.asarray(a, dtype=dtype), size, fill)  # one dtype: an integer array would compile again


def _host(a: Any) -> np.ndarray:
    out = np.array(a)
    return out.astype(np.float64) if out.dtype == np.float32 else out


_EYE = np.eye(3)
_EYE2 = np.eye(2)


class JaxOps:
    """The same kernels in ``jax.numpy``, jit-compiled, in ``dtype`` (float64: ``"jax"``, float32: ``"jax32"``;
    ``jax_enable_x64`` is switched on). Inputs are cast to ``dtype``, results returned as numpy float64."""

    def __init__(self, noise: UnicycleNoise, dtype: Any = np.float64) -> None:
        import_jax()
        import jax.numpy as jnp

        self.dtype = np.dtype(dtype)
        if self.dtype not in (np.float64, np.float32):
            raise ValueError(f"JaxOps: dtype must be float64 or float32, not {self.dtype}")
        self.name = "jax" if self.dtype == np.float64 else "jax32"
        self.noise = noise
        self._jnp = jnp
        self.compiles: Counter[str] = Counter()
        """Compilations per kernel (``predict``, ``pose``, ``absolute``, ``landmark``): one per padded batch size."""
        self._predict = self._jit("predict", lambda x, P, v, w, dt: _predict(jnp, noise, x, P, v, w, dt))
        self._pose = self._jit("pose", lambda *a: _pose(jnp, *a))
        self._absolute = self._jit("absolute", lambda *a: _absolute(jnp, *a))
        self._landmark = self._jit("landmark", lambda *a: _landmark(jnp, *a))
        self.stamp = device_stamp(noise, self.dtype)
        """A whole stamp in one device call (:mod:`swarmloc.engine.jax_stamp`), shared by the engines of this noise and
        dtype; its ``compiles`` count its shapes, its ``calls`` the stamps."""

    def _jit(self, name: str, fn: Any) -> Any:
        import jax

        def traced(*args: Any) -> Any:
            self.compiles[name] += 1  # runs when jax traces: once per new argument shape, then never again
            return fn(*args)

        return jax.jit(traced)

    def _call(self, kernel: Any, *padded: tuple[np.ndarray, np.ndarray | float]) -> Arrays:
        """``kernel`` on the arrays of ``padded`` (``(array, fill)`` pairs), each cast to the dtype and padded to the
        bucket of the first one's rows with its fill; the results cut back to those rows, as numpy float64."""
        n = padded[0][0].shape[0]
        b = bucket(n)
        res = kernel(*(_pad(a, b, fill, self.dtype) for a, fill in padded))
        return tuple(_host(r[:n]) for r in res)  # writable numpy copies, floats as float64

    def predict(self, x: np.ndarray, P: np.ndarray, v: np.ndarray, w: np.ndarray, dt: np.ndarray) -> Arrays:
        return self._call(self._predict, (x, 0.0), (P, _EYE), (v, 0.0), (w, 0.0), (dt, 0.0))

    def pose_update(
        self, x: np.ndarray, P: np.ndarray, xk: np.ndarray, Pk: np.ndarray, z: np.ndarray, Rz: np.ndarray
    ) -> Arrays:
        return self._call(self._pose, (x, 0.0), (P, _EYE), (xk, 1.0), (Pk, _EYE), (z, 1.0), (Rz, _EYE))

    def absolute_update(self, x: np.ndarray, P: np.ndarray, z: np.ndarray, Rz: np.ndarray) -> Arrays:
        return self._call(self._absolute, (x, 0.0), (P, _EYE), (z, 0.0), (Rz, _EYE))

    def landmark_update(
        self, x: np.ndarray, P: np.ndarray, lk: np.ndarray, L: np.ndarray, z: np.ndarray, Rz: np.ndarray
    ) -> Arrays:
        # a padded row's landmark 1.4 m from its observer: finite
        return self._call(self._landmark, (x, 0.0), (P, _EYE), (lk, 1.0), (L, _EYE2), (z, 1.0), (Rz, _EYE2))


FastOps: TypeAlias = "NumpyOps | JaxOps | NumbaOps"
"""A backend's fast-path kernels (:func:`make_ops`): batched prediction and EKF updates of SE(2) rows; numba's also
in place on one thread, JAX's also a whole stamp in one device call."""


def make_ops(backend: str, noise: UnicycleNoise) -> FastOps:
    """The fast-path kernels of ``backend`` (one of :data:`BACKENDS`)."""
    if backend == "numpy":
        return NumpyOps(noise)
    if backend in ("jax", "jax32"):
        return JaxOps(noise, np.float64 if backend == "jax" else np.float32)
    if backend == "numba":
        try:
            from swarmloc.engine.numba_ops import NumbaOps
        except ImportError as exc:  # pragma: no cover - depends on the environment
            raise ImportError("backend 'numba' needs numba: pip install numba") from exc
        return NumbaOps(noise)
    raise ValueError(f"unknown backend {backend!r}; choose from {list(BACKENDS)}")


def team_step(xp: Any, noise: UnicycleNoise, x: Any, P: Any, v: Any, w: Any, dt: Any, z: Any, R: Any, t: Any,
              *, barrier: Any = None) -> tuple[Any, Any]:  # fmt: skip
    """One step of the whole team in array module ``xp``, no scheduling: predict every robot, then fuse detection
    position ``j = 0 .. k-1`` of every robot at once (robot ``i`` sees robot ``t[i, j]`` as ``z[i, j]`` with noise
    ``R[i, j]``; shapes ``x (n, 3)``, ``P (n, 3, 3)``, ``v, w, dt (n,)``, ``z (n, k, 3)``, ``R (n, k, 3, 3)``, ``t (n,
    k)`` ints). A neighbour's state is read after the previous position's updates (Jacobi within a position). The
    states are one ``(n, 9)`` array at each position, behind ``barrier`` (``jax.lax.optimization_barrier``): gathered
    from per-entry arrays that XLA may fuse, it recomputed their producers per element, stage after stage (measured
    on a CPU: 1e3 robot-updates/s at any size with 3 neighbours). Returns ``(x, P)``."""
    fence = barrier or (lambda a: a)
    xs, ps = soa.predict(xp, _cols(x), _up(P), v, w, dt, noise)
    for j in range(z.shape[1]):
        S = fence(xp.stack(xs + ps, -1))
        G = S[t[:, j]]
        xs, ps = tuple(S[:, i] for i in range(3)), tuple(S[:, i] for i in range(3, 9))
        xk, pk = tuple(G[:, i] for i in range(3)), tuple(G[:, i] for i in range(3, 9))
        xs, ps, _, _ = soa.pose_update(xp, xs, ps, xk, pk, _cols(z[:, j]), _up(R[:, j]))
    return xp.stack(xs, -1), _full(xp, ps)


def jax_team_step(noise: UnicycleNoise) -> Any:
    """:func:`team_step` as one ``jax.jit`` function ``f(x, P, v, w, dt, z, R, t) -> (x, P)`` on jax arrays (their
    dtype, float64 or float32, is the computation's); it compiles once per shape and dtype."""
    jax = import_jax()
    import jax.numpy as jnp

    return jax.jit(lambda *a: team_step(jnp, noise, *a, barrier=jax.lax.optimization_barrier))
