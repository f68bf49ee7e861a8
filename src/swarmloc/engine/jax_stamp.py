"""A whole stamp of the engine's fast EKF path as one compiled JAX call (backends ``"jax"`` and ``"jax32"``).

The call reads the team's states on the device (:class:`swarmloc.engine.resident.DeviceTeam` keeps them there between
stamps) and the stamp's detections, uploaded as one array (canonical order), and gives back the states and clocks
(device arrays), each detection's outcome (a device array) and the stamp's book: the count of each (outcome,
reason) and the number of levels, the one download of a stamp. In between, on the device and in this order: the
screening of :func:`swarmloc.engine.outcomes.screen` (:func:`_screen`), the prediction to ``t`` of the observers,
of the neighbours they ask and of the robots given a command at ``t`` (the observers' and those robots' stored),
the Gauss-Seidel levels of :mod:`swarmloc.engine.stamp` (:func:`_levels`), the pending rows sorted by (level,
position in the group, kind), and their fusion segment by segment inside a ``lax.while_loop``: a segment is one
level's groups at one position, all of one kind, so its rows touch distinct observers and fuse at once. Each chunk
of a segment runs in a branch (``lax.switch``) compiled for its kind and the smallest of a few static sizes that
holds it (:data:`SIZE_STEPS`), so a short late level does not cost a long one's work.

A row's fusion is the fast path's: relative poses, absolute fixes and range-bearing detections of map landmarks or
of robots (the robot's position and covariance as a landmark's) by the formulas of :mod:`swarmloc.engine.soa`,
gated and checked as :func:`swarmloc.engine.outcomes.gate_rows` and :class:`swarmloc.engine.fuse_ekf.EkfFusion`
do (degenerate range-bearing geometry, gate, non-finite NIS, numerical failure). A neighbour with a smaller id is
read after its own group, one with a larger id before it (the nodes' order).

On the device the states are ``(N, 9)`` float64 rows: ``x [m], y [m], theta [rad]`` and the covariance's upper
triangle ``P00, P01, P02, P11, P12, P22`` (``"jax32"`` computes in float32 and stores the rows it changes back as
float64; the others keep their values); the detections are one ``(12, M)`` float64 array (:func:`pack`: observer,
target and kind codes, ``z``, the noise's upper triangle), padded to a power of two, so a run compiles once per team
size and bucket of detections (:func:`device_stamp` shares the compilations between engines).
"""

from __future__ import annotations

from collections import Counter
from functools import cache
from types import ModuleType
from typing import TYPE_CHECKING, Any, Protocol, TypeAlias

import numpy as np

from swarmloc.engine import soa
from swarmloc.engine.codes import (
    ABSOLUTE,
    FUSED,
    MODEL,
    NO_LANDMARK,
    OUTCOMES,
    PENDING,
    POSE,
    R_DEGENERATE,
    R_NUMERICAL,
    REASONS,
    REJECTED,
)
from swarmloc.engine.detections import Detections
from swarmloc.engine.formulas import build
from swarmloc.engine.replay_io import constants
from swarmloc.events import Kind
from swarmloc.motion import UnicycleNoise
from swarmloc.node.update import Gate
from swarmloc.sensors import planar
from swarmloc.sensors.models import KIND_ORDER

if TYPE_CHECKING:  # jax is optional: imported where it runs
    from jax import Array

