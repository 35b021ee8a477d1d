"""Benchmark: CPU and wall time of ``mocapnet evaluate`` before and after the parallel, vectorised harness.

Runs the same command line three times as child processes and takes each one's CPU time (user + system of
the process and every worker it started, from ``getrusage(RUSAGE_CHILDREN)``):

* ``before``: the harness at ``--old`` (default 58b4b19), in one process, as it was;
* ``after, 1 process``: the harness at ``--new`` (default HEAD) with ``--workers 0`` (vectorised scoring);
* ``after, Dask``: the same with its default, one worker process per core.

Each commit is checked out with ``git worktree`` into a temporary folder and put first on the path, so edits
in the working tree during the run change nothing. Since the one reference rule, ``after`` adds
``gaussian-tuned`` (a reference for noise) to the command, so ``before`` is given ``--method gaussian-tuned``
too: both tune and score the same four methods. The rows of the methods whose definition did not change
(all but gaussian-tuned, whose tuning now minimises the reported figure) must agree to 1e-9, per metric.
Threads: 1 per process (``mocapnet.threads``).

    python scripts/bench_evaluate.py                      # 1,000 bandai2 clips, gaussian-58ms, 5 repeats
    python scripts/bench_evaluate.py --limit 100 --repeats 1
Writes benchmarks/results/evaluate_speed.json and .md.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCORES = ("angle_err_deg", "gap_err_deg", "rot_err_deg", "pos_err_cm")
CHANGED = ("gaussian-tuned",)  # methods whose scores are meant to differ
# `mocapnet evaluate ARGS`, its --csv rows dumped at full precision (JSON) instead of the CSV's 6 digits.
CHILD = """import json, sys
from mocapnet.evaluate import report
report.write_csv = lambda path, rows: __import__("pathlib").Path(path).write_text(json.dumps(rows))
from mocapnet.cli import main
sys.exit(main(sys.argv[1:]))"""


def run(args: list[str], checkout: str | None, data: Path) -> tuple[float, float]:
    """(CPU seconds of the child and its descendants, wall seconds) of ``mocapnet ARGS`` (``CHILD``) run in
    ``checkout`` (first on the path, ahead of the editable install; default this one)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    env.update(PYTHONPATH=checkout or str(ROOT), MOCAPNET_DATA=str(data))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", CHILD, *args], env=env, check=True, cwd=checkout or ROOT)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, wall


def max_score_diff(a: Path, b: Path) -> dict[str, float]:
    """Largest absolute difference of each score over the rows of ``a`` (each must be in ``b`` too), methods
    in ``CHANGED`` left out."""
    key = ("method", "file", "repeat")
    rows_a = [r for r in json.loads(a.read_text()) if r["method"] not in CHANGED]
    by_key = {tuple(r[k] for k in key): r for r in json.loads(b.read_text())}
    if any(tuple(r[k] for k in key) not in by_key for r in rows_a):
        raise SystemExit(f"{b} lacks rows of {a}")
    rows_b = [by_key[tuple(r[k] for k in key)] for r in rows_a]
    x = np.array([[float(r[k]) for k in SCORES] for r in rows_a])
    y = np.array([[float(r[k]) for k in SCORES] for r in rows_b])
    if not np.array_equal(np.isnan(x), np.isnan(y)):
        raise SystemExit(f"{a} and {b}: missing scores differ")
    diff = np.abs(x - y)
    return {k: float(np.nanmax(diff[:, i])) if np.isfinite(diff[:, i]).any() else 0.0 for i, k in enumerate(SCORES)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default="bandai2")
    parser.add_argument("--limit", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--method", default="gaussian-58ms")
    parser.add_argument("--corruption", default="angular-0.5")
    parser.add_argument("--old", default="58b4b19", help="commit of the harness before")
    parser.add_argument("--new", default="HEAD", help="commit of the harness after")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "evaluate_speed")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from mocapnet.corpus import data_root, load_corpus
    from mocapnet.evaluate.benchmark import git_commit
    from mocapnet.parallel import local_cores

    load_corpus(args.data, progress=False, limit=args.limit)  # parse cache warm for every run
    common = ["evaluate", "--data", args.data, "--limit", str(args.limit), "--repeats", str(args.repeats)]
    common += ["--corruption", args.corruption, "--method", args.method, "--quiet"]
    with tempfile.TemporaryDirectory(prefix="bench_evaluate_") as tmp:
        old, new = Path(tmp) / "old", Path(tmp) / "new"
        new_commit = subprocess.run(["git", "rev-parse", "--short", args.new], cwd=ROOT, capture_output=True,
                                    text=True, check=True).stdout.strip()  # fmt: skip
        for folder, commit in ((old, args.old), (new, new_commit)):
            subprocess.run(["git", "worktree", "add", "--detach", str(folder), commit], cwd=ROOT, check=True)
        try:
            runs = {
                f"before ({args.old}), 1 process": (["--method", "gaussian-tuned", "--csv", f"{tmp}/before.csv"],
                                                     str(old)),
                f"after ({new_commit}), 1 process (--workers 0)": (
                    ["--workers", "0", "--csv", f"{tmp}/serial.csv"], str(new)),
                f"after ({new_commit}), Dask ({local_cores()} worker processes)": (
                    ["--csv", f"{tmp}/dask.csv"], str(new)),
            }  # fmt: skip
            results = {}
            for name, (extra, path) in runs.items():
                cpu, wall = run(common + extra, path, data_root())
                results[name] = {"cpu_s": round(cpu, 2), "wall_s": round(wall, 2)}
                print(f"{name}: CPU {cpu:.1f} s, wall {wall:.1f} s", flush=True)
            diffs = {
                "serial vs before": max_score_diff(Path(f"{tmp}/before.csv"), Path(f"{tmp}/serial.csv")),
                "dask vs before": max_score_diff(Path(f"{tmp}/before.csv"), Path(f"{tmp}/dask.csv")),
            }
            methods = {k: sorted({r["method"] for r in json.loads(Path(f"{tmp}/{k}.csv").read_text())})
                       for k in ("before", "dask")}  # fmt: skip
        finally:
            for folder in (old, new):
                subprocess.run(["git", "worktree", "remove", "--force", str(folder)], cwd=ROOT, check=False)
    base = next(iter(results.values()))["cpu_s"]
    command = "python scripts/bench_evaluate.py " + " ".join(sys.argv[1:])
    record = {"command": command, "commit": git_commit(), "new": new_commit, "mocapnet_args": common,
              "methods": methods, "runs": results, "max_abs_score_diff": diffs, "cores": local_cores()}  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(record, indent=1) + "\n")
    lines = [
        f"# `mocapnet evaluate` speed: {args.limit} {args.data} clips × {args.repeats} repeats, {args.method}",
        "",
        f"`{command}`; {local_cores()} cores (shared machine). Methods scored (the one asked for and the "
        f"reference baselines the harness adds): before {', '.join(methods['before'])}; after "
        f"{', '.join(methods['dask'])}.",
        "",
        "| run | CPU s | ÷ before | wall s |",
        "|---|---|---|---|",
    ]
    lines += [f"| {k} | {v['cpu_s']:.1f} | {v['cpu_s'] / base:.3f} | {v['wall_s']:.1f} |" for k, v in results.items()]
    lines += ["", f"Largest score difference to before (rows of the methods but {', '.join(CHANGED)}):", ""]
    lines += [f"- {run}: " + ", ".join(f"{k} {v:.1e}" for k, v in d.items()) for run, d in diffs.items()]
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
