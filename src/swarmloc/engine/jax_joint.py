"""The centralized EKFs (``cekf``, ``iekf``) and ``diekf`` replayed with JAX: :mod:`swarmloc.engine.joint`'s loop
as one compiled ``lax.scan`` (``run_engine(source, "cekf" | "iekf" | "diekf", backend="jax")``), and many runs of
one team size at once (:func:`replay_joint_batch`, ``jax.vmap``: Monte Carlo sweeps on a GPU).

A :class:`~swarmloc.engine.detections.Timeline` becomes a list of **events** in the order the compiled loop takes
them: at each stamp its detections (canonical order), then its commands, then its record. The scan runs one event
per step, in a branch for its type (``lax.switch``); the state is the joint ``X (n, 3)`` and ``P (3n, 3n)`` with
each robot's clock and command. What each event does is :func:`swarmloc.engine.joint.replay_joint`'s, formula by
formula: the scalar prediction of :mod:`swarmloc.engine.soa`, the screening of the centralized nodes (or of
``diekf``'s, whose robots start at their own first input), the measurement models of every kind (a 1- or 2-row
measurement padded to 3 rows whose extra rows are zero in ``H`` and the residual and one in the noise: they change
nothing), the Joseph update, the gate and the positive-definite check, the invariant filters' correction on the
group. One difference in arithmetic only: a prediction is applied to ``P`` at once, where the numba loop keeps it
pending until an update reads ``P`` (the same products, rounded in another order: results equal to 1e-10).

The events are padded to a power of two (:func:`swarmloc.engine.jax_stamp.bucket`), so a team size compiles once
per bucket of events and of record stamps (``COMPILES`` counts the traces). float64 only. Units: m, rad, s.
"""

from __future__ import annotations

from collections import Counter
from functools import cache
from typing import Any

import numpy as np

from swarmloc.engine import soa
from swarmloc.engine.codes import (
    ABSOLUTE,
    FUSED,
    GATED,
    NO_LANDMARK,
    POSE,
    R_DEGENERATE,
    R_LANDMARKS_OFF,
    R_NO_LANDMARK,
    R_NONFINITE,
    R_NOT_STARTED,
    R_NUMERICAL,
    R_OFF,
    R_SELF,
    R_TEAM,
    R_UNUSABLE,
    REJECTED,
    UNKNOWN,
    UNKNOWN_ROBOT,
    UNUSABLE,
)
from swarmloc.engine.detections import Timeline
from swarmloc.engine.jax_stamp import bucket, import_jax, pad_rows
from swarmloc.kernels.invariant import cartesian_to_world_cov
from swarmloc.motion import UnicycleNoise
from swarmloc.node.update import Gate
from swarmloc.sensors.models import KIND_ORDER, MIN_RANGE, MODELS

DET, CMD, REC, NOOP = range(4)
"""Event types: a detection, a command, a record of every robot, padding."""
RANGE_BEARING, RANGE, BEARING = KIND_ORDER["range_bearing"], KIND_ORDER["range"], KIND_ORDER["bearing"]
COMPILES: Counter[tuple] = Counter()
"""Traces of the scan per ``(robots, steps, commands, record slots, landmarks, runs, invariant, distributed)``: one per
shape."""


def events(tl: Timeline, size: int | None = None, csize: int | None = None) -> tuple[dict, dict]:
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


# ------------------------------------------------------------------------------------------------ the pieces
def _wrap(jnp: Any, a: Any) -> Any:
    return soa.wrap(jnp, a)


def _sym(jnp: Any, q: Any) -> Any:
    """The symmetric 3x3 of an upper triangle ``(q00, q01, q02, q11, q12, q22)``."""
    q00, q01, q02, q11, q12, q22 = q
    return jnp.stack([jnp.stack([q00, q01, q02]), jnp.stack([q01, q11, q12]), jnp.stack([q02, q12, q22])])


