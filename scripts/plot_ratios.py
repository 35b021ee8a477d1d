"""Draw the ratio column of ``bench_neural`` results files as bars per corruption, one panel per corpus.

    python scripts/plot_ratios.py benchmarks/results/neural_r2lm_bandai2_s30.json \
        benchmarks/results/gaussian_cv_joined_bandai2_s24.json benchmarks/results/neural_noise_bandai2.json \
        benchmarks/results/neural_r2lm_bandai1_s30.json benchmarks/results/gaussian_cv_joined_bandai1_s24.json \
        benchmarks/results/neural_noise_bandai1.json --method ebf --method gaussian-cv --method ebf-paper \
        --title "Shipped ebf (R2LM) vs gaussian-cv and a short ebf-paper run, ratio to the best of 3 Gaussians" \
        --out benchmarks/results/ebf_transfer.png

A method scored in several files (same corpus and corruption) is drawn from the first file that has it.
"""

from __future__ import annotations

import argparse

from mocapnet.evaluate.report import plot_ratios
from mocapnet.evaluate.results import read_json


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("results", nargs="+", help="bench_neural .json files (their 'quality' rows)")
    parser.add_argument("--method", action="append", required=True, help="a method to draw (repeatable, in order)")
    parser.add_argument("--title", default="", help="figure title")
    parser.add_argument("--out", required=True, help="the PNG to write")
    args = parser.parse_args(argv)
    rows = [row for path in args.results for row in read_json(path)["quality"]]
    plot_ratios(rows, args.method, args.out, args.title)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
