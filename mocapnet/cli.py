"""Command line: ``mocapnet evaluate | clean | methods | train``. Run ``mocapnet <verb> --help``."""

from __future__ import annotations

import argparse
import sys
import textwrap
import warnings
from pathlib import Path

EVALUATE_EXAMPLE = """\
examples:
  mocapnet evaluate --data sample --corruption angular-0.5 --method gaussian-58ms --method gaussian-125ms
  mocapnet evaluate --data ../shared/data/bvh/bandai_namco_2 --corruption angular-0.5 \\
      --method noisy --method gaussian-58ms --method gaussian-125ms --repeats 2 --csv scores.csv
  mocapnet evaluate --data ../shared/data/c3d/hdm05 --corruption segment-gap:left-arm:2 --method knn --method lerp

data: a corpus name (sample = the CMU clip shipped with mocapnet; bandai2, bandai1, cmu120 under the data root
$MOCAPNET_DATA, default ../shared/data), a folder of .bvh/.bvh.gz files, or a folder of .c3d files.
corruptions: angular-0.1|0.5|0.9, spatial-0.1cm|0.5cm|1cm|3cm, spatial-ends, uniform-0.5, bias-const, bias-sine,
gaps, gaps-long, noise+gaps, segment-gap:SEG:SECONDS (SEG: left-arm right-arm arms left-leg right-leg legs),
marker-gap:SECONDS. Methods: see `mocapnet methods`.
The table shows the mean over clips and repeats of each clip's error; 'ratio' divides the headline error by
that of the best Gaussian baseline (noise), lerp+gaussian-58ms (noise+gaps) or lerp (gaps, point data)."""

CLEAN_EXAMPLE = """\
examples:
  mocapnet clean take.c3d -o take_filled.c3d                      # fill the file's own gaps (PCA, no database)
  mocapnet clean take.c3d -o take_filled.c3d --method knn --database clean_takes/
  mocapnet clean take.c3d -o take_live.c3d --method extrapolate+cm
  mocapnet clean walk.bvh -o walk_clean.bvh                       # denoise with the shipped EBF for this skeleton
  mocapnet clean walk.bvh -o walk_clean.bvh --method gaussian-58ms
  mocapnet clean walk.bvh -o walk_filled.bvh --mask missing.npy   # bool [T, C] or [T, J], True = missing

The output is written only when cleaning succeeded, never over the input. C3D output holds the markers
(analog channels and model outputs are not copied)."""


def _evaluate(args: argparse.Namespace) -> int:
    from mocapnet.evaluate.harness import evaluate
    from mocapnet.evaluate.report import plot_per_motion, table, write_csv

    ev = evaluate(
        args.data,
        args.corruption,
        args.method or ["noisy", "gaussian-58ms", "gaussian-125ms"],
        args.repeats,
        args.fold,
        args.limit,
        progress=not args.quiet,
        style=args.style,
    )
    where = f"fold {ev.fold} test clips" if ev.fold is not None else "all clips"
    n_files = len({r["file"] for r in ev.rows})
    print(f"{ev.data}: {ev.corruption}, {n_files} files ({where}), {ev.repeats} repeats")
    print(table(ev))
    for name, reason in ev.skipped[:5]:
        print(f"skipped: {reason if reason.startswith(name) else f'{name}: {reason}'}", file=sys.stderr)
    if len(ev.skipped) > 5:
        print(f"skipped {len(ev.skipped) - 5} more clips for the same kind of reason", file=sys.stderr)
    if args.csv:
        write_csv(args.csv, ev.rows)
        print(f"wrote {len(ev.rows)} rows to {args.csv}")
    if args.markdown:
        Path(args.markdown).write_text(table(ev, markdown=True) + "\n")
    if args.plot:
        plot_per_motion(ev, args.plot)
        print(f"wrote {args.plot}")
    return 0


def _clean(args: argparse.Namespace) -> int:
    from mocapnet.clean import CleanOptions, clean_file

    options = CleanOptions(method=args.method, model=args.model, mask=args.mask, database=args.database)
    print(clean_file(args.input, args.output, options).message)
    return 0


def _methods(args: argparse.Namespace) -> int:
    from mocapnet.methods.registry import available

    for spec in available():
        print(f"{spec.name:22s} {spec.space:7s} {spec.help}")
    return 0


