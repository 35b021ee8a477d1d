"""Heavy-occlusion benchmark of C3D gap filling: the per-gap ``auto`` filler against single fillers and PyPI
``gapfill`` on (a) every shared take with real gaps, (b) complete takes under the real occlusion masks of
other takes and (c) ``mocapnet.corrupt`` gaps. What each part does: ``mocapnet.evaluate.c3d_bench``.

Writes ``benchmarks/results/c3d_fill.md`` and the whole report, per case, as ``c3d_fill.json.gz``.

    nice -n 5 .venv/bin/python scripts/bench_c3d_fill.py        # about 1 min of CPU
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mocapnet.corpus import data_root
from mocapnet.evaluate import c3d_bench
from mocapnet.evaluate.results import provenance, rounded, write_results
from mocapnet.threads import pin_threads

REPO = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-root", type=Path, default=data_root(), help="shared data folder")
    parser.add_argument("--window-s", type=float, default=8.0, help="longest window cut from a complete take (s)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the windows and mask starts")
    parser.add_argument(
        "--targets", nargs="*", default=list(c3d_bench.TARGETS), help="complete takes (relative to the root)"
    )
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results", help="output folder")
    parser.add_argument("--quiet", action="store_true", help="no per-case progress on stderr")
    args = parser.parse_args(argv)
    missing = [f for f in (*c3d_bench.MASK_SOURCES, *args.targets) if not (args.data_root / f).exists()]
    if missing:
        print(f"error: data not found under {args.data_root}: {', '.join(missing)}", file=sys.stderr)
        return 2
    pin_threads()
    result = c3d_bench.run(args.data_root, args.window_s, args.seed, tuple(args.targets), not args.quiet)
    report = provenance(argv) | result
    write_results(args.out / "c3d_fill", rounded(report), c3d_bench.markdown(report), json_suffix=".json.gz")
    return 0


if __name__ == "__main__":
    sys.exit(main())