def _world_noise(x: Any, y: Any, q: tuple) -> tuple:
    """:func:`swarmloc.engine.joint.world_noise`: ``N^-1 Q N^-T`` at ``(x, y)``, upper triangles."""
    q00, q01, q02, q11, q12, q22 = q
    a02, a12 = q02 + y * q22, q12 - x * q22
    return (q00 + 2 * y * q02 + y * y * q22, q01 - x * q02 + y * a12, a02, q11 - 2 * x * q12 + x * x * q22, a12, q22)


def _step(jnp: Any, noise: UnicycleNoise, invariant: bool, x: Any, v: Any, w: Any, dt: Any) -> tuple:
    """One robot's (or a batch's) prediction over ``dt``: the new pose, its shear ``(a, b)`` and process noise
    (upper triangle; world-frame with ``invariant``, and no shear); ``dt <= 0`` changes nothing."""
    z = jnp.zeros_like(x[..., 0])
    xs, q = soa.predict(jnp, (x[..., 0], x[..., 1], x[..., 2]), (z,) * 6, v, w, dt, noise)
    if invariant:
        return jnp.stack(xs, -1), z, z, _world_noise(xs[0], xs[1], q)
    return jnp.stack(xs, -1), -(xs[1] - x[..., 1]), xs[0] - x[..., 0], q


def _advance(jnp: Any, lax: Any, noise: UnicycleNoise, invariant: bool, state: tuple, k: Any, t: Any) -> tuple:
    """Robot ``k`` moved to ``t`` (not before its clock): ``X``, its rows and columns of ``P`` sheared and its block
    given the process noise (the numba loop's pending prediction, applied at once)."""
    X, P, tc, v, w = state
    N = P.shape[0]
    xn, a, b, q = _step(jnp, noise, invariant, X[k], v[k], w[k], t - tc[k])
    i = 3 * k
    if not invariant:
        rows = lax.dynamic_slice(P, (i, 0), (3, N))
        rows = rows.at[0].add(a * rows[2]).at[1].add(b * rows[2])
        P = lax.dynamic_update_slice(P, rows, (i, 0))
        cols = lax.dynamic_slice(P, (0, i), (N, 3))
        cols = cols.at[:, 0].add(a * cols[:, 2]).at[:, 1].add(b * cols[:, 2])
        P = lax.dynamic_update_slice(P, cols, (0, i))
    block = lax.dynamic_slice(P, (i, i), (3, 3)) + _sym(jnp, q)
    P = lax.dynamic_update_slice(P, block, (i, i))
    return X.at[k].set(xn), P, tc.at[k].set(jnp.maximum(tc[k], t)), v, w


def _marginals(jnp: Any, noise: UnicycleNoise, invariant: bool, state: tuple, t: Any) -> tuple:
    """Every robot's Cartesian marginal predicted to ``t`` (not stored): ``x (n, 3)``, ``P (n, 3, 3)``."""
    X, P, tc, v, w = state
    n = X.shape[0]
    xn, a, b, q = _step(jnp, noise, invariant, X, v, w, t - tc)
    idx = jnp.arange(n)
    M = P.reshape(n, 3, n, 3)[idx, :, idx, :]
    one, zero = jnp.ones(n), jnp.zeros(n)
    if invariant:
        M = M + jnp.moveaxis(_sym(jnp, q), -1, 0)
        A = jnp.stack([jnp.stack([one, zero, -xn[:, 1]], -1), jnp.stack([zero, one, xn[:, 0]], -1),
                       jnp.stack([zero, zero, one], -1)], -2)  # fmt: skip
        return xn, A @ M @ jnp.swapaxes(A, -1, -2)
    A = jnp.stack([jnp.stack([one, zero, a], -1), jnp.stack([zero, one, b], -1), jnp.stack([zero, zero, one], -1)], -2)
    return xn, A @ M @ jnp.swapaxes(A, -1, -2) + jnp.moveaxis(_sym(jnp, q), -1, 0)


