"""Benchmark the learned cleaners (EBF variants, EBD) against the baselines, across corpora, and their speed.

    python scripts/bench_neural.py                                   # writes benchmarks/results/neural.{json,md}
    python scripts/bench_neural.py --clips 60 --repeats 2            # a subset of test clips (stated in the output)
    python scripts/bench_neural.py --method ebf-free=runs/x/best.ckpt --skip-speed   # a candidate checkpoint

Quality: every corruption of PROTOCOL.md on the fold-0 test clips of bandai2 (the models trained on folds
2-4 and were selected on fold 1) and of bandai1 (never trained, tuned or selected on: cross-corpus). Each
table row is ``report.summarize``: mean over (clip, repeat) of per-clip RMS errors; the ratio divides the
headline error by the best reference baseline of ``harness.reference`` (the best of gaussian-58ms,
gaussian-125ms and gaussian-tuned for noise; the better of lerp and spline for gaps; lerp+gaussian-58ms for
noise+gaps). EBD is also scored per gap-length bin against lerp and spline.

Speed (1 torch/BLAS thread): offline cleaning of a 10,000-frame clip, peak memory of a 300,000-frame clean
(``clean_channels``, in a child process), and the CPU time of ``EBFStream.push`` per frame.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import mocapnet.methods.neural  # noqa: F401  (registers the EBF variant names)
from mocapnet.corpus import load_corpus
from mocapnet.corrupt import ANGLE_CORRUPTIONS, corrupt_motion, seed_for
from mocapnet.evaluate.benchmark import git_commit
from mocapnet.evaluate.harness import Evaluation, corpus_references, evaluate_angles, has_gaps
from mocapnet.evaluate.metrics import wrapped_diff
from mocapnet.evaluate.report import summarize
from mocapnet.fill import runs
from mocapnet.methods.registry import build_method
from mocapnet.motion import Motion
from mocapnet.threads import pin_threads

ROOT = Path(__file__).resolve().parents[1]
CORRUPTIONS = [c for c in ANGLE_CORRUPTIONS if c != "none"] + ["segment-gap:left-arm:0.5", "segment-gap:left-arm:2"]
GAP_BINS = ((1, 5), (6, 15), (16, 30), (31, 60), (61, 10**9))  # frames, inclusive
BIN_LABELS = ("≤ 5", "6–15", "16–30", "31–60", "> 60")
BIN_CORRUPTIONS = ("gaps", "gaps-long", "segment-gap:left-arm:0.5", "segment-gap:left-arm:2")


def shipped_variants(motion: Motion) -> list[str]:
    """The EBF-family methods shipped for ``motion``'s skeleton: ``ebf`` and each variant by name."""
    from mocapnet.nn.checkpoints import EBF_VARIANTS, read_index
    from mocapnet.nn.features import topology_hash

    mine = topology_hash(motion.skeleton)
    names = [e["method"] for e in read_index() if e["skeleton_hash"] == mine]
    return ["ebf"] + [n for n in (*EBF_VARIANTS, "bf", "nn") if n in names]


def neural_methods(corruption: str, motion: Motion, extra: list[str]) -> list[str]:
    """What to score beside the references: EBF variants on noise, EBD on gaps, EBD+EBF on noise+gaps."""
    if corruption == "noise+gaps":
        return ["ebd+ebf"]
    if has_gaps(corruption):
        return ["ebd"]
    return shipped_variants(motion) + extra


