"""Benchmark the shipped learned cleaners: quality against the baselines and speed on this machine.

    python scripts/bench_neural.py                       # everything, writes benchmarks/results/neural.{json,md}
    python scripts/bench_neural.py --repeats 1 --limit 50 --out /tmp/neural   # a quick look

Quality: the harness (``mocapnet.evaluate.harness.evaluate_angles``) on bandai2 fold-0 test clips
(angular-0.5, noise+gaps, gaps-long, gaps) and on the test segment (last 15 %) of the CMU 120 fps clip;
errors are means over (clip, repeat) of per-clip RMS (PROTOCOL.md), ratios divide by the best Gaussian
(angular noise) or by lerp / lerp+gaussian-58ms (gaps).

Speed (torch threads = ``--threads``): offline cleaning of a 10,000-frame clip (sequence and windowed mode,
and the Gaussian baseline, each the median of ``--timing-repeats`` runs, gap filling and features included);
streaming per-frame latency of EBF in windowed mode (``EBFStream.push``) against a streaming Gaussian that
smooths the same 31-frame buffer; training frames/s of the bandai2 EBF configuration against the Gaussian
baseline's own training (``gaussian-tuned``: choosing σ per channel on training clips), with and without
jemalloc preloaded when ``/usr/lib/x86_64-linux-gnu/libjemalloc.so.2`` exists.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from mocapnet.corpus import load_corpus
from mocapnet.corrupt import corrupt_motion
from mocapnet.evaluate.harness import Evaluation, evaluate_angles
from mocapnet.evaluate.report import summarize
from mocapnet.methods.baselines import gaussian_smooth, tune_sigmas
from mocapnet.methods.registry import build_method
from mocapnet.motion import Motion

ROOT = Path(__file__).resolve().parents[1]
JEMALLOC = Path("/usr/lib/x86_64-linux-gnu/libjemalloc.so.2")
QUALITY = {
    "angular-0.5": ["noisy", "gaussian-58ms", "gaussian-125ms", "ebf", "ebf:mode=windowed", "bf", "nn"],
    "noise+gaps": ["lerp", "lerp+gaussian-58ms", "ebf", "ebd+ebf"],
    "gaps-long": ["lerp", "ebd", "ebd:mode=windowed"],
    "gaps": ["lerp", "ebd"],
}
CMU_QUALITY = {
    "angular-0.5": ["noisy", "gaussian-58ms", "gaussian-125ms", "ebf", "ebf:mode=windowed"],
    "noise+gaps": ["lerp", "lerp+gaussian-58ms", "ebf", "ebd+ebf"],
    "gaps-long": ["lerp", "ebd"],
}


def available_methods(methods: list[str], motion: Motion, given: dict[str, str]) -> list[str]:
    """The methods that can run on ``motion``'s skeleton: baselines, methods with a checkpoint in ``given``
    (name → path, written ``name=path``) and those with a shipped checkpoint."""
    from mocapnet.nn.checkpoints import shipped_checkpoint

    kept = []
    for text in methods:
        if text in given:
            kept.append(f"{text}={given[text]}")
            continue
        names = text.split(":")[0].split("+")
        try:
            for name in names:
                if name in ("ebf", "ebd", "bf", "nn"):
                    shipped_checkpoint(name, motion.skeleton)
        except LookupError:
            continue
        kept.append(text)
    return kept


def quality(
    corpus_name: str, clips: list[Motion], train: list[Motion], table: dict, repeats: int, given: dict[str, str]
) -> list[dict]:
    """Summaries (``report.summarize``) per corruption."""
    corpus = load_corpus(corpus_name, progress=False)
    out = []
    for corruption, methods in table.items():
        wanted = available_methods(methods, clips[0], given)
        start = time.perf_counter()
        rows, skipped = evaluate_angles(corpus, clips, train, corruption, wanted, repeats, progress=False)
        ev = Evaluation(corpus_name, corruption, "angles", wanted, rows, skipped, 0, repeats)
        for entry in summarize(ev):
            entry.update(corpus=corpus_name, corruption=corruption, clips=len(clips), repeats=repeats)
            out.append(entry)
        print(
            f"{corpus_name} {corruption}: {len(clips)} clips × {repeats} in {time.perf_counter() - start:.0f} s",
            flush=True,
        )
    return out


def long_clip(clips: list[Motion], n_frames: int) -> Motion:
    """``n_frames`` frames made of consecutive clips (timing only: the joins are discontinuous)."""
    ch = np.concatenate([m.channels for m in clips], axis=0)
    reps = int(np.ceil(n_frames / len(ch)))
    return clips[0].with_channels(np.tile(ch, (reps, 1))[:n_frames])


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def offline_speed(clip: Motion, repeats: int) -> dict:
    """Frames/s of cleaning ``clip`` (angular-0.5) by EBF in both modes and by the Gaussian baseline."""
    noisy_ch, mask = corrupt_motion(clip, "angular-0.5", np.random.default_rng(0))
    noisy = clip.with_channels(noisy_ch)
    out = {"frames": clip.n_frames}
    for text in ("gaussian-58ms", "ebf", "ebf:mode=windowed"):
        clean = build_method(text).clean
        clean(noisy, mask)  # warm-up (loads the checkpoint)
        seconds = median_time(lambda c=clean: c(noisy, mask), repeats)
        out[text] = {"seconds": seconds, "frames_per_s": clip.n_frames / seconds}
    return out


def streaming_latency(clip: Motion, n_frames: int, threads: int) -> dict:
    """Per-frame latency of ``EBFStream.push`` (after the first window) and of a streaming Gaussian, with
    ``threads`` torch threads (one stream per thread is the natural deployment: batch-1 steps gain nothing
    from more)."""
    import torch

    from mocapnet.nn.checkpoints import shipped_checkpoint
    from mocapnet.nn.infer import EBFStream, load_model

    previous_threads = torch.get_num_threads()
    torch.set_num_threads(threads)

    model = load_model(shipped_checkpoint("ebf", clip.skeleton))
    noisy_ch, _ = corrupt_motion(clip, "angular-0.5", np.random.default_rng(1))
    frames = noisy_ch[:n_frames]
    stream = EBFStream(model, clip.skeleton, clip.fps)
    width = 2 * model.hparams.half + 1
    ebf_times, gauss_times = [], []
    scored = clip.skeleton.scored_mask
    for t, frame in enumerate(frames):
        start = time.perf_counter()
        stream.push(frame)
        elapsed = time.perf_counter() - start
        if t >= width:
            ebf_times.append(elapsed)
            window = frames[t - width + 1 : t + 1]
            start = time.perf_counter()
            result = frame.copy()
            result[scored] = gaussian_smooth(window[:, scored], 0.058, clip.fps)[width // 2]
            gauss_times.append(time.perf_counter() - start)

    def stats(times: list[float]) -> dict:
        ms = np.asarray(times) * 1e3
        return {"median_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99)), "n": len(ms)}

    torch.set_num_threads(previous_threads)
    return {
        "ebf_windowed": stats(ebf_times),
        "gaussian-58ms": stats(gauss_times),
        "lookahead_frames": width // 2,
        "torch_threads": threads,
    }


def training_speed(steps: int) -> dict:
    """Training frames/s of the bandai2_ebf configuration (data sampling and corruption included) and the
    Gaussian baseline's tuning frames/s on the same training clips."""
    import torch
    from hydra import compose, initialize_config_dir

    from mocapnet.nn.train import build

    with initialize_config_dir(config_dir=str(ROOT / "mocapnet" / "conf"), version_base="1.3"):
        cfg = compose("train", overrides=["experiment=bandai2_ebf", "name=bench", "runs_root=/tmp"])
    data, model = build(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    rng = np.random.default_rng(0)
    model.train()
    frames, seconds = 0, 0.0
    for step in range(steps + 3):
        start = time.perf_counter()
        batch = data.sample_batch(rng)
        sq, sel = model.loss_terms(batch, model.predict_batch(batch))
        loss = (sq * sel).sum() / sel.sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step >= 3:  # warm-up steps excluded
            seconds += time.perf_counter() - start
            frames += batch["clean"].shape[0] * batch["clean"].shape[1]
    train, _, _ = load_corpus("bandai2", progress=False).split(0)
    clips = train[:: max(1, len(train) // 200)][:200]
    start = time.perf_counter()
    tune_sigmas(clips, "angular-0.5", "bandai2", max_clips=len(clips))
    tune_s = time.perf_counter() - start
    return {
        "ebf_train_frames_per_s": frames / seconds,
        "ebf_steps": steps,
        "batch": f"{cfg.data.batch_size} crops of {cfg.data.crop_min}-{cfg.data.crop_max} frames "
        f"({cfg.data.window_fraction:.0%} of batches {cfg.data.window_frames})",
        "gaussian_tuned_frames_per_s": sum(m.n_frames for m in clips) / tune_s,
        "ld_preload": os.environ.get("LD_PRELOAD", ""),
    }


def training_speed_subprocess(steps: int, threads: int, preload: str | None) -> dict:
    env = dict(os.environ)
    env.pop("LD_PRELOAD", None)
    if preload:
        env["LD_PRELOAD"] = preload
    cmd = [sys.executable, __file__, "--train-speed-only", str(steps), "--threads", str(threads)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def machine(threads: int) -> dict:
    import torch

    cpu = next((ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name")), "?")
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "load_average_at_start": os.getloadavg(),
        "torch": torch.__version__,
        "torch_threads": threads,
        "python": platform.python_version(),
        "git_commit": commit,
    }


def markdown(result: dict) -> str:
    lines = [
        "# Learned cleaners (EBF / EBD): quality and speed",
        "",
        f"Command: `{result['command']}`  ",
        *(
            [f"Quality figures from an earlier run of: `{result['quality_command']}`  "]
            if "quality_command" in result
            else []
        ),
        f"Git commit: `{result['machine']['git_commit']}`  ",
        f"Machine: {result['machine']['cpu']}, {result['machine']['cores']} cores, torch "
        f"{result['machine']['torch']} with {result['machine']['torch_threads']} threads; load average at start "
        f"{', '.join(f'{x:.1f}' for x in result['machine']['load_average_at_start'])} (shared machine).  ",
        "Checkpoints: the shipped ones (`mocapnet/checkpoints/index.json`).",
        "",
        "## Quality",
        "",
        "Mean over (clip, repeat) of per-clip RMS errors in degrees (PROTOCOL.md). Ratio: error ÷ best Gaussian "
        "(angular noise, on angle_err) or ÷ best of lerp / lerp+gaussian-58ms (gaps, on gap_err). bandai2: fold-0 "
        "test clips; cmu120: the last 15 % of the clip (the first 70 % trained the model, the next 15 % selected "
        "it).",
        "",
        "| corpus | corruption | clips × repeats | method | angle_err_deg | gap_err_deg | rot_err_deg | ratio |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for e in result["quality"]:
        lines.append(
            f"| {e['corpus']} | {e['corruption']} | {e['clips']} × {e['repeats']} | {e['method']} | "
            f"{e['angle_err_deg']:.3f} | {e['gap_err_deg']:.3f} | {e['rot_err_deg']:.3f} | {e['ratio']:.3f} |"
        )
    off = result["speed"]["offline"]
    lines += [
        "",
        "## Speed",
        "",
        f"Offline cleaning of a {off['frames']:,}-frame bandai2 clip (angular-0.5; gap filling and features "
        "included), median of runs:",
        "",
        "| method | seconds | frames/s | × Gaussian time |",
        "|---|---|---|---|",
    ]
    g = off["gaussian-58ms"]["seconds"]
    for key in ("gaussian-58ms", "ebf", "ebf:mode=windowed"):
        lines.append(
            f"| {key} | {off[key]['seconds']:.4f} | {off[key]['frames_per_s']:,.0f} | {off[key]['seconds'] / g:.1f} |"
        )
    st = result["speed"]["streaming"]
    lines += [
        "",
        f"Streaming (windowed EBF, lookahead {st['lookahead_frames']} frames, {st['torch_threads']} torch "
        f"thread), per-frame latency over {st['ebf_windowed']['n']} frames:",
        "",
        "| method | median ms | p99 ms |",
        "|---|---|---|",
        f"| EBFStream.push | {st['ebf_windowed']['median_ms']:.3f} | {st['ebf_windowed']['p99_ms']:.3f} |",
        f"| Gaussian 58 ms on the same 31-frame buffer | {st['gaussian-58ms']['median_ms']:.3f} | "
        f"{st['gaussian-58ms']['p99_ms']:.3f} |",
        "",
        "Training (bandai2_ebf configuration, one process):",
        "",
        "| run | EBF training frames/s | Gaussian-tuned tuning frames/s |",
        "|---|---|---|",
    ]
    for key, tr in result["speed"]["training"].items():
        lines.append(f"| {key} | {tr['ebf_train_frames_per_s']:,.0f} | {tr['gaussian_tuned_frames_per_s']:,.0f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="corruption repeats per clip (PROTOCOL: 5)")
    parser.add_argument("--limit", type=int, default=None, help="score only the first N test clips")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    parser.add_argument("--timing-repeats", type=int, default=5)
    parser.add_argument("--stream-threads", type=int, default=1, help="torch threads for the streaming latency")
    parser.add_argument("--train-steps", type=int, default=20)
    parser.add_argument(
        "--skip-quality", action="store_true", help="time only; keep the quality section of an existing results file"
    )
    parser.add_argument(
        "--method-checkpoint",
        action="append",
        default=[],
        metavar="NAME=PATH",
        help="score bandai2 method NAME (e.g. nn) from PATH instead of a shipped checkpoint",
    )
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "neural"), help="path without suffix")
    parser.add_argument("--train-speed-only", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()

    import torch

    torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)
    if args.train_speed_only is not None:
        print(json.dumps(training_speed(args.train_speed_only)))
        return
    result = {
        "command": "python " + " ".join([Path(sys.argv[0]).as_posix()] + sys.argv[1:]),
        "machine": machine(args.threads),
    }
    bandai = load_corpus("bandai2", progress=False)
    train, _, test = bandai.split(0)
    test = test[: args.limit] if args.limit else test
    out = Path(args.out)
    previous = json.loads(out.with_suffix(".json").read_text()) if out.with_suffix(".json").exists() else {}
    if args.skip_quality and "quality" in previous:  # keep the earlier quality run and its command
        result["quality"] = previous["quality"]
        result["quality_command"] = previous.get("quality_command", previous["command"])
    if not args.skip_quality:
        from mocapnet.nn.data import corpus_splits

        given = dict(item.split("=", 1) for item in args.method_checkpoint)
        result["quality"] = quality("bandai2", test, train, QUALITY, args.repeats, given)
        cmu_train, _, cmu_test = corpus_splits("cmu120", 0)
        result["quality"] += quality("cmu120", cmu_test, cmu_train, CMU_QUALITY, args.repeats, {})
    clip = long_clip(test, 10_000)
    result["speed"] = {
        "offline": offline_speed(clip, args.timing_repeats),
        "streaming": streaming_latency(clip, 3000, args.stream_threads),
        "training": {"default allocator": training_speed_subprocess(args.train_steps, args.threads, None)},
    }
    if JEMALLOC.exists():
        result["speed"]["training"]["jemalloc (LD_PRELOAD)"] = training_speed_subprocess(
            args.train_steps, args.threads, str(JEMALLOC)
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    if "quality" in result:
        out.with_suffix(".md").write_text(markdown(result))
    print(json.dumps(result["speed"], indent=1, default=float))


if __name__ == "__main__":
    main()