def _screen(jnp: Any, distributed: bool, kind: Any, i: Any, j: Any, t: Any, t0: Any, relative: Any,
            lm_on: Any) -> tuple:  # fmt: skip
    """``(outcome, reason)`` decided before a state is read (0, 0: go on): :func:`swarmloc.engine.joint._screen`,
    or with ``distributed`` :func:`swarmloc.engine.joint.screen_started`; the first rule that holds decides."""
    n = t0.shape[0]
    lm = j <= NO_LANDMARK
    lm_rule = (lm & ~lm_on, REJECTED, R_LANDMARKS_OFF), (j == NO_LANDMARK, UNKNOWN, R_NO_LANDMARK), (lm, 0, 0)
    if distributed:
        started = t >= t0[jnp.where(j >= 0, j, j + n) % n]
        rules = [(j == UNUSABLE, REJECTED, R_UNUSABLE), (~relative, REJECTED, R_OFF),
                 (j == UNKNOWN_ROBOT, UNKNOWN, R_TEAM), (j == i, REJECTED, R_SELF),
                 (~started, UNKNOWN, R_NOT_STARTED)]  # fmt: skip
    else:
        rules = [(j == UNKNOWN_ROBOT, jnp.where(relative, UNKNOWN, REJECTED), jnp.where(relative, R_TEAM, R_OFF)),
                 (j < 0, REJECTED, R_UNUSABLE), (~relative, REJECTED, R_OFF), (j == i, REJECTED, R_SELF)]  # fmt: skip
    st, why = jnp.int32(0), jnp.int32(0)
    for cond, s, r in reversed([(kind == ABSOLUTE, 0, 0), *lm_rule, *rules]):
        st, why = jnp.where(cond, s, st), jnp.where(cond, r, why)
    return st, why


def _measure(jnp: Any, kind: Any, xi: Any, xk: Any, z: Any, R: Any) -> tuple:
    """Residual ``r (3,)``, Jacobian ``H (3, 6)`` (observer's columns, then the target's) and noise ``Rm (3, 3)``
    of :func:`swarmloc.engine.joint.measure`, a 1- or 2-row measurement padded with rows that change nothing."""
    x0, y0, th = xi[0], xi[1], xi[2]
    dx, dy = xk[0] - x0, xk[1] - y0
    c, s = jnp.cos(th), jnp.sin(th)
    bx, by = c * dx + s * dy, -s * dx + c * dy
    o, e = jnp.zeros(()), jnp.ones(())
    eye = jnp.eye(3)
    h_abs = jnp.concatenate([eye, jnp.zeros((3, 3))], 1)
    r_abs = jnp.stack([z[0] - x0, z[1] - y0, _wrap(jnp, z[2] - th)])
    h_pose = jnp.stack([jnp.stack([-c, -s, by, c, s, o]), jnp.stack([s, -c, -bx, -s, c, o]),
                        jnp.stack([o, o, -e, o, o, e])])  # fmt: skip
    r_pose = jnp.stack([z[0] - bx, z[1] - by, _wrap(jnp, z[2] - _wrap(jnp, xk[2] - th))])
    cz, sz = jnp.cos(z[2]), jnp.sin(z[2])
    B = jnp.stack([jnp.stack([cz, -sz, o]), jnp.stack([sz, cz, o]), jnp.stack([o, o, e])])
    q = dx * dx + dy * dy
    rng = jnp.sqrt(q)
    row0 = jnp.stack([-dx / rng, -dy / rng, o, dx / rng, dy / rng, o])
    row1 = jnp.stack([dy / q, -dx / q, -e, -dy / q, dx / q, o])
    bearing = _wrap(jnp, z[1] - _wrap(jnp, jnp.arctan2(by, bx)))
    zero6 = jnp.zeros(6)
    h_rb = jnp.stack([row0, row1, zero6])
    r_rb = jnp.stack([z[0] - rng, bearing, o])
    R_rb = jnp.zeros((3, 3)).at[:2, :2].set(R[:2, :2]).at[2, 2].set(1.0)
    R_one = jnp.diag(jnp.stack([R[0, 0], e, e]))
    h_r, h_b = jnp.stack([row0, zero6, zero6]), jnp.stack([row1, zero6, zero6])
    r_r = jnp.stack([z[0] - rng, o, o])
    r_b = jnp.stack([_wrap(jnp, z[0] - _wrap(jnp, jnp.arctan2(by, bx))), o, o])
    pick = [kind == ABSOLUTE, kind == POSE, kind == RANGE_BEARING, kind == RANGE]
    H = jnp.select(pick, [h_abs, h_pose, h_rb, h_r], h_b)
    r = jnp.select(pick, [r_abs, r_pose, r_rb, r_r], r_b)
    Rm = jnp.select(pick, [R, B @ R @ B.T, R_rb, R_one], R_one)
    return r, H, Rm


