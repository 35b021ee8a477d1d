"""What every results file of ``benchmarks/results`` shares, light to import (no harness, no scipy): number
formatting (``fmt``), markdown tables, provenance of a run, and JSON dumps written atomically, gzip-compressed
reproducibly for ``.gz`` paths (the per-row dumps: 5-15x smaller in git)."""

from __future__ import annotations

import gzip
import io
import json
import math
import os
import platform
import shlex
import sys
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import numpy as np

from mocapnet.evaluate.benchmark import REPO, git_commit
from mocapnet.io.atomic import atomic_output


def fmt(x: float | None, digits: int = 3) -> str:
    """``x`` with ``digits`` decimals; "—" for None, NaN or infinity."""
    return "—" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}f}"


def markdown_table(head: Sequence[str], rows: Iterable[Sequence[Any]]) -> list[str]:
    """Lines of a markdown table: the header, the rule and one line per row (cells formatted with ``str``)."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    return lines + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]


@contextmanager
def text_output(path: str | os.PathLike, newline: str | None = None) -> Iterator[IO[str]]:
    """A UTF-8 text stream written atomically to ``path``; gzip-compressed, reproducibly (no name or time in
    the header: the same text gives the same bytes), when ``path`` ends in ``.gz``."""
    with atomic_output(path) as tmp, open(tmp, "wb") as raw:
        packed = gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0) if str(path).endswith(".gz") else None
        with io.TextIOWrapper(packed or raw, encoding="utf-8", newline=newline) as fh:
            yield fh


def rounded(value: Any, digits: int = 6) -> Any:
    """``value`` (nested dicts / lists) with floats rounded to ``digits`` significant digits."""
    if isinstance(value, float):
        return float(f"{value:.{digits}g}")
    if isinstance(value, dict):
        return {k: rounded(v, digits) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [rounded(v, digits) for v in value]
    return value


def write_json(path: str | os.PathLike, data: Any, indent: int | None = None) -> None:
    """``data`` as JSON (compact unless ``indent``), atomically; gzip-compressed when ``path`` ends in ``.gz``
    (per-row dumps: 5-10x smaller in git). NumPy scalars are written as numbers."""
    with text_output(path) as fh:
        json.dump(data, fh, indent=indent, separators=None if indent else (",", ":"), default=float)
        fh.write("\n")


def write_results(
    stem: str | os.PathLike, data: Any, text: str, json_suffix: str = ".json", indent: int | None = None
) -> None:
    """A benchmark's results: ``text`` (markdown) to ``stem.md`` and ``data`` to ``stem`` + ``json_suffix``
    (``.json.gz`` for per-row dumps) with ``write_json``, each atomically, the folder made if needed; ``text``
    is printed too."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    write_json(stem.with_name(stem.name + json_suffix), data, indent)
    with atomic_output(stem.with_name(stem.name + ".md")) as tmp:
        tmp.write_text(text)
    print(text)


def read_json(path: str | os.PathLike) -> Any:
    """A results file written by ``write_json`` (``.json`` or ``.json.gz``)."""
    with (gzip.open if str(path).endswith(".gz") else open)(path, "rt", encoding="utf-8") as fh:
        return json.load(fh)


def provenance(argv: Sequence[str] | None = None) -> dict[str, str]:
    """``command`` (this interpreter and script relative to the repo, then ``argv``, default the process's
    arguments), ``git_commit`` and ``machine`` (processor, cores, niceness, versions, threads) of a run."""
    args = sys.argv[1:] if argv is None else list(argv)
    command = shlex.join([os.path.relpath(sys.executable, REPO), os.path.relpath(sys.argv[0], REPO), *args])
    machine = (
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs shared with other jobs, process "
        f"niceness {os.nice(0)}, Python {platform.python_version()}, NumPy {np.__version__}, "
        f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}"
    )
    return {"command": command, "git_commit": git_commit(), "machine": machine}


def provenance_header(title: str, result: Mapping[str, Any]) -> list[str]:
    """The first lines of a results Markdown file: ``# title``, then the command, git commit, load average and
    machine that ``provenance`` (plus a ``load`` entry) recorded in ``result``."""
    return [
        f"# {title}",
        "",
        f"Command: `{result['command']}`  ",
        f"Git commit: `{result['git_commit']}`; load average at start {result['load']} ({result['machine']}).",
        "",
    ]


def ratio_bars(ax: Any, labels: Sequence[str], series: Mapping[str, Sequence[float]], value_size: float = 7) -> None:
    """Horizontal bars of ratios on a matplotlib ``ax``: one row per label (top to bottom), one bar per entry of
    ``series`` (name -> a value per label, NaN for none) with its value written beside it, and a line at 1 (the
    reference)."""
    y = np.arange(len(labels))
    height = 0.8 / len(series)
    for k, (name, values) in enumerate(series.items()):
        bars = ax.barh(y + (k - (len(series) - 1) / 2) * height, values, height, label=name)
        ax.bar_label(bars, fmt="%.3f", fontsize=value_size, padding=2)
    ax.axvline(1.0, color="black", linewidth=1)
    ax.set_yticks(y, labels, fontsize=8)
    ax.invert_yaxis()


def save_figure(fig: Any, path: str | os.PathLike) -> None:
    """Write a matplotlib figure as a PNG at ``path`` (110 dpi, atomically) and close it."""
    import matplotlib.pyplot as plt

    with atomic_output(Path(path)) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
