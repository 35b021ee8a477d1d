"""Benchmark: BVH loading CPU time of mocapnet's reader vs the PyPI ``bvh`` package (the reference).

Interleaved per file, ``time.process_time``, several rounds; "text" (same in-memory text, ``read_bvh``'s
defaults) and "file" (``read_bvh(path)`` vs gzip + the package); values compared file by file; a synthetic
10,000-joint hierarchy and a 1,000-level chain. The work is in ``mocapnet.evaluate.bvh_bench``.

    nice -n 5 .venv/bin/python scripts/bench_bvh_io.py                  # first 830 bandai2 files + all bandai1
    .venv/bin/python scripts/bench_bvh_io.py --files 100 --quick --out /tmp/bvh   # smoke run
    nice -n 5 .venv/bin/python scripts/bench_bvh_io.py --baseline 0313cc4    # and an older commit's reader
Writes benchmarks/results/bvh_io.md and .json.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mocapnet.corpus import data_root, list_bvh
from mocapnet.evaluate import bvh_bench
from mocapnet.evaluate.benchmark import REPO
from mocapnet.evaluate.results import provenance, rounded, write_results
from mocapnet.threads import pin_threads


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-root", type=Path, default=None, help="shared data root (default: MOCAPNET_DATA)")
    parser.add_argument("--files", type=int, default=830, help="bandai2 files to load (default 830)")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (default 3)")
    parser.add_argument("--quick", action="store_true", help="skip bandai1")
    parser.add_argument("--baseline", default=None, help="also time mocapnet/io/bvh.py of this git commit")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results", help="output folder")
    args = parser.parse_args(argv)
    pin_threads(1)
    root = args.data_root or data_root()
    sets = {"bandai2": list_bvh(root / "bvh/bandai_namco_2")[: args.files]}
    if not args.quick:
        sets["bandai1"] = list_bvh(root / "bvh/bandai_namco_1")
    if not all(sets.values()):
        print(f"error: BVH corpora not found under {root}", file=sys.stderr)
        return 2
    baseline = bvh_bench.previous_reader(args.baseline) if args.baseline else None
    report = provenance(argv)
    report.update(baseline=args.baseline, corpora={})
    for name, files in sets.items():
        report["corpora"][name] = bvh_bench.bench_corpus(files, args.rounds, baseline, args.baseline or "")
        print(name, rounded(report["corpora"][name], 4), flush=True)
    report["hierarchy"] = bvh_bench.hierarchy_timings(baseline)
    report = rounded(report, 4)
    write_results(args.out / "bvh_io", report, bvh_bench.markdown(report), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