RANGE_BEARING = KIND_ORDER[Kind.RANGE_BEARING]
DEVICE_KINDS = (ABSOLUTE, POSE, RANGE_BEARING)
"""Kinds the device stamp fuses; a stamp holding a detection of another kind takes the per-level kernels."""
CHUNK = 4
SIZE_STEPS = 3
"""Static sizes of a stamp's chunks: the bucket of its rows or robots (the smaller) divided by :data:`CHUNK`, then
by 4 and 16 (not below 8); a segment longer than the first runs as several chunks. Each size is a compiled branch
per kind: more sizes waste less work on short segments and take longer to compile (on a 2-core CPU at 10,000
robots 8 s with 2 sizes, 14 s with 4, 23 s with 7, for the same step time)."""
_KIND_INDEX = np.zeros(len(MODEL), dtype=np.int64)
_KIND_INDEX[list(DEVICE_KINDS)] = np.arange(len(DEVICE_KINDS))
_FILL = np.array([0.0, -1.0, POSE, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0])
"""A padded detection (a column of :func:`pack`): robot 0 seeing an absent target with a relative pose, the identity
noise (never pending)."""
DEVICE_PAD = 1 << 16
"""Detections from this many on are packed and padded on the device (no host copy); fewer on the host (no
compilation)."""
_COVERED = np.zeros(len(MODEL), dtype=bool)
_COVERED[list(DEVICE_KINDS)] = True

Carry: TypeAlias = "tuple[Array, Array, Array]"
"""What the fusion of a stamp's segments carries on: the states ``(N, 9)``, each detection's outcome and reason."""
Rows: TypeAlias = "tuple[Array, Array, Array, Array, Array, Array, Array]"
"""The pending rows, sorted: detection index, observer and target as rows, landmark index (-1: none), whether the
target is read after its own group, ``z (3)``, the noise's upper triangle ``R (6)``."""
Const: TypeAlias = "tuple[Array, Array, Array, Array, Array]"
"""What every segment reads: the states predicted to ``t``, the gate's threshold per kind, whether the gate is on,
the map's landmarks ``xy (L, 2)`` and covariances' upper triangles ``(L, 3)``."""
DeviceState: TypeAlias = "tuple[Array, Array, Array, Array, Array]"
"""The team on the device: ``S (N, 9)`` (the rows of the module docstring), ``clock (N,)``, ``t0 (N,)``, ``v (N,)``,
``w (N,)``, float64."""
Consts: TypeAlias = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""A stamp's options as the kernel reads them: the gate's threshold per kind, the flags (gate on, relative, landmark
measurements on) and the map's ``xy (L, 2)`` and covariances' upper triangles ``(L, 3)``, padded."""
Landmarks: TypeAlias = tuple[np.ndarray, np.ndarray]
"""A map's ``(xy (L, 2), cov (L, 2, 2))``."""


class _Config(Protocol):
    """What is set here of ``jax.config`` (its ``update`` carries no types)."""

    def update(self, name: str, value: bool, /) -> None: ...


def import_jax() -> ModuleType:
    """``jax``, with ``jax_enable_x64`` switched on (float64 where asked; float32 arrays stay float32)."""
    try:
        import jax
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("backend 'jax' needs jax: pip install 'swarmloc[jax]'") from exc
    config: _Config = jax.config
    config.update("jax_enable_x64", True)
    return jax


def bucket(n: int) -> int:
    """The power of two (at least 8) an array of ``n`` rows is padded to."""
    return max(8, 1 << max(0, (int(n) - 1).bit_length()))


