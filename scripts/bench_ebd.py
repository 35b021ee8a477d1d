"""EBD against lerp and spline, per corruption and per gap-length bin (issue 11), and the tuning of its blend.

    python scripts/bench_ebd.py --corpus bandai1                   # results/neural_gaps_bandai1.{md,json,png}
    python scripts/bench_ebd.py --corpus bandai1 --replot          # redraw the PNG from the JSON
    python scripts/bench_ebd.py --corpus bandai2 --clips 150 --repeats 2
    python scripts/bench_ebd.py --tune                             # bandai2 fold 1: candidates of ebd.GAP_BLEND
    python scripts/bench_ebd.py --compare clip=a.ckpt --compare corpus=b.ckpt --split style:elderly --clips 84

Test figures: fold-0 clips, the shipped EBD as ``ebd`` (network blended with interpolation and self-checked,
``mocapnet.nn.ebd.blend_gaps``) and as ``ebd-raw`` (the networks' fill as it comes: the shipped main network's, and
its short-gap partner's on the gaps shorter than 0.2 s). ``--checkpoint PATH[:short=PATH2]`` scores another network
(and partner) instead. ``--tune`` scores blend
settings on bandai2 fold 1 (the validation fold; bandai1 is never tuned on) with ``gap_bins.ratios``.
``--compare`` scores EBD networks (each with the shipped blend, and raw) on a selection set: bandai2 fold 1
(``--split val``) or the clips of a style or content the networks were trained without (``--split style:NAME``,
``--split content:NAME``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mocapnet.evaluate import gap_bins
from mocapnet.evaluate.neural_bench import split_arg, split_clips
from mocapnet.evaluate.results import read_json, write_results
from mocapnet.threads import pin_threads

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--corpus", default=None, help="test corpus (default bandai1)")
    parser.add_argument(
        "--clips", type=int, default=None, help="N evenly spaced clips of fold 0 or of --split (default: all)"
    )
    parser.add_argument("--repeats", type=int, default=None, help="default 5 (test), 2 (--tune)")
    parser.add_argument("--tune", action="store_true", help="score blend settings on bandai2 fold 1")
    parser.add_argument("--grid", default="around", choices=("around", "gates"), help="--tune's blend settings")
    parser.add_argument(
        "--checkpoint",
        default=None,
        help="an EBD checkpoint instead of the shipped pair (PATH[:short=PATH2] for a pair)",
    )
    parser.add_argument(
        "--compare",
        action="append",
        default=[],
        metavar="LABEL=CKPT",
        help="score this EBD checkpoint (CKPT[:OPTIONS], e.g. a.ckpt:rehearse=2) on --split (repeatable; bandai2 only)",
    )
    parser.add_argument(
        "--split",
        type=split_arg,
        default="val",
        help="--compare's clips: val (fold 1), style:NAME or content:NAME (outside fold 0; default val)",
    )
    parser.add_argument("--out", default=None, help="path without suffix")
    parser.add_argument(
        "--replot", action="store_true", help="redraw the PNG of an existing test result (--corpus / --out) and stop"
    )
    args = parser.parse_args()
    if args.replot and (args.tune or args.compare):
        parser.error("--replot redraws a test result (--corpus, --out): not with --tune or --compare")
    checkpoints = dict(c.split("=", 1) for c in args.compare if "=" in c)
    labels_ok = all(label and not set(label) & set(":/,") for label in checkpoints)
    if len(checkpoints) != len(args.compare) or not labels_ok or not all(checkpoints.values()):
        parser.error("--compare takes LABEL=CKPT[:OPTIONS] with distinct labels (no ':', '/' or ',' in a label)")
    if checkpoints and args.split == "test":
        parser.error("--compare is for choosing: give --split val or style:NAME (fold 0 is the test)")
    if checkpoints and (args.tune or args.corpus not in (None, "bandai2")):
        parser.error("--compare selects on bandai2 (fold 1 or a held-out style): not with --tune or another --corpus")
    pin_threads(1)
    command = "python " + " ".join(["scripts/bench_ebd.py", *sys.argv[1:]])
    if checkpoints:
        _, clips, _ = split_clips("bandai2", args.split, args.clips)
        result = gap_bins.compare("bandai2", clips, checkpoints, args.repeats or 2)
        result |= {"command": command, "split": f"bandai2 {args.split}"}
        tag = args.split.replace(":", "_")
        out = Path(args.out or ROOT / "benchmarks" / "results" / f"neural_gaps_compare_{tag}")
        write_results(out, result, gap_bins.compare_markdown(result), indent=1)
        return
    corpus = args.corpus or "bandai1"
    name = "neural_gaps_tune" if args.tune else f"neural_gaps_{corpus}"
    out = Path(args.out or ROOT / "benchmarks" / "results" / name)
    if args.replot:
        stored = out.with_name(out.name + ".json")
        if not stored.is_file():
            parser.error(f"--replot: {stored} not found; run without --replot first")
        gap_bins.plot(read_json(stored), out.with_name(out.name + ".png"))
        return
    result = (
        gap_bins.tune(args.repeats or 2, args.checkpoint, args.grid)
        if args.tune
        else gap_bins.test(corpus, args.clips, args.repeats or 5, args.checkpoint)
    )
    result["command"] = command
    write_results(out, result, gap_bins.tune_markdown(result) if args.tune else gap_bins.markdown(result), indent=1)
    if not args.tune:
        gap_bins.plot(result, out.with_name(out.name + ".png"))


if __name__ == "__main__":
    main()
