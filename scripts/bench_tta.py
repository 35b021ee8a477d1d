"""Inference cost of the learned cleaners' test-time augmentation and blend options (``ebf:tta=…``,
``ebf:blend=…``) against the plain method: CPU seconds (``time.process_time``, robust to other jobs on the
machine, unlike wall time) to clean one long bandai2 clip, 1 thread. Quality is ``scripts/bench_neural.py
--method ebf:tta=reverse …``; this measures what ``scripts/bench_neural.py``'s speed table cannot take (method
strings). ``--passes`` adds what explains the quality: the error of each pass of ``tta=reverse+warp`` alone
(the clip cleaned as it is, time-reversed, at 0.9× and 1.1× speed) and of the reverse mean, with the shipped
``ebf`` on bandai2 fold-1 clips (the selection set, never a test set) and the harness's seeds.

    python scripts/bench_tta.py --method ebf --method ebf:tta=reverse --method ebf:tta=warp
    python scripts/bench_tta.py --passes angular-0.5 --passes none --clips 30 --out benchmarks/results/neural_tta_passes
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from mocapnet.corpus import load_corpus
from mocapnet.corrupt import corrupt_motion, seed_for
from mocapnet.evaluate.metrics import angle_err_deg
from mocapnet.evaluate.neural_bench import long_clip, split_clips
from mocapnet.evaluate.results import fmt, markdown_table, provenance, provenance_header, write_results
from mocapnet.methods.neural import augmented_pass, tta_mean, tta_passes
from mocapnet.methods.registry import MethodContext, build_method
from mocapnet.nn.features import scored_index
from mocapnet.threads import pin_threads


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--method", action="append", default=[], help="method string; the first is the base")
    parser.add_argument("--passes", action="append", default=[], help="corruption: fold-1 error of each pass")
    parser.add_argument("--clips", type=int, default=30, help="fold-1 clips of --passes (evenly spaced)")
    parser.add_argument("--frames", type=int, default=10_000, help="clip length (frames of bandai2 fold-0 clips)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per method (median)")
    parser.add_argument("--corruption", default="angular-0.5")
    parser.add_argument("--out", default=os.path.join("benchmarks", "results", "neural_tta_cost"))
    args = parser.parse_args(argv)
    if not args.method and not args.passes:
        parser.error("give --method (cost) and/or --passes (per-pass quality)")
    return args


def cpu_seconds(clean, clip, noisy: np.ndarray, mask: np.ndarray, repeats: int) -> list[float]:
    """CPU seconds of ``repeats`` calls of ``clean`` on ``noisy`` / ``mask`` after one untimed warm-up."""
    clean(clip.with_channels(noisy), mask)
    times = []
    for _ in range(repeats):
        start = time.process_time()
        clean(clip.with_channels(noisy), mask)
        times.append(time.process_time() - start)
    return times


def cost(methods: list[str], n_frames: int, corruption: str, repeats: int) -> dict:
    """CPU seconds (median of ``repeats``) of each method on one ``n_frames`` clip, and the ratio to the first."""
    clip = long_clip(n_frames)
    noisy, mask = corrupt_motion(clip, corruption, np.random.default_rng(0))
    # gaussian-tuned (a blend partner) tunes on the training folds when built: build time is not timed
    context = MethodContext(load_corpus("bandai2", progress=False).split(0)[0], "bandai2", corruption)
    rows = []
    for text in methods:
        times = cpu_seconds(build_method(text, context).clean, clip, noisy, mask, repeats)
        rows.append({"method": text, "cpu_s": times, "median_cpu_s": float(np.median(times))})
        print(f"{text}: CPU {np.median(times):.3f} s", flush=True)
    for row in rows:
        row["ratio"] = row["median_cpu_s"] / rows[0]["median_cpu_s"]
    return {"frames": clip.n_frames, "corruption": corruption, "repeats": repeats, "rows": rows}


def pass_errors(corruptions: list[str], n_clips: int) -> list[dict]:
    """Mean over bandai2 fold-1 clips (1 repeat, the harness's seeds) of the per-clip RMS angle error (degrees,
    scored channels) of each pass of ``tta=reverse+warp`` alone and of the reverse mean, shipped ``ebf``."""
    from mocapnet.nn.checkpoints import shipped_checkpoint
    from mocapnet.nn.infer import clean_channels, load_model

    corpus, clips, _ = split_clips("bandai2", "val", n_clips)
    sk = clips[0].skeleton
    model, idx = load_model(shipped_checkpoint("ebf", sk)), scored_index(sk)
    out = []
    for corruption in corruptions:
        errors: dict[str, list[float]] = {}
        for motion in clips:
            rng = np.random.default_rng(seed_for(corpus.name, motion.name, 0, corruption))
            noisy, mask = corrupt_motion(motion, corruption, rng)

            def clean(channels: np.ndarray, gaps: np.ndarray, fps: float = motion.fps) -> np.ndarray:
                return clean_channels(model, channels, gaps, sk, fps)

            passes = {PASS_NAMES[p]: augmented_pass(clean, noisy, mask, idx, *p) for p in tta_passes("reverse+warp")}
            passes["mean of as is and reversed"] = tta_mean([passes["as is"], passes["reversed"]])
            truth = motion.channels[:, idx]
            for name, cleaned in passes.items():
                errors.setdefault(name, []).append(angle_err_deg(cleaned, truth, np.ones(len(idx), dtype=bool)))
        row = {"corruption": corruption, "clips": len(clips)} | {k: float(np.mean(v)) for k, v in errors.items()}
        out.append(row)
        print(row, flush=True)
    return out


PASS_NAMES = {
    (False, 1.0): "as is",
    (False, 0.9): "0.9× speed",
    (False, 1.1): "1.1× speed",
    (True, 1.0): "reversed",
    (True, 0.9): "reversed, 0.9×",
    (True, 1.1): "reversed, 1.1×",
}


def markdown(result: dict) -> str:
    """The results file: provenance, the cost table and/or the per-pass table."""
    title = "Test-time augmentation of the shipped ebf: cost (CPU time, 1 thread) and the error of each pass"
    lines = provenance_header(title, result)
    if "cost" in result:
        c, rows = result["cost"], result["cost"]["rows"]
        lines += [
            f"One {c['frames']:,}-frame bandai2 clip, {c['corruption']}, median CPU s of {c['repeats']} runs:",
            "",
        ]
        lines += markdown_table(
            ("method", "CPU s", f"× {rows[0]['method']}", "CPU frames/s"),
            ((r["method"], f"{r['median_cpu_s']:.3f}", f"{r['ratio']:.2f}", f"{c['frames'] / r['median_cpu_s']:,.0f}")
             for r in rows),
        )  # fmt: skip
        lines.append("")
    if "passes" in result:
        names = [k for k in result["passes"][0] if k not in ("corruption", "clips")]
        lines += ["bandai2 fold 1 (selection set), shipped ebf, mean per-clip RMS error ° of each pass alone:", ""]
        lines += markdown_table(
            ("corruption", "clips", *names),
            ((r["corruption"], r["clips"], *(fmt(r[n]) for n in names)) for r in result["passes"]),
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    pin_threads(1)
    result = {**provenance(argv), "load": ", ".join(f"{x:.1f}" for x in os.getloadavg())}
    if args.method:
        result["cost"] = cost(args.method, args.frames, args.corruption, args.repeats)
    if args.passes:
        result["passes"] = pass_errors(args.passes, args.clips)
    write_results(args.out, result, markdown(result), indent=1)


if __name__ == "__main__":
    main()