def _inverse(jnp: Any, S: Any) -> tuple:
    """A 3x3 inverse by cofactors (:func:`swarmloc.engine.joint.inverse`) and whether ``S`` is regular."""
    co = [[S[(c + 1) % 3, (r + 1) % 3] * S[(c + 2) % 3, (r + 2) % 3] - S[(c + 1) % 3, (r + 2) % 3]
           * S[(c + 2) % 3, (r + 1) % 3] for c in range(3)] for r in range(3)]  # fmt: skip
    adj = jnp.stack([jnp.stack(row) for row in co])
    det = S[0, 0] * adj[0, 0] + S[0, 1] * adj[1, 0] + S[0, 2] * adj[2, 0]
    regular = det != 0.0
    return adj / jnp.where(regular, det, 1.0), regular


def _left_correct(jnp: Any, X: Any, delta: Any) -> Any:
    """Every pose corrected on the group by its world-frame ``delta (n, 3)`` (:func:`swarmloc.engine.joint.
    left_correct`, the same Taylor branches)."""
    d0, d1, d2 = delta[:, 0], delta[:, 1], delta[:, 2]
    c, s = jnp.cos(d2), jnp.sin(d2)
    t2 = d2 * d2
    near = jnp.abs(d2) < 0.05
    safe = jnp.where(near, 1.0, d2)
    A = jnp.where(near, (((t2 / 362880.0 - 1.0 / 5040.0) * t2 + 1.0 / 120.0) * t2 - 1.0 / 6.0) * t2 + 1.0,
                  jnp.sin(safe) / safe)  # fmt: skip
    B = jnp.where(near, d2 * ((((t2 / 3628800.0 - 1.0 / 40320.0) * t2 + 1.0 / 720.0) * t2 - 1.0 / 24.0) * t2 + 0.5),
                  safe * (2.0 * jnp.sin(safe / 2) ** 2 / (safe * safe)))  # fmt: skip
    x, y, ct, st = X[:, 0], X[:, 1], jnp.cos(X[:, 2]), jnp.sin(X[:, 2])
    th = _wrap(jnp, jnp.arctan2(s * ct + c * st, c * ct - s * st))
    return jnp.stack([c * x - s * y + (A * d0 - B * d1), s * x + c * y + (B * d0 + A * d1), th], -1)


def _kalman(jnp: Any, lax: Any, invariant: bool, X: Any, P: Any, r: Any, H: Any, Rm: Any, i: Any, jj: Any) -> tuple:
    """:func:`swarmloc.engine.joint._kalman` on the columns of robots ``i`` and ``jj``: ``(X+, P+, nis, ok)``."""
    N = P.shape[0]
    Pc = jnp.concatenate([lax.dynamic_slice(P, (0, 3 * i), (N, 3)), lax.dynamic_slice(P, (0, 3 * jj), (N, 3))], 1)
    U = Pc @ H.T
    Uc = jnp.concatenate([lax.dynamic_slice(U, (3 * i, 0), (3, 3)), lax.dynamic_slice(U, (3 * jj, 0), (3, 3))])
    S = H @ Uc + Rm
    S_inv, regular = _inverse(jnp, S)
    nis = jnp.where(regular, r @ S_inv @ r, jnp.nan)
    K = U @ S_inv
    W = U - K @ S
    step = (K @ r).reshape(-1, 3)
    if invariant:
        xn = _left_correct(jnp, X, step)
    else:
        xn = (X + step).at[:, 2].set(_wrap(jnp, X[:, 2] + step[:, 2]))
    A = P - K @ U.T - W @ K.T
    Pn = 0.5 * (A + A.T)
    ok = regular & jnp.isfinite(nis) & jnp.isfinite(xn).all() & jnp.isfinite(Pn).all()
    return xn, Pn, nis, ok


