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
