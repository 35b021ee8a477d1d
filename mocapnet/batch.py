"""Clean a folder of recordings (BVH and C3D, recursing) into another folder, in parallel.

Each file goes through ``mocapnet.clean.clean_file`` — the one-file clean — on a Dask worker
(``mocapnet.parallel``), so a batch output equals the one-file output bit for bit. Outputs keep the input's
path relative to the input folder. A file that fails is reported (``status="failed"`` with the error) and
the batch goes on; an output newer than its input is left alone (``status="up to date"``) unless ``force``.
"""

from __future__ import annotations

import csv
import json
import os
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from mocapnet.clean import CleanOptions, CleanResult, clean_file, file_format
from mocapnet.io.atomic import MocapFileError, atomic_output

if TYPE_CHECKING:
    from mocapnet.parallel import Parallel

REPORT_FIELDS = ("file", "output", "status", "method", "frames", "samples_filled", "seconds", "error", "reason")
CLEANED, UP_TO_DATE, FAILED = "cleaned", "up to date", "failed"
# Errors that describe a bad input (their message names the file); anything else also gets its type name.
_INPUT_ERRORS = (MocapFileError, ValueError, LookupError, FileNotFoundError)


@dataclass
class FileReport:
    """One file of a batch: what was done, in how many seconds, or why it failed (``error``).

    ``frames`` and ``samples_filled`` are those of ``CleanResult``; ``details`` its method-specific facts;
    ``reason`` why the BVH default (``auto``) ran ``method`` on this file (C3D's ``auto`` chooses per gap: see
    ``details["gaps"]``).
    """

    file: str
    output: str
    status: str
    method: str = ""
    frames: int = 0
    samples_filled: int = 0
    seconds: float = 0.0
    error: str = ""
    details: dict = field(default_factory=dict)

    @property
    def reason(self) -> str:
        """Why ``auto`` chose ``method`` (its ``details["auto"]``), else empty."""
        return str(self.details.get("auto", ""))

    @classmethod
    def from_result(cls, result: CleanResult, seconds: float) -> FileReport:
        return cls(
            str(result.source), str(result.output), CLEANED, result.method, result.frames,
            result.samples_filled, seconds, details=dict(result.details),
        )  # fmt: skip


def is_recording(path: Path) -> bool:
    """A ``.bvh``, ``.bvh.gz`` or ``.c3d`` file that is not hidden (atomic writes use hidden temp files)."""
    if path.name.startswith(".") or not path.is_file():
        return False
    try:
        file_format(path)
    except MocapFileError:
        return False
    return True


def find_recordings(folder: str | os.PathLike, exclude: str | os.PathLike | None = None) -> list[Path]:
    """Every recording under ``folder`` (recursing, sorted), leaving out anything under ``exclude``."""
    root = Path(folder)
    skip = Path(exclude).resolve() if exclude is not None else None
    found = []
    for path in sorted(root.rglob("*")):
        if skip is not None and path.resolve().is_relative_to(skip):
            continue
        if is_recording(path):
            found.append(path)
    return found


def plan(src_dir: str | os.PathLike, out_dir: str | os.PathLike) -> list[tuple[Path, Path]]:
    """``(input, output)`` pairs: every recording under ``src_dir`` mapped to the same relative path under
    ``out_dir``. Raises ValueError when the folders are the same (outputs would replace the inputs)."""
    src, out = Path(src_dir), Path(out_dir)
    if not src.is_dir():
        raise FileNotFoundError(f"{src}: no such folder")
    if out.resolve() == src.resolve():
        raise ValueError(f"{out}: the output folder is the input folder; choose another one")
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: cleaning a folder needs an output folder, and this is a file")
    return [(p, out / p.relative_to(src)) for p in find_recordings(src, exclude=out)]


def is_up_to_date(src: Path, out: Path) -> bool:
    """True when ``out`` exists and is at least as new as ``src`` (make's rule)."""
    return out.exists() and out.stat().st_mtime >= src.stat().st_mtime


