"""CPU and wall time of ``mocapnet evaluate`` at an older commit vs now, in one process and on Dask
(``scripts/bench_evaluate.py`` is the command line).

Each run is a child process ``mocapnet evaluate ...`` (``CHILD``) whose CPU time is user + system of the child
and of every process it started and waited for (``getrusage(RUSAGE_CHILDREN)``: Dask workers, forked or
spawned, are children of the ``evaluate`` process). Commits are checked out with ``git worktree`` into a
temporary folder and put first on the path, so edits in the working tree during a run change nothing.
Runs are repeated in ``rounds`` whose order rotates (interleaved), and the machine's load is recorded.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from mocapnet.evaluate.benchmark import REPO
from mocapnet.evaluate.results import fmt, markdown_table

SCORES = ("angle_err_deg", "gap_err_deg", "rot_err_deg", "pos_err_cm")
# `mocapnet evaluate ARGS`, its --csv rows dumped at full precision (JSON) instead of the CSV's 6 digits.
CHILD = """import json, pathlib, sys
from mocapnet.evaluate import report
report.write_csv = lambda path, rows: pathlib.Path(path).write_text(json.dumps(rows))
from mocapnet.cli import main
sys.exit(main(sys.argv[1:]))"""


def child_cpu(args: Sequence[str], checkout: Path, data: Path) -> tuple[float, float]:
    """(CPU seconds of ``mocapnet ARGS`` run from ``checkout`` and its descendants, wall seconds); one thread
    per process."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    env.update(PYTHONPATH=str(checkout), MOCAPNET_DATA=str(data), MOCAPNET_THREADS="1")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", CHILD, *args], env=env, check=True, cwd=checkout)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, wall


def max_score_diff(a: Path, b: Path, changed: Sequence[str] = ()) -> dict[str, float]:
    """Largest absolute difference of each score over the rows of ``a`` (each must be in ``b`` too), the
    methods in ``changed`` left out."""
    key = ("method", "file", "repeat")
    rows_a = [r for r in json.loads(a.read_text()) if r["method"] not in changed]
    by_key = {tuple(r[k] for k in key): r for r in json.loads(b.read_text())}
    missing = [r for r in rows_a if tuple(r[k] for k in key) not in by_key]
    if missing:
        raise ValueError(f"{b} lacks {len(missing)} rows of {a}")
    x = np.array([[float(r[k]) for k in SCORES] for r in rows_a])
    y = np.array([[float(by_key[tuple(r[k] for k in key)][s]) for s in SCORES] for r in rows_a])
    if not np.array_equal(np.isnan(x), np.isnan(y)):
        raise ValueError(f"{a} and {b}: missing scores differ")
    diff = np.abs(x - y)
    return {k: float(np.nanmax(diff[:, i])) if np.isfinite(diff[:, i]).any() else 0.0 for i, k in enumerate(SCORES)}


@contextmanager
def worktrees(commits: Sequence[str]) -> Iterator[list[Path]]:
    """Each commit checked out (detached) in a temporary folder; removed afterwards."""
    with tempfile.TemporaryDirectory(prefix="bench_evaluate_") as tmp:
        folders = [Path(tmp) / f"tree{i}" for i in range(len(commits))]
        try:
            for folder, commit in zip(folders, commits):
                subprocess.run(["git", "worktree", "add", "--detach", str(folder), commit], cwd=REPO, check=True)
            yield folders
        finally:
            for folder in folders:
                subprocess.run(["git", "worktree", "remove", "--force", str(folder)], cwd=REPO, check=False)


def short_commit(rev: str) -> str:
    return subprocess.run(
        ["git", "rev-parse", "--short", rev], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout.strip()


def measure(common: Sequence[str], old: str, new: str, data: Path, rounds: int = 1, workers: int = 2) -> dict:
    """Run ``mocapnet evaluate COMMON`` as before (``old``, one process, also asked for gaussian-tuned, which
    the new reference rule adds), after in one process (``--workers 0``) and after on Dask (default local
    cluster), ``rounds`` times in rotating order. Returns every run's CPU and wall seconds, the mean CPU
    ratio to before, the load average around each run and the largest score differences to before (rows of
    the methods but gaussian-tuned, whose tuning changed)."""
    old, new = short_commit(old), short_commit(new)
    names = [f"before ({old}), 1 process", f"after ({new}), 1 process (--workers 0)"]
    names.append(f"after ({new}), Dask ({workers} worker processes)")
    extra = [["--method", "gaussian-tuned"], ["--workers", "0"], ["--workers", str(workers)]]
    runs: dict[str, list[dict]] = {name: [] for name in names}
    with worktrees([old, new]) as (old_tree, new_tree), tempfile.TemporaryDirectory() as tmp:
        trees = [old_tree, new_tree, new_tree]
        for r in range(rounds):
            for i in [(r + k) % 3 for k in range(3)]:
                load = os.getloadavg()[0]
                rows = Path(tmp) / f"{i}.json"
                cpu, wall = child_cpu([*common, *extra[i], "--csv", str(rows)], trees[i], data)
                runs[names[i]].append(
                    {"cpu_s": cpu, "wall_s": wall, "load_before": load, "load_after": os.getloadavg()[0]}
                )
                print(f"{names[i]}: CPU {cpu:.1f} s, wall {wall:.1f} s, load {load:.1f}", flush=True)
        diffs = {
            names[i]: max_score_diff(Path(tmp) / "0.json", Path(tmp) / f"{i}.json", ("gaussian-tuned",)) for i in (1, 2)
        }
        methods = {
            names[i]: sorted({r["method"] for r in json.loads((Path(tmp) / f"{i}.json").read_text())}) for i in (0, 2)
        }
    base = float(np.mean([run["cpu_s"] for run in runs[names[0]]]))
    ratios = {name: float(np.mean([run["cpu_s"] for run in rs])) / base for name, rs in runs.items()}
    return {
        "old": old,
        "new": new,
        "runs": runs,
        "cpu_ratio_to_before": ratios,
        "max_abs_score_diff": diffs,
        "methods": methods,
    }


def markdown(record: dict, title: str) -> str:
    """The results page: one row per run (CPU, ÷ before's mean, wall, load) and the score differences."""
    base = float(np.mean([run["cpu_s"] for run in next(iter(record["runs"].values()))]))
    rows = [
        (name, i + 1, fmt(run["cpu_s"], 1), fmt(run["cpu_s"] / base), fmt(run["wall_s"], 1),
         f"{run['load_before']:.1f} → {run['load_after']:.1f}")
        for name, rs in record["runs"].items()
        for i, run in enumerate(rs)
    ]  # fmt: skip
    lines = [f"# {title}", "", f"`{record['command']}` at {record['git_commit']}; {record['machine']}.", ""]
    scored = "; ".join(f"{k}: {', '.join(v)}" for k, v in record["methods"].items())
    lines += [f"Methods scored (the one asked for and the reference baselines the harness adds): {scored}.", ""]
    lines += markdown_table(("run", "round", "CPU s", "÷ before (mean)", "wall s", "load average"), rows)
    lines += [
        "",
        "Mean CPU ÷ before: " + ", ".join(f"{k} **{v:.3f}**" for k, v in record["cpu_ratio_to_before"].items()),
    ]
    lines += ["", "Largest score difference to before (rows of the methods but gaussian-tuned):", ""]
    lines += [
        f"- {k}: " + ", ".join(f"{m} {v:.1e}" for m, v in d.items()) for k, d in record["max_abs_score_diff"].items()
    ]
    return "\n".join(lines) + "\n"
