"""The one process pool of the simulations and studies: fork where the platform has it and the
process runs one thread (the scene and its imports are inherited, no re-import per worker),
spawn elsewhere; or no pool at all when one process is asked for or there is a single job (the
same results, in this process). A worker that dies is an error (BrokenProcessPool), never a
wait: multiprocessing.Pool replaced a dead worker and waited forever for its job.
Given a scheduler address (host:port of a running Dask distributed scheduler, for sweeps on a
cluster), the jobs go to that cluster's workers instead: the same map / as_done, the same
results (every job is a pure function of its arguments; test_workers).
"""
from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import threading
from typing import Callable, Iterable, Iterator, TypeVar

J = TypeVar('J')
R = TypeVar('R')


def process_context():
    """fork where available in a process of one thread, else spawn. A forked child holds only
    the forking thread: the state other threads left (a DDS participant's, in a process that ran
    a ROS node) killed both pool workers of a pytest worker that had run graph tests, at once."""
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context('fork' if 'fork' in methods and single_threaded() else 'spawn')


def single_threaded() -> bool:
    """Whether this process runs one OS thread (threads of C++ libraries included)."""
    try:
        return len(os.listdir('/proc/self/task')) == 1
    except OSError:   # no procfs: Python's own threads are all it can see
        return threading.active_count() == 1


def dask_client(scheduler: str):
    """A dask.distributed Client of the scheduler at `scheduler`; one clear line when Dask is
    not installed or the scheduler does not answer."""
    try:
        from distributed import Client
    except ImportError:
        raise SystemExit(f'scheduler {scheduler}: Dask distributed is not installed (pip install distributed)')
    try:
        return Client(scheduler, timeout=10)
    except (OSError, TimeoutError) as exc:
        raise SystemExit(f'scheduler {scheduler}: cannot connect: {exc}')


class WorkerPool:
    """At most `workers` processes for maps of up to `jobs` jobs; in this process when either is
    1; on the Dask cluster of `scheduler` when one is given (`workers` is then the cluster's).
    Use as a context manager, or call close()."""

    def __init__(self, workers: int, jobs: int, scheduler: str | None = None):
        self.client = dask_client(scheduler) if scheduler else None
        self.pool = (concurrent.futures.ProcessPoolExecutor(min(workers, jobs), mp_context=process_context())
                     if self.client is None and workers > 1 and jobs > 1 else None)

    def map(self, fn: Callable[[J], R], jobs: Iterable[J]) -> list[R]:
        """fn over jobs, results in the jobs' order."""
        if self.client is not None:
            return self.client.gather(self.client.map(fn, list(jobs), pure=False))
        return [fn(j) for j in jobs] if self.pool is None else list(self.pool.map(fn, list(jobs)))

    def as_done(self, fn: Callable[[J], R], jobs: Iterable[J]) -> Iterator[R]:
        """fn over jobs, each result as it is done (in any order with a pool or a cluster)."""
        if self.client is not None:
            from distributed import as_completed
            futures = self.client.map(fn, list(jobs), pure=False)
            return (result for _, result in as_completed(futures, with_results=True))
        if self.pool is None:
            return (fn(j) for j in jobs)
        futures = [self.pool.submit(fn, j) for j in jobs]
        return (f.result() for f in concurrent.futures.as_completed(futures))

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
        if self.pool is not None:
            self.pool.shutdown(wait=True)
            self.pool = None

    def __enter__(self) -> 'WorkerPool':
        return self

    def __exit__(self, *exc) -> None:
        if exc[0] is not None and self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)   # the jobs not begun are dropped
            self.pool = None
        self.close()


__all__ = ['WorkerPool', 'dask_client', 'process_context', 'single_threaded']