def clean_one(pair: tuple[Path, Path], options: CleanOptions) -> FileReport:
    """Clean one file as ``clean_file`` does, turning any error into a ``failed`` report (runs on workers)."""
    src, out = pair
    start = time.perf_counter()
    try:
        result = clean_file(src, out, options)
    except Exception as exc:  # one bad file never stops a batch: it is reported
        message = str(exc) if isinstance(exc, _INPUT_ERRORS) else f"{type(exc).__name__}: {exc}"
        if str(src) not in message:
            message = f"{src}: {message}"
        return FileReport(str(src), str(out), FAILED, options.method or "", seconds=time.perf_counter() - start,
                          error=message)  # fmt: skip
    return FileReport.from_result(result, time.perf_counter() - start)


def clean_folder(
    src_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    options: CleanOptions,
    parallel: Parallel | None = None,
    force: bool = False,
    progress: bool = True,
) -> list[FileReport]:
    """Clean every recording under ``src_dir`` into ``out_dir`` (see module docstring); one report per file,
    in path order. ``parallel``: a ``mocapnet.parallel.Parallel`` (default: local worker processes)."""
    from mocapnet.parallel import Parallel, map_tasks

    if options.mask:
        raise ValueError("--mask names one file's missing samples; it cannot be used when cleaning a folder")
    # Absolute paths: workers of a cluster started elsewhere do not share this working directory.
    pairs = plan(Path(src_dir).absolute(), Path(out_dir).absolute())
    options = _absolute_paths(options)
    todo = [p for p in pairs if force or not is_up_to_date(*p)]
    done = map_tasks(clean_one, todo, (options,), parallel or Parallel(), progress, "cleaning", "file")
    by_pair = dict(zip(todo, done))
    return [by_pair.get(p) or FileReport(str(p[0]), str(p[1]), UP_TO_DATE) for p in pairs]


def _absolute_paths(options: CleanOptions) -> CleanOptions:
    """``options`` with its existing database folder and checkpoint files made absolute."""

    def absolute(text: str | None) -> str | None:
        return str(Path(text).absolute()) if text and Path(text).exists() else text

    model = ",".join(absolute(m.strip()) or "" for m in options.model.split(",")) if options.model else None
    return replace(options, model=model, database=absolute(options.database))


def report_format(path: str | os.PathLike) -> str:
    """``"csv"`` or ``"json"`` from a report's file name; ValueError for anything else."""
    suffix = Path(path).suffix.lower()
    if suffix not in (".csv", ".json"):
        raise ValueError(f"{path}: a report must end in .csv or .json")
    return suffix[1:]


def write_report(path: str | os.PathLike, reports: Sequence[FileReport]) -> None:
    """Write ``reports`` as CSV (``.csv``: the columns of ``REPORT_FIELDS``) or JSON (``.json``: a list of
    objects with those keys plus ``details``). Raises ValueError for another suffix."""
    kind = report_format(path)
    with atomic_output(path) as tmp:
        if kind == "json":
            rows = [asdict(r) | {"reason": r.reason} for r in reports]
            tmp.write_text(json.dumps(rows, indent=1, default=str) + "\n")
            return
        with open(tmp, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(REPORT_FIELDS))
            writer.writeheader()
            for r in reports:
                row = {k: getattr(r, k) for k in REPORT_FIELDS}
                row["seconds"] = f"{r.seconds:.4f}"
                writer.writerow(row)


def summary(reports: Sequence[FileReport]) -> str:
    """A text table: files, frames, samples filled and seconds per (status, method)."""
    groups: dict[tuple[str, str], list[FileReport]] = {}
    for r in reports:
        groups.setdefault((r.status, r.method if r.status == CLEANED else ""), []).append(r)
    head = ("status", "method", "files", "frames", "samples filled", "seconds")
    body = [
        (status, method, str(len(rs)), f"{sum(r.frames for r in rs):,}", f"{sum(r.samples_filled for r in rs):,}",
         f"{sum(r.seconds for r in rs):.1f}")
        for (status, method), rs in sorted(groups.items())
    ]  # fmt: skip
    widths = [max(len(h), *(len(row[i]) for row in body)) if body else len(h) for i, h in enumerate(head)]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths)))

    return "\n".join([line(head), line(["-" * w for w in widths]), *(line(row) for row in body)])
