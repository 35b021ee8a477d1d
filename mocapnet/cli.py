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
  mocapnet evaluate --data sample --corruption none --corruption angular-0.1 --method gaussian-cv \\
      --markdown scores.md                                        # one table per corruption
  mocapnet evaluate --data ../shared/data/bvh/bandai_namco_2 --corruption angular-0.5 \\
      --method noisy --method gaussian-58ms --method gaussian-125ms --repeats 2 --csv scores.csv
  mocapnet evaluate --data ../shared/data/c3d/hdm05 --corruption segment-gap:left-arm:2 --method knn --method lerp

data: a corpus name (sample = the CMU clip shipped with mocapnet; bandai2, bandai1, cmu120 under the data root
$MOCAPNET_DATA, default ../shared/data), a folder of .bvh/.bvh.gz files, or a folder of .c3d files.
corruptions: angular-0.1|0.5|0.9, spatial-0.1cm|0.5cm|1cm|3cm, spatial-ends, uniform-0.5, bias-const, bias-sine,
gaps, gaps-long, noise+gaps, segment-gap:SEG:SECONDS (SEG: left-arm right-arm arms left-leg right-leg legs),
marker-gap:SECONDS. Methods: see `mocapnet methods`.
Clips are scored on Dask worker processes (one per core, 1 torch/BLAS thread each; --workers 0 = in this
process, --scheduler = an existing cluster); methods are built and tuned once, and every clip's corruption is
seeded by (corpus, file, repeat, corruption), so the scores do not depend on where they ran.
The table shows the mean over clips and repeats of each clip's error; 'ratio' divides the headline error by
that of the best reference baseline (PROTOCOL.md): of gaussian-58ms, gaussian-125ms and gaussian-tuned for
noise, of lerp and spline for gaps (angles or points), lerp+gaussian-58ms for noise+gaps."""

CLEAN_EXAMPLE = """\
examples:
  mocapnet clean take.c3d -o take_filled.c3d --plot fills.png     # fill the file's own gaps (auto), draw them
  mocapnet clean take.c3d -o take_filled.c3d --method pca          # one filler for every gap, unchecked
  mocapnet clean take.c3d -o take_filled.c3d --method knn --database clean_takes/
  mocapnet clean take.c3d -o take_live.c3d --method extrapolate+cm
  mocapnet clean take.c3d -o take_smooth.c3d --method gaussian-cv  # denoise the measured samples, gaps left as they are
  mocapnet clean walk.bvh -o walk_clean.bvh                       # shipped EBF for the skeleton, else gaussian-cv
  mocapnet clean walk.bvh -o walk_clean.bvh --method gaussian-58ms
  mocapnet clean walk.bvh -o walk_filled.bvh --mask missing.npy   # bool [T, C] or [T, J], True = missing
  mocapnet clean archive/ -o cleaned/ --report cleaned/report.csv  # a folder (recursing), on all local cores
  mocapnet clean archive/ -o cleaned/ --method gaussian-58ms --scheduler tcp://10.0.0.5:8786

The output is written only when cleaning succeeded, never over the input, and only with the input's format
(.bvh/.bvh.gz or .c3d, any case). C3D output is the input file with only the filled samples changed (residual
0 = computed) — or, with the denoiser gaussian-cv, only the measured samples' positions (residual and cameras
kept): every other point, analog channel, event, parameter and the header stay as they were. Gaps that no
filler fills plausibly stay missing and are listed in the report.

A folder: every .bvh, .bvh.gz and .c3d under it (recursing) is cleaned to the same relative path under the
output folder, each exactly as the one-file clean would do it, in parallel on Dask worker processes (one per
core, 1 torch/BLAS thread each; --workers 0 runs them one by one in this process). A file that fails is
reported and skipped; outputs newer than their input are left alone unless --force (so a rerun only does
what is missing or failed; after changing --method, use --force). --report writes one row per file
(method, frames, samples filled, seconds, error, why BVH auto chose the method): .csv, or .json with each file's
details (e.g. per-gap reports); it also works for one file. Exit code: 0 when every file is clean or up
to date, 1 when some failed, 2 for a usage error (nothing cleaned).

