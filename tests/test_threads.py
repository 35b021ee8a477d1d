"""Threads are set in one place (mocapnet.threads) for this process and for every Dask worker."""

from __future__ import annotations

import os

import pytest
from threadpoolctl import threadpool_info

from mocapnet import threads
from mocapnet.parallel import Parallel, map_tasks


@pytest.fixture()
def restore_threads():
    saved = {k: os.environ.get(k) for k in threads.THREAD_ENV}
    yield
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
    threads._pinned.clear()
    threads.pin_threads(1)


def test_pin_threads_sets_env_and_loaded_pools(restore_threads, monkeypatch):
    import numpy as np

    np.ones(4) @ np.ones(4)  # BLAS loaded
    assert threads.pin_threads(2) == 2
    assert all(os.environ[k] == "2" for k in threads.THREAD_ENV)
    assert all(pool["num_threads"] <= 2 for pool in threadpool_info())
    threads.pin_threads(1)
    assert all(pool["num_threads"] == 1 for pool in threadpool_info())
    monkeypatch.setenv("MOCAPNET_THREADS", "3")
    assert threads.default_threads() == 3
    monkeypatch.setenv("MOCAPNET_THREADS", "many")
    with pytest.raises(ValueError, match="MOCAPNET_THREADS"):
        threads.default_threads()
    with pytest.raises(ValueError, match="at least 1"):
        threads.pin_threads(0)


def test_workers_are_pinned(restore_threads):
    """A worker process runs its tasks with the threads asked for (here 3; the default is 1). (``os.getenv``
    pickles by name, so it reads the worker's environment.)"""
    got = map_tasks(os.getenv, ["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "x"],
                    parallel=Parallel(workers=1, threads=3))  # fmt: skip
    assert got == ["3", "3", "3", None]


def test_in_process_library_call_leaves_threads_alone(restore_threads):
    threads.pin_threads(2)
    assert map_tasks(os.getenv, ["OMP_NUM_THREADS"], parallel=Parallel(workers=0)) == ["2"]
    assert map_tasks(os.getenv, ["OMP_NUM_THREADS"], parallel=Parallel(workers=0, threads=1)) == ["1"]