def _segment(jnp: Any, code: int, size: int, carry: Carry, rows: Rows, start: Array, count: Array,
             const: Const) -> Carry:  # fmt: skip
    """Fuse rows ``start : start + count`` (at most ``size``, all of kind ``code``) of the sorted pending rows into
    ``carry``."""
    from jax import lax

    cur, status, reason = carry
    prior, thr, gate_on, lxy, lcov = const
    at, lo, lt, lmk, after, z, R = (lax.dynamic_slice_in_dim(a, start, size) for a in rows)
    valid = jnp.arange(size) < count
    X = cur[lo]
    x, p = tuple(X[:, i] for i in range(3)), tuple(X[:, 3 + i] for i in range(6))
    if code != ABSOLUTE:
        nb = jnp.where(after[:, None], cur[lt], prior[lt])
        xk, pk = tuple(nb[:, i] for i in range(3)), tuple(nb[:, 3 + i] for i in range(6))
    degenerate = jnp.zeros(size, dtype=bool)
    zs, rs = tuple(z[:, i] for i in range(3)), tuple(R[:, i] for i in range(6))
    if code == POSE:
        xn, pn, nis, ok = soa.pose_update(jnp, x, p, xk, pk, zs, rs)
    elif code == ABSOLUTE:
        xn, pn, nis, ok = soa.absolute_update(jnp, x, p, zs, rs)
    else:  # range-bearing of a map landmark, or of a robot at its position with its covariance
        on_map = lmk >= 0
        k = jnp.maximum(lmk, 0)
        lk = tuple(jnp.where(on_map, lxy[k, i], xk[i]) for i in range(2))
        lp = (jnp.where(on_map, lcov[k, 0], pk[0]), jnp.where(on_map, lcov[k, 1], pk[1]),
              jnp.where(on_map, lcov[k, 2], pk[3]))  # fmt: skip
        degenerate = planar.build(jnp).degenerate(x[0], x[1], lk[0], lk[1])
        lk = tuple(jnp.where(degenerate, 1.0 + a, a) for a in lk)  # finite; a degenerate row's result is discarded
        xn, pn, nis, ok = soa.landmark_update(jnp, x, p, lk, lp, zs[:2], (rs[0], rs[1], rs[3]))
    ok = ok & soa.positive_definite(jnp, pn)
    F = build(jnp)
    d = F.rule((0, 0, False), degenerate, REJECTED, R_DEGENERATE)
    out, why = F.decided(F.rule(F.gate_rules(d, nis, thr[code], gate_on), ~ok, REJECTED, R_NUMERICAL), FUSED)
    commit = valid & (out == FUSED)
    new = jnp.stack((*xn, *pn), -1).astype(cur.dtype)
    cur = cur.at[jnp.where(commit, lo, cur.shape[0])].set(new, mode="drop")
    at = jnp.where(valid, at, status.shape[0])
    status = status.at[at].set(out.astype(status.dtype), mode="drop")
    reason = reason.at[at].set(why.astype(reason.dtype), mode="drop")
    return cur, status, reason


def _screen(jnp: Any, obs: Array, tgt: Array, kind: Array, valid: Array, t: Array, t0: Array, relative: Array,
            lm_on: Array) -> tuple[Array, Array, Array, Array]:  # fmt: skip
    """:func:`swarmloc.engine.formulas.screen_stamp` on the device (as :func:`swarmloc.engine.outcomes.screen`):
    ``(status, reason, obs_ok, needs)``; padded rows (``valid`` False) are neither pending nor running."""
    n = t0.shape[0]
    obs_ok = valid & (t >= t0[obs])
    status, reason, needs = build(jnp).screen_stamp(kind, obs, tgt, obs_ok, t >= t0[jnp.clip(tgt, 0, n - 1)],
                                                    relative, lm_on)  # fmt: skip
    return status.astype(jnp.int8), reason.astype(jnp.int8), obs_ok, needs


def _levels(jnp: Any, n: int, edge: Array, src: Array, dst: Array) -> Array:
    """:func:`swarmloc.engine.stamp.levels` on the device: longest-path levels of ``n`` robots over the ``edge``
    rows' ``src -> dst``."""
    from jax import lax

    dst = jnp.where(edge, dst, n)

    def step(c: tuple[Array, Array]) -> tuple[Array, Array]:
        level, _ = c
        new = jnp.zeros(n, level.dtype).at[dst].max(level[src] + 1, mode="drop")
        return new, jnp.any(new != level)

    start: tuple[Array, Array] = (jnp.zeros(n, jnp.int32), jnp.asarray(True))
    return lax.while_loop(lambda c: c[1], step, start)[0]


