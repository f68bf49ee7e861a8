"""Where the engine keeps its team between stamps: host arrays (:class:`HostTeam`, backends ``"numpy"`` and
``"numba"``) or jax's device (:class:`DeviceTeam`, ``"jax"`` and ``"jax32"``: the states stay on the device from one
stamp to the next, read back only when the host reads them).

Both hand the host arrays out the same way (:class:`HostState`): :meth:`~HostTeam.host` to read them,
:meth:`~HostTeam.edit` to change them in place or rebind them. A device team keeps per field which copy is current
(the sync rule, :class:`DeviceTeam`), and runs a stamp, a prediction and a command on the device.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Any

import numpy as np

from swarmloc.engine.jax_stamp import DeviceStamp, DeviceState, Landmarks, bucket, import_jax
from swarmloc.node.update import Gate

if TYPE_CHECKING:  # jax is optional: imported where it runs
    from jax import Array

    from swarmloc.engine.detections import Detections

FIELDS = ("S", "clock", "t0", "v", "w")
"""The device's fields (:data:`~swarmloc.engine.jax_stamp.DeviceState`)."""
_FIELD = {"a": "S", "b": "S", "t": "clock", "t0": "t0", "v": "v", "w": "w"}
"""Host field -> the device field that holds it."""
_I, _J = np.triu_indices(3)  # the upper triangle in the device rows' order: 00, 01, 02, 11, 12, 22


@dataclass(slots=True)
class HostState:
    """The team on the host, as :class:`~swarmloc.engine.Engine` keeps it: states ``a``, ``b`` (``"dekf"`` on
    SE(2): ``x (N, 3)``, ``P (N, 3, 3)``), clocks ``t`` [s], start times ``t0`` [s], commands ``v``, ``w``."""

    a: np.ndarray
    b: np.ndarray
    t: np.ndarray
    t0: np.ndarray
    v: np.ndarray
    w: np.ndarray


class HostTeam:
    """The team in host arrays only: read and written in place."""

    def __init__(self, state: HostState) -> None:
        self.state = state

    def host(self, *names: str) -> HostState:
        """The arrays, to read (the fields ``names``, default all)."""
        return self.state

    def edit(self, *names: str) -> HostState:
        """The arrays, to change the fields ``names`` (in place or rebound)."""
        return self.state