def _train(args: argparse.Namespace) -> int:
    import subprocess

    script = Path(__file__).resolve().parents[1] / "scripts" / "train.py"
    if not script.exists():
        raise FileNotFoundError(f"{script}: training needs a source checkout of mocapnet (scripts/ and conf/)")
    return subprocess.call([sys.executable, str(script), *args.overrides])


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mocapnet",
        description="Clean motion-capture data: denoise and fill gaps in BVH and C3D recordings.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Run `mocapnet <verb> --help` for examples.",
    )
    sub = parser.add_subparsers(dest="verb", required=True)
    raw = argparse.RawDescriptionHelpFormatter

    ev = sub.add_parser(
        "evaluate",
        help="score methods on corrupted clean data",
        epilog=EVALUATE_EXAMPLE,
        formatter_class=raw,
        description="Corrupt clean clips reproducibly and score methods.",
    )
    ev.add_argument("--data", required=True, help="corpus name, BVH folder or C3D folder")
    ev.add_argument("--corruption", default="angular-0.5", help="corruption name (default angular-0.5)")
    ev.add_argument("--method", action="append", help="method (repeatable); default: noisy + Gaussians")
    ev.add_argument("--repeats", type=int, default=5, help="corrupted copies per clip (default 5)")
    ev.add_argument("--fold", type=int, default=None, help="score only this fold's test clips (0-4)")
    ev.add_argument("--style", help="score only clips of this style label (Bandai names), e.g. elderly")
    ev.add_argument("--limit", type=int, default=None, help="use only the first N files (quick runs)")
    ev.add_argument("--csv", help="write one row per (method, corruption, file, repeat)")
    ev.add_argument("--markdown", help="write the summary table as markdown")
    ev.add_argument("--plot", help="write a PNG of the error per motion")
    ev.add_argument("--quiet", action="store_true", help="no progress bar")
    ev.set_defaults(func=_evaluate)

    cl = sub.add_parser(
        "clean",
        help="clean one BVH or C3D file",
        epilog=CLEAN_EXAMPLE,
        formatter_class=raw,
        description="Denoise and/or fill the gaps of one file and write the result.",
    )
    cl.add_argument("input", help="input .bvh, .bvh.gz or .c3d")
    cl.add_argument("-o", "--output", required=True, help="output file (same format as the input)")
    cl.add_argument(
        "--method", help="method (default: ebf for BVH, ebd+ebf with --mask; pca for C3D, knn with --database)"
    )
    cl.add_argument("--model", help="checkpoint(s) for a neural method, comma-separated for ebd+ebf")
    cl.add_argument("--mask", help="BVH: .npy bool mask of missing samples, [T, C] or [T, J]")
    cl.add_argument("--database", help="C3D: folder of clean C3D takes of the same marker set (knn)")
    cl.set_defaults(func=_clean)

    me = sub.add_parser("methods", help="list the available methods")
    me.set_defaults(func=_methods)

    tr = sub.add_parser(
        "train",
        help="train EBF/EBD (runs scripts/train.py with Hydra overrides, e.g. experiment=sample_quick)",
        description="Train a network from the Hydra configs in conf/; arguments are Hydra overrides.",
        epilog="examples:\n  mocapnet train experiment=sample_quick\n  mocapnet train experiment=bandai2_ebf "
        "trainer.max_time=00:00:20:00",
        formatter_class=raw,
    )
    tr.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. experiment=bandai2_ebf trainer.max_epochs=5")
    tr.set_defaults(func=_train)
    return parser


def main(argv: list[str] | None = None) -> int:
    from mocapnet.io.atomic import MocapFileError

    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            return args.func(args)
    except (MocapFileError, OSError, ValueError, LookupError, OverflowError, RecursionError) as exc:
        print(f"mocapnet: error: {error_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("mocapnet: interrupted; nothing was written for the file in progress", file=sys.stderr)
        return 130


def error_line(exc: BaseException) -> str:
    """One line, at most ~300 characters, naming the file where the exception knows it."""
    if isinstance(exc, OSError) and exc.filename is not None:
        msg = f"{exc.filename}: {exc.strerror or type(exc).__name__}"
    elif isinstance(exc, KeyError) and exc.args:
        msg = str(exc.args[0])
    else:
        msg = str(exc) or type(exc).__name__
    return textwrap.shorten(msg[:2000], 300, placeholder=" …")


if __name__ == "__main__":
    sys.exit(main())
