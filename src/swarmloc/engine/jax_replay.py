"""What the JAX replays of a whole timeline share (:mod:`swarmloc.engine.jax_joint`: ``cekf``, ``iekf``, ``diekf``;
:mod:`swarmloc.engine.jax_pairs`: ``rdl``): the events, one ``lax.scan`` around a form's kernels, the measurement
models and screening as traced code, and the host side of a batch of runs.

A :class:`~swarmloc.engine.detections.Timeline` becomes **steps** and **commands** in the order the compiled numba
loops take them: at each stamp its detections (canonical order), then its commands, then its record. The scan runs
one step (a detection or a record) per iteration, in a branch for its type (``lax.cond``), after the commands that
come before it in a tight inner loop (``lax.fori_loop``, no branch: on a CPU an XLA conditional costs more than a
command's prediction). A form gives three kernels on its state (a tuple whose first five entries are the poses,
the covariances, the clocks and the commands ``v``, ``w``): ``advance(state, k, t)``, ``detection(state, step)
-> (state, outcome, reason)`` and ``marginals(state, t) -> (x (n, 3), P (n, 3, 3))``, Cartesian.

Steps and commands are padded to powers of two (:func:`swarmloc.engine.jax_stamp.bucket`), so a team size compiles
once per bucket (:data:`COMPILES` counts the traces); many runs of one team size run in one call vectorized over
the runs (``jax.vmap``: a Monte Carlo sweep). float64 only. Units: m, rad, s.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from functools import cache
from typing import Any

import numpy as np

from swarmloc.engine import blocks as _blocks
from swarmloc.engine import soa
from swarmloc.engine.codes import ABSOLUTE, FUSED, POSE, R_NUMERICAL, REJECTED
from swarmloc.engine.detections import Timeline
from swarmloc.engine.formulas import RANGE_BEARING, build
from swarmloc.engine.jax_stamp import bucket, import_jax, pad_rows
from swarmloc.engine.replay_io import Events, Replayed, Traced

DET, CMD, REC, NOOP = range(4)
"""Event types: a detection, a command, a record of every robot, padding."""
COMPILES: Counter[Traced] = Counter()
"""Traces per ``(form, robots, steps, commands, record slots, landmarks, runs)``: one per shape."""
Kernels = tuple[Callable[..., Any], Callable[..., Any], Callable[..., Any]]
"""``(advance, detection, marginals)`` of a form (the module's docstring)."""


def events(tl: Timeline, size: int | None = None, csize: int | None = None) -> tuple[Events, Events]:
    """``tl`` as the scan's events: ``(steps, commands)``.

    ``steps``: the detections and records in the loop's order, then one padding step, padded to ``size`` rows
    (default :func:`bucket` of their count): ``type``, ``t`` [s], ``a`` (observer, or record slot), ``b`` (target
    code), ``kind``, ``z (E, 3)``, ``R (E, 3, 3)``, ``q`` (detection row, -1 for a record), and ``c0``, ``c1``: the
    commands the loop takes before the step (rows of ``commands``). ``commands``: ``a`` (robot), ``t`` [s], ``v``
    [m/s], ``w`` [rad/s], in the loop's order, padded to ``csize`` rows (default :func:`bucket`)."""
    m, c, s = len(tl.det), tl.robot.size, len(tl)
    rec = np.flatnonzero(tl.record)
    stamp = np.concatenate([np.repeat(np.arange(s), np.diff(tl.d0)), np.repeat(np.arange(s), np.diff(tl.c0)), rec])
    typ = np.concatenate([np.full(m, DET), np.full(c, CMD), np.full(rec.size, REC)])
    idx = np.concatenate([np.arange(m), np.arange(c), np.arange(rec.size)])
    order = np.lexsort((idx, typ, stamp))
    typ, idx, stamp = typ[order], idx[order], stamp[order]
    cmd = typ == CMD
    qc = idx[cmd]
    commands = {"a": tl.robot[qc], "t": tl.stamps[stamp[cmd]].astype(float), "v": tl.v[qc], "w": tl.w[qc]}
    before = np.cumsum(cmd) - cmd  # commands before each event
    step = ~cmd
    typ, idx, stamp, c1 = (np.append(a[step], fill) for a, fill in ((typ, NOOP), (idx, 0), (stamp, 0), (before, c)))
    det = typ == DET
    qd, e = idx[det], typ.size
    steps = {"type": typ, "t": np.append(tl.stamps, 0.0)[np.where(typ == NOOP, -1, stamp)].astype(float),
             "a": idx.copy(), "b": np.zeros(e, dtype=np.int64), "kind": np.zeros(e, dtype=np.int64),
             "z": np.zeros((e, 3)), "R": np.zeros((e, 3, 3)), "q": np.where(det, idx, -1),
             "c0": np.concatenate([[0], c1[:-1]]), "c1": c1}  # fmt: skip
    steps["a"][det], steps["b"][det], steps["kind"][det] = tl.det.observer[qd], tl.det.target[qd], tl.det.kind[qd]
    steps["z"][det], steps["R"][det] = tl.det.z[qd], tl.det.R[qd]
    size, csize = bucket(e) if size is None else size, bucket(c) if csize is None else csize
    fill = {"type": NOOP, "q": -1, "c0": c, "c1": c}
    return ({k: pad_rows(v, size, fill.get(k, 0)) for k, v in steps.items()},
            {k: pad_rows(v, csize, 0) for k, v in commands.items()})  # fmt: skip


# ------------------------------------------------------------------------------------------------ traced pieces
def wrap(jnp: Any, a: Any) -> Any:
    return soa.wrap(jnp, a)


def sym(jnp: Any, q: Any) -> Any:
    """The symmetric ``(..., 3, 3)`` of an upper triangle ``(q00, q01, q02, q11, q12, q22)`` (entries ``(...)``)."""
    q00, q01, q02, q11, q12, q22 = q
    return jnp.stack([jnp.stack([q00, q01, q02], -1), jnp.stack([q01, q11, q12], -1), jnp.stack([q02, q12, q22], -1)],
                     -2)  # fmt: skip


def formulas() -> Any:
    """The shared formulas (:mod:`swarmloc.engine.formulas`) on ``jax.numpy``."""
    import jax.numpy as jnp

    return build(jnp)


def blocks() -> Any:
    """The shared block math (:mod:`swarmloc.engine.blocks`) on ``jax.numpy``."""
    import jax.numpy as jnp

    return _blocks.build(jnp)


def entries(M: Any) -> Traced:
    """``M (..., 3, 3)`` as rows of entries ``(...)`` (:mod:`swarmloc.engine.blocks`' matrices)."""
    return tuple(tuple(M[..., r, c] for c in range(3)) for r in range(3))


def matrix(jnp: Any, rows: Traced) -> Any:
    """Rows of entries ``(...)`` as ``(..., 3, 3)`` (:func:`entries`' inverse)."""
    return jnp.stack([jnp.stack([jnp.broadcast_to(a, jnp.shape(rows[0][0])) for a in row], -1) for row in rows], -2)


def cartesian(jnp: Any, invariant: bool, x: Any, M: Any, a: Any, b: Any, q: Any) -> Any:
    """Robots' blocks ``M (n, 3, 3)`` after their prediction (shear ``(a, b)``, noise ``q``) to poses ``x (n, 3)``,
    Cartesian (:func:`swarmloc.engine.blocks.predicted_block`, then ``N M N^T`` with ``invariant``: the numba
    records')."""
    B = blocks()
    M = B.predicted_block(entries(M), a, b, q)
    return matrix(jnp, B.sheared(M, -x[:, 1], x[:, 0]) if invariant else M)


def usable(jnp: Any, P: Any) -> Any:
    """Finite and positive definite (a Cholesky factorization: :func:`swarmloc.node.update.usable_covariance`)."""
    return jnp.isfinite(P).all() & jnp.isfinite(jnp.linalg.cholesky(P)).all()


def verdict(jnp: Any, d: Traced, gate_on: Any, nis: Any, thr: Any, ok: Any, Pn: Any) -> Traced:
    """The rules ``d`` (:func:`swarmloc.engine.formulas.rule`'s) then those after an update with ``nis``, its
    finite-ness ``ok`` and its covariance ``Pn``: the gate (threshold ``thr``) and the positive-definite check, as
    :func:`swarmloc.engine.joint_math.verdict`; ``(outcome, reason)``, ``FUSED`` when no rule decides."""
    F = formulas()
    st, why = F.decided(F.rule(F.gate_rules(d, nis, thr, gate_on), ~(ok & usable(jnp, Pn)), REJECTED, R_NUMERICAL),
                        FUSED)  # fmt: skip
    return st, why


def measure(jnp: Any, kind: Any, xi: Any, xk: Any, z: Any, R: Any) -> Traced:
    """Residual ``r (3,)``, Jacobian ``H (3, 6)`` (observer's columns, then the target's) and noise ``Rm (3, 3)``
    of :func:`swarmloc.engine.formulas.measure`, a 1- or 2-row measurement padded with rows that change nothing
    (zero in ``H`` and the residual, one in the noise)."""
    r, H, (cz, sz) = formulas().measure(kind, xi[0], xi[1], xi[2], (xk[0], xk[1], xk[2]), (z[0], z[1], z[2]))
    o, e = jnp.zeros(()), jnp.ones(())
    B = jnp.stack([jnp.stack([cz, -sz, o]), jnp.stack([sz, cz, o]), jnp.stack([o, o, e])])
    R_rb = jnp.zeros((3, 3)).at[:2, :2].set(R[:2, :2]).at[2, 2].set(1.0)
    R_one = jnp.diag(jnp.stack([R[0, 0], e, e]))
    Rm = jnp.select([kind == ABSOLUTE, kind == POSE, kind == RANGE_BEARING], [R, B @ R @ B.T, R_rb], R_one)
    return jnp.stack([jnp.asarray(a) for a in r]), jnp.stack([jnp.stack([jnp.asarray(a) for a in h]) for h in H]), Rm


def inverse(jnp: Any, S: Any) -> Traced:
    """3x3 inverses by cofactors (:func:`swarmloc.engine.blocks.inverse3`) of ``S (..., 3, 3)`` and whether each is
    regular."""
    inv, regular = blocks().inverse3(entries(S))
    return matrix(jnp, inv), regular


# ------------------------------------------------------------------------------------------------ the scan
def _scan(jnp: Any, lax: Any, kernels: Kernels, state: Traced, ev: Events, cmd: Events, slots: int) -> Traced:
    """The steps of one run: ``(outcomes, reasons)`` per step and the records ``(slots, n, 3)``, ``(slots, n, 3,
    3)``."""
    advance, detection, marginals = kernels
    n = state[0].shape[0]
    nothing = (jnp.zeros((n, 3)), jnp.zeros((n, 3, 3)))
    no = jnp.int32(0)

    def command(c: Any, state: Any) -> Any:
        k = cmd["a"][c]
        s = advance(state, k, cmd["t"][c])
        return (*s[:3], s[3].at[k].set(cmd["v"][c]), s[4].at[k].set(cmd["w"][c]), *s[5:])

    def found(state: Any, ev: Any) -> Any:
        state, st, why = detection(state, ev)
        return state, jnp.int32(st), jnp.int32(why), *nothing

    def record(state: Any, ev: Any) -> Any:
        return state, no, no, *marginals(state, ev["t"])

    def pad(state: Any, ev: Any) -> Any:  # noqa: ARG001
        return state, no, no, *nothing

    def other(state: Any, ev: Any) -> Any:
        return lax.cond(ev["type"] == REC, record, pad, state, ev)

    def body(carry: Any, ev: Any) -> Any:
        state, ox, oP = carry
        state = lax.fori_loop(ev["c0"], ev["c1"], command, state)  # the commands before the step: no branch
        state, st, why, mx, mP = lax.cond(ev["type"] == DET, found, other, state, ev)
        slot = jnp.where(ev["type"] == REC, ev["a"], slots)  # the last slot takes the other steps' zeros
        ox = lax.dynamic_update_slice(ox, mx[None], (slot, 0, 0))
        oP = lax.dynamic_update_slice(oP, mP[None], (slot, 0, 0, 0))
        return (state, ox, oP), (jnp.int8(st), jnp.int8(why))

    carry = (state, jnp.zeros((slots + 1, n, 3)), jnp.zeros((slots + 1, n, 3, 3)))
    (_, ox, oP), (st, why) = lax.scan(body, carry, ev)
    return st, why, ox[:slots], oP[:slots]


@cache
def compiled(form: Any, make: Callable[..., Kernels], batched: bool) -> Any:
    """The jitted scan of a form (``make(jnp, lax, t0, const) -> kernels``; ``form`` names it in
    :data:`COMPILES`), over one run or (``batched``) over runs: ``fn(state, steps, commands, t0, const, slots=)``."""
    jax = import_jax()
    import jax.numpy as jnp
    from jax import lax

    def run(state: Any, ev: Any, cmd: Any, t0: Any, const: Any, slots: Any) -> Any:
        return _scan(jnp, lax, make(jnp, lax, t0, const), state, ev, cmd, slots)

    def traced(state: Any, ev: Any, cmd: Any, t0: Any, const: Any, *, slots: Any) -> Any:
        runs = state[0].shape[0] if batched else 1
        COMPILES[(form, state[2].shape[-1], ev["t"].shape[-1], cmd["t"].shape[-1], slots, const[-2].shape[0],
                  runs)] += 1  # fmt: skip
        if batched:
            return jax.vmap(lambda s, e, c, t: run(s, e, c, t, const, slots))(state, ev, cmd, t0)
        return run(state, ev, cmd, t0, const, slots)

    return jax.jit(traced, static_argnames=("slots",))


def run_batch(fn: Any, tls: Sequence[Timeline], states: Sequence[Traced], t0s: Sequence[np.ndarray], const: Traced,
              single: bool) -> list[Replayed]:  # fmt: skip
    """Runs through ``fn`` (:func:`compiled`; ``single``: its one-run form, one run): each run's timeline, state at
    its start (numpy) and each robot's start ``(n,)`` [s]; returns each run's ``(status, reason, records)`` as
    :func:`swarmloc.engine.joint.replay_joint` gives them. The runs' steps and commands are padded to one bucket."""
    size = bucket(max(len(tl.det) + int(tl.record.sum()) + 1 for tl in tls))
    csize = bucket(max(tl.robot.size for tl in tls))
    slots = bucket(max(int(tl.record.sum()) for tl in tls))
    both = [events(tl, size, csize) for tl in tls]
    ev = {k: np.stack([e[0][k] for e in both]) for k in both[0][0]}
    cmd = {k: np.stack([e[1][k] for e in both]) for k in both[0][1]}
    state = tuple(np.stack(a) for a in zip(*states, strict=True))
    t0 = np.stack(t0s)
    if single:
        first = (tuple(a[0] for a in state), {k: a[0] for k, a in ev.items()}, {k: a[0] for k, a in cmd.items()})
        res = tuple(np.asarray(a)[None] for a in fn(*first, t0[0], const, slots=slots))
    else:
        res = tuple(np.asarray(a) for a in fn(state, ev, cmd, t0, const, slots=slots))
    out = []
    for b, tl in enumerate(tls):
        m = len(tl.det)
        status, reason = np.zeros(m, dtype=np.int8), np.zeros(m, dtype=np.int8)
        q = ev["q"][b]
        det = q >= 0
        status[q[det]], reason[q[det]] = res[0][b][det], res[1][b][det]
        out.append((status, reason, _records(tl, t0[b], res[2][b], res[3][b])))
    return out


def _records(tl: Timeline, starts: np.ndarray, ox: np.ndarray, oP: np.ndarray) -> Traced:
    """``(robot, stamp index, x, P)`` of every started robot at every recorded stamp, stamp then row order."""
    rec = np.flatnonzero(tl.record)
    live = tl.stamps[rec][:, None] >= starts[None, :]
    slot, robot = np.nonzero(live)
    return robot.astype(np.int64), rec[slot].astype(np.int64), ox[slot, robot], oP[slot, robot]
