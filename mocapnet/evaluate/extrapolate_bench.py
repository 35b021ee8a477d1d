"""Benchmark of the streaming extrapolator (``scripts/bench_extrapolate.py``): gap-filling error vs gap length,
an exactness check and per-frame latency.

Drops single markers (``marker-gap:S``) and whole limbs (``segment-gap:SEG:S``, SEG in ``SEGMENTS``) for S in
``GAP_SECONDS`` at random onsets (seeded with ``seed_for``) from complete C3D files and from the joint
positions of a CMU BVH clip, and scores the mean distance (cm) of the filled points to the truth over the
missing samples (:func:`score_clip`), for:

* the causal, real-time methods ``STREAMING`` (registered: ``hold``, ``extrapolate-linear``,
  ``extrapolate-circular``, ``extrapolate``, ``extrapolate+cm``), run up to the end of the last gap;
* offline references that also see the data after the gap (``OFFLINE``): the registered ``lerp`` and the PyPI
  package ``gapfill``: its B-spline fill and its rigid-body fill from a cluster of three markers (same limb
  segment, or the three most rigid markers visible through the gap). Their fill fraction is reported.

:func:`synthetic_check` predicts a point on an exact circle / line for 2 s from its own past;
:func:`latency` times ``Extrapolator.push`` per frame with 40 markers (``hold`` measured in the same run).
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapnet.corrupt import Corruption, corrupt_markers, gap_mask, motion_markers, point_gap_mask, seed_for
from mocapnet.evaluate.benchmark import gapfill_rigid_body, gapfill_spline, gapfill_spline_as_shipped, numpy_int_alias
from mocapnet.evaluate.results import fmt, markdown_table
from mocapnet.io.atomic import atomic_output
from mocapnet.io.bvh import read_bvh
from mocapnet.io.c3d import read_c3d
from mocapnet.methods import build_method
from mocapnet.methods.extrapolate import Extrapolator
from mocapnet.motion import Markers
from mocapnet.segments import marker_segment, skeleton_segment

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
GAPFILL_NOTE = (
    "fill_marker_gap_interp (spline) and fill_marker_gap_pattern call np.int, removed in NumPy 1.24: as shipped "
    "they fail under this NumPy ({shipped}); this benchmark runs them with a temporary alias np.int = int. "
    "fill_marker_gap_rbt needs the three cluster markers visible through the whole gap and the target visible on "
    "both sides, so it fills nothing when the whole limb is missing (segment-gap with a same-segment cluster). "
    "gapfill-rbt-segment: the three markers of the target's limb (segments.py) whose distance to it varies least "
    "(every marker when the target is on no limb); gapfill-rbt-rigid3: the three least varying among the markers "
    "visible through the gap. gapfill has no causal (real-time) mode: every function interpolates across the gap."
)


@dataclass
class Clip:
    """A clean clip and how to corrupt it: ``segment_tracks(seg)`` gives a limb's tracks, ``candidates`` the
    tracks a single-marker gap may pick."""

    corpus: str
    file: str
    markers: Markers
    segment_tracks: Callable[[str], list[int]]
    candidates: list[int]

    @property
    def source(self) -> str:
        return "bvh" if self.corpus.startswith("bvh") else "c3d"


def load_clips(root: Path, files: tuple[str, ...]) -> list[Clip]:
    """The clips of ``files`` (relative to ``root``): BVH as joint positions with the skeleton's limbs and
    scored joints; C3D as their physical markers (``read_c3d``) with every complete marker a candidate."""
    clips = []
    for rel in files:
        path, corpus = root / rel, str(Path(rel).parent)
        if rel.startswith("bvh/"):
            motion = read_bvh(path)
            tracks = lambda seg, sk=motion.skeleton: skeleton_segment(sk, seg)  # noqa: E731
            candidates = [int(j) for j in motion.skeleton.scored_joints]
            clips.append(Clip(corpus, path.name, motion_markers(motion), tracks, candidates))
        else:
            markers = read_c3d(path)
            tracks = lambda seg, lab=markers.labels: marker_segment(lab, seg)  # noqa: E731
            candidates = list(np.flatnonzero(markers.visible.all(axis=0)))
            clips.append(Clip(corpus, path.name, markers, tracks, candidates))
    return clips


def corrupt(clip: Clip, corruption: str, repeat: int) -> Markers:
    """Corrupted copy of the clip: C3D through ``corrupt_markers``; BVH joints with the skeleton's limbs
    (``corrupt_markers`` only knows Plug-in-Gait labels) and its scored joints as single-gap candidates."""
    rng = np.random.default_rng(seed_for(clip.corpus, clip.file, repeat, corruption))
    m = clip.markers
    if clip.source == "c3d":
        return corrupt_markers(m, corruption, rng)
    mask = point_gap_mask(corruption, m.n_frames, m.fps, rng, clip.segment_tracks, m.n_markers, clip.candidates, m.name)
    return Markers(m.points, m.visible & ~mask, m.labels, m.fps, m.name)


def distance_spread(points: np.ndarray, target: int) -> np.ndarray:
    """Std over all frames of the distance from ``target`` to every marker, ``[M]`` cm (NaN frames skipped;
    inf where seen together in fewer than 2 frames, and for the target itself)."""
    dist = np.linalg.norm(points - points[:, [target]], axis=2)
    count = np.isfinite(dist).sum(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spread = np.nanstd(dist, axis=0)
    spread[(count < 2) | ~np.isfinite(spread)] = np.inf
    spread[target] = np.inf
    return spread


def rbt_cluster(noisy: Markers, target: int, pool: list[int]) -> list[int]:
    """The (at most) three markers of ``pool`` whose distance to ``target`` varies least (most rigid)."""
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
    out = {name: noisy.points.copy() for name in OFFLINE[1:]}
    with numpy_int_alias():
        for i in np.flatnonzero((~noisy.visible).any(axis=0)):
            gap = ~noisy.visible[:, i]
            through_gap = [j for j in range(noisy.n_markers) if noisy.visible[gap, j].all()]
            for name, pool in (("gapfill-rbt-segment", limb_of(clip, i)), ("gapfill-rbt-rigid3", through_gap)):
                cluster = rbt_cluster(noisy, i, pool)
                if len(cluster) == 3:
                    out[name][:, i] = gapfill_rigid_body(noisy.points, i, cluster)
            out["gapfill-spline"][:, i] = gapfill_spline(noisy.points, i)
    return out


def score_clip(clip: Clip, corruption: str, repeat: int, acc: dict, per_file: dict) -> None:
    """Fill one corrupted copy with every method and add, per ``(source or file, kind, gap s, method)``, the
    summed error (cm), the samples filled and the samples missing to ``acc`` and ``per_file``."""
    noisy = corrupt(clip, corruption, repeat)
    truth = clip.markers.points
    miss = ~noisy.visible
    end = int(np.flatnonzero(miss.any(axis=1)).max()) + 1  # the streaming methods are causal: stop at gap end
    head = Markers(noisy.points[:end], noisy.visible[:end], noisy.labels, noisy.fps, noisy.name)
    fills = {name: build_method(name).clean(head) for name in STREAMING}
    fills["lerp"] = build_method("lerp", space="points").clean(noisy)[:end]
    fills.update({k: v[:end] for k, v in gapfill_fills(clip, noisy).items()})
    c = Corruption.parse(corruption)
    for name, fill in fills.items():
        err = np.linalg.norm(fill[:end][miss[:end]] - truth[:end][miss[:end]], axis=1)
        done = np.isfinite(err)
        for table, group in ((acc, clip.source), (per_file, clip.file)):
            entry = table.setdefault((group, c.kind, c.level, name), [0.0, 0, 0])
            entry[0] += float(err[done].sum())
            entry[1] += int(done.sum())
            entry[2] += int(err.size)


def corruptions() -> list[str]:
    """Every corruption scored: ``marker-gap:S``, then ``segment-gap:SEG:S`` for each S and limb."""
    return [f"marker-gap:{s:g}" for s in GAP_SECONDS] + [
        f"segment-gap:{seg}:{s:g}" for s in GAP_SECONDS for seg in SEGMENTS
    ]


def summarise(acc: dict, first: str = "source") -> list[dict]:
    """Rows of mean error and fill fraction from ``{(source or file, kind, gap s, method): [sum, filled, n]}``."""
    return [
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
        for (group, kind, seconds, method), (total, filled, missing) in sorted(acc.items())
    ]


def synthetic_check(fps: float = 120.0, seconds: float = 2.0) -> dict:
    """Largest error (cm) over ``seconds`` of prediction for an exact circle and an exact line."""
    n_seen = int(fps)
    t = np.arange(n_seen + int(seconds * fps)) / fps
    e1 = np.array([1.0, 0.2, 0.1]) / np.linalg.norm([1.0, 0.2, 0.1])
    e2 = np.cross(e1, [0.3, 0.1, 1.0])
    e2 /= np.linalg.norm(e2)
    circle = np.array([3.0, -2.0, 50.0]) + 15.0 * (np.cos(2 * t)[:, None] * e1 + np.sin(2 * t)[:, None] * e2)
    line = np.array([1.0, 2.0, 3.0]) + t[:, None] * np.array([30.0, -10.0, 5.0])
    result = {"fps": fps, "seconds_predicted": seconds, "seen_frames": n_seen,
              "circle": "radius 15 cm, 2 rad/s, tilted plane", "line": "velocity (30, -10, 5) cm/s"}  # fmt: skip
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
    """Per-frame ``push`` time (µs, wall and thread CPU) with ``n_markers`` markers under random occlusions
    (``gap_mask``). The methods take turns frame by frame, so load from other processes hits them alike."""
    rel = C3D_FILES[0]
    markers = read_c3d(root / rel).select(list(range(n_markers)))
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
        "load_average": ", ".join(f"{x:.2f}" for x in os.getloadavg()),
    }
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
        entry = result["methods"][name] = {}
        for pre, times in (("", wall[k]), ("cpu_", cpu[k])):
            entry |= {f"{pre}median_us": float(np.median(times)), f"{pre}p99_us": float(np.percentile(times, 99)),
                      f"{pre}max_us": float(times.max())}  # fmt: skip
    base = result["methods"]["hold"]
    for entry in result["methods"].values():
        for key in ("median_us", "p99_us", "cpu_median_us", "cpu_p99_us"):
            entry[key.replace("_us", "_ratio_to_hold")] = entry[key] / base[key]
    return result


def run(root: Path, files: tuple[str, ...], repeats: int, progress: bool = False) -> dict:
    """Every corruption × ``repeats`` onsets on ``files``, the exactness check and the latency, as a report."""
    from tqdm import tqdm

    started = time.time()
    clips = load_clips(root, files)
    acc: dict = {}
    per_file: dict = {}
    skipped = []
    jobs = [(clip, corr, r) for clip in clips for corr in corruptions() for r in range(repeats)]
    for clip, corr, r in tqdm(jobs, desc="gaps", unit="gap", disable=not progress):
        try:
            score_clip(clip, corr, r, acc, per_file)
        except ValueError as exc:
            if "too short" not in str(exc):
                raise
            skipped.append({"file": clip.file, "corruption": corr, "repeat": r})
    lat = latency(root)
    import gapfill

    shipped = gapfill_spline_as_shipped()
    return {
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
        ],  # fmt: skip
        "skipped": skipped,
        "summary": summarise(acc),
        "per_file": summarise(per_file, "file"),
        "gapfill": {
            "version": gapfill.__version__,
            "without_np_int_alias": shipped,
            "note": GAPFILL_NOTE.format(shipped=shipped),
        },  # fmt: skip
        "synthetic": synthetic_check(),
        "latency": lat,
        "wall_s": time.time() - started,
    }


def _with_ratio(err: float | None, ref: float | None) -> str:
    """``err`` (cm, 2 decimals) and its ratio to ``ref`` in brackets."""
    return fmt(err, 2) + (f" ({err / ref:.2f})" if err is not None and ref else "")


def _error_tables(rows: list[dict]) -> list[str]:
    """Per source and corruption kind: mean error (cm) per gap length and method, ratio to lerp in brackets."""
    lines = []
    for source in ("c3d", "bvh"):
        for kind in ("marker-gap", "segment-gap"):
            sel = [r for r in rows if r["source"] == source and r["corruption"] == kind]
            if not sel:
                continue
            body = []
            for s in GAP_SECONDS:
                cells = {r["method"]: r["mean_err_cm"] for r in sel if r["gap_s"] == s}
                if cells:
                    body.append([f"{s:g}", *(_with_ratio(cells.get(m), cells["lerp"]) for m in METHODS)])
            lines += ["", f"## {source.upper()} — `{kind}` (mean error, cm)", ""]
            lines += markdown_table(["gap s", *METHODS], body)
    return lines


def _fill_fraction_table(rows: list[dict]) -> list[str]:
    body = []
    for source in ("c3d", "bvh"):
        for kind in ("marker-gap", "segment-gap"):
            for s in GAP_SECONDS:
                cells = {
                    r["method"]: r for r in rows if (r["source"], r["corruption"], r["gap_s"]) == (source, kind, s)
                }
                if cells:
                    body.append([source, kind, f"{s:g}", *(fmt(cells[m]["filled_fraction"]) for m in OFFLINE[1:])])
    return markdown_table(["source", "corruption", "gap s", *OFFLINE[1:]], body)


def _skipped_line(skipped: list[dict]) -> list[str]:
    if not skipped:
        return []
    cases = sorted({f"{s['file']} {s['corruption'].split(':')[0]} {s['corruption'].split(':')[-1]} s" for s in skipped})
    return ["- skipped (clip too short for the gap with 1 s visible on each side): " + ", ".join(cases)]


def _synthetic_section(syn: dict) -> list[str]:
    body = [key.split("_")[:2] + [f"{v:.3g}"] for key, v in syn.items() if key.endswith("_max_err_cm")]
    return [
        "## Synthetic exactness check",
        "",
        f"A point seen for {syn['seen_frames']} frames at {syn['fps']:g} Hz, then predicted from its own past "
        f"for {syn['seconds_predicted']:g} s; largest error (cm). Circle: {syn['circle']}; line: {syn['line']}.",
        "",
        *markdown_table(["trajectory", "mode", "max error cm"], body),
    ]


def _latency_section(lat: dict) -> list[str]:
    body = [
        [
            name,
            clock,
            f"{e[pre + 'median_us']:.1f}",
            f"{e[pre + 'p99_us']:.1f}",
            f"{e[pre + 'max_us']:.0f}",
            f"{e[pre + 'median_ratio_to_hold']:.1f}",
            f"{e[pre + 'p99_ratio_to_hold']:.1f}",
        ]  # fmt: skip
        for name, e in lat["methods"].items()
        for clock, pre in (("wall", ""), ("thread CPU", "cpu_"))
    ]
    return [
        "## Per-frame latency of `Extrapolator.push`",
        "",
        f"{lat['markers']} markers of `{lat['file']}`, {lat['frames']} frames, {lat['occlusion']} "
        f"(measured {100 * lat['missing_fraction']:.1f}% missing, {lat['mean_missing_per_frame']:.1f} markers "
        f"missing per frame on average). The methods take turns frame by frame in one process (single "
        f"thread); load average (1, 5, 15 min) just before timing: {lat['load_average']}.",
        "",
        *markdown_table(["method", "clock", "median µs", "p99 µs", "max µs", "median / hold", "p99 / hold"], body),
    ]


def markdown(report: dict) -> str:
    """The results file ``extrapolate.md`` of a report made by :func:`run` plus ``report.provenance``."""
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
        *(
            f"  - `{c['path']}`: {c['markers']} points, {c['frames']} frames at {c['fps']:g} Hz"
            for c in report["clips"]
        ),
        *_skipped_line(report["skipped"]),
        "",
        "Causal, real-time methods see only the past; `lerp` and the `gapfill` functions are offline references",
        "that also use the data after the gap. `gapfill-*` errors are over the samples they filled; see the fill",
        "fraction table.",
        *_error_tables(report["summary"]),
        "",
        "## gapfill: fraction of missing samples filled",
        "",
        *_fill_fraction_table(report["summary"]),
        "",
        f"gapfill {report['gapfill']['version']}: {report['gapfill']['note']}",
        "",
        *_synthetic_section(report["synthetic"]),
        "",
        *_latency_section(report["latency"]),
        "",
        "Per-file errors are in `extrapolate.json.gz` (`per_file`).",
        "",
    ]
    return "\n".join(lines)


def plot(report: dict, path: Path) -> None:
    """Mean error vs gap length (log-log), one panel per source and corruption kind; causal methods solid."""
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
