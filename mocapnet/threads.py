"""One place that sets how many threads torch and the BLAS/OpenMP libraries may use in a process.

On a shared machine the libraries' defaults (one thread per core, busy waiting) make every process slower
than one thread would: mocapnet runs work in parallel as *processes* (Dask workers) and gives each
``threads`` threads, 1 by default. ``pin_threads`` is called by ``mocapnet clean`` and ``evaluate`` in the
driver and in every worker, and by the benchmark scripts.

It sets the environment variables read by libraries loaded later (``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``,
``OPENBLAS_NUM_THREADS``, …), limits the libraries already loaded through ``threadpoolctl``, and calls
``torch.set_num_threads`` when torch has been imported (it never imports torch itself).
"""

from __future__ import annotations

import os
import sys

THREAD_ENV = (
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "BLIS_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)
DEFAULT_THREADS = 1

_pinned: dict[str, int] = {}  # what this process was last pinned to: {"blas": n, "torch": n}


def default_threads() -> int:
    """Threads per process: ``$MOCAPNET_THREADS`` when set, else 1."""
    text = os.environ.get("MOCAPNET_THREADS", "")
    if not text:
        return DEFAULT_THREADS
    if not text.isdigit() or int(text) < 1:
        raise ValueError(f"MOCAPNET_THREADS={text!r}: expected a positive integer")
    return int(text)


def pin_threads(n: int | None = None) -> int:
    """Let this process's torch and BLAS/OpenMP pools use ``n`` threads (default ``default_threads()``).

    Cheap when nothing changed, so it may be called before every task; torch is pinned as soon as it has
    been imported by someone. Returns ``n``.
    """
    n = default_threads() if n is None else int(n)
    if n < 1:
        raise ValueError(f"threads must be at least 1, got {n}")
    if _pinned.get("blas") != n:
        for var in THREAD_ENV:
            os.environ[var] = str(n)
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=n)
        _pinned["blas"] = n
    torch = sys.modules.get("torch")
    if torch is not None and _pinned.get("torch") != n:
        torch.set_num_threads(n)
        _pinned["torch"] = n
    return n
