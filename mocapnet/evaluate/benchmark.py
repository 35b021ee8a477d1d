"""Small helpers shared by the benchmark scripts (``scripts/bench_*.py``): provenance and peer quirks."""

from __future__ import annotations

import subprocess
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]


def git_commit(short: bool = False) -> str:
    """The checkout's HEAD commit, ``unknown`` when git cannot tell."""
    args = ["git", "rev-parse", *(["--short"] if short else []), "HEAD"]
    try:
        return subprocess.run(args, cwd=REPO, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


@contextmanager
def numpy_int_alias() -> Iterator[None]:
    """The PyPI ``gapfill`` 0.0.7 calls ``np.int`` (removed in NumPy 1.24): alias it to ``int`` for the
    duration of the block only."""
    np.int = int  # type: ignore[attr-defined]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        del np.int  # type: ignore[attr-defined]