def stamp_kernel(jnp: Any, noise: UnicycleNoise, sizes: tuple[int, ...], dtype: Any) -> Any:
    """The device stamp for chunks of at most ``sizes[0]`` rows (the ``sizes`` descending) computing in ``dtype``: a
    function of the team on the device (:data:`DeviceState`), ``t``, the robots to move (a mask), the packed
    detections (:func:`pack`, ``m`` of them real) and the options (:data:`Consts`) returning ``(S, clock, status,
    book)``: the states (float64) and clocks, each detection's outcome and the book, the count of each (outcome,
    reason) pair (row-major, :data:`~swarmloc.engine.codes.OUTCOMES` by :data:`~swarmloc.engine.codes.REASONS`)
    followed by the number of levels."""
    from jax import lax

    def run(S0: Array, tc: Array, t0: Array, v: Array, w: Array, t: Array, move: Array, det: Array, m: Array,
            thr: Array, flags: Array, lxy: Array, lcov: Array) -> tuple[Array, Array, Array, Array]:  # fmt: skip
        n, mb = tc.shape[0], det.shape[1]
        gate_on, relative, lm_on = flags[0], flags[1], flags[2]
        X, v, w, thr, lxy, lcov = (a.astype(dtype) for a in (S0, v, w, thr, lxy, lcov))
        obs, tgt, kind = (a.astype(jnp.int32) for a in det[:3])
        z, R = det[3:6].T.astype(dtype), det[6:].T.astype(dtype)
        valid = jnp.arange(mb) < m
        status, reason, obs_ok, needs = _screen(jnp, obs, tgt, kind, valid, t, t0, relative, lm_on)
        observer = jnp.zeros(n, bool).at[jnp.where(obs_ok, obs, n)].set(True, mode="drop")
        involved = (observer | move).at[jnp.where(needs, tgt, n)].set(True, mode="drop")
        stored = observer | move
        dt = jnp.where(involved, t - tc, 0.0)
        xs, ps = soa.predict(jnp, tuple(X[:, i] for i in range(3)), tuple(X[:, 3 + i] for i in range(6)), v, w,
                             dt.astype(X.dtype), noise)  # fmt: skip
        prior = jnp.stack(xs + ps, -1)
        clock = jnp.where(stored & (dt > 0), t, tc)
        safe = jnp.clip(tgt, 0, n - 1)
        edge = needs & (tgt < obs) & observer[safe]
        level = _levels(jnp, n, edge, safe, obs)
        row_level = jnp.where(obs_ok, level[obs], -1)
        idx = jnp.arange(mb)
        first = jnp.concatenate([jnp.ones(1, bool), obs[1:] != obs[:-1]])
        pos = idx - lax.cummax(jnp.where(first, idx, 0))
        pend = status == PENDING
        width = jnp.max(jnp.where(pend, pos, 0)) + 1
        big = jnp.iinfo(jnp.int64).max  # 64 bits: levels x positions x kinds cannot overflow
        rank = jnp.asarray(_KIND_INDEX, dtype=jnp.int64)[kind]
        key = jnp.where(pend, (row_level.astype(jnp.int64) * width + pos) * len(DEVICE_KINDS) + rank, big)
        order = jnp.argsort(key, stable=True)  # (level, position, kind); not pending last
        ks = key[order]
        new = (ks != big) & jnp.concatenate([jnp.ones(1, bool), ks[1:] != ks[:-1]])
        npend = jnp.sum(pend)
        seg = jnp.nonzero(new, size=mb + 1, fill_value=npend)[0]
        nseg = jnp.sum(new)
        segkind = ks[jnp.minimum(seg, mb - 1)] % len(DEVICE_KINDS)
        lmk = jnp.where(tgt <= NO_LANDMARK, NO_LANDMARK - 1 - tgt, -1)
        rows = tuple(jnp.concatenate([a, a]) for a in (order, *(b[order] for b in (obs, safe, lmk, tgt < obs, z, R))))
        const = (prior, thr, gate_on, lxy, lcov)
        branches = [lambda c, a, k, kk=kk, s=s: _segment(jnp, kk, s, c, rows, a, k, const)
                    for kk in DEVICE_KINDS for s in sizes]  # fmt: skip
        small = jnp.asarray(sizes[1:] or (0,))

        def body(c: tuple[Array, Array, Carry]) -> tuple[Array, Array, Carry]:
            # chunk ``off`` of segment ``i``: at most sizes[0] rows
            i, off, carry = c
            start = seg[i] + off
            count = jnp.minimum(seg[i + 1] - start, sizes[0])
            which = jnp.sum(count <= small) if len(sizes) > 1 else 0  # the smallest size that holds the chunk
            carry = lax.switch(segkind[i] * len(sizes) + which, branches, carry, start, count)
            done = start + count >= seg[i + 1]
            return jnp.where(done, i + 1, i), jnp.where(done, 0, off + count), carry

        zero = jnp.zeros((), seg.dtype)
        _, _, (cur, status, reason) = lax.while_loop(lambda c: c[0] < nseg, body, (zero, zero, (prior, status, reason)))
        S = jnp.where(stored[:, None], cur.astype(S0.dtype), S0)
        pair = status.astype(jnp.int32) * len(REASONS) + reason
        table = jnp.zeros(len(OUTCOMES) * len(REASONS), jnp.int32).at[pair].add(valid.astype(jnp.int32))
        return S, clock, status, jnp.concatenate([table, (jnp.max(row_level) + 1)[None]])

    return run