class DeviceTeam:
    """The team resident on jax's device, :data:`~swarmloc.engine.jax_stamp.DeviceState` (float64), with a host copy.

    The sync rule, per device field (:data:`FIELDS`): the current copy is the host's, the device's or both.
    :meth:`host` downloads the fields read that are newer on the device, once (then both are current); :meth:`edit`
    does that and marks the fields edited newer on the host; :meth:`device` uploads the fields newer on the host,
    once; a stamp (:meth:`stamp`) and a prediction (:meth:`predict`) read and write the device's arrays only; a
    command (:meth:`command`) is written where the commands are current. :attr:`transfers` counts each field's
    uploads and downloads (``"up S"``, ``"down clock"``, ...). ``t0`` never changes: the host's is always current.
    """

    def __init__(self, state: HostState, kernel: DeviceStamp) -> None:
        self.kernel = kernel
        """The compiled stamps (:class:`~swarmloc.engine.jax_stamp.DeviceStamp`)."""
        self.transfers: Counter[str] = Counter()
        self._host = state
        self._dev: dict[str, Array] = {}
        self._newer_host = set(FIELDS)
        self._newer_device: set[str] = set()
        self._jax = import_jax()
        self._scatter = _scatter()

    def host(self, *names: str) -> HostState:
        """The host arrays, to read the fields ``names`` (``"a"``, ``"t"``, ...; default all): those newer on the
        device downloaded first."""
        want = {_FIELD[n] for n in names} if names else set(FIELDS)
        for f in sorted(self._newer_device & want):
            self._download(f)
        self._newer_device -= want
        return self._host

    def edit(self, *names: str) -> HostState:
        """The host arrays (:meth:`host`), to change the host fields ``names`` (``"a"``, ``"t"``, ...): newer on
        the host from now on."""
        state = self.host()
        self._newer_host.update(_FIELD[n] for n in names)
        return state

    def resident(self) -> bool:
        """Whether the device's copy is current in every field (nothing to upload)."""
        return not self._newer_host

    def device(self) -> DeviceState:
        """The device arrays: the fields newer on the host uploaded first."""
        for f in sorted(self._newer_host):
            self._upload(f)
        self._newer_host.clear()
        S, clock, t0, v, w = (self._dev[f] for f in FIELDS)
        return S, clock, t0, v, w

    def stamp(self, t: float, move: np.ndarray, det: Detections, gate: Gate, relative: bool, lm_on: bool,
              landmarks: Landmarks | None) -> tuple[Array, np.ndarray, int]:  # fmt: skip
        """One stamp on the device (:meth:`DeviceStamp.__call__ <swarmloc.engine.jax_stamp.DeviceStamp.__call__>`):
        ``(status, table, levels)``, the outcomes (padded) on the device, the book downloaded."""
        S, clock, status, table, levels = self.kernel(self.device(), t, move, det, gate, relative, lm_on, landmarks)
        self._put(S=S, clock=clock)
        return status, table, levels

    def predict(self, t: float, move: np.ndarray) -> None:
        """The robots ``move (N,)`` (a mask) predicted to ``t`` and stored, on the device."""
        S, clock = self.kernel.predict(self.device(), t, move)
        self._put(S=S, clock=clock)

    def command(self, robots: np.ndarray, v: np.ndarray, w: np.ndarray) -> None:
        """Commands ``(v, w)`` of ``robots`` (distinct rows): written on the host when it holds them newer, else
        scattered on the device (one upload of ``(robots, v, w)``), and on the host too when it is current."""
        if {"v", "w"} & self._newer_host:
            state = self.edit("v", "w")
            state.v[robots], state.w[robots] = v, w
            return
        k, n = len(robots), self._host.t.shape[0]
        cmd = np.empty((3, bucket(k)))
        cmd[:, k:] = np.array([[n], [0.0], [0.0]])  # padding: no row (dropped)
        cmd[0, :k], cmd[1, :k], cmd[2, :k] = robots, v, w
        self._dev["v"], self._dev["w"] = self._scatter(self._dev["v"], self._dev["w"], cmd)
        if {"v", "w"} & self._newer_device:
            return
        self._host.v[robots], self._host.w[robots] = v, w  # both stay current

    def _put(self, **fields: Array) -> None:
        self._dev.update(fields)
        self._newer_device.update(fields)

    def _download(self, f: str) -> None:
        self.transfers[f"down {f}"] += 1
        a = np.array(self._dev[f])  # a writable copy
        s = self._host
        if f == "S":
            s.a = a[:, :3].copy()
            s.b = np.empty((a.shape[0], 3, 3))
            s.b[:, _I, _J] = s.b[:, _J, _I] = a[:, 3:]
        elif f == "clock":
            s.t = a
        else:
            setattr(s, f, a)

    def _upload(self, f: str) -> None:
        self.transfers[f"up {f}"] += 1
        s = self._host
        if f == "S":
            a = np.concatenate([s.a, s.b[:, _I, _J]], axis=1)
        else:  # a copy: on a CPU the device array may share the host array's memory, which the host may change
            a = np.array(s.t if f == "clock" else getattr(s, f), dtype=np.float64)
        self._dev[f] = self._jax.device_put(a)


@cache
def _scatter() -> Any:
    """``f(v, w, cmd) -> (v, w)``: the rows ``cmd[0]`` of the commands set to ``cmd[1]``, ``cmd[2]`` (rows past the
    team dropped), jitted once per process (one compilation per bucket of rows)."""
    jax = import_jax()

    def scatter(v: Array, w: Array, cmd: Array) -> tuple[Array, Array]:
        rows = cmd[0].astype(np.int64)
        return v.at[rows].set(cmd[1], mode="drop"), w.at[rows].set(cmd[2], mode="drop")

    return jax.jit(scatter)