def subset(clips: list[Motion], n: int | None) -> list[Motion]:
    """``n`` clips evenly spaced over ``clips`` (the fold's order is stratified by content), or all."""
    return clips if not n or n >= len(clips) else clips[:: len(clips) // n][:n]


def quality(name: str, n_clips: int | None, repeats: int, extra: list[str], corruptions: list[str]) -> list[dict]:
    corpus = load_corpus(name, progress=False)
    train, _, test = corpus.split(0)
    clips = subset(test, n_clips)
    out = []
    for corruption in corruptions:
        start = time.perf_counter()
        methods = corpus_references(name, corruption) + neural_methods(corruption, clips[0], extra)
        rows, skipped = evaluate_angles(corpus, clips, train, corruption, methods, repeats, progress=False)
        ev = Evaluation(name, corruption, "angles", methods, rows, skipped, 0, repeats)
        n_scored = len({r["file"] for r in rows})
        for entry in summarize(ev):
            out.append({**entry, "corpus": name, "corruption": corruption, "clips": n_scored, "repeats": repeats})
        print(f"{name} {corruption}: {n_scored} clips x {repeats} in {time.perf_counter() - start:.0f} s", flush=True)
    return out


def gap_bins(name: str, n_clips: int | None, repeats: int) -> list[dict]:
    """RMS gap error (degrees) per gap-length bin of EBD, lerp and spline; a gap is one run of missing frames
    of one scored joint, its error taken over that joint's scored channels."""
    corpus = load_corpus(name, progress=False)
    clips = subset(corpus.split(0)[2], n_clips)
    methods = {m: build_method(m).clean for m in ("lerp", "spline", "ebd")}
    out = []
    for corruption in BIN_CORRUPTIONS:
        sse = np.zeros((len(methods), len(GAP_BINS)))
        count = np.zeros(len(GAP_BINS))
        gaps = np.zeros(len(GAP_BINS), dtype=int)
        for motion in clips:
            sk = motion.skeleton
            scored = np.flatnonzero(sk.scored_mask)
            cols_of = [c for c in (np.intersect1d(sk.joint_channels(j), scored) for j in sk.scored_joints) if c.size]
            for rep in range(repeats):
                rng = np.random.default_rng(seed_for(name, motion.name, rep, corruption))
                try:
                    noisy, mask = corrupt_motion(motion, corruption, rng)
                except ValueError:
                    break
                outs = [clean(motion.with_channels(noisy), mask) for clean in methods.values()]
                for cols in cols_of:
                    for a, b in runs(mask[:, cols[0]]):
                        k = next(i for i, (lo, hi) in enumerate(GAP_BINS) if lo <= b - a <= hi)
                        gaps[k] += 1
                        count[k] += (b - a) * len(cols)
                        for m, o in enumerate(outs):
                            sse[m, k] += float((wrapped_diff(o[a:b, cols], motion.channels[a:b, cols]) ** 2).sum())
        for m, method in enumerate(methods):
            for k in range(len(GAP_BINS)):
                rms = float(np.sqrt(sse[m, k] / count[k])) if count[k] else float("nan")
                out.append(
                    {
                        "corpus": name,
                        "corruption": corruption,
                        "method": method,
                        "bin": BIN_LABELS[k],
                        "gaps": int(gaps[k]),
                        "rms_deg": rms,
                    }
                )
        print(f"bins {name} {corruption}: {len(clips)} clips x {repeats}", flush=True)
    return out


def long_clip(n_frames: int) -> Motion:
    """``n_frames`` of bandai2 fold-0 test clips, each played forth and back (timing and memory only)."""
    test = load_corpus("bandai2", progress=False).split(0)[2][:40]
    ch = np.concatenate([np.concatenate([m.channels, m.channels[::-1]]) for m in test])
    return test[0].with_channels(np.tile(ch, (int(np.ceil(n_frames / len(ch))), 1))[:n_frames])


def speed(methods: list[str], repeats: int) -> dict:
    clip = long_clip(10_000)
    noisy, mask = corrupt_motion(clip, "angular-0.5", np.random.default_rng(0))
    offline = {}
    for text in ["gaussian-58ms", *methods]:
        clean = build_method(text).clean
        clean(clip.with_channels(noisy), mask)  # warm-up: loads the checkpoint
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            clean(clip.with_channels(noisy), mask)
            times.append(time.perf_counter() - start)
        offline[text] = {"seconds": float(np.median(times)), "frames_per_s": clip.n_frames / float(np.median(times))}
    return {
        "offline_frames": clip.n_frames,
        "offline": offline,
        "streaming": streaming(clip, methods, 3000),
        "rss_300k": {m: rss_child(m) for m in methods},
    }


def streaming(clip: Motion, methods: list[str], n_frames: int) -> dict:
    from mocapnet.nn.checkpoints import shipped_checkpoint
    from mocapnet.nn.infer import EBFStream, load_model

    noisy, _ = corrupt_motion(clip, "angular-0.5", np.random.default_rng(1))
    out = {}
    for name in (m for m in methods if m.startswith("ebf")):
        stream = EBFStream(load_model(shipped_checkpoint(name, clip.skeleton)), clip.skeleton, clip.fps)
        cpu, wall = [], []
        for frame in noisy[:n_frames]:
            c0, w0 = time.thread_time(), time.perf_counter()
            stream.push(frame)
            cpu.append(time.thread_time() - c0)
            wall.append(time.perf_counter() - w0)
        cpu_ms, wall_ms = np.array(cpu[2 * stream.half + 2 :]) * 1e3, np.array(wall[2 * stream.half + 2 :]) * 1e3
        out[name] = {
            "cpu_median_ms": float(np.median(cpu_ms)),
            "cpu_p99_ms": float(np.percentile(cpu_ms, 99)),
            "wall_median_ms": float(np.median(wall_ms)),
            "wall_p99_ms": float(np.percentile(wall_ms, 99)),
        }
    return out


def rss_child(method: str) -> dict:
    """Peak RSS (MB) of a fresh process cleaning 300,000 frames with ``method`` (``--rss-child``)."""
    cmd = [sys.executable, __file__, "--rss-child", method]
    return json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.splitlines()[-1])


