"""Benchmark of the data-driven gap filler ``knn`` against lerp, spline, PCA and ``gapfill`` (issue 12): BVH
(bandai2 and bandai1 fold 0, database bandai2), C3D whole-segment gaps, fill time per second of gap; the
work is in ``mocapnet.evaluate.knn_bench``. Writes ``benchmarks/results/knn.md`` and ``knn.json``;
``--tune`` scores setting variations on bandai2 fold 1 only and writes ``knn_tuning.md`` / ``.json``.

    nice -n 5 .venv/bin/python scripts/bench_knn.py --tune     # bandai2 fold 1 only
    nice -n 5 .venv/bin/python scripts/bench_knn.py            # the benchmark
    .venv/bin/python scripts/bench_knn.py --clips 2 --out /tmp/knn   # smoke run
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from mocapnet.corpus import data_root
from mocapnet.evaluate import knn_bench
from mocapnet.evaluate.benchmark import REPO, git_commit
from mocapnet.io.atomic import atomic_output
from mocapnet.threads import pin_threads


def write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as tmp:
        tmp.write_text(text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clips", type=int, default=60, help="BVH clips per corpus (default 60; --tune: 20)")
    parser.add_argument("--repeats", type=int, default=1, help="repeats per clip and corruption (default 1)")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results", help="output folder")
    parser.add_argument("--tune", action="store_true", help="score setting variations on bandai2 fold 1 instead")
    args = parser.parse_args(argv)
    pin_threads(1)
    command = shlex.join(["python", "scripts/bench_knn.py", *(sys.argv[1:] if argv is None else argv)])
    root = data_root()
    needed = knn_bench.C3D_FILES + knn_bench.C3D_DATABASE_ONLY + ("bvh/bandai_namco_1", "bvh/bandai_namco_2")
    missing = [f for f in needed if not (root / f).exists()]
    if missing:
        print(f"error: data not found under {root}: {', '.join(missing)}", file=sys.stderr)
        return 2
    started = time.time()
    if args.tune:
        rows = knn_bench.tune(min(args.clips, 20))
        write(
            args.out / "knn_tuning.json",
            json.dumps({"command": command, "git_commit": git_commit(), "rows": rows}) + "\n",
        )
        text = knn_bench.tune_markdown(rows, command)
        write(args.out / "knn_tuning.md", text)
        print(text)
        return 0
    speed = knn_bench.bench_speed(10)
    bvh = knn_bench.bench_bvh(args.clips, args.repeats)
    c3d = knn_bench.bench_c3d(root, args.repeats)
    report = {
        "command": command,
        "git_commit": git_commit(),
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs shared, one thread, NumPy {np.__version__}",
        "n_clips": args.clips,
        "repeats": args.repeats,
        "bvh": bvh,
        "c3d": c3d,
        "speed": speed,
        "wall_s": time.time() - started,
    }
    write(args.out / "knn.json", json.dumps(report, separators=(",", ":"), default=float) + "\n")
    text = knn_bench.markdown(report)
    write(args.out / "knn.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