# ------------------------------------------------------------------------------------------------ the events
def _detection(jnp: Any, lax: Any, form: tuple, state: tuple, ev: dict, const: tuple) -> tuple:
    """A detection: the observer moved to its stamp, the screening, the target (a robot: moved to the stamp too;
    ``diekf``: only if it takes the update), the measurement, the update and its outcome."""
    noise, invariant, distributed = form
    t0, thr, gate_on, relative, lm_on, lxy, lcov = const
    i, j, kind, t = ev["a"], ev["b"], ev["kind"], ev["t"]
    state = _advance(jnp, lax, noise, invariant, state, i, t)
    st0, why0 = _screen(jnp, distributed, kind, i, j, t, t0, relative, lm_on)
    robot = j >= 0
    jr = jnp.where(robot, j, i)
    moved = _advance(jnp, lax, noise, invariant, state, jr, t)
    s1 = tuple(jnp.where(robot, a, b) for a, b in zip(moved, state, strict=True))
    X, P = s1[0], s1[1]
    lk = jnp.clip(NO_LANDMARK - 1 - j, 0, lxy.shape[0] - 1)
    xk = jnp.where(robot, X[jr], jnp.concatenate([lxy[lk], jnp.zeros(1)]))
    degenerate = (kind >= RANGE_BEARING) & (jnp.hypot(xk[0] - X[i, 0], xk[1] - X[i, 1]) < MIN_RANGE)
    r, H, Rm = _measure(jnp, kind, X[i], xk, ev["z"], ev["R"])
    Hk = H[:, 3:5]
    Rm = jnp.where(~robot & (kind != ABSOLUTE), Rm + Hk @ lcov[lk] @ Hk.T, Rm)  # a map landmark's covariance
    H = jnp.where(robot, H, H.at[:, 3:].set(0.0))
    if invariant:  # world-frame error columns: H N
        H = H.at[:, 5].add(jnp.where(robot, -xk[1] * H[:, 3] + xk[0] * H[:, 4], 0.0))
        H = H.at[:, 2].add(-X[i, 1] * H[:, 0] + X[i, 0] * H[:, 1])
    xn, Pn, nis, ok = _kalman(jnp, lax, invariant, X, P, r, H, Rm, i, jr)
    usable = jnp.isfinite(jnp.linalg.cholesky(Pn)).all()
    rules = [
        (st0 != 0, st0, why0),
        (degenerate, REJECTED, R_DEGENERATE),
        (gate_on & ~jnp.isfinite(nis), REJECTED, R_NONFINITE),
        (gate_on & (nis > thr[kind]), GATED, 0),
        (~(ok & usable), REJECTED, R_NUMERICAL),
    ]
    st, why = jnp.int32(FUSED), jnp.int32(0)
    for cond, s, w in reversed(rules):
        st, why = jnp.where(cond, s, st), jnp.where(cond, w, why)
    fused = st == FUSED
    keep = state if distributed else tuple(jnp.where(st0 != 0, a, b) for a, b in zip(state, s1, strict=True))
    out = (xn, Pn, *s1[2:])
    return tuple(jnp.where(fused, a, b) for a, b in zip(out, keep, strict=True)), st, why