@cache
def device_stamp(noise: UnicycleNoise, dtype: Any) -> DeviceStamp:
    """The :class:`DeviceStamp` of ``noise`` and ``dtype``, one per process: engines of the same noise share its
    compilations."""
    return DeviceStamp(noise, dtype)


class DeviceStamp:
    """The compiled device stamps of one noise model and dtype (one per static shape; :func:`device_stamp` shares
    them between engines): :attr:`compiles` counts the compilations per chunk sizes, :attr:`calls` the stamps."""

    def __init__(self, noise: UnicycleNoise, dtype: Any) -> None:
        import jax
        import jax.numpy as jnp

        self.noise, self.dtype, self._jax, self._jnp = noise, np.dtype(dtype), jax, jnp
        self.compiles: Counter[tuple[int, ...]] = Counter()
        self.calls = 0
        self._fns: dict[tuple[int, ...], Any] = {}

        self._columns = jax.jit(lambda *a, size: pack(Detections(*a), size, jnp), static_argnames="size")
        """:func:`pack` on the device, of the detections' five arrays."""

    def _fn(self, sizes: tuple[int, ...]) -> Any:
        if sizes not in self._fns:
            kernel = stamp_kernel(self._jnp, self.noise, sizes, self.dtype)

            def traced(*args: Any) -> Any:
                self.compiles[sizes] += 1  # once per new argument shape
                return kernel(*args)

            self._fns[sizes] = self._jax.jit(traced)
        return self._fns[sizes]

    def __call__(self, state: DeviceState, t: float, move: np.ndarray, det: Detections, gate: Gate, relative: bool,
                 lm_on: bool, landmarks: Landmarks | None) -> tuple[Array, Array, Array, np.ndarray, int]:  # fmt: skip
        """One stamp: ``(S, clock, status, table, levels)``, the states, clocks and each detection's outcome
        (padded) as device arrays, the count of each (outcome, reason) ``(len(OUTCOMES), len(REASONS))`` and the
        number of levels downloaded (the stamp's one download).

        ``state``: the team before the stamp (:data:`DeviceState`); ``move (N,)``: robots to move to ``t`` besides
        the observers (a command's); ``det``: the stamp's detections (canonical order, all of
        :data:`DEVICE_KINDS`), screened, scheduled and fused on the device; ``gate``, ``relative``, ``lm_on`` as the
        engine's; ``landmarks`` its map ``(xy (L, 2), cov (L, 2, 2))`` or None. The detections are padded to a power
        of two; the segments' static sizes follow from it and ``N``."""
        self.calls += 1
        m = len(det)
        S, clock, status, book = self._run(state, t, move, self._pack(det), m, consts(gate, relative, lm_on, landmarks))
        book = np.asarray(book)
        return S, clock, status, book[:-1].reshape(len(OUTCOMES), len(REASONS)), int(book[-1])

    def predict(self, state: DeviceState, t: float, move: np.ndarray) -> tuple[Array, Array]:
        """The robots ``move (N,)`` (a mask) predicted to ``t`` and stored (a stamp without detections: the same
        compiled call), ``(S, clock)`` on the device; nothing downloaded."""
        S, clock, _, _ = self._run(state, t, move, _EMPTY, 0, _NO_OPTIONS)
        return S, clock

    def _run(self, state: DeviceState, t: float, move: np.ndarray, det: Any, m: int, options: Consts) -> Any:
        """The compiled stamp for the bucket of ``det``'s columns and the team's size, called."""
        mb = det.shape[1]
        top = max(8, bucket(min(mb, state[1].shape[0])) // CHUNK)
        sizes = tuple(s for s in (top >> (2 * i) for i in range(SIZE_STEPS)) if s >= 8) or (8,)
        return self._fn(sizes)(*state, np.float64(t), move, det, np.int64(m), *options)

    def _pack(self, det: Detections) -> Any:
        """:func:`pack` of ``det`` padded to its bucket: on the host when small (one array to upload), else on the
        device (one ``device_put`` of the detections' arrays as they are, no host copy; it compiles once per
        count)."""
        m = len(det)
        if m < DEVICE_PAD:
            return pack(det, bucket(m))
        arrays = [det.observer, det.target, det.kind, det.z, det.R]
        arrays[:3] = (a.astype(np.int64, copy=False) for a in arrays[:3])  # one integer type: another compiles again
        return self._columns(*self._jax.device_put(arrays), size=bucket(m))


def consts(gate: Gate, relative: bool, lm_on: bool, landmarks: Landmarks | None) -> Consts:
    """The options of a stamp as the kernel reads them (:data:`Consts`)."""
    thr = constants(gate=gate.p).thr  # the compiled replays' table (inf: no gate)
    if landmarks is None:
        lxy, lcov = np.zeros((8, 2)), np.tile([1.0, 0.0, 1.0], (8, 1))
    else:
        nl = landmarks[0].shape[0]
        lxy = pad_rows(landmarks[0], bucket(nl), 0.0)
        lcov = pad_rows(landmarks[1][:, [0, 0, 1], [0, 1, 1]], bucket(nl), np.array([1.0, 0.0, 1.0]))
    return thr, np.array([gate.p is not None, relative, lm_on]), lxy, lcov


def pack(det: Detections, size: int, xp: Any = np) -> Any:
    """The detections ``det`` (planar) as one ``(12, size)`` float64 array of ``xp`` (numpy's on the host, jax's on
    the device), a column per detection: observer, target and kind codes, ``z[:3]``, the upper triangle of
    ``R[:3, :3]`` (``R00, R01, R02, R11, R12, R22``); columns past ``len(det)`` padded (:data:`_FILL`)."""
    cols = [det.observer, det.target, det.kind, *(det.z[:, i] for i in range(3)),
            *(det.R[:, i, j] for i, j in soa.UPPER)]  # fmt: skip
    fill = xp.broadcast_to(_FILL[:, None], (12, size - len(det)))
    return xp.concatenate([xp.stack(cols).astype(xp.float64), fill], axis=1)


_EMPTY = np.repeat(_FILL[:, None], 8, axis=1)
"""No detections (one bucket of padding): a stamp that only predicts."""
_NO_OPTIONS = consts(Gate(None), True, True, None)


def covered(det: Detections) -> bool:
    """Whether every detection of the stamp is of a kind the device stamp fuses (:data:`DEVICE_KINDS`)."""
    return bool(_COVERED[det.kind].all())


def pad_rows(x: np.ndarray, size: int, fill: Any) -> np.ndarray:
    """``x`` with ``size`` rows, the rows past its own set to ``fill`` (``x`` itself when it has them; padded rows
    are masked: their results are cut)."""
    x = np.asarray(x)
    if x.shape[0] == size:
        return x
    out = np.empty((size, *x.shape[1:]), dtype=x.dtype)
    out[: x.shape[0]] = x
    out[x.shape[0] :] = fill
    return out
