"""Benchmark of the streaming extrapolator: gap-filling error vs gap length, exactness check and latency.

Single-marker and whole-limb gaps of 0.1-2 s on complete C3D takes and a CMU BVH clip's joints, filled by the
causal methods (hold, extrapolate-linear/-circular, extrapolate, extrapolate+cm) and offline references (lerp,
PyPI gapfill); what is scored and how: ``mocapnet.evaluate.extrapolate_bench``.

Writes ``benchmarks/results/extrapolate.md``, ``extrapolate_error_vs_gap.png`` and the whole report (with the
per-file errors) as ``extrapolate.json.gz``.

    nice -n 10 .venv/bin/python scripts/bench_extrapolate.py            # full run, 20 onsets (committed run: 541 s)
    .venv/bin/python scripts/bench_extrapolate.py --quick --out /tmp/x  # small run
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mocapnet.corpus import data_root
from mocapnet.evaluate import extrapolate_bench as bench
from mocapnet.evaluate.results import provenance, write_results
from mocapnet.threads import pin_threads

REPO = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--data-root",
        type=Path,
        default=data_root(),
        help="shared data folder (default: $MOCAPNET_DATA or ../shared/data)",
    )
    parser.add_argument(
        "--repeats", type=int, help="random onsets per file and corruption (default 20, 2 with --quick)"
    )
    parser.add_argument("--quick", action="store_true", help="two C3D files, 2 repeats: a small run")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results", help="output folder")
    args = parser.parse_args(argv)
    files = bench.QUICK_FILES if args.quick else bench.C3D_FILES + bench.BVH_FILES
    missing = [f for f in files if not (args.data_root / f).exists()]
    if missing:
        print(f"error: data not found under {args.data_root}: {', '.join(missing)}", file=sys.stderr)
        return 2
    pin_threads()
    result = bench.run(args.data_root, files, args.repeats or (2 if args.quick else 20), progress=True)
    report = provenance(argv) | result
    write_results(args.out / "extrapolate", report, bench.markdown(report), json_suffix=".json.gz")
    bench.plot(report, args.out / "extrapolate_error_vs_gap.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
