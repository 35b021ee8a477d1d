"""Benchmark of the learned cleaners (EBF variants, EBD) against the baselines, across corpora, and their
speed; ``scripts/bench_neural.py`` is its command line.

Quality: each corruption on a split of a corpus (``split="test"``: fold-0 test clips, the models trained on
folds 2-4 and were selected on fold 1; ``split="val"``: the fold-1 clips, for choosing between checkpoints;
``split="fast"``: the same, the clips with the most fast movement first (``fast_motion``);
``split="style:NAME"``: the clips of one style outside fold 0, for models trained without that style;
bandai1 is test only). Scoring is ``harness.evaluate_angles`` and each row ``report.summarize``: mean over
(clip, repeat) of per-clip RMS errors and the ratio to the best reference baseline of ``harness.reference``
(the best of gaussian-58ms, gaussian-125ms and gaussian-tuned for noise; the better of lerp and spline for
gaps; lerp+gaussian-58ms for noise+gaps). EBD is also scored per gap-length bin against lerp and spline.

Speed (1 torch/BLAS thread): offline cleaning of a 10,000-frame clip, peak memory of a 300,000-frame clean
(``clean_channels``, in a child process: ``python -m mocapnet.evaluate.neural_bench METHOD``), and the CPU
time of ``EBFStream.push`` per frame.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from collections.abc import Sequence

import numpy as np

import mocapnet.methods.neural  # noqa: F401  (registers the EBF variant names)
from mocapnet.corpus import load_corpus
from mocapnet.corrupt import ANGLE_CORRUPTIONS, corrupt_motion, seed_for
from mocapnet.evaluate import gap_bins as gap_bins_module
from mocapnet.evaluate.harness import Evaluation, corpus_references, evaluate_angles, has_gaps
from mocapnet.evaluate.metrics import angle_err_deg
from mocapnet.evaluate.report import fmt, markdown_table, summarize
from mocapnet.evaluate.results import provenance_header
from mocapnet.fill import gaussian_smooth
from mocapnet.methods.registry import build_method
from mocapnet.motion import Motion
from mocapnet.threads import pin_threads

CORRUPTIONS = [c for c in ANGLE_CORRUPTIONS if c != "none"] + ["segment-gap:left-arm:0.5", "segment-gap:left-arm:2"]
#: The corruptions and rule that choose the shipped ``ebf`` among candidates (fold 1 only): mean ratio.
SELECTION = ("angular-0.1", "angular-0.5", "angular-0.9", "spatial-0.5cm", "uniform-0.5", "bias-sine")
SPLITS = ("test", "val", "fast")
#: ``"fast"``: the fold-1 clips ordered by how much fast movement they hold (``fast_motion``), the most first;
#: ``--clips N`` takes the first N. bandai1's clean motion holds ~2.4x more of it than bandai2's (gaussian-58ms
#: changes clean bandai1 by 1.451°, bandai2 by 0.617°): a selection set like the cross-corpus test in that respect.
FAST_SIGMA_S = 0.058
#: Prefix of the unseen-style split (``"style:elderly"``): every clip of one style, for models trained with
#: ``data.holdout_style`` set to it (a transfer check inside bandai2; bandai1 stays the test).
STYLE_SPLIT = "style:"
#: Prefix of the unseen-content split (``"content:run"``): every clip of one content outside fold 0, for models
#: trained with ``data.holdout_content`` set to it (bandai1's contents are mostly ones bandai2 never shows).
CONTENT_SPLIT = "content:"


def split_arg(split: str) -> str:
    """``check_split`` for argparse (its message shown as the error)."""
    try:
        return check_split(split)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def check_split(split: str) -> str:
    """``split`` if it is ``"test"``, ``"val"``, ``"fast"``, ``"style:NAME"`` or ``"content:NAME"``, else
    ``ValueError``."""
    if split in SPLITS or any(split.startswith(p) and len(split) > len(p) for p in (STYLE_SPLIT, CONTENT_SPLIT)):
        return split
    raise ValueError(
        f"split must be one of {SPLITS}, {STYLE_SPLIT}NAME (e.g. style:elderly) or {CONTENT_SPLIT}NAME (e.g. "
        f"content:run), got {split!r}"
    )


def shipped_variants(motion: Motion) -> list[str]:
    """The EBF-family methods shipped for ``motion``'s skeleton: ``ebf`` and each other variant by name (the one
    ``ebf`` runs is not scored twice)."""
    from mocapnet.nn.checkpoints import EBF_VARIANTS, read_index
    from mocapnet.nn.features import topology_hash

    mine = topology_hash(motion.skeleton)
    entries = [e for e in read_index() if e["skeleton_hash"] == mine]
    names = {e["method"] for e in entries if not e.get("ebf")}
    return ["ebf"] + [n for n in (*EBF_VARIANTS, "bf", "nn") if n in names]


def neural_methods(corruption: str, motion: Motion, extra: Sequence[str], shipped: bool = True) -> list[str]:
    """What to score beside the references: EBF variants (``shipped``) and ``extra`` on noise; the shipped EBD on
    gaps and EBD+EBF on noise+gaps, each with the ``extra`` methods of that family (``ebd=…`` / ``ebd+ebf=…``:
    other checkpoints of it; the denoisers of ``extra`` have nothing to do there)."""
    if has_gaps(corruption):
        family = "ebd+ebf" if corruption == "noise+gaps" else "ebd"
        mine = [m for m in extra if m.split(":")[0].split("=")[0] == family]
        return [family, *(m for m in mine if m != family)]
    return (shipped_variants(motion) if shipped else []) + list(extra)


def fast_motion(motion: Motion) -> float:
    """How much fast movement ``motion`` holds: the RMS (degrees, over frames and scored channels) of the change
    Gaussian smoothing at ``FAST_SIGMA_S`` makes to its (clean) channels, unwrapped."""
    scored = np.asarray(motion.skeleton.scored_mask, dtype=bool)
    x = np.unwrap(motion.channels[:, scored].astype(np.float64), period=360.0, axis=0)
    return float(np.sqrt(np.mean((gaussian_smooth(x, FAST_SIGMA_S, motion.fps) - x) ** 2)))


def split_clips(name: str, split: str, n_clips: int | None):
    """``(corpus, scored clips, training clips)``: fold-0 test clips (``"test"``), the fold-1 validation
    clips (``"val"``, bandai2-style corpora only; ``"fast"``: the same ordered by ``fast_motion``, most first, and
    ``n_clips`` takes the first), or the clips of one style outside the fold-0 test clips
    (``"style:NAME"``, for models trained with ``holdout_style=NAME``; the training clips are fold 0's without
    that style, which ``gaussian-tuned`` is tuned on; ValueError when there is none), or likewise the clips of one
    content (``"content:NAME"``, for ``holdout_content=NAME``); ``n_clips`` of them (``subset``)."""
    check_split(split)
    corpus = load_corpus(name, progress=False)
    for prefix, kind in ((STYLE_SPLIT, "style"), (CONTENT_SPLIT, "content")):
        if split.startswith(prefix):
            label = split[len(prefix) :]
            train, _, test = corpus.split(0, **{f"holdout_{kind}": label})
            held_out = {m.name for m in test}
            labelled = corpus.style_clips(label) if kind == "style" else corpus.content_clips(label)
            clips = [m for m in labelled if m.name not in held_out]
            if not clips:
                raise ValueError(f"{name}: no clip of {kind} {label!r} outside the fold-0 test clips")
            return corpus, gap_bins_module.subset(clips, n_clips), train
    train, val, test = corpus.split(0)
    if split == "fast":
        ranked = sorted(val, key=fast_motion, reverse=True)
        return corpus, ranked[:n_clips] if n_clips else ranked, train
    return corpus, gap_bins_module.subset(test if split == "test" else val, n_clips), train


def quality(
    name: str,
    n_clips: int | None,
    repeats: int,
    extra: Sequence[str],
    corruptions: Sequence[str],
    split: str = "test",
    shipped: bool = True,
) -> list[dict]:
    """``report.summarize`` rows (plus corpus, corruption, clips, repeats, split) of the references and the
    learned methods on each corruption."""
    corpus, clips, train = split_clips(name, split, n_clips)
    out = []
    for corruption in corruptions:
        start = time.perf_counter()
        methods = corpus_references(name, corruption) + neural_methods(corruption, clips[0], extra, shipped)
        rows, skipped = evaluate_angles(corpus, clips, train, corruption, methods, repeats, progress=False)
        ev = Evaluation(name, corruption, "angles", methods, rows, skipped, 0, repeats)
        n_scored = len({r["file"] for r in rows})
        meta = {"corpus": name, "corruption": corruption, "clips": n_scored, "repeats": repeats, "split": split}
        out += [{**entry, **meta} for entry in summarize(ev)]
        print(f"{name} {split} {corruption}: {n_scored} clips x {repeats} in {time.perf_counter() - start:.0f} s")
    return out


def selection_scores(rows: Sequence[dict], corruptions: Sequence[str] = SELECTION) -> dict[str, float]:
    """Mean over ``corruptions`` of each method's ratio to the best Gaussian (``quality`` rows); only
    methods scored on every one of them."""
    ratios: dict[str, dict[str, float]] = {}
    for r in rows:
        if r["corruption"] in corruptions:
            ratios.setdefault(r["method"], {})[r["corruption"]] = r["ratio"]
    return {m: float(np.mean(list(v.values()))) for m, v in ratios.items() if len(v) == len(corruptions)}


def gap_bins(name: str, n_clips: int | None, repeats: int) -> list[dict]:
    """RMS gap error (degrees) per gap-length bin of EBD, lerp and spline on fold-0 test clips, as
    ``mocapnet.evaluate.gap_bins`` scores them (a gap: one run of missing frames of the scored channels that
    share a missing pattern), one row per corpus, corruption, method and bin."""
    _, clips, _ = split_clips(name, "test", n_clips)
    methods = ("lerp", "spline", "ebd")
    fillers = {m: build_method(m).clean for m in methods}
    out = []
    for corruption in gap_bins_module.TEST:
        filled = gap_bins_module.fill_clips(name, clips, corruption, repeats, fillers)
        for row in gap_bins_module.bin_errors(filled, methods):
            for method in methods:
                head = {"corpus": name, "corruption": corruption, "method": method, "bin": row["bin"]}
                out.append({**head, "gaps": row["gaps"], "rms_deg": row[method]})
        print(f"bins {name} {corruption}: {len(clips)} clips x {repeats}", flush=True)
    return out


def long_clip(n_frames: int) -> Motion:
    """``n_frames`` of bandai2 fold-0 test clips, each played forth and back (timing and memory only)."""
    test = load_corpus("bandai2", progress=False).split(0)[2][:40]
    ch = np.concatenate([np.concatenate([m.channels, m.channels[::-1]]) for m in test])
    return test[0].with_channels(np.tile(ch, (int(np.ceil(n_frames / len(ch))), 1))[:n_frames])


def speed(methods: Sequence[str], repeats: int) -> dict:
    """Offline frames/s (median of ``repeats``) and 300k-frame peak RSS per method."""
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
        "rss_300k": {m: rss_child(m) for m in methods},
    }


#: Streams pushed together in the ``EBFStreams`` timing.
LOCKSTEP_STREAMS = 8


def push_times(pushes: dict, frames: dict, skip: int, rounds: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """CPU (``time.thread_time_ns``) and wall milliseconds of each call ``pushes[key](frame)`` over
    ``frames[key] [N, ...]``, the first ``skip`` (the first window, run by the torch modules) left out. The keys
    take turns in ``rounds`` rounds of ``N / rounds`` frames each, so that they share the machine's changing
    load."""
    n = len(next(iter(frames.values())))
    times = {k: (np.zeros(n), np.zeros(n)) for k in pushes}
    for chunk in np.array_split(np.arange(n), rounds):
        for key, push in pushes.items():
            cpu, wall = times[key]
            for i in chunk:
                c0, w0 = time.thread_time_ns(), time.perf_counter_ns()
                push(frames[key][i])
                cpu[i], wall[i] = time.thread_time_ns() - c0, time.perf_counter_ns() - w0
    return {k: (cpu[skip:] / 1e6, wall[skip:] / 1e6) for k, (cpu, wall) in times.items()}


def _percentiles(cpu_ms: np.ndarray, wall_ms: np.ndarray, per: int = 1) -> dict:
    """p50/p99 of CPU and wall milliseconds, divided by ``per`` (streams per push)."""
    out = {"pushes": len(cpu_ms), "streams": per}
    for key, ms in (("cpu", cpu_ms), ("wall", wall_ms)):
        out |= {f"{key}_p50_ms": float(np.median(ms)) / per, f"{key}_p99_ms": float(np.percentile(ms, 99)) / per}
    return out


def streaming(clip: Motion, methods: Sequence[str], n_frames: int, rounds: int = 6) -> dict:
    """Per-frame cost of streaming each shipped EBF method on ``n_frames`` of angular-0.5 noise: CPU time
    (``time.thread_time_ns``, what the machine's other load least disturbs) and wall time per
    ``EBFStream.push``, p50 and p99 over the pushes after the first window, for each kernel (``numpy``;
    ``onnx`` when installed) and per stream of ``LOCKSTEP_STREAMS`` streams pushed together (``EBFStreams``:
    one push's time ÷ the streams), taking turns in ``rounds`` rounds (``push_times``), with the load average
    before and after."""
    from mocapnet.nn import onnx_kernel
    from mocapnet.nn.checkpoints import shipped_checkpoint
    from mocapnet.nn.infer import load_model
    from mocapnet.nn.stream import EBFStream, EBFStreams

    noisy, _ = corrupt_motion(clip, "angular-0.5", np.random.default_rng(1))
    frames = noisy[:n_frames]
    n = LOCKSTEP_STREAMS
    batch = np.stack([np.roll(frames, 7 * i, axis=0) for i in range(n)], axis=1)  # [N, n, C]
    backends = ["numpy"] + (["onnx"] if onnx_kernel.available() else [])
    out: dict = {"load_before": list(os.getloadavg()), "rounds": rounds}
    for name in methods:
        model = load_model(shipped_checkpoint(name, clip.skeleton))
        pushes = {b: EBFStream(model, clip.skeleton, clip.fps, backend=b).push for b in backends}
        pushes[f"numpy x{n}"] = EBFStreams(model, clip.skeleton, clip.fps, n).push
        inputs = {key: batch if key.endswith(f"x{n}") else frames for key in pushes}
        times = push_times(pushes, inputs, 2 * model.hparams.half + 2, rounds)
        out[name] = {key: _percentiles(*t, per=n if key.endswith(f"x{n}") else 1) for key, t in times.items()}
    out["load_after"] = list(os.getloadavg())
    return out


def streaming_quality(
    checkpoint: str, name: str, corruptions: Sequence[str], n_clips: int | None, split: str = "val"
) -> list[dict]:
    """What streaming costs in quality: mean over clips of the per-clip RMS angle error (degrees) of windowed
    mode (whole-clip statistics) and of ``EBFStream`` (for a ``norm="clip"`` network: running statistics of
    the frames seen so far), on each corruption, 1 repeat."""
    from mocapnet.nn.infer import clean_channels, load_model
    from mocapnet.nn.stream import EBFStream

    model = load_model(checkpoint)
    _, clips, _ = split_clips(name, split, n_clips)
    out = []
    for corruption in corruptions:
        errors: dict[str, list[float]] = {"windowed": [], "stream": []}
        for motion in clips:
            rng = np.random.default_rng(seed_for(name, motion.name, 0, corruption))
            noisy, mask = corrupt_motion(motion, corruption, rng)
            windowed = clean_channels(model, noisy, mask, motion.skeleton, motion.fps, "windowed")
            stream = EBFStream(model, motion.skeleton, motion.fps)
            frames = [f for row in noisy for _, f in stream.push(row)] + [f for _, f in stream.flush()]
            for key, cleaned in (("windowed", windowed), ("stream", np.stack(frames))):
                errors[key].append(angle_err_deg(cleaned, motion.channels, motion.skeleton.scored_mask))
        row = {"corpus": name, "split": split, "corruption": corruption, "clips": len(clips)}
        out.append(row | {f"{k}_deg": float(np.mean(v)) for k, v in errors.items()})
    return out


def rss_child(method: str) -> dict:
    """Peak RSS (MB) of a fresh process cleaning 300,000 frames with ``method`` (``rss_run``)."""
    cmd = [sys.executable, "-m", "mocapnet.evaluate.neural_bench", method]
    return json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.splitlines()[-1])


def rss_run(method: str) -> None:
    """Print as JSON the peak RSS (MB) of cleaning a 300,000-frame clip with ``method`` in this process."""
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
    """The results file: provenance, the quality table, the gap-length bins and the speed table."""
    lines = provenance_header("Learned cleaners (EBF variants, EBD): quality across corpora and speed", result)
    if result.get("quality"):
        lines += markdown_table(
            ("corpus", "split", "corruption", "clips × repeats", "method", "headline °", "ratio", "frames/s"),
            (
                (e["corpus"], e.get("split", "test"), e["corruption"], f"{e['clips']} × {e['repeats']}", e["method"])
                + (f"{fmt(e[e['ratio_of']])} ({e['ratio_of'].removesuffix('_deg')})", fmt(e["ratio"]))
                + (f"{e['frames_per_s']:,.0f}",)
                for e in result["quality"]
            ),
        )
    if result.get("selection"):
        lines += ["", f"Selection score (mean ratio over {', '.join(SELECTION)}; lowest wins):", ""]
        lines += markdown_table(("method", "score"), ((m, fmt(s)) for m, s in result["selection"].items()))
    if result.get("stream_quality"):
        lines += ["", "Streaming cost: mean per-clip RMS error °, windowed mode vs EBFStream (1 repeat):", ""]
        lines += markdown_table(
            ("corpus", "split", "corruption", "clips", "windowed °", "EBFStream °"),
            (
                (r["corpus"], r["split"], r["corruption"], r["clips"], fmt(r["windowed_deg"]), fmt(r["stream_deg"]))
                for r in result["stream_quality"]
            ),
        )
    if result.get("gap_bins"):
        lines += ["", "EBD gap error per gap length (frames), RMS °:", ""]
        by: dict[tuple, dict] = {}
        for b in result["gap_bins"]:
            by.setdefault((b["corpus"], b["corruption"], b["bin"]), {})[b["method"]] = b
        lines += markdown_table(
            ("corpus", "corruption", "bin", "gaps", "lerp", "spline", "ebd"),
            (
                (*key, m["lerp"]["gaps"], *(fmt(m[k]["rms_deg"]) for k in ("lerp", "spline", "ebd")))
                for key, m in by.items()
                if m["lerp"]["gaps"]
            ),
        )
    if result.get("speed"):
        sp = result["speed"]
        lines += [
            "",
            f"Speed, 1 thread: offline {sp['offline_frames']:,}-frame bandai2 clip (median), 300,000-frame "
            "clean peak RSS (fresh process):",
            "",
        ]
        rows = []
        for m, o in sp["offline"].items():
            r = sp["rss_300k"].get(m)
            rss = (f"{r['peak_mb']:.0f}", f"{r['seconds']:.1f}") if r else ("—", "—")
            rows.append((m, f"{o['frames_per_s']:,.0f}", *rss))
        lines += markdown_table(("method", "offline frames/s", "300k peak RSS MB", "300k s"), rows)
    if result.get("streaming"):
        lines += ["", *streaming_markdown(result["streaming"], result.get("streaming_run"))]
    return "\n".join(lines) + "\n"


def streaming_markdown(st: dict, run: dict | None = None) -> list[str]:
    """The streaming table of ``streaming``'s result; ``run``: the provenance of a run that redid only it."""
    load = ", ".join(f"{x:.1f}" for x in st["load_before"]) + " → " + ", ".join(f"{x:.1f}" for x in st["load_after"])
    rerun = [f"Streaming rerun alone: `{run['command']}` at `{run['git_commit']}`.", ""] if run else []
    lines = rerun + [
        f"Streaming, 1 thread: time per frame of EBFStream.push after the first window (load average {load}); "
        f"CPU = time.thread_time_ns; kernels taking turns in {st.get('rounds', 1)} rounds; `numpy xN`: N streams "
        "pushed together (EBFStreams), per stream:",
        "",
    ]
    rows = [
        (
            m,
            kernel,
            f"{r['pushes']:,}",
            *(f"{r[k]:.3f}" for k in ("cpu_p50_ms", "cpu_p99_ms", "wall_p50_ms", "wall_p99_ms")),
        )
        for m, kernels in st.items()
        if isinstance(kernels, dict)
        for kernel, r in kernels.items()
    ]
    return lines + markdown_table(
        ("method", "kernel", "pushes", "CPU p50 ms", "CPU p99 ms", "wall p50 ms", "wall p99 ms"), rows
    )


if __name__ == "__main__":
    rss_run(sys.argv[1])
