"""C3D denoising benchmark: gaussian-cv against fixed Gaussians on real takes with white noise added. What it
does: ``mocapnet.evaluate.c3d_smooth_bench``. Writes ``benchmarks/results/c3d_smooth.{md,json}``.

    nice -n 5 .venv/bin/python scripts/bench_c3d_smooth.py        # a few minutes of CPU
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mocapnet.corpus import data_root
from mocapnet.evaluate import c3d_smooth_bench as bench
from mocapnet.evaluate.results import provenance, rounded, write_results
from mocapnet.threads import pin_threads

REPO = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-root", type=Path, default=data_root(), help="shared data folder")
    parser.add_argument("--takes", nargs="*", default=list(bench.TAKES), help="takes (relative to <root>/c3d)")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results", help="output folder")
    args = parser.parse_args(argv)
    root = args.data_root / "c3d"
    missing = [t for t in args.takes if not (root / t).exists()]
    if missing:
        print(f"error: data not found under {root}: {', '.join(missing)}", file=sys.stderr)
        return 2
    pin_threads()
    report = provenance(argv) | bench.run(root, tuple(args.takes))
    write_results(args.out / "c3d_smooth", rounded(report), bench.markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
