"""Run many independent tasks (files to clean, clips to score) on Dask, or in this process.

By default the tasks run on a ``dask.distributed.LocalCluster`` of worker *processes* on this machine, one
per core, one thread each (``mocapnet.threads`` pins torch and BLAS in every worker). With a scheduler
address (``tcp://HOST:PORT``) the same tasks run on an existing Dask cluster — e.g. one that
``dask-jobqueue`` started on SLURM or PBS; its workers must have mocapnet installed and see the same file
paths (a shared file system). ``workers=0`` runs everything here, one task after the other.

Results come back in the order of the inputs, so a parallel run returns what the serial one returns.
``distributed`` is imported only when a cluster is used.
"""

from __future__ import annotations

import ctypes
import logging
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from mocapnet.threads import THREAD_ENV, default_threads, pin_threads

JOBQUEUE_HELP = """\
a cluster on SLURM or PBS (dask-jobqueue, pip install dask-jobqueue), started from a Python prompt on the
login node, then given to mocapnet by address:
  from dask_jobqueue import SLURMCluster        # or PBSCluster
  cluster = SLURMCluster(cores=1, processes=1, memory="4GB", walltime="02:00:00",
                         job_script_prologue=["source /path/to/mocapnet/.venv/bin/activate"])
  cluster.scale(jobs=32)                        # 32 single-core workers
  print(cluster.scheduler_address)              # tcp://10.0.0.5:8786 -> --scheduler tcp://10.0.0.5:8786
or by hand: `dask scheduler` on one node, `dask worker tcp://HOST:8786 --nworkers N --nthreads 1` on others.
Workers need mocapnet installed and the same paths (shared file system)."""


def local_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


@dataclass(frozen=True)
class Parallel:
    """Where tasks run: an existing Dask cluster at ``scheduler`` (``tcp://HOST:PORT``), else a local cluster
    of ``workers`` processes (``None`` = one per core; ``0`` = in this process, no Dask). ``threads``: torch
    and BLAS threads per worker process (``None`` = ``mocapnet.threads.default_threads()``, i.e. 1); when tasks
    run in this process its threads are pinned only if ``threads`` is given."""

    scheduler: str | None = None
    workers: int | None = None
    threads: int | None = None

    def __post_init__(self) -> None:
        if self.workers is not None and self.workers < 0:
            raise ValueError(f"workers must be 0 (this process) or more, got {self.workers}")
        if self.scheduler is not None and self.workers is not None:
            raise ValueError("give either a scheduler address or a number of local workers, not both")

    @property
    def in_process(self) -> bool:
        return self.scheduler is None and self.workers == 0

    def describe(self) -> str:
        if self.scheduler:
            return f"Dask cluster {self.scheduler}"
        if self.in_process:
            return "one process (no Dask)"
        return f"{self.workers or local_cores()} local worker processes"


def _tune_malloc() -> None:
    """Apply ``WORKER_MALLOC`` to this (worker) process with glibc's ``mallopt``, once: a forked worker does
    not read the variables again, nor does one started by hand for ``--scheduler``. A no-op without glibc."""
    global _malloc_tuned
    if _malloc_tuned or not sys.platform.startswith("linux"):
        return
    _malloc_tuned = True
    try:
        libc = ctypes.CDLL(None)
        libc.mallopt(_M_MMAP_THRESHOLD, WORKER_MALLOC["MALLOC_MMAP_THRESHOLD_"])
        libc.mallopt(_M_TRIM_THRESHOLD, WORKER_MALLOC["MALLOC_TRIM_THRESHOLD_"])
    except (OSError, AttributeError):  # not glibc (e.g. musl): keep its defaults
        pass


def worker_info(_: object = None) -> dict[str, Any]:
    """What a task sees of its process (run it through ``map_tasks`` to inspect workers): ``pid``, whether
    ``WORKER_MALLOC`` was applied (``malloc_tuned``), and the OpenMP thread setting."""
    return {"pid": os.getpid(), "malloc_tuned": _malloc_tuned, "omp_threads": os.environ.get("OMP_NUM_THREADS")}


def _run_pinned(item: Any, fn: Callable[..., Any], threads: int, *shared: Any) -> Any:
    """Run one task on a worker after pinning its threads and tuning its malloc (no-ops once done; covers
    late-joining workers)."""
    pin_threads(threads)
    _tune_malloc()
    return fn(item, *shared)


# glibc malloc settings of local workers: numpy temporaries up to 16 MiB come from the heap and up to 128 MiB
# of freed heap is kept. Without them a worker (whose tasks run in a non-main thread, with its own arena)
# returned and re-faulted its temporaries on every call: 290,000 page faults and 1 s of system time per worker
# for 150 clips, 20 % more thread time than the same scoring in the main process.
WORKER_MALLOC = {"MALLOC_MMAP_THRESHOLD_": 1 << 24, "MALLOC_TRIM_THRESHOLD_": 1 << 27}
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc mallopt parameters
_malloc_tuned = False


