"""The worker pool: local processes, or a Dask distributed cluster given its scheduler address."""
import numpy as np
import pytest

from fabric_guidance.experiments import fit_wearer, population_fit as pf
from fabric_guidance.workers import WorkerPool


def _square(x):
    return x * x


def test_without_dask_a_scheduler_address_is_one_line(monkeypatch):
    import builtins
    real = builtins.__import__

    def no_dask(name, *args, **kwargs):
        if name == 'distributed' or name.startswith('distributed.'):
            raise ImportError(name)
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, '__import__', no_dask)
    with pytest.raises(SystemExit, match=r'^scheduler tcp://x:1: Dask distributed is not installed'):
        WorkerPool(2, 4, 'tcp://x:1')


def test_a_dask_local_cluster_gives_the_rows_of_the_local_pool():
    """The same design sweep (two seeds, three wearers each, two arm_spreads) through two local
    processes and through a Dask LocalCluster of two worker processes: identical rows, and the
    pool's map keeps the jobs' order there too."""
    distributed = pytest.importorskip('distributed')
    bases = [fit_wearer.base_scene('speed', a) for a in (0.0, 0.2)]
    local = pf.run_designs(bases, (3, 4), 3, workers=2)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        on_dask = pf.run_designs(bases, (3, 4), 3, scheduler=cluster.scheduler_address)
        with WorkerPool(2, 5, cluster.scheduler_address) as pool:
            assert pool.map(_square, range(5)) == [0, 1, 4, 9, 16]
            assert sorted(pool.as_done(_square, range(5))) == [0, 1, 4, 9, 16]
    assert len(local) == len(on_dask) == 2
    for a, b in zip(local, on_dask):
        assert len(a.y) == 6
        np.testing.assert_array_equal(a.u, b.u)
        np.testing.assert_array_equal(a.y, b.y)
        np.testing.assert_array_equal(a.seeds, b.seeds)


def _die(x):
    import os
    os._exit(3)   # a worker that dies (a crash, the OOM killer) mid-job


def test_a_worker_that_dies_is_an_error_not_a_wait():
    """multiprocessing.Pool replaced a dead worker and waited for its job forever: a fresh CI-like
    run hung 18 min in test_fit_wearer until it was killed."""
    import subprocess
    import sys
    code = ('from concurrent.futures.process import BrokenProcessPool\n'
            'from fabric_guidance.workers import WorkerPool\n'
            'from test_workers import _die\n'
            'try:\n'
            '    with WorkerPool(2, 2) as pool:\n'
            '        pool.map(_die, [1, 2])\n'
            'except BrokenProcessPool as exc:\n'
            '    print("broken:", exc)\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120,
                         cwd=str(__import__('pathlib').Path(__file__).parent))
    assert out.stdout.startswith('broken:'), out.stdout + out.stderr


def test_a_process_with_other_threads_does_not_fork_its_workers():
    """A forked child holds only the forking thread; with DDS's threads in the parent both
    workers of a pool died at once (fork is kept for a single-threaded process: the scene is
    inherited, not imported again)."""
    import multiprocessing
    import subprocess
    import sys
    code = ('import threading, time\n'
            'from fabric_guidance.workers import process_context\n'
            'alone = process_context().get_start_method()\n'
            'threading.Thread(target=time.sleep, args=(5,), daemon=True).start()\n'
            'print(alone, process_context().get_start_method())\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60, check=True)
    fork = 'fork' if 'fork' in multiprocessing.get_all_start_methods() else 'spawn'
    assert out.stdout.split() == [fork, 'spawn'], out.stdout + out.stderr
