"""The one process pool of the simulations and studies: fork where the platform has it (the
scene and its imports are inherited, no re-import per worker), spawn elsewhere; or no pool at
all when one process is asked for or there is a single job (the same results, in this process).
"""
from __future__ import annotations

import multiprocessing
from typing import Callable, Iterable, Iterator, TypeVar

J = TypeVar('J')
R = TypeVar('R')


def process_context():
    """fork where available, else spawn."""
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context('fork' if 'fork' in methods else 'spawn')


class WorkerPool:
    """At most `workers` processes for maps of up to `jobs` jobs; in this process when either is
    1. Use as a context manager, or call close()."""

    def __init__(self, workers: int, jobs: int):
        self.pool = process_context().Pool(min(workers, jobs)) if workers > 1 and jobs > 1 else None

    def map(self, fn: Callable[[J], R], jobs: Iterable[J]) -> list[R]:
        """fn over jobs, results in the jobs' order."""
        return [fn(j) for j in jobs] if self.pool is None else self.pool.map(fn, list(jobs), chunksize=1)

    def as_done(self, fn: Callable[[J], R], jobs: Iterable[J]) -> Iterator[R]:
        """fn over jobs, each result as it is done (in any order with a pool)."""
        if self.pool is None:
            return (fn(j) for j in jobs)
        return self.pool.imap_unordered(fn, list(jobs))

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()
            self.pool.join()
            self.pool = None

    def __enter__(self) -> 'WorkerPool':
        return self

    def __exit__(self, *exc) -> None:
        if exc[0] is not None and self.pool is not None:
            self.pool.terminate()
        self.close()


__all__ = ['WorkerPool', 'process_context']
