"""Array backends of the engine's fast EKF path: the structure-of-arrays kernels of :mod:`swarmloc.engine.soa`
run by numpy (``"numpy"``) or by ``jax.numpy`` under ``jax.jit`` in float64 (``"jax"``, CPU or GPU); the same
formulas compiled as scalar loops by numba (``"numba"``, :mod:`swarmloc.engine.numba_ops`).

Both take and return numpy arrays: states ``x (B, 3)`` ``(x [m], y [m], theta [rad])``, covariances
``P (B, 3, 3)``, commands ``v [m/s]``, ``w [rad/s]``, intervals ``dt [s]`` ``(B,)``. The jax backend pads every
batch to a power of two (at least 8) so that a run compiles each function for a handful of sizes only.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from swarmloc.engine import soa
from swarmloc.motion import UnicycleNoise

BACKENDS = ("numpy", "jax", "numba")

Arrays = tuple[np.ndarray, ...]

_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _up(P: Any) -> tuple[Any, ...]:
    return tuple(P[..., i, j] for i, j in _UPPER)


def _full(xp: Any, p: tuple[Any, ...]) -> Any:
    p00, p01, p02, p11, p12, p22 = p
    return xp.stack([xp.stack([p00, p01, p02], -1), xp.stack([p01, p11, p12], -1), xp.stack([p02, p12, p22], -1)], -2)


def _cols(x: Any) -> tuple[Any, ...]:
    return x[..., 0], x[..., 1], x[..., 2]


def _predict(xp: Any, noise: UnicycleNoise, x: Any, P: Any, v: Any, w: Any, dt: Any) -> tuple[Any, Any]:
    xs, ps = soa.predict(xp, _cols(x), _up(P), v, w, dt, noise)
    return xp.stack(xs, -1), _full(xp, ps)


def _finish(xp: Any, res: tuple) -> tuple[Any, ...]:
    xs, ps, nis, ok = res
    return xp.stack(xs, -1), _full(xp, ps), nis, ok, soa.positive_definite(xp, ps)


def _pose(xp: Any, x: Any, P: Any, xk: Any, Pk: Any, z: Any, Rz: Any) -> tuple[Any, ...]:
    return _finish(xp, soa.pose_update(xp, _cols(x), _up(P), _cols(xk), _up(Pk), _cols(z), _up(Rz)))


def _absolute(xp: Any, x: Any, P: Any, z: Any, Rz: Any) -> tuple[Any, ...]:
    return _finish(xp, soa.absolute_update(xp, _cols(x), _up(P), _cols(z), _up(Rz)))


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


def _bucket(n: int) -> int:
    return max(8, 1 << max(0, (n - 1).bit_length()))


def _pad(a: np.ndarray, size: int, fill: np.ndarray | float) -> np.ndarray:
    """``a`` as float64 with ``size`` rows, the rows past its own set to ``fill`` (masked: their results are cut)."""
    a = np.asarray(a, dtype=float)  # one dtype: an integer array would compile another version
    if a.shape[0] == size:
        return a
    out = np.empty((size, *a.shape[1:]))
    out[: a.shape[0]] = a
    out[a.shape[0] :] = fill
    return out


_EYE = np.eye(3)


class JaxOps:
    """The same kernels in ``jax.numpy``, jit-compiled, float64 (``jax_enable_x64`` is switched on)."""

    name = "jax"

    def __init__(self, noise: UnicycleNoise) -> None:
        try:
            import jax
        except ImportError as exc:  # pragma: no cover - depends on the environment
            raise ImportError("backend 'jax' needs jax: pip install 'swarmloc[jax]'") from exc
        jax.config.update("jax_enable_x64", True)
        import jax.numpy as jnp

        self.noise = noise
        self._jnp = jnp
        self.compiles: Counter[str] = Counter()
        """Compilations per kernel (``predict``, ``pose``, ``absolute``): one per padded batch size (bucket)."""
        self._predict = self._jit("predict", lambda x, P, v, w, dt: _predict(jnp, noise, x, P, v, w, dt))
        self._pose = self._jit("pose", lambda *a: _pose(jnp, *a))
        self._absolute = self._jit("absolute", lambda *a: _absolute(jnp, *a))

    def _jit(self, name: str, fn: Any) -> Any:
        import jax

        def traced(*args: Any) -> Any:
            self.compiles[name] += 1  # runs when jax traces: once per new argument shape, then never again
            return fn(*args)

        return jax.jit(traced)

    @staticmethod
    def _out(res: tuple, n: int) -> Arrays:
        return tuple(np.array(r[:n]) for r in res)  # writable numpy copies

    def predict(self, x: np.ndarray, P: np.ndarray, v: np.ndarray, w: np.ndarray, dt: np.ndarray) -> Arrays:
        n = x.shape[0]
        b = _bucket(n)
        res = self._predict(_pad(x, b, 0.0), _pad(P, b, _EYE), _pad(v, b, 0.0), _pad(w, b, 0.0), _pad(dt, b, 0.0))
        return self._out(res, n)

    def pose_update(
        self, x: np.ndarray, P: np.ndarray, xk: np.ndarray, Pk: np.ndarray, z: np.ndarray, Rz: np.ndarray
    ) -> Arrays:
        n = x.shape[0]
        b = _bucket(n)
        args = (
            _pad(x, b, 0.0),
            _pad(P, b, _EYE),
            _pad(xk, b, 1.0),
            _pad(Pk, b, _EYE),
            _pad(z, b, 1.0),
            _pad(Rz, b, _EYE),
        )
        return self._out(self._pose(*args), n)

    def absolute_update(self, x: np.ndarray, P: np.ndarray, z: np.ndarray, Rz: np.ndarray) -> Arrays:
        n = x.shape[0]
        b = _bucket(n)
        args = (_pad(x, b, 0.0), _pad(P, b, _EYE), _pad(z, b, 0.0), _pad(Rz, b, _EYE))
        return self._out(self._absolute(*args), n)


def make_ops(backend: str, noise: UnicycleNoise) -> Any:
    """The fast-path kernels of ``backend`` (one of :data:`BACKENDS`)."""
    if backend == "numpy":
        return NumpyOps(noise)
    if backend == "jax":
        return JaxOps(noise)
    if backend == "numba":
        try:
            from swarmloc.engine.numba_ops import NumbaOps
        except ImportError as exc:  # pragma: no cover - depends on the environment
            raise ImportError("backend 'numba' needs numba: pip install numba") from exc
        return NumbaOps(noise)
    raise ValueError(f"unknown backend {backend!r}; choose from {list(BACKENDS)}")
