"""The jax backends keep the team on the device between stamps (:class:`swarmloc.engine.resident.DeviceTeam`): a run
of covered stamps and commands neither downloads nor re-uploads the states (each stamp reads the arrays the one
before left on the device), a read downloads what changed once, a stamp on the level path uploads what it changed
once, and every read equals the numpy engine's."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from test_engine import _outcome_mix
from test_engine_device import _engines, _robot_ranges

from swarmloc.engine import Detections, Engine
from swarmloc.engine.resident import DeviceTeam

# slow: the first test of the module compiles the engine's JAX kernels
pytestmark = [pytest.mark.unit, pytest.mark.slow]


class _Spy:
    """A device stamp that records, per call, whether the states it was given are the ones the call before left."""

    def __init__(self, kernel: Any) -> None:
        self.kernel, self.last, self.chained = kernel, None, []

    def _seen(self, state: tuple, out: tuple) -> tuple:
        self.chained.append(state[0] is self.last)
        self.last = out[0]
        return out

    def __call__(self, state: tuple, *args: Any) -> tuple:
        return self._seen(state, self.kernel(state, *args))

    def predict(self, state: tuple, *args: Any) -> tuple:
        return self._seen(state, self.kernel.predict(state, *args))


def _stamp(engines: dict[str, Engine], t: float, det: Detections | None, cmd: tuple) -> None:
    for eng in engines.values():
        eng.step(t, det, cmd, presorted=True)


def _same_reads(engines: dict[str, Engine], t: float) -> None:
    ref, jx = engines["numpy"], engines["jax"]
    for got, want in zip(jx.belief(t), ref.belief(t), strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(jx.t, ref.t)
    np.testing.assert_array_equal(jx.v, ref.v)
    np.testing.assert_allclose(jx.a, ref.a, rtol=0, atol=1e-12)
    assert jx.counts == ref.counts and jx.reasons == ref.reasons and jx.last_levels == ref.last_levels


def test_covered_stamps_keep_the_states_on_the_device_and_a_read_downloads_them_once() -> None:
    """Eight stamps (detections and commands; every other one commands only) after the first upload: no download,
    no upload of a state, each stamp fed the arrays the one before returned; then a read downloads the states and
    clocks once (the commands, written on both sides, not at all) and equals numpy; a stamp with a range-only
    detection (the level path: predicted on the device, fused on the host) downloads the states and clocks once and
    the covered stamp after it uploads the states (not the clocks) once."""
    rng = np.random.default_rng(23)
    engines, _ = _engines(rng, ("numpy", "jax"))
    jx = engines["jax"]
    team = jx.team
    assert isinstance(team, DeviceTeam)
    spy = _Spy(team.kernel)
    team.kernel = spy  # type: ignore[assignment]
    x = engines["numpy"].a
    _stamp(engines, 0.5, _outcome_mix(x, 20, rng), (np.arange(1, 5), np.full(4, 0.3), np.full(4, 0.1)))
    first = dict(team.transfers)
    assert first == {"up S": 1, "up clock": 1, "up t0": 1, "up v": 1, "up w": 1}
    for k in range(2, 10):
        det = _outcome_mix(x, 20, rng) if k % 2 else None
        _stamp(engines, 0.5 * k, det, (np.arange(1, 7), rng.uniform(0, 1, 6), rng.uniform(-1, 1, 6)))
    assert dict(team.transfers) == first and spy.chained[1:] == [True] * 8
    _same_reads(engines, 5.0)
    read = {**first, "down S": 1, "down clock": 1}
    assert dict(team.transfers) == read
    _same_reads(engines, 5.5)  # nothing changed: nothing more downloaded
    assert dict(team.transfers) == read
    det = Detections.concat(_outcome_mix(x, 20, rng), _robot_ranges(x, 6, rng, "range")).canonical()
    _stamp(engines, 5.5, det, (np.arange(1, 5), np.full(4, 0.2), np.full(4, 0.0)))
    _stamp(engines, 6.0, _outcome_mix(x, 20, rng), (np.arange(1, 5), np.full(4, 0.2), np.full(4, 0.0)))
    assert dict(team.transfers) == {**read, "up S": 2, "down S": 2, "down clock": 2}  # the clocks moved on the device
    _same_reads(engines, 6.5)
    assert jx.counts["fused"] >= 20 and jx.counts["gated"] >= 20


def test_detections_packed_on_the_device_equal_the_hosts() -> None:
    """A stamp's detections from :data:`~swarmloc.engine.jax_stamp.DEVICE_PAD` on go up as they are and are packed
    and padded on the device: the same ``(12, bucket)`` array as :func:`~swarmloc.engine.jax_stamp.pack` on the
    host, whatever the integer type of the codes."""
    from swarmloc.engine.jax_stamp import DEVICE_PAD, bucket, device_stamp, pack
    from swarmloc.motion import UnicycleNoise

    rng = np.random.default_rng(29)
    m = DEVICE_PAD + 5
    A = rng.normal(size=(m, 3, 3))
    det = Detections(rng.integers(0, 9, m).astype(np.int32), rng.integers(-9, 9, m), rng.integers(0, 4, m),
                     rng.normal(size=(m, 3)), A @ np.swapaxes(A, 1, 2))  # fmt: skip
    got = np.asarray(device_stamp(UnicycleNoise(), np.float64)._pack(det))
    want = pack(det, bucket(m))
    assert got.shape == (12, 2 * DEVICE_PAD) and not np.isnan(want).any()
    np.testing.assert_array_equal(got, want)