def rss_run(method: str) -> None:
    pin_threads(1)
    clip = long_clip(300_000)
    clean = build_method(method).clean
    mask = np.zeros(clip.channels.shape, dtype=bool)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    start = time.perf_counter()
    clean(clip, mask)
    seconds = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"peak_mb": peak, "before_clean_mb": before, "seconds": seconds, "frames": clip.n_frames}))


def markdown(result: dict) -> str:
    lines = [
        "# Learned cleaners (EBF variants, EBD): quality across corpora and speed",
        "",
        f"Command: `{result['command']}`  ",
        f"Git commit: `{result['commit']}`; load average at start {result['load']} on the shared 2-core machine.",
        "",
    ]
    if result.get("quality"):
        lines += [
            "| corpus | corruption | clips × repeats | method | headline ° | ratio | frames/s |",
            "|---|---|---|---|---|---|---|",
        ]
        for e in result["quality"]:
            err = e[e["ratio_of"]]
            lines.append(
                f"| {e['corpus']} | {e['corruption']} | {e['clips']} × {e['repeats']} | {e['method']} | "
                f"{err:.3f} ({e['ratio_of'].removesuffix('_deg')}) | {e['ratio']:.3f} | {e['frames_per_s']:,.0f} |"
            )
    if result.get("gap_bins"):
        lines += [
            "",
            "EBD gap error per gap length (frames), RMS °:",
            "",
            "| corpus | corruption | bin | gaps | lerp | spline | ebd |",
            "|---|---|---|---|---|---|---|",
        ]
        by = {}
        for b in result["gap_bins"]:
            by.setdefault((b["corpus"], b["corruption"], b["bin"]), {})[b["method"]] = b
        for (corpus, corruption, bin_), m in by.items():
            if m["lerp"]["gaps"]:
                lines.append(
                    f"| {corpus} | {corruption} | {bin_} | {m['lerp']['gaps']} | {m['lerp']['rms_deg']:.3f} | "
                    f"{m['spline']['rms_deg']:.3f} | {m['ebd']['rms_deg']:.3f} |"
                )
    if result.get("speed"):
        sp = result["speed"]
        lines += [
            "",
            f"Speed, 1 thread: offline {sp['offline_frames']:,}-frame bandai2 clip (median), 300,000-frame "
            "clean peak RSS (fresh process), EBFStream.push per frame after the first window:",
            "",
            "| method | offline frames/s | 300k peak RSS MB | 300k s | push CPU median / p99 ms | wall p99 ms |",
            "|---|---|---|---|---|---|",
        ]
        for m, o in sp["offline"].items():
            r, s = sp["rss_300k"].get(m), sp["streaming"].get(m)
            lines.append(
                f"| {m} | {o['frames_per_s']:,.0f} | {r['peak_mb']:.0f} | {r['seconds']:.1f} | "
                if r
                else f"| {m} | {o['frames_per_s']:,.0f} | — | — | "
            )
            lines[-1] += (
                f"{s['cpu_median_ms']:.3f} / {s['cpu_p99_ms']:.3f} | {s['wall_p99_ms']:.2f} |" if s else "— | — |"
            )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--clips", type=int, default=None, help="score N evenly spaced fold-0 test clips per corpus")
    parser.add_argument("--corpus", action="append", help="corpora (default bandai2 and bandai1)")
    parser.add_argument("--corruption", action="append", help="corruptions (default: all of PROTOCOL.md)")
    parser.add_argument("--method", action="append", default=[], help="extra noise method, e.g. ebf-free=PATH")
    parser.add_argument("--skip-quality", action="store_true")
    parser.add_argument("--skip-bins", action="store_true")
    parser.add_argument("--skip-speed", action="store_true")
    parser.add_argument("--timing-repeats", type=int, default=5)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "neural"), help="path without suffix")
    parser.add_argument("--rss-child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.rss_child:
        return rss_run(args.rss_child)
    pin_threads(1)
    import os

    result = {
        "command": "python " + " ".join([Path(sys.argv[0]).as_posix()] + sys.argv[1:]),
        "commit": git_commit(),
        "load": ", ".join(f"{x:.1f}" for x in os.getloadavg()),
    }
    corpora = args.corpus or ["bandai2", "bandai1"]
    corruptions = args.corruption or CORRUPTIONS
    if not args.skip_quality:
        result["quality"] = [e for c in corpora for e in quality(c, args.clips, args.repeats, args.method, corruptions)]
    if not args.skip_bins:
        result["gap_bins"] = [b for c in corpora for b in gap_bins(c, args.clips, args.repeats)]
    if not args.skip_speed:
        result["speed"] = speed(shipped_variants(long_clip(100)), args.timing_repeats)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    out.with_suffix(".md").write_text(markdown(result))
    print(out.with_suffix(".md").read_text())


if __name__ == "__main__":
    main()
