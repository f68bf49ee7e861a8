"""Fan a sweep's independent jobs out: in this process, in local worker processes, or on a Dask cluster.

Every sweep (``compare --runs``, the consistency Monte Carlo, the 3-D study, the thesis tables) is a list of
independent jobs, each a pure function of its arguments (seeds included), so where a job runs does not change its
result. :func:`fan_out` runs them

* in this process when ``jobs <= 1`` (or there is one job),
* in ``jobs`` local worker processes (spawned, not forked: a process that imported JAX is multithreaded), the
  default of the commands, with nothing to start; if worker processes cannot be started here, in this process,
* on a Dask cluster when ``cluster`` is given: the address of a running scheduler (``tcp://host:8786``) or a
  :class:`distributed.Client`. Dask reschedules the jobs of a worker that is lost on the workers that remain (up
  to its ``distributed.scheduler.allowed-failures``, 3 by default), so a lost worker costs time, not results.
  Every worker needs swarmloc installed (the same version) and, for MRCLAM sweeps, the data at the same path.

Dask (``pip install 'swarmloc[cluster]'``) rather than Ray: a pure-Python install, the :mod:`concurrent.futures`
interface the local pool already has, a scheduler and workers started with one command each
(``dask scheduler``, ``dask worker ADDRESS``) or by the Helm chart or operator on Kubernetes.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from distributed import Client

__all__ = [
    "CLUSTER_HINT", "MAX_RUNS", "ClusterUnavailable", "check_jobs", "check_runs", "cluster_address", "connected",
    "fan_out", "max_jobs",
]  # fmt: skip

log = logging.getLogger(__name__)

JobResult = TypeVar("JobResult")

CLUSTER_HINT = "pip install 'swarmloc[cluster]'"
"""The install command that brings Dask's distributed scheduler (the ``cluster`` extra)."""

CONNECT_TIMEOUT_S = 10.0
"""How long [s] :func:`fan_out` waits for the scheduler at an address before it gives up."""


MAX_RUNS = 10_000
"""Most runs (seeds) one sweep takes: its job list is built before the first runs, and 10,000 runs of the smallest
simulated team (about a second each) already take hours on two cores."""


def check_runs(runs: object, what: str = "runs") -> int:
    """``runs`` if it is an integer in ``[1, MAX_RUNS]``, else ValueError naming ``what``."""
    if isinstance(runs, bool) or not isinstance(runs, int) or not 1 <= runs <= MAX_RUNS:
        raise ValueError(f"{what} must be an integer in [1, {MAX_RUNS}], got {runs!r}")
    return runs


def max_jobs() -> int:
    """Most local worker processes a sweep starts: four per core of this machine (each holds its own interpreter,
    numpy and estimators: more only queue for the cores and fill the memory)."""
    return 4 * (os.cpu_count() or 1)


def check_jobs(jobs: object) -> int:
    """``jobs`` if it is an integer in ``[0, max_jobs()]`` (0 and 1: in this process), else ValueError."""
    if isinstance(jobs, bool) or not isinstance(jobs, int) or not 0 <= jobs <= max_jobs():
        raise ValueError(f"jobs (local worker processes) must be an integer in [0, {max_jobs()}] here, got {jobs!r}")
    return jobs


class ClusterUnavailable(RuntimeError):
    """The cluster cannot be used: Dask is not installed, or no scheduler answers at the address."""


def cluster_address(cluster: str | Client | None) -> str | None:
    """The scheduler's address of ``cluster`` (an address or a client) for a report; None for local processes."""
    if cluster is None or isinstance(cluster, str):
        return cluster
    return str(cluster.scheduler.address)


def fan_out(
    fn: Callable[..., JobResult],
    tasks: Sequence[tuple[Any, ...]],
    *,
    jobs: int = 1,
    cluster: str | Client | None = None,
) -> Iterator[tuple[int, JobResult]]:
    """``(i, fn(*tasks[i]))`` for every task, in the order the jobs complete (module docstring for where they run).

    ``fn`` must be a module-level function (it is pickled to the workers). ``jobs``: local worker processes (ignored
    with a cluster; :func:`check_jobs`, before anything runs); ``cluster``: a Dask scheduler's address or a
    :class:`distributed.Client` (not closed here). A job's exception is raised here, after the jobs still running
    are cancelled."""
    check_jobs(jobs)
    if cluster is not None:
        yield from _on_cluster(fn, tasks, cluster)
    elif jobs <= 1 or len(tasks) <= 1:
        for i, t in enumerate(tasks):
            yield i, fn(*t)
    else:
        yield from _in_processes(fn, tasks, jobs)


def _in_processes(
    fn: Callable[..., JobResult], tasks: Sequence[tuple[Any, ...]], jobs: int
) -> Iterator[tuple[int, JobResult]]:
    """Local worker processes; in this process what is left if they cannot be started (no process support here) or
    the pool breaks (a worker killed). A job's own exception is raised, not retried."""
    done: set[int] = set()
    pool = None
    try:
        pool = ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn"))
        futures = {pool.submit(fn, *t): i for i, t in enumerate(tasks)}
    except OSError as exc:
        log.warning("no worker processes here (%s); running the %d jobs in this process", exc, len(tasks))
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
    else:
        try:
            for f in as_completed(futures):
                r = f.result()
                done.add(futures[f])
                yield futures[f], r
            return
        except BrokenProcessPool as exc:
            log.warning("worker processes failed (%s); the %d jobs left run in this process", exc,
                        len(tasks) - len(done))  # fmt: skip
        finally:  # a job's error, or a caller that stops reading: the jobs not started are not run
            pool.shutdown(wait=True, cancel_futures=True)
    for i, t in enumerate(tasks):
        if i not in done:
            yield i, fn(*t)


@contextmanager
def connected(cluster: str | Client | None) -> Iterator[Client | None]:
    """A client of ``cluster``: None for None (local processes), a given client as it is, an address connected
    (within :data:`CONNECT_TIMEOUT_S`) and closed on exit. Raises :class:`ClusterUnavailable` when Dask is not
    installed or no scheduler answers, before any job runs."""
    if cluster is None:
        yield None
        return
    try:
        from distributed import Client
    except ImportError as exc:
        raise ClusterUnavailable(f"a cluster needs Dask's distributed scheduler: {CLUSTER_HINT}") from exc
    if isinstance(cluster, Client):
        yield cluster
        return
    try:
        client = Client(str(cluster), timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ClusterUnavailable(
            f"no Dask scheduler answered at {cluster!r} within {CONNECT_TIMEOUT_S:g} s ({exc})"
        ) from exc
    try:
        yield client
    finally:
        client.close()


def _on_cluster(
    fn: Callable[..., JobResult], tasks: Sequence[tuple[Any, ...]], cluster: str | Client
) -> Iterator[tuple[int, JobResult]]:
    """The jobs on a Dask cluster, a future each; a lost worker's jobs are rescheduled by Dask."""
    with connected(cluster) as client:
        assert client is not None
        from distributed import as_completed as completed

        futures = [client.submit(fn, *t, pure=False) for t in tasks]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for f in completed(futures, loop=client.loop):
                yield index[f.key], f.result()
        finally:
            client.cancel([f for f in futures if not f.done()])