"""


def _evaluate(args: argparse.Namespace) -> int:
    from mocapnet.corrupt import check_corruption
    from mocapnet.evaluate.harness import evaluate
    from mocapnet.evaluate.report import plot_per_motion, table, write_csv

    # every name checked before any clip is scored; files are written only after every corruption was scored
    corruptions = list(dict.fromkeys(check_corruption(c) for c in args.corruption or ["angular-0.5"]))
    evaluations, parallel = [], _parallel(args)
    for corruption in corruptions:
        ev = evaluate(
            args.data,
            corruption,
            args.method or ["noisy", "gaussian-58ms", "gaussian-125ms"],
            args.repeats,
            args.fold,
            args.limit,
            progress=not args.quiet,
            style=args.style,
            parallel=parallel,
        )
        print(_evaluation_heading(ev))
        print(table(ev))
        for name, reason in ev.skipped[:5]:
            print(f"skipped: {reason if reason.startswith(name) else f'{name}: {reason}'}", file=sys.stderr)
        if len(ev.skipped) > 5:
            print(f"skipped {len(ev.skipped) - 5} more clips for the same kind of reason", file=sys.stderr)
        evaluations.append(ev)
    several = len(evaluations) > 1
    if args.csv:
        rows = [row for ev in evaluations for row in ev.rows]
        write_csv(args.csv, rows)
        print(f"wrote {len(rows)} rows to {args.csv}")
    if args.markdown:
        tables = [
            (f"## {_evaluation_heading(ev)}\n\n" if several else "") + table(ev, markdown=True) for ev in evaluations
        ]
        Path(args.markdown).write_text("\n\n".join(tables) + "\n")
    for ev in evaluations if args.plot else []:
        plot = Path(args.plot)
        plot = plot.with_name(f"{plot.stem}_{_file_safe(str(ev.corruption))}{plot.suffix}") if several else plot
        plot_per_motion(ev, plot)
        print(f"wrote {plot}")
    return 0


def _evaluation_heading(ev) -> str:
    """``DATA: CORRUPTION, N files (which clips), R repeats`` of one evaluation."""
    where = f"fold {ev.fold} test clips" if ev.fold is not None else "all clips"
    return f"{ev.data}: {ev.corruption}, {len({r['file'] for r in ev.rows})} files ({where}), {ev.repeats} repeats"


def _file_safe(text: str) -> str:
    """``text`` with every character but letters, digits, '.', '-' and '_' replaced by '_' (a corruption name
    such as ``segment-gap:left-arm:2`` in a file name)."""
    return "".join(c if c.isalnum() or c in ".-_" else "_" for c in text)


def _parallel(args: argparse.Namespace):
    from mocapnet.parallel import Parallel
    from mocapnet.threads import default_threads

    return Parallel(scheduler=args.scheduler, workers=args.workers, threads=args.threads or default_threads())


def _clean(args: argparse.Namespace) -> int:
    import time

    from mocapnet.batch import FAILED, FileReport, clean_folder, report_format, summary, write_report
    from mocapnet.clean import CleanOptions, clean_file
    from mocapnet.threads import pin_threads

    options = CleanOptions(
        method=args.method,
        model=args.model,
        mask=args.mask,
        database=args.database,
        plot=args.plot,
        allow_truncated=args.allow_truncated,
    )
    parallel = _parallel(args)
    if args.report:
        report_format(args.report)
    if not Path(args.input).is_dir():
        pin_threads(args.threads)
        start = time.perf_counter()
        result = clean_file(args.input, args.output, options)
        print(result.message)
        if result.details.get("gaps"):
            from mocapnet.methods.autofill import summary_table

            print(summary_table(result.details["gaps"], first_frame=result.details.get("file_first_frame", 0)))
        if args.plot:
            print(f"wrote {args.plot}")
        if args.report:
            write_report(args.report, [FileReport.from_result(result, time.perf_counter() - start)])
        return 0
    if args.plot:
        raise ValueError("--plot draws one C3D file's fills; give a file, not a folder")
    print(f"cleaning {args.input} -> {args.output} on {parallel.describe()}", file=sys.stderr)
    reports = clean_folder(args.input, args.output, options, parallel, args.force, progress=not args.quiet)
    print(summary(reports))
    failed = [r for r in reports if r.status == FAILED]
    for r in failed:
        print(f"failed: {textwrap.shorten(r.error, 400)}", file=sys.stderr)
    if args.report:
        write_report(args.report, reports)
        print(f"wrote {args.report}")
    return 1 if failed else 0


def _methods(args: argparse.Namespace) -> int:
    from mocapnet.methods.registry import available

    for spec in available():
        print(f"{spec.name:22s} {spec.space:7s} {spec.help}")
    return 0


def _train(args: argparse.Namespace) -> int:
    from mocapnet.nn.train import main as train_main

    print(train_main(args.overrides))
    return 0


def _train_epilog() -> str:
    """Examples and the experiment configs shipped in mocapnet/conf/experiment (read without importing torch)."""
    names = sorted(p.stem for p in (Path(__file__).resolve().parent / "conf" / "experiment").glob("*.yaml"))
    return (
        "examples:\n  mocapnet train experiment=sample_quick\n"
        "  mocapnet train experiment=bandai2_ebf trainer.max_time=00:00:20:00   # resumes from last.ckpt\n"
        "  mocapnet train experiment=bandai2_ebf_mix threads=1 ckpt_path=null   # start afresh\n\n"
        f"experiments: {', '.join(names)}\n"
        "Runs go to $MOCAPNET_RUNS/<name> (default runs/<name> under the current directory)."
    )


def _at_least_one(text: str) -> int:
    """argparse type: a whole number >= 1 (a count of clips, repeats or threads)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a whole number >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"a whole number >= 1, got {value}")
    return value


