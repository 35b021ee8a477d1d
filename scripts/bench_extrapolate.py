"""Benchmark of the streaming extrapolator: gap-filling error vs gap length, exactness check and latency.

Drops single markers (``marker-gap:S``) and whole limbs (``segment-gap:SEG:S``, SEG in left/right arm/leg)
for S = 0.1, 0.25, 0.5, 1 and 2 s at random onsets (seeded with ``seed_for``) from complete C3D files and
from the joint positions of a CMU BVH clip, and scores the mean distance (cm) of the filled points to the
truth over the missing samples, for:

* the causal, real-time methods: ``hold``, ``extrapolate-linear``, ``extrapolate-circular``,
  ``extrapolate`` (blend) and ``extrapolate+cm`` (blend + constraint matrix);
* offline references that also see the data after the gap: ``lerp`` (``np.interp`` over the gap) and the
  PyPI package ``gapfill``: its B-spline fill and its rigid-body fill from a cluster of three markers (same
  limb segment, or the three most rigid markers visible through the gap). Their fill fraction is reported.

Also checks that a point on an exact circle / line is predicted to 1e-6 cm for 2 s from its own past, and
times ``Extrapolator.push`` per frame with 40 markers (``hold`` measured in the same run as the baseline).

Writes ``benchmarks/results/extrapolate.json``, ``extrapolate.md`` and ``extrapolate_error_vs_gap.png``.

Example::

    nice -n 10 .venv/bin/python scripts/bench_extrapolate.py            # full run
    .venv/bin/python scripts/bench_extrapolate.py --quick --out /tmp/x  # small run
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shlex
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mocapnet.corpus import data_root  # noqa: E402
from mocapnet.corrupt import corrupt_markers, gap_mask, motion_markers, point_gap_mask, seed_for  # noqa: E402
from mocapnet.evaluate.benchmark import (  # noqa: E402
    gapfill_rigid_body,
    gapfill_spline,
    gapfill_spline_as_shipped,
    git_commit,
    numpy_int_alias,
)
from mocapnet.io.atomic import atomic_output  # noqa: E402
from mocapnet.io.bvh import read_bvh  # noqa: E402
from mocapnet.io.c3d import read_c3d  # noqa: E402
from mocapnet.methods import build_method  # noqa: E402
from mocapnet.methods.baselines import lerp_fill  # noqa: E402
from mocapnet.methods.extrapolate import Extrapolator  # noqa: E402
from mocapnet.motion import Markers  # noqa: E402
from mocapnet.segments import marker_segment, skeleton_segment  # noqa: E402

GAP_SECONDS = (0.1, 0.25, 0.5, 1.0, 2.0)
SEGMENTS = ("left-arm", "right-arm", "left-leg", "right-leg")
C3D_FILES = (
    "c3d/hdm05/HDM_bd_01-02_01_120.c3d",
    "c3d/hdm05/HDM_bd_05-01_01_120.c3d",
    "c3d/hdm05/HDM_mm_01-02_03_120.c3d",
    "c3d/cmu/02_01.c3d",
    "c3d/cmu/85_02.c3d",
    "c3d/kineticstoolkit/kinematics_tennis_serve.c3d",
    "c3d/pycgm/Movement_trial.c3d",
)
BVH_FILES = ("bvh/cmu_cgspeed/01_01.bvh.gz",)
QUICK_FILES = ("c3d/hdm05/HDM_bd_01-02_01_120.c3d", "c3d/kineticstoolkit/kinematics_tennis_serve.c3d")
STREAMING = ("hold", "extrapolate-linear", "extrapolate-circular", "extrapolate", "extrapolate+cm")
OFFLINE = ("lerp", "gapfill-spline", "gapfill-rbt-segment", "gapfill-rbt-rigid3")
METHODS = STREAMING + OFFLINE
LATENCY_MODES = (
    ("hold", "hold", False),
    ("extrapolate-linear", "linear", False),
    ("extrapolate", "blend", False),
    ("extrapolate+cm", "blend", True),
)
# Plug-in-Gait model outputs stored as points (bone origins/axes such as PELO, LFEA) and centre-of-mass points.
_MODEL_POINT = re.compile(r"^(PEL|HED|TRX|[LR](FE|TI|FO|TO|CL|HU|RA|HN))[OALP]$|^Centre", re.IGNORECASE)


@dataclass
class Clip:
    """A clean clip and how to corrupt it."""

    corpus: str
    file: str
    markers: Markers
    segment_tracks: Callable[[str], list[int]]
    candidates: list[int]  # tracks a single-marker gap may pick


def physical_markers(markers: Markers) -> Markers:
    """Drop Plug-in-Gait model-output points (``PELO``, ``LFEA``, …, ``CentreOfMass``) kept by ``read_c3d``."""
    keep = [i for i, lab in enumerate(markers.labels) if not _MODEL_POINT.match(lab.rsplit(":", 1)[-1])]
    return markers.select(keep)


def load_clips(root: Path, files: tuple[str, ...]) -> list[Clip]:
    clips = []
    for rel in files:
        path = root / rel
        corpus = str(Path(rel).parent)
        if rel.startswith("bvh/"):
            motion = read_bvh(path)
            clips.append(
                Clip(
                    corpus,
                    path.name,
                    motion_markers(motion),
                    lambda seg, sk=motion.skeleton: skeleton_segment(sk, seg),
                    [int(j) for j in motion.skeleton.scored_joints],
                )
            )
        else:
            markers = physical_markers(read_c3d(path))
            clips.append(
                Clip(
                    corpus,
                    path.name,
                    markers,
                    lambda seg, lab=markers.labels: marker_segment(lab, seg),
                    list(np.flatnonzero(markers.visible.all(axis=0))),
                )
            )
    return clips


def corrupt(clip: Clip, corruption: str, repeat: int) -> Markers:
    """Corrupted copy of the clip: C3D through ``corrupt_markers``; BVH joints with the skeleton's limbs
    (``corrupt_markers`` only knows Plug-in-Gait labels) and its scored joints as single-gap candidates."""
    rng = np.random.default_rng(seed_for(clip.corpus, clip.file, repeat, corruption))
    m = clip.markers
    if clip.corpus.startswith("c3d"):
        return corrupt_markers(m, corruption, rng)
    mask = point_gap_mask(corruption, m.n_frames, m.fps, rng, clip.segment_tracks, m.n_markers, clip.candidates, m.name)
    return Markers(m.points, m.visible & ~mask, m.labels, m.fps, m.name)


def distance_spread(points: np.ndarray, target: int) -> np.ndarray:
    """Std over time of the distance from ``target`` to every marker, ``[M]`` cm (NaN frames skipped; inf
    where never seen together, and for the target itself)."""
    dist = np.linalg.norm(points - points[:, [target]], axis=2)
    count = np.isfinite(dist).sum(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spread = np.nanstd(dist, axis=0)
    spread[(count < 2) | ~np.isfinite(spread)] = np.inf
    spread[target] = np.inf
    return spread


def rbt_cluster(noisy: Markers, target: int, pool: list[int]) -> list[int]:
    """The three markers of ``pool`` whose distance to ``target`` varies least (most rigid)."""
    spread = distance_spread(noisy.points, target)
    pool = [j for j in pool if j != target and np.isfinite(spread[j])]
    return sorted(pool, key=lambda j: spread[j])[:3]


def limb_of(clip: Clip, marker: int) -> list[int]:
    """The markers of the limb segment holding ``marker``; every marker when it is in none."""
    for seg in SEGMENTS:
        tracks = clip.segment_tracks(seg)
        if marker in tracks:
            return tracks
    return list(range(clip.markers.n_markers))


def gapfill_fills(clip: Clip, noisy: Markers) -> dict[str, np.ndarray]:
    """``[T, M, 3]`` fills (NaN where gapfill left a sample missing) of the three gapfill variants."""
    missing = np.flatnonzero((~noisy.visible).any(axis=0))
    out = {name: noisy.points.copy() for name in ("gapfill-spline", "gapfill-rbt-segment", "gapfill-rbt-rigid3")}
    with numpy_int_alias():
        for i in missing:
            gap = ~noisy.visible[:, i]
            through_gap = [j for j in range(noisy.n_markers) if noisy.visible[gap, j].all()]
            for name, cluster in (
                ("gapfill-rbt-segment", rbt_cluster(noisy, i, limb_of(clip, i))),
                ("gapfill-rbt-rigid3", rbt_cluster(noisy, i, through_gap)),
            ):
                if len(cluster) == 3:
                    out[name][:, i] = gapfill_rigid_body(noisy.points, i, cluster)
            out["gapfill-spline"][:, i] = gapfill_spline(noisy.points, i)
    return out


def lerp_points(noisy: Markers) -> np.ndarray:
    """Offline linear interpolation over every gap, ``[T, M, 3]`` cm."""
    t, m = noisy.visible.shape
    mask = np.repeat(~noisy.visible, 3, axis=1)
    return lerp_fill(noisy.points.reshape(t, m * 3), mask).reshape(t, m, 3)


def score_clip(clip: Clip, corruption: str, repeat: int, acc: dict, per_file: dict) -> None:
    """Fill one corrupted copy with every method and add its errors to the accumulators."""
    noisy = corrupt(clip, corruption, repeat)
    truth = clip.markers.points
    miss = ~noisy.visible
    end = int(np.flatnonzero(miss.any(axis=1)).max()) + 1  # the streaming methods are causal: stop at gap end
    head = Markers(noisy.points[:end], noisy.visible[:end], noisy.labels, noisy.fps, noisy.name)
    fills = {name: build_method(name).clean(head) for name in STREAMING}
    fills["lerp"] = lerp_points(noisy)[:end]
    fills.update({k: v[:end] for k, v in gapfill_fills(clip, noisy).items()})
    kind = corruption.split(":")[0]
    seconds = float(corruption.split(":")[-1])
    for name, fill in fills.items():
        err = np.linalg.norm(fill[:end][miss[:end]] - truth[:end][miss[:end]], axis=1)
        done = np.isfinite(err)
        for table, key in ((acc, (source_of(clip), kind, seconds, name)), (per_file, (clip.file, kind, seconds, name))):
            entry = table.setdefault(key, [0.0, 0, 0])
            entry[0] += float(err[done].sum())
            entry[1] += int(done.sum())
            entry[2] += int(err.size)


def source_of(clip: Clip) -> str:
    return "bvh" if clip.corpus.startswith("bvh") else "c3d"


def corruptions() -> list[str]:
    out = [f"marker-gap:{s:g}" for s in GAP_SECONDS]
    out += [f"segment-gap:{seg}:{s:g}" for s in GAP_SECONDS for seg in SEGMENTS]
    return out


def synthetic_check(fps: float = 120.0, seconds: float = 2.0) -> dict:
    """Largest error (cm) over ``seconds`` of prediction for an exact circle and an exact line."""
    n_seen = int(fps)
    t = np.arange(n_seen + int(seconds * fps)) / fps
    e1 = np.array([1.0, 0.2, 0.1]) / np.linalg.norm([1.0, 0.2, 0.1])
    e2 = np.cross(e1, [0.3, 0.1, 1.0])
    e2 /= np.linalg.norm(e2)
    circle = np.array([3.0, -2.0, 50.0]) + 15.0 * (np.cos(2 * t)[:, None] * e1 + np.sin(2 * t)[:, None] * e2)
    line = np.array([1.0, 2.0, 3.0]) + t[:, None] * np.array([30.0, -10.0, 5.0])
    result = {
        "fps": fps,
        "seconds_predicted": seconds,
        "seen_frames": n_seen,
        "circle": "radius 15 cm, 2 rad/s, tilted plane",
        "line": "velocity (30, -10, 5) cm/s",
    }
    for name, traj, modes in (
        ("circle", circle, ("circular", "blend", "linear")),
        ("line", line, ("linear", "blend", "circular")),
    ):
        for mode in modes:
            ex = Extrapolator(["p"], fps, mode)
            out = np.array([ex.push(p[None], np.array([k < n_seen]))[0] for k, p in enumerate(traj)])
            result[f"{name}_{mode}_max_err_cm"] = float(np.abs(out[n_seen:] - traj[n_seen:]).max())
    return result


def latency(root: Path, n_markers: int = 40) -> dict:
    """Per-frame ``push`` time (µs) with ``n_markers`` markers under random occlusions (``gap_mask``)."""
    rel = C3D_FILES[0]
    markers = physical_markers(read_c3d(root / rel)).select(list(range(n_markers)))
    rng = np.random.default_rng(seed_for("latency", Path(rel).name, 0, "gaps"))
    visible = ~gap_mask(markers.n_frames, n_markers, markers.fps, rng)
    result: dict = {
        "file": rel,
        "markers": n_markers,
        "frames": markers.n_frames,
        "occlusion": "gap_mask: exponential gaps, mean 0.5 s, ~10% of each marker's frames",
        "missing_fraction": float((~visible).mean()),
        "mean_missing_per_frame": float((~visible).sum(axis=1).mean()),
        "frames_with_missing_fraction": float((~visible).any(axis=1).mean()),
        "methods": {},
    }
    result["load_average"] = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    # Methods take turns frame by frame, so load from other processes hits them alike. Wall time counts the
    # time the process waits for a core on a busy machine; thread CPU time does not.
    predictors = [Extrapolator(markers.labels, markers.fps, mode, cm) for _, mode, cm in LATENCY_MODES]
    wall = np.empty((len(predictors), markers.n_frames))
    cpu = np.empty_like(wall)
    for t in range(markers.n_frames):
        for k, ex in enumerate(predictors):
            start, start_cpu = time.perf_counter_ns(), time.thread_time_ns()
            ex.push(markers.points[t], visible[t])
            cpu[k, t] = (time.thread_time_ns() - start_cpu) / 1e3
            wall[k, t] = (time.perf_counter_ns() - start) / 1e3
    for k, (name, _, _) in enumerate(LATENCY_MODES):
        result["methods"][name] = {
            "median_us": float(np.median(wall[k])),
            "p99_us": float(np.percentile(wall[k], 99)),
            "max_us": float(wall[k].max()),
            "cpu_median_us": float(np.median(cpu[k])),
            "cpu_p99_us": float(np.percentile(cpu[k], 99)),
            "cpu_max_us": float(cpu[k].max()),
        }
    base = result["methods"]["hold"]
    for entry in result["methods"].values():
        for key in ("median_us", "p99_us", "cpu_median_us", "cpu_p99_us"):
            entry[key.replace("_us", "_ratio_to_hold")] = entry[key] / base[key]
    return result


def summarise(acc: dict, first: str = "source") -> list[dict]:
    """Rows of mean error and fill fraction from ``{(source or file, kind, gap s, method): [sum, filled, n]}``."""
    rows = []
    for (group, kind, seconds, method), (total, filled, missing) in sorted(acc.items()):
        rows.append(
            {
                first: group,
                "corruption": kind,
                "gap_s": seconds,
                "method": method,
                "mean_err_cm": total / filled if filled else None,
                "filled_samples": filled,
                "missing_samples": missing,
                "filled_fraction": filled / missing if missing else None,
            }
        )
    return rows


def _fmt(value: float | None, digits: int = 2) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def markdown(report: dict) -> str:
    rows = report["summary"]
    lines = [
        "# Streaming extrapolation benchmark (`mocapnet.methods.extrapolate`)",
        "",
        f"- command: `{report['command']}`",
        f"- git commit: `{report['git_commit']}`",
        f"- machine: {report['machine']}",
        f"- wall time: {report['wall_s']:.0f} s",
        f"- repeats (random onsets) per file and corruption: {report['repeats']}",
        f"- corruptions: `marker-gap:S` and `segment-gap:SEG:S`, SEG in {', '.join(SEGMENTS)}, "
        f"S in {', '.join(f'{s:g}' for s in GAP_SECONDS)} s; seeds `seed_for(corpus, file, repeat, corruption)`",
        "- metric: mean distance (cm) of the filled point to the truth over the missing samples (pooled over "
        "files, repeats and segments); in brackets the ratio to `lerp`",
        "- files (complete, no gaps of their own):",
    ]
    lines += [
        f"  - `{c['path']}`: {c['markers']} points, {c['frames']} frames at {c['fps']:g} Hz" for c in report["clips"]
    ]
    if report["skipped"]:
        lines.append(
            "- skipped (clip too short for the gap with 1 s visible on each side): "
            + ", ".join(
                sorted(
                    {
                        f"{s['file']} {s['corruption'].split(':')[0]} {s['corruption'].split(':')[-1]} s"
                        for s in report["skipped"]
                    }
                )
            )
        )
    lines += [
        "",
        "Causal, real-time methods see only the past; `lerp` and the `gapfill` functions are offline references",
        "that also use the data after the gap. `gapfill-*` errors are over the samples they filled; see the fill",
        "fraction table.",
    ]
    for source in ("c3d", "bvh"):
        for kind in ("marker-gap", "segment-gap"):
            sel = [r for r in rows if r["source"] == source and r["corruption"] == kind]
            if not sel:
                continue
            lines += [
                "",
                f"## {source.upper()} — `{kind}` (mean error, cm)",
                "",
                "| gap s | " + " | ".join(METHODS) + " |",
                "|---" * (len(METHODS) + 1) + "|",
            ]
            for s in GAP_SECONDS:
                cells = {r["method"]: r for r in sel if r["gap_s"] == s}
                if not cells:
                    continue
                ref = cells["lerp"]["mean_err_cm"]
                out = []
                for m in METHODS:
                    err = cells[m]["mean_err_cm"] if m in cells else None
                    ratio = f" ({err / ref:.2f})" if err is not None and ref else ""
                    out.append(_fmt(err) + ratio)
                lines.append(f"| {s:g} | " + " | ".join(out) + " |")
    lines += [
        "",
        "## gapfill: fraction of missing samples filled",
        "",
        "| source | corruption | gap s | " + " | ".join(OFFLINE[1:]) + " |",
        "|---" * (2 + len(OFFLINE)) + "|",
    ]
    for source in ("c3d", "bvh"):
        for kind in ("marker-gap", "segment-gap"):
            for s in GAP_SECONDS:
                key = (source, kind, s)
                cells = {r["method"]: r for r in rows if (r["source"], r["corruption"], r["gap_s"]) == key}
                if cells:
                    lines.append(
                        f"| {source} | {kind} | {s:g} | "
                        + " | ".join(_fmt(cells[m]["filled_fraction"], 3) for m in OFFLINE[1:])
                        + " |"
                    )
    lines += ["", f"gapfill {report['gapfill']['version']}: {report['gapfill']['note']}", ""]
    syn = report["synthetic"]
    lines += [
        "## Synthetic exactness check",
        "",
        f"A point seen for {syn['seen_frames']} frames at {syn['fps']:g} Hz, then predicted from its own past "
        f"for {syn['seconds_predicted']:g} s; largest error (cm). Circle: {syn['circle']}; line: {syn['line']}.",
        "",
        "| trajectory | mode | max error cm |",
        "|---|---|---|",
    ]
    for key, value in syn.items():
        if key.endswith("_max_err_cm"):
            shape, mode = key.split("_")[:2]
            lines.append(f"| {shape} | {mode} | {value:.3g} |")
    lat = report["latency"]
    lines += [
        "",
        "## Per-frame latency of `Extrapolator.push`",
        "",
        f"{lat['markers']} markers of `{lat['file']}`, {lat['frames']} frames, {lat['occlusion']} "
        f"(measured {100 * lat['missing_fraction']:.1f}% missing, {lat['mean_missing_per_frame']:.1f} markers "
        f"missing per frame on average). The methods take turns frame by frame in one process (single "
        f"thread); load average (1, 5, 15 min) just before timing: {lat['load_average']}.",
        "",
        "| method | clock | median µs | p99 µs | max µs | median / hold | p99 / hold |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, e in lat["methods"].items():
        for clock, pre in (("wall", ""), ("thread CPU", "cpu_")):
            lines.append(
                f"| {name} | {clock} | {e[pre + 'median_us']:.1f} | {e[pre + 'p99_us']:.1f} | "
                f"{e[pre + 'max_us']:.0f} | {e[pre + 'median_ratio_to_hold']:.1f} | "
                f"{e[pre + 'p99_ratio_to_hold']:.1f} |"
            )
    lines += ["", "Per-file errors are in `extrapolate.json` (`per_file`).", ""]
    return "\n".join(lines)


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = dict(zip(METHODS, plt.get_cmap("tab10").colors))
    sources = [src for src in ("c3d", "bvh") if any(r["source"] == src for r in report["summary"])]
    fig, axes = plt.subplots(len(sources), 2, figsize=(12, 1 + 4 * len(sources)), sharex=True, squeeze=False)
    for row, source in enumerate(sources):
        for col, kind in enumerate(("marker-gap", "segment-gap")):
            ax = axes[row, col]
            for method in METHODS:
                pts = [
                    (r["gap_s"], r["mean_err_cm"])
                    for r in report["summary"]
                    if (r["source"], r["corruption"], r["method"]) == (source, kind, method)
                    and r["mean_err_cm"] is not None
                ]
                if pts:
                    xs, ys = zip(*sorted(pts))
                    ax.plot(xs, ys, "--" if method in OFFLINE else "-", marker="o", color=colours[method], label=method)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xticks(GAP_SECONDS, [f"{s:g}" for s in GAP_SECONDS])
            ax.set_title(f"{source.upper()} — {kind}")
            ax.set_xlabel("gap length (s)")
            ax.set_ylabel("mean error over missing samples (cm)")
            ax.grid(True, which="both", alpha=0.3)
    handles = [plt.Line2D([], [], color=colours[m], ls="--" if m in OFFLINE else "-", marker="o") for m in METHODS]
    fig.legend(handles, METHODS, loc="lower center", ncol=5, fontsize=8)
    fig.suptitle("Streaming extrapolation (solid: causal) vs offline references (dashed)")
    fig.tight_layout(rect=(0, 0.06 * 2 / len(sources), 1, 1))
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example: nice -n 10 .venv/bin/python scripts/bench_extrapolate.py --quick",
    )
    parser.add_argument(
        "--data-root",
        type=Path,
        default=data_root(),
        help="shared data folder (default: $MOCAPNET_DATA or ../shared/data from the repo root)",
    )
    parser.add_argument(
        "--repeats", type=int, default=None, help="random onsets per file and corruption (default 20, 2 with --quick)"
    )
    parser.add_argument("--quick", action="store_true", help="two C3D files, 2 repeats: a small run")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results", help="output folder")
    args = parser.parse_args(argv)
    repeats = args.repeats or (2 if args.quick else 20)
    files = QUICK_FILES if args.quick else C3D_FILES + BVH_FILES
    missing = [f for f in files if not (args.data_root / f).exists()]
    if missing:
        print(f"error: data not found under {args.data_root}: {', '.join(missing)}", file=sys.stderr)
        return 2
    started = time.time()
    clips = load_clips(args.data_root, files)
    acc: dict = {}
    per_file: dict = {}
    skipped = []
    jobs = [(clip, corr, r) for clip in clips for corr in corruptions() for r in range(repeats)]
    for clip, corr, r in tqdm(jobs, desc="gaps", unit="gap"):
        try:
            score_clip(clip, corr, r, acc, per_file)
        except ValueError as exc:
            if "too short" not in str(exc):
                raise
            skipped.append({"file": clip.file, "corruption": corr, "repeat": r})
    lat = latency(args.data_root)
    import gapfill

    shipped = gapfill_spline_as_shipped()
    report = {
        "command": shlex.join(
            [
                os.path.relpath(sys.executable, REPO),
                os.path.relpath(sys.argv[0], REPO),
                *(sys.argv[1:] if argv is None else argv),
            ]
        ),
        "git_commit": git_commit(),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs shared with other jobs, "
        f"process niceness {os.nice(0)}, Python {platform.python_version()}, NumPy {np.__version__}",
        "repeats": repeats,
        "gap_seconds": list(GAP_SECONDS),
        "segments": list(SEGMENTS),
        "methods": list(METHODS),
        "clips": [
            {
                "path": str(Path(c.corpus) / c.file),
                "markers": c.markers.n_markers,
                "frames": c.markers.n_frames,
                "fps": c.markers.fps,
            }
            for c in clips
        ],
        "skipped": skipped,
        "summary": summarise(acc),
        "per_file": summarise(per_file, "file"),
        "gapfill": {
            "version": gapfill.__version__,
            "without_np_int_alias": shipped,
            "note": (
                "fill_marker_gap_interp (spline) and fill_marker_gap_pattern call np.int, removed in NumPy "
                "1.24: as shipped they fail under this NumPy ("
                + shipped
                + "); this benchmark runs them with a temporary alias np.int = int. fill_marker_gap_rbt needs "
                "the three cluster markers visible through the whole gap and the target visible on both "
                "sides, so it fills nothing when the whole limb is missing (segment-gap with a same-segment "
                "cluster). gapfill-rbt-segment: the three markers of the target's limb (segments.py) whose "
                "distance to it varies least (every marker when the target is on no limb); "
                "gapfill-rbt-rigid3: the three least varying among the markers visible through the gap. "
                "gapfill has no causal (real-time) mode: every function interpolates across the gap."
            ),
        },
        "synthetic": synthetic_check(),
        "latency": lat,
    }
    report["wall_s"] = time.time() - started
    args.out.mkdir(parents=True, exist_ok=True)
    with atomic_output(args.out / "extrapolate.json") as tmp:
        tmp.write_text(json.dumps(report, indent=1))
    with atomic_output(args.out / "extrapolate.md") as tmp:
        tmp.write_text(markdown(report))
    plot(report, args.out / "extrapolate_error_vs_gap.png")
    print(markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