@cache
def _runner(noise: UnicycleNoise, invariant: bool, distributed: bool, batched: bool) -> Any:
    """The jitted scan over a run's events (``batched``: over runs, ``jax.vmap``), one compilation per shape."""
    jax = import_jax()
    import jax.numpy as jnp
    from jax import lax

    form = (noise, invariant, distributed)

    def run(X, P, tc, v, w, ev, cmd, t0, thr, gate_on, relative, lm_on, lxy, lcov, slots):  # noqa: ANN001, ANN202
        n = X.shape[0]
        nothing = (jnp.zeros((n, 3)), jnp.zeros((n, 3, 3)))
        no = jnp.int32(0)

        def command(c, state):  # noqa: ANN001, ANN202
            k = cmd["a"][c]
            X, P, tc, v, w = _advance(jnp, lax, noise, invariant, state, k, cmd["t"][c])
            return X, P, tc, v.at[k].set(cmd["v"][c]), w.at[k].set(cmd["w"][c])

        def detection(state, ev):  # noqa: ANN001, ANN202
            const = (t0, thr, gate_on, relative, lm_on, lxy, lcov)
            return (*_detection(jnp, lax, form, state, ev, const), *nothing)

        def record(state, ev):  # noqa: ANN001, ANN202
            return state, no, no, *_marginals(jnp, noise, invariant, state, ev["t"])

        def pad(state, ev):  # noqa: ANN001, ANN202, ARG001
            return state, no, no, *nothing

        def other(state, ev):  # noqa: ANN001, ANN202
            return lax.cond(ev["type"] == REC, record, pad, state, ev)

        def body(carry, ev):  # noqa: ANN001, ANN202
            state, ox, oP = carry
            state = lax.fori_loop(ev["c0"], ev["c1"], command, state)  # the commands before the step: no branch
            state, st, why, mx, mP = lax.cond(ev["type"] == DET, detection, other, state, ev)
            slot = jnp.where(ev["type"] == REC, ev["a"], slots)  # the last slot takes the other steps' zeros
            ox = lax.dynamic_update_slice(ox, mx[None], (slot, 0, 0))
            oP = lax.dynamic_update_slice(oP, mP[None], (slot, 0, 0, 0))
            return (state, ox, oP), (jnp.int8(st), jnp.int8(why))

        carry = ((X, P, tc, v, w), jnp.zeros((slots + 1, n, 3)), jnp.zeros((slots + 1, n, 3, 3)))
        (_, ox, oP), (st, why) = lax.scan(body, carry, ev)
        return st, why, ox[:slots], oP[:slots]

    def traced(X, P, tc, v, w, ev, cmd, t0, *const, slots):  # noqa: ANN001, ANN202
        runs = X.shape[0] if batched else 1
        shape = (tc.shape[-1], ev["t"].shape[-1], cmd["t"].shape[-1], slots, const[-2].shape[0], runs)
        COMPILES[(*shape, invariant, distributed)] += 1
        if batched:
            inner = jax.vmap(lambda *a: run(*a, *const, slots), in_axes=(0,) * 8)
            return inner(X, P, tc, v, w, ev, cmd, t0)
        return run(X, P, tc, v, w, ev, cmd, t0, *const, slots)

    return jax.jit(traced, static_argnames=("slots",))


