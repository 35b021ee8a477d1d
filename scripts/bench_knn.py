"""Benchmark of the data-driven gap filler ``knn`` against lerp, spline, PCA and ``gapfill`` (issue 12): BVH
(bandai2 and bandai1 fold 0, database bandai2), C3D whole-segment gaps, fill time per second of gap; the
work is in ``mocapnet.evaluate.knn_bench``. Writes ``benchmarks/results/knn.md`` and ``knn.json.gz``;
``--tune`` scores setting variations on bandai2 fold 1 only and writes ``knn_tuning.md`` / ``.json.gz``
(``--grid plateau|twist|gate|still|fallback|pcagate|forearm|pair``: later rounds, ``knn_tuning_<grid>.md``).

    nice -n 5 .venv/bin/python scripts/bench_knn.py --tune     # bandai2 fold 1 only
    nice -n 5 .venv/bin/python scripts/bench_knn.py            # the benchmark
    nice -n 5 .venv/bin/python scripts/bench_knn.py --parts bandai1,speed   # rerun parts, keep the rest
    .venv/bin/python scripts/bench_knn.py --clips 2 --out /tmp/knn   # smoke run (an empty --out: all parts)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from mocapnet.corpus import data_root
from mocapnet.evaluate import knn_bench
from mocapnet.evaluate.benchmark import REPO
from mocapnet.evaluate.results import provenance, read_json, write_results
from mocapnet.threads import pin_threads


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clips", type=int, default=60, help="BVH clips per corpus (default 60; --tune: 20)")
    parser.add_argument("--repeats", type=int, default=1, help="repeats per clip and corruption (default 1)")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results", help="output folder")
    parser.add_argument("--tune", action="store_true", help="score setting variations on bandai2 fold 1 instead")
    grids = ", ".join(knn_bench.GRIDS)
    parser.add_argument("--grid", choices=knn_bench.GRIDS, default="main", help=f"--tune: variations ({grids})")
    parser.add_argument(
        "--parts",
        default=",".join(knn_bench.PARTS),
        help=f"comma-separated parts to run (of {','.join(knn_bench.PARTS)}; default all); the other parts' results "
        "are kept from the knn.json.gz already in --out",
    )
    args = parser.parse_args(argv)
    pin_threads(1)
    report = provenance(argv)
    root = data_root()
    needed = knn_bench.C3D_FILES + knn_bench.C3D_DATABASE_ONLY + ("bvh/bandai_namco_1", "bvh/bandai_namco_2")
    missing = [f for f in needed if not (root / f).exists()]
    if missing:
        print(f"error: data not found under {root}: {', '.join(missing)}", file=sys.stderr)
        return 2
    started = time.time()
    if args.tune:
        rows = knn_bench.tune(min(args.clips, 20), knn_bench.GRIDS[args.grid])
        report.update(rows=rows, wall_s=time.time() - started)
        stem = "knn_tuning" + ("" if args.grid == "main" else f"_{args.grid}")
        write_results(args.out / stem, report, knn_bench.tune_markdown(rows, report), json_suffix=".json.gz")
        return 0
    parts = [p for p in args.parts.split(",") if p]
    previous_path = args.out / "knn.json.gz"
    previous = read_json(previous_path) if previous_path.exists() else None
    try:
        knn_bench.check_parts(parts, previous is not None)  # before the work, not after it
        fresh = knn_bench.run_parts(parts, root, args.clips, args.repeats)
        run = knn_bench.run_record(report, args.clips, args.repeats, time.time() - started)
        merged = knn_bench.merge_parts(previous, fresh, parts, run)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    write_results(args.out / "knn", merged, knn_bench.markdown(merged), json_suffix=".json.gz")
    return 0


if __name__ == "__main__":
    sys.exit(main())