def _add_parallel_args(parser: argparse.ArgumentParser) -> None:
    from mocapnet.parallel import JOBQUEUE_HELP

    parser.epilog = f"{parser.epilog}\n\nparallel runs: {JOBQUEUE_HELP}"
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--scheduler", help="address of an existing Dask scheduler, e.g. tcp://10.0.0.5:8786")
    group.add_argument(
        "--workers", type=int, help="local worker processes (default: one per core; 0 = in this process)"
    )
    parser.add_argument("--threads", type=_at_least_one, help="torch/BLAS threads per worker process (default 1)")


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
    ev.add_argument(
        "--corruption",
        action="append",
        help="corruption name (repeatable: one table each; default angular-0.5)",
    )
    ev.add_argument("--method", action="append", help="method (repeatable); default: noisy + Gaussians")
    ev.add_argument("--repeats", type=_at_least_one, default=5, help="corrupted copies per clip (default 5)")
    ev.add_argument("--fold", type=int, default=None, help="score only this fold's test clips (0-4)")
    ev.add_argument("--style", help="score only clips of this style label (Bandai names), e.g. elderly")
    ev.add_argument("--limit", type=_at_least_one, default=None, help="use only the first N files (quick runs)")
    ev.add_argument("--csv", help="write one row per (method, corruption, file, repeat)")
    ev.add_argument("--markdown", help="write the summary table as markdown")
    ev.add_argument(
        "--plot", help="write a PNG of the error per motion (several corruptions: one PNG each, NAME_CORRUPTION.png)"
    )
    ev.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_parallel_args(ev)
    ev.set_defaults(func=_evaluate)

    cl = sub.add_parser(
        "clean",
        help="clean one BVH or C3D file",
        epilog=CLEAN_EXAMPLE,
        formatter_class=raw,
        description="Denoise and/or fill the gaps of one file and write the result.",
    )
    cl.add_argument("input", help="input .bvh, .bvh.gz or .c3d, or a folder of them")
    cl.add_argument("-o", "--output", required=True, help="output file (same format as the input) or folder")
    cl.add_argument(
        "--method",
        help="method (default auto. BVH: the EBF shipped for the skeleton, ebd+ebf with --mask, on any other "
        "skeleton or frame rate gaussian-cv, below 10 fps lerp (samples kept); angles are cleaned continuous, Euler "
        "flips near gimbal lock included, and written back on the file's own branches, unchanged samples exactly. "
        "C3D: per gap rigid-body, pca, knn with --database, spline or lerp, each fill checked, implausible gaps left "
        "missing; gaussian-cv denoises instead)",
    )
    cl.add_argument("--model", help="checkpoint(s) for a neural method, comma-separated for ebd+ebf")
    cl.add_argument(
        "--mask",
        help="BVH: .npy bool mask of missing samples, [T, C] or [T, J] (a joint's every channel; their stored values "
        "are never read; in a file whose rotations all lie within -180..180 or 0..360, a gap whose edges differ by "
        "more than 270 deg is joined the short way round: a wrap, as far as the file can tell). The method fills "
        "the scored rotations; gaps in the root's and other unscored channels (positions) are filled linearly",
    )
    cl.add_argument("--database", help="C3D: folder of clean C3D takes of the same marker set (knn)")
    cl.add_argument("--plot", help="C3D: write a PNG of the filled markers' trajectories, filled spans highlighted")
    cl.add_argument(
        "--allow-truncated",
        action="store_true",
        help="C3D: a file whose data block is shorter than its header says: warn and clean the frames present",
    )
    cl.add_argument("--report", help="write one row per file: .csv, or .json with each file's details")
    cl.add_argument("--force", action="store_true", help="folder: clean again files whose output is up to date")
    cl.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_parallel_args(cl)
    cl.set_defaults(func=_clean)

    me = sub.add_parser("methods", help="list the available methods")
    me.set_defaults(func=_methods)

    tr = sub.add_parser(
        "train",
        help="train EBF/EBD in this process (Hydra overrides, e.g. experiment=sample_quick)",
        description="Train a network from the Hydra configs packaged in mocapnet/conf; arguments are Hydra "
        "overrides. Prints the best checkpoint's path.",
        epilog=_train_epilog(),
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
            warnings.showwarning = _show_warning
            return args.func(args)
    except (MocapFileError, OSError, ValueError, LookupError, OverflowError, RecursionError) as exc:
        print(f"mocapnet: error: {error_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("mocapnet: interrupted; nothing was written for the file in progress", file=sys.stderr)
        return 130


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line each on stderr: ``mocapnet: warning: …``."""
    print(f"mocapnet: warning: {textwrap.shorten(str(message)[:2000], 300, placeholder=' …')}", file=sys.stderr)


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