def _start(x: np.ndarray, P: np.ndarray, t0: Any, invariant: bool) -> tuple:
    """The joint state of :func:`swarmloc.engine.joint.replay_joint` from Cartesian beliefs: ``(X, J, clocks,
    starts)``."""
    n = x.shape[0]
    starts = np.broadcast_to(np.asarray(t0, dtype=float), (n,)).copy()
    x = np.ascontiguousarray(x, dtype=float)
    P = cartesian_to_world_cov(x, np.asarray(P, dtype=float)) if invariant else np.asarray(P, dtype=float)
    J = np.zeros((3 * n, 3 * n))
    for k in range(n):
        J[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = P[k]
    return x.copy(), J, np.where(np.isfinite(starts), starts, 0.0), starts


def _records(tl: Timeline, starts: np.ndarray, ox: np.ndarray, oP: np.ndarray) -> tuple:
    """``(robot, stamp index, x, P)`` of every started robot at every recorded stamp, stamp then row order."""
    rec = np.flatnonzero(tl.record)
    live = tl.stamps[rec][:, None] >= starts[None, :]
    slot, robot = np.nonzero(live)
    return robot.astype(np.int64), rec[slot].astype(np.int64), ox[slot, robot], oP[slot, robot]


def _constants(gate: float | None, use_relative: bool, use_landmarks: bool, landmarks: Any) -> tuple:
    g = Gate(gate)
    thr = np.array([g.threshold(MODELS[name].size) for name in sorted(KIND_ORDER, key=KIND_ORDER.get)])
    lxy, lcov = landmarks if landmarks is not None else (np.zeros((1, 2)), np.zeros((1, 2, 2)))
    if len(lxy) == 0:
        lxy, lcov = np.zeros((1, 2)), np.zeros((1, 2, 2))
    return (thr, np.bool_(g.p is not None), np.bool_(use_relative), np.bool_(use_landmarks),
            np.asarray(lxy, dtype=float), np.asarray(lcov, dtype=float))  # fmt: skip


def replay_joint_jax(
    tl: Timeline,
    x: np.ndarray,
    P: np.ndarray,
    t0: float | np.ndarray,
    noise: UnicycleNoise,
    *,
    gate: float | None = None,
    use_relative: bool = True,
    use_landmarks: bool = True,
    landmarks: tuple[np.ndarray, np.ndarray] | None = None,
    invariant: bool = False,
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """:func:`swarmloc.engine.joint.replay_joint` (the same arguments and results) as one JAX call."""
    kw = {"gate": gate, "use_relative": use_relative, "use_landmarks": use_landmarks, "landmarks": landmarks}
    return replay_joint_batch([tl], x[None], P[None], [t0], noise, invariant=invariant, _single=True, **kw)[0]


def replay_joint_batch(
    tls: list[Timeline],
    x: np.ndarray,
    P: np.ndarray,
    t0: list[Any],
    noise: UnicycleNoise,
    *,
    gate: float | None = None,
    use_relative: bool = True,
    use_landmarks: bool = True,
    landmarks: tuple[np.ndarray, np.ndarray] | None = None,
    invariant: bool = False,
    _single: bool = False,
) -> list[tuple[np.ndarray, np.ndarray, tuple]]:
    """Runs of one team of ``n`` robots (``x (B, n, 3)``, ``P (B, n, 3, 3)``, each run its own timeline and start
    ``t0[b]``, every other argument shared) in one call vectorized over the runs (``jax.vmap``): a Monte Carlo
    sweep. Each run's result is :func:`replay_joint_jax`'s. The runs' events are padded to one bucket."""
    if len(tls) != x.shape[0] or len(t0) != x.shape[0]:
        raise ValueError(f"replay_joint_batch: {len(tls)} timelines, {x.shape[0]} initial states, {len(t0)} starts")
    n = x.shape[1]
    distributed = np.ndim(t0[0]) == 1
    if distributed and not invariant:
        raise ValueError("replay_joint: per-robot starts are diekf's (invariant=True); cekf starts at one t0")
    size = bucket(max(len(tl.det) + int(tl.record.sum()) + 1 for tl in tls))
    csize = bucket(max(tl.robot.size for tl in tls))
    slots = bucket(max(int(tl.record.sum()) for tl in tls))
    both = [events(tl, size, csize) for tl in tls]
    ev = {k: np.stack([e[0][k] for e in both]) for k in both[0][0]}
    cmd = {k: np.stack([e[1][k] for e in both]) for k in both[0][1]}
    starts = [_start(x[b], P[b], t0[b], invariant) for b in range(len(tls))]
    X, J, clock, st0 = (np.stack(a) for a in zip(*starts, strict=True))
    zero = np.zeros((len(tls), n))
    const = _constants(gate, use_relative, use_landmarks, landmarks)
    fn = _runner(noise, bool(invariant), bool(distributed), not _single)
    args = (X, J, clock, zero, zero, ev, cmd, st0)
    if _single:
        first = [a[0] if isinstance(a, np.ndarray) else {k: v[0] for k, v in a.items()} for a in args]
        res = tuple(np.asarray(a)[None] for a in fn(*first, *const, slots=slots))
    else:
        res = tuple(np.asarray(a) for a in fn(*args, *const, slots=slots))
    out = []
    for b, tl in enumerate(tls):
        m = len(tl.det)
        status, reason = np.zeros(m, dtype=np.int8), np.zeros(m, dtype=np.int8)
        q = ev["q"][b]
        det = q >= 0
        status[q[det]], reason[q[det]] = res[0][b][det], res[1][b][det]
        out.append((status, reason, _records(tl, st0[b], res[2][b], res[3][b])))
    return out
