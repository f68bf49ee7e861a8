"""Sweeps on a Dask cluster (:mod:`swarmloc.runner.fanout`): a local cluster of two worker processes on 127.0.0.1,
started here, runs the consistency sweep and ``compare --runs 4``; the results equal the local run's bit for bit, and
a worker killed mid-sweep loses nothing. Plus the local paths and the refusals (no Dask, no scheduler)."""

from __future__ import annotations

import json
import math
import os
import signal
import sys
import time
from collections.abc import Iterator
from typing import Any

import distributed
import numpy as np
import pytest

from swarmloc.cli import main
from swarmloc.experiments.consistency import _job as consistency_job
from swarmloc.experiments.consistency import consistency
from swarmloc.runner import fanout
from swarmloc.runner.fanout import ClusterUnavailable, connected, fan_out

TIMING = {"wall_s", "run_wall_s", "update_us", "predict_us", "x_real_time", "cluster", "jobs"}
"""Keys of a summary that say how long or where it ran, not what it computed."""


def results_of(summary: Any) -> Any:
    """``summary`` without its timing and placement keys (what must be equal wherever the jobs ran)."""
    if isinstance(summary, dict):
        return {k: results_of(v) for k, v in summary.items() if k not in TIMING}
    if isinstance(summary, list):
        return [results_of(v) for v in summary]
    return summary


def same_bits(a: Any, b: Any) -> bool:
    """Equal to the last bit: the same keys, arrays of one dtype and shape with equal elements (NaN equal to NaN),
    floats equal (or both NaN); timing and placement keys left out."""
    a, b = results_of(a), results_of(b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same_bits(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(same_bits(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray):
        nan = a.dtype.kind == "f"
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=nan)
    if isinstance(a, float):
        return isinstance(b, float) and (a == b or (math.isnan(a) and math.isnan(b)))
    return bool(a == b)


def _square(x: int) -> int:
    return x * x


# ------------------------------------------------------------------------------------------------------ local paths
@pytest.mark.unit
@pytest.mark.parametrize("jobs", [1, 2])
def test_local_fan_out_gives_every_job_once_with_its_index(jobs: int) -> None:
    got = list(fan_out(_square, [(i,) for i in range(7)], jobs=jobs))
    assert sorted(got) == [(i, i * i) for i in range(7)]


@pytest.mark.unit
@pytest.mark.parametrize("jobs", [1, 2])
def test_a_jobs_own_error_is_raised_not_rerun(jobs: int) -> None:
    with pytest.raises(ZeroDivisionError):
        list(fan_out(divmod, [(1, 1), (1, 0), *[(2, 1)] * 6], jobs=jobs))


@pytest.mark.unit
def test_without_dask_a_cluster_is_refused_with_the_install_command(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(ClusterUnavailable, match=r"pip install 'swarmloc\[cluster\]'"):
        list(fan_out(_square, [(1,)], cluster="tcp://127.0.0.1:1"))


@pytest.mark.unit
def test_an_unreachable_scheduler_is_refused_before_anything_runs(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from swarmloc.net.transport import free_ports

    monkeypatch.setattr(fanout, "CONNECT_TIMEOUT_S", 1.0)
    address = f"tcp://127.0.0.1:{free_ports(1)[0]}"
    t0 = time.monotonic()
    with pytest.raises(ClusterUnavailable, match="no Dask scheduler answered"), connected(address):
        pass
    assert time.monotonic() - t0 < 30
    rc = main(["compare", "--scenario", "sim:random", "--estimators", "dekf", "--runs", "2", "--duration", "5",
               "--cluster", address, "--quiet"])  # fmt: skip
    assert rc == 2
    err = capsys.readouterr().err
    assert "swarmloc compare: no Dask scheduler answered at" in err and "Traceback" not in err


# ---------------------------------------------------------------------------------------------------- on a cluster
@pytest.fixture(scope="module")
def cluster() -> Iterator[Any]:
    """Two worker processes of one thread each and their scheduler, on 127.0.0.1 (no dashboard); the client not set
    as the process's default, so that what swarmloc does with an address is tested on its own."""
    local = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                     dashboard_address=None)  # fmt: skip
    with local as lc, distributed.Client(lc, set_as_default=False) as client:
        client.wait_for_workers(2, timeout=60)
        yield lc, client


SWEEP = dict(seeds=3, robots=3, duration=10.0, landmarks=(False, True))


@pytest.mark.network
@pytest.mark.slow
def test_the_consistency_sweep_on_a_cluster_equals_the_local_run(cluster: Any) -> None:
    lc, client = cluster
    local = consistency(["dekf", "ci", "diekf"], jobs=2, **SWEEP)
    remote = consistency(["dekf", "ci", "diekf"], cluster=client, **SWEEP)
    assert remote["cluster"] == lc.scheduler_address and local["cluster"] is None
    assert same_bits(local, remote)
    assert not same_bits(local, consistency(["dekf", "ci", "diekf"], jobs=1, **{**SWEEP, "seeds": 2}))  # it can fail


@pytest.mark.network
@pytest.mark.slow
def test_compare_runs_4_through_the_command_line_equals_the_local_run(cluster: Any, tmp_path: Any) -> None:
    lc, _ = cluster
    args = ["compare", "--scenario", "sim:random", "--estimators", "dekf,rdl,expfusion", "--runs", "4",
            "--duration", "10", "--robots", "3", "--quiet"]  # fmt: skip
    assert main([*args, "--jobs", "2", "--out", str(tmp_path / "local")]) == 0
    assert main([*args, "--cluster", lc.scheduler_address, "--out", str(tmp_path / "remote")]) == 0
    local = json.loads((tmp_path / "local" / "compare.json").read_text())
    remote = json.loads((tmp_path / "remote" / "compare.json").read_text())
    assert remote["runs"] == 4 and remote["cluster"] == lc.scheduler_address
    assert same_bits(local, remote)
    assert math.isfinite(remote["estimators"]["dekf"]["anees"])


@pytest.mark.network
@pytest.mark.slow
def test_a_worker_killed_mid_sweep_loses_nothing(cluster: Any) -> None:
    lc, client = cluster
    tasks = [(e, s, 3, 15.0, False, True) for e in ("dekf", "ci") for s in range(6)]
    local = dict(fan_out(consistency_job, tasks, jobs=1))
    pids = client.run(os.getpid)
    got: dict[int, Any] = {}
    killed: tuple[str, list[str]] | None = None
    for i, r in fan_out(consistency_job, tasks, cluster=client):
        got[i] = r
        if killed is None:  # after the first result: kill a worker while it runs a job
            busy = {w: list(keys) for w, keys in client.processing().items() if keys}
            assert busy, "no worker is running a job"
            victim = next(iter(busy))
            os.kill(pids[victim], signal.SIGKILL)
            killed = (victim, busy[victim])
    assert killed is not None and killed[1]
    assert sorted(got) == list(range(len(tasks)))  # every job's result, the killed worker's included
    assert same_bits({str(i): local[i] for i in local}, {str(i): got[i] for i in got})
    client.wait_for_workers(2, timeout=60)  # the nanny restarted the killed worker's process
    assert pids[killed[0]] not in client.run(os.getpid).values()
