"""Local Dask workers: started by fork while torch is not loaded, glibc malloc tuned in every worker."""

from __future__ import annotations

import os
import sys

import pytest

from mocapnet.parallel import Parallel, _start_method, map_tasks, worker_info


def test_start_method_follows_torch(monkeypatch):
    monkeypatch.delitem(sys.modules, "torch", raising=False)
    assert _start_method() == ("fork" if sys.platform.startswith("linux") else "spawn")
    monkeypatch.setitem(sys.modules, "torch", object())
    assert _start_method() == "spawn"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc mallopt")
def test_local_workers_are_tuned_and_pinned():
    infos = map_tasks(worker_info, list(range(6)), parallel=Parallel(workers=2, threads=2))
    assert all(info["malloc_tuned"] for info in infos)
    assert all(info["omp_threads"] == "2" for info in infos)
    assert os.getpid() not in {info["pid"] for info in infos}
    here = worker_info()
    assert here["pid"] == os.getpid()
