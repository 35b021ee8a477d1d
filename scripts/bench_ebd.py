"""EBD against lerp and spline, per corruption and per gap-length bin (issue 11), and the tuning of its blend.

    python scripts/bench_ebd.py --corpus bandai1                   # benchmarks/results/neural_gaps_bandai1.{md,json}
    python scripts/bench_ebd.py --corpus bandai2 --clips 150 --repeats 2
    python scripts/bench_ebd.py --tune                             # bandai2 fold 1: candidates of ebd.GAP_BLEND

Test figures: fold-0 clips, the shipped EBD as ``ebd`` (network blended with interpolation and self-checked,
``mocapnet.nn.ebd.blend_gaps``) and as ``ebd-raw`` (the network's fill as it comes). ``--tune`` scores blend
settings on bandai2 fold 1 (the validation fold; bandai1 is never tuned on) with ``gap_bins.ratios``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mocapnet.evaluate import gap_bins
from mocapnet.evaluate.results import write_results
from mocapnet.threads import pin_threads

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--corpus", default="bandai1")
    parser.add_argument("--clips", type=int, default=None, help="N evenly spaced fold-0 clips (default: all)")
    parser.add_argument("--repeats", type=int, default=None, help="default 5 (test), 2 (--tune)")
    parser.add_argument("--tune", action="store_true", help="score blend settings on bandai2 fold 1")
    parser.add_argument("--grid", default="around", choices=("around", "gates"), help="--tune's blend settings")
    parser.add_argument("--checkpoint", default=None, help="an EBD checkpoint instead of the shipped one")
    parser.add_argument("--out", default=None, help="path without suffix")
    args = parser.parse_args()
    pin_threads(1)
    command = "python " + " ".join(["scripts/bench_ebd.py", *sys.argv[1:]])
    name = "neural_gaps_tune" if args.tune else f"neural_gaps_{args.corpus}"
    out = Path(args.out or ROOT / "benchmarks" / "results" / name)
    result = (
        gap_bins.tune(args.repeats or 2, args.checkpoint, args.grid)
        if args.tune
        else gap_bins.test(args.corpus, args.clips, args.repeats or 5, args.checkpoint)
    )
    result["command"] = command
    write_results(out, result, gap_bins.tune_markdown(result) if args.tune else gap_bins.markdown(result), indent=1)


if __name__ == "__main__":
    main()
