"""Benchmark the learned cleaners (EBF variants, EBD) against the baselines, across corpora, and their speed
(the logic is ``mocapnet.evaluate.neural_bench``; this is its command line).

    python scripts/bench_neural.py                                   # writes benchmarks/results/neural.{json,md}
    python scripts/bench_neural.py --clips 60 --repeats 2            # a subset of test clips (stated in the output)
    python scripts/bench_neural.py --method ebf-free=runs/x/best.ckpt --skip-speed   # a candidate checkpoint
    python scripts/bench_neural.py --split val --corpus bandai2 --select --no-shipped \\
        --method ebf=a.ckpt --method ebf=b.ckpt --skip-bins --skip-speed       # choose among candidates (fold 1)
    python scripts/bench_neural.py --split style:elderly --corpus bandai2 --select --no-shipped \\
        --method ebf-free=noeld.ckpt --skip-bins --skip-speed   # transfer to a style the model never saw
    python scripts/bench_neural.py --only stream      # rerun the streaming timing; keep the rest of the file
"""

from __future__ import annotations

import argparse
import os

from mocapnet.evaluate import neural_bench as bench
from mocapnet.evaluate.results import provenance, read_json, write_results
from mocapnet.threads import pin_threads


def positive_int(text: str) -> int:
    """An argparse type: a whole number >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}")
    return value


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument(
        "--clips",
        type=positive_int,
        default=None,
        help="score N evenly spaced clips per corpus (--split fast: the first N)",
    )
    parser.add_argument("--corpus", action="append", help="corpora (default bandai2 and bandai1)")
    parser.add_argument("--corruption", action="append", help="corruptions (default: all of PROTOCOL.md)")
    parser.add_argument(
        "--method", action="append", default=[], help="extra noise method, e.g. ebf-free=PATH (also timed, but ebd*)"
    )
    parser.add_argument("--no-shipped", action="store_true", help="score only --method, not the shipped variants")
    parser.add_argument(
        "--split",
        type=bench.split_arg,
        default="test",
        help="fold-0 test clips (test), fold-1 clips for selection (val; fast: the same, the clips with the most "
        "fast movement first, --clips N takes the first N), or every clip of one style or content outside fold 0 "
        "(style:NAME / content:NAME, for models trained with data.holdout_style=NAME / data.holdout_content=NAME)",
    )
    parser.add_argument(
        "--select", action="store_true", help=f"selection score: mean ratio over {', '.join(bench.SELECTION)}"
    )
    parser.add_argument(
        "--stream-quality", metavar="CKPT", help="windowed vs EBFStream error of a checkpoint (running clip stats)"
    )
    parser.add_argument("--skip-quality", action="store_true")
    parser.add_argument("--skip-bins", action="store_true")
    parser.add_argument("--skip-speed", action="store_true")
    parser.add_argument(
        "--only", choices=("stream",), help="rerun only this part; the others are kept from the existing --out file"
    )
    parser.add_argument("--stream-frames", type=int, default=3000, help="frames pushed per streaming timing")
    parser.add_argument("--timing-repeats", type=int, default=5)
    parser.add_argument("--out", default=os.path.join("benchmarks", "results", "neural"), help="path without suffix")
    args = parser.parse_args(argv)
    if args.split != "test" and not (args.skip_bins or args.only):
        parser.error(
            "the gap-length bins are scored on fold-0 test clips: give --skip-bins with --split val, fast or style:NAME"
        )
    if args.split != "test" and "bandai1" in (args.corpus or ["bandai1"]):
        parser.error(
            "bandai1 is test only (never select on it): give --corpus bandai2 with --split val, fast or style:NAME"
        )
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    pin_threads(1)
    result = {**provenance(argv), "load": ", ".join(f"{x:.1f}" for x in os.getloadavg())}
    if args.only == "stream":
        kept = read_json(args.out + ".json")
        kept.get("speed", {}).pop("streaming", None)  # the layout before the streaming part stood alone
        result = kept | {"streaming": streaming_part(args), "streaming_run": result}
        write_results(args.out, result, bench.markdown(result), indent=1)
        return
    corpora = args.corpus or ["bandai2", "bandai1"]
    corruptions = args.corruption or (list(bench.SELECTION) if args.select else bench.CORRUPTIONS)
    if not args.skip_quality:
        result["quality"] = [
            e
            for c in corpora
            for e in bench.quality(
                c, args.clips, args.repeats, args.method, corruptions, args.split, not args.no_shipped
            )
        ]
        if args.select:
            result["selection"] = bench.selection_scores(result["quality"])
    if args.stream_quality:
        result["stream_quality"] = [
            row
            for c in corpora
            for row in bench.streaming_quality(args.stream_quality, c, corruptions, args.clips, args.split)
        ]
    if not args.skip_bins:
        result["gap_bins"] = [b for c in corpora for b in bench.gap_bins(c, args.clips, args.repeats)]
    if not args.skip_speed:
        shipped = bench.shipped_variants(bench.long_clip(100))
        extra = [m for m in args.method if m not in shipped and not m.startswith("ebd")]  # gap fillers: not on noise
        timed = [*shipped, *dict.fromkeys(extra)]
        result["speed"] = bench.speed(timed, args.timing_repeats)
        result["streaming"] = streaming_part(args)
    write_results(args.out, result, bench.markdown(result), indent=1)


def streaming_part(args: argparse.Namespace) -> dict:
    """``neural_bench.streaming`` of the shipped EBF methods on ``--stream-frames`` bandai2 frames."""
    methods = [m for m in bench.shipped_variants(bench.long_clip(100)) if m.startswith("ebf")]
    return bench.streaming(bench.long_clip(args.stream_frames), methods, args.stream_frames)


if __name__ == "__main__":
    main()