def _start_method() -> str:
    """How local workers start: ``fork`` on Linux while torch is not loaded here (a worker then inherits the
    imported modules: 0.05 s of CPU to its first task instead of 0.8 s), else ``spawn`` (a fresh interpreter;
    torch's thread pools do not survive a fork)."""
    return "fork" if sys.platform.startswith("linux") and "torch" not in sys.modules else "spawn"


def _local_cluster_config(threads: int) -> dict[str, Any]:
    """Dask settings for a local cluster of CPU-bound tasks. Workers start with the thread variables and
    ``WORKER_MALLOC`` (instead of distributed's ``MALLOC_TRIM_THRESHOLD_=65536``, which makes every numpy
    temporary over 64 kB an mmap), by ``_start_method()``, without the statistical profiler (a sampling
    thread), and with slower housekeeping timers: an idle 2-worker cluster burnt 0.07-0.09 CPU-s per second
    with the defaults, 0.013 with these."""
    return {
        "distributed.nanny.pre-spawn-environ": {**{var: threads for var in THREAD_ENV}, **WORKER_MALLOC},
        "distributed.worker.multiprocessing-method": _start_method(),
        "distributed.worker.profile.enabled": False,
        "distributed.admin.tick.interval": "500ms",
        "distributed.admin.system-monitor.interval": "2s",
        "distributed.worker.memory.monitor-interval": "1s",
        "distributed.scheduler.work-stealing-interval": "1s",
    }


@contextmanager
def dask_client(parallel: Parallel) -> Iterator[Any]:
    """A ``distributed.Client`` for ``parallel`` (starts and stops a LocalCluster unless a scheduler is given).

    Raises ValueError when the scheduler cannot be reached. Tasks pin their worker's threads themselves.
    """
    from distributed import Client, LocalCluster

    threads = parallel.threads or default_threads()
    cluster = None
    if parallel.scheduler:
        try:
            client = Client(parallel.scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise ValueError(f"cannot reach the Dask scheduler {parallel.scheduler}: {exc}") from exc
    else:
        import dask

        with dask.config.set(_local_cluster_config(threads)):
            cluster = LocalCluster(
                n_workers=parallel.workers or local_cores(),
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",  # the scheduler serves HTTP anyway: on a free port
                silence_logs=logging.ERROR,
            )
        client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def imap_tasks(
    fn: Callable[..., Any],
    items: Sequence[Any],
    shared: Sequence[Any] = (),
    parallel: Parallel | None = None,
    progress: bool = False,
    desc: str = "",
    unit: str = "task",
    sizes: Sequence[int] | None = None,
) -> Iterator[tuple[int, Any]]:
    """Yield ``(i, fn(items[i], *shared))`` as tasks finish (any order), with a tqdm progress bar that counts
    ``sizes[i]`` per task (default 1).

    ``fn`` must be a module-level function (workers import it by name); ``shared`` objects are sent to each
    worker once. An exception raised by a task is raised here. A single task with no scheduler given runs
    in this process (starting a local cluster would only cost time).
    """
    from tqdm import tqdm

    parallel = parallel or Parallel()
    sizes = [1] * len(items) if sizes is None else list(sizes)
    bar = tqdm(total=sum(sizes), desc=desc, unit=unit, disable=not progress)
    try:
        if parallel.in_process or (len(items) <= 1 and not parallel.scheduler):
            if parallel.threads is not None:  # this process: pinned only when asked (a library call)
                pin_threads(parallel.threads)
            for i, item in enumerate(items):
                yield i, fn(item, *shared)
                bar.update(sizes[i])
            return
        from distributed import as_completed

        with dask_client(parallel) as client:
            sent = [client.scatter([obj], broadcast=True, hash=False)[0] for obj in shared]
            threads = parallel.threads or default_threads()
            futures = [client.submit(_run_pinned, item, fn, threads, *sent, pure=False) for item in items]
            index = {f.key: i for i, f in enumerate(futures)}
            for future in as_completed(futures):
                i = index[future.key]
                yield i, future.result()
                futures[i] = None  # let the worker forget the result
                bar.update(sizes[i])
    finally:
        bar.close()


def map_tasks(
    fn: Callable[..., Any],
    items: Sequence[Any],
    shared: Sequence[Any] = (),
    parallel: Parallel | None = None,
    progress: bool = False,
    desc: str = "",
    unit: str = "task",
    sizes: Sequence[int] | None = None,
) -> list[Any]:
    """``[fn(item, *shared) for item in items]`` run as ``imap_tasks`` does, in the order of ``items``."""
    results: list[Any] = [None] * len(items)
    for i, value in imap_tasks(fn, items, shared, parallel, progress, desc, unit, sizes):
        results[i] = value
    return results
