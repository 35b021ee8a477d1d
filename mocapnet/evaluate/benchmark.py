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


def gapfill_rigid_body(points: np.ndarray, marker: int, cluster: list[int] | np.ndarray) -> np.ndarray:
    """The PyPI ``gapfill`` rigid-body fill of ``points[:, marker]`` (``[T, M, 3]`` cm, NaN where missing)
    from three cluster markers; returns the track ``[T, 3]`` (NaN where gapfill left it missing). Call it
    inside ``numpy_int_alias()``."""
    import gapfill

    target = points[:, marker].copy()
    gapfill.fill_marker_gap_rbt(target, points[:, list(cluster)].transpose(1, 0, 2).copy())
    return target


def gapfill_spline(points: np.ndarray, marker: int) -> np.ndarray:
    """The PyPI ``gapfill`` spline fill of ``points[:, marker]``; returns the track ``[T, 3]``. Call it
    inside ``numpy_int_alias()``."""
    import gapfill

    target = points[:, marker].copy()
    gapfill.fill_marker_gap_interp(target)
    return target


def gapfill_spline_as_shipped() -> str:
    """What ``gapfill.fill_marker_gap_interp`` does under this NumPy without the ``np.int`` alias."""
    import gapfill

    track = np.tile(np.arange(60.0)[:, None], (1, 3))
    track[20:30] = np.nan
    try:
        gapfill.fill_marker_gap_interp(track)
    except AttributeError as exc:
        return f"AttributeError: {exc}".splitlines()[0]
    return "runs without error"
