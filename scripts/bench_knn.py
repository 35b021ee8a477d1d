"""Benchmark of the data-driven gap filler (``mocapnet.methods.knn``) against PCA, interpolation and gapfill.

Whole body segments (left-arm, right-arm, arms, left-leg, right-leg, legs) are removed for 1, 2 and 4 s
(``segment-gap:SEG:S``, random onsets with 1 s visible on each side, seeds ``seed_for(corpus, file, repeat,
corruption)``) and filled by:

* ``knn`` — the paper's method, default options (k = 8, levels automatic, all points reliable, schedule 0.25);
* ``knn+offset`` — the same with our ``offset`` extension (continuity with the visible frames);
* ``pca`` — Gløersen & Federolf (2016) PCA of inter-marker correlations (no database);
* ``lerp`` / ``spline`` — linear and cubic-spline interpolation of each coordinate (``methods.baselines``);
* ``gapfill-rbt`` / ``gapfill-spline`` — PyPI ``gapfill``: rigid-body fill from the three markers nearest to
  the target among those visible through its gap, and its spline fill; errors over what they filled, with
  the fraction filled.

Data: complete C3D files, with the database = the other files of the same marker set (41-marker
HDM05 + CMU set, ``cmu/01_01.c3d`` in the database only; Plug-in-Gait tennis serve + pyCGM trial, on their 39
common labels); the real NaN gaps of ``kinematics_tennis_serve_nan.c3d`` scored against its complete twin;
BVH joint positions (with End Sites) of ``cmu120`` (one clip: each half is filled from the other half) and of
a subset of ``bandai2`` (database = the subset's other files), scored in position space and, after
``inverse_kinematics``, in angle space against linear / spline interpolation of the angles.

Also: database build, kd-tree build and query times for the whole 41-marker corpus, and the time to fill a
gap against its length (``knn_time_vs_gap.png``).

Writes ``benchmarks/results/knn.json``, ``knn.md`` and ``knn_time_vs_gap.png``.

Example::

    nice -n 10 .venv/bin/python scripts/bench_knn.py            # full run
    .venv/bin/python scripts/bench_knn.py --quick --out /tmp/x  # small run
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mocapnet.corpus import data_root  # noqa: E402
from mocapnet.corrupt import corrupt_markers, joint_mask_to_channels, point_gap_mask, seed_for  # noqa: E402
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
from mocapnet.kinematics import inverse_kinematics, joint_positions  # noqa: E402
from mocapnet.methods.baselines import lerp_fill, spline_fill  # noqa: E402
from mocapnet.methods.knn import MotionDatabase, bare_label, fill_gaps  # noqa: E402
from mocapnet.methods.pca import pca_fill  # noqa: E402
from mocapnet.motion import Markers, Motion  # noqa: E402
from mocapnet.segments import SEGMENTS, skeleton_segment  # noqa: E402

GAP_SECONDS = (1.0, 2.0, 4.0)
CMU41 = (
    "c3d/hdm05/HDM_bd_01-02_01_120.c3d",
    "c3d/hdm05/HDM_bd_05-01_01_120.c3d",
    "c3d/hdm05/HDM_mm_01-02_03_120.c3d",
    "c3d/cmu/02_01.c3d",
    "c3d/cmu/85_02.c3d",
    "c3d/cmu/85_12.c3d",
)
CMU41_DB_ONLY = ("c3d/cmu/01_01.c3d",)
PIG = ("c3d/kineticstoolkit/kinematics_tennis_serve.c3d", "c3d/pycgm/Movement_trial.c3d")
REAL_NAN = ("c3d/kineticstoolkit/kinematics_tennis_serve_nan.c3d", "c3d/kineticstoolkit/kinematics_tennis_serve.c3d")
CMU120 = "bvh/cmu_cgspeed/01_01.bvh.gz"
BANDAI2 = "bvh/bandai_namco_2"
POINT_METHODS = ("knn", "knn+offset", "pca", "lerp", "spline", "gapfill-rbt", "gapfill-spline")
BVH_METHODS = ("knn", "knn+offset", "pca", "lerp", "spline")
ANGLE_METHODS = ("knn+IK", "knn+offset+IK", "lerp-positions+IK", "truth-positions+IK", "lerp-angles", "spline-angles")
TIMING_GAPS = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0)
TIMING_FILE = "c3d/hdm05/HDM_bd_05-01_01_120.c3d"
PAPER_NOTE = (
    "kNN completion paper (HDM05 at 30 Hz, database = hours of HDM05): left arm missing, actor not in "
    "the database 2.5 cm (walk) to 5 cm (cartwheel); Table 2 (actor's other takes in the database) "
    "0.59-10.2 cm over left/right arm, both arms, left/right leg, both legs; time about 10x the gap "
    "length, linear in it."
)


def flat_fill(fill: Callable[[np.ndarray, np.ndarray], np.ndarray], noisy: Markers) -> np.ndarray:
    """Apply a ``[T, C]`` channel filler (lerp_fill / spline_fill) to points ``[T, M, 3]``."""
    t, m = noisy.visible.shape
    return fill(noisy.points.reshape(t, m * 3), np.repeat(~noisy.visible, 3, axis=1)).reshape(t, m, 3)


def gapfill_fills(noisy: Markers) -> dict[str, np.ndarray]:
    """``gapfill`` rigid-body and spline fills ``[T, M, 3]`` (NaN where gapfill left a sample missing)."""
    out = {"gapfill-rbt": noisy.points.copy(), "gapfill-spline": noisy.points.copy()}
    with numpy_int_alias():
        for i in np.flatnonzero((~noisy.visible).any(axis=0)):
            gap = ~noisy.visible[:, i]
            through = np.flatnonzero(noisy.visible[gap].all(axis=0))
            dist = np.nanmean(np.linalg.norm(noisy.points[:, through] - noisy.points[:, [i]], axis=-1), axis=0)
            cluster = through[np.argsort(dist)[:3]]
            if len(cluster) == 3:
                out["gapfill-rbt"][:, i] = gapfill_rigid_body(noisy.points, i, cluster)
            out["gapfill-spline"][:, i] = gapfill_spline(noisy.points, i)
    return out


def point_fills(noisy: Markers, db: MotionDatabase, exclude: str, methods: tuple[str, ...]) -> dict[str, tuple]:
    """Every method's fill ``[T, M, 3]`` and its CPU seconds."""
    fills: dict[str, tuple] = {}
    runners: dict[str, Callable[[], np.ndarray]] = {
        "knn": lambda: fill_gaps(noisy, db, exclude=exclude)[0],
        "knn+offset": lambda: fill_gaps(noisy, db, offset=True, exclude=exclude)[0],
        "pca": lambda: pca_fill(noisy.points, noisy.visible),
        "lerp": lambda: flat_fill(lerp_fill, noisy),
        "spline": lambda: flat_fill(spline_fill, noisy),
    }
    for name in methods:
        if name in runners:
            t0 = time.process_time()
            fills[name] = (runners[name](), time.process_time() - t0)
    if "gapfill-rbt" in methods:
        t0 = time.process_time()
        gf = gapfill_fills(noisy)
        spent = (time.process_time() - t0) / 2
        fills.update({k: (v, spent) for k, v in gf.items()})
    return fills


def score(fill: np.ndarray, truth: np.ndarray, miss: np.ndarray) -> tuple[float, int, int]:
    """(sum of distances over the filled missing samples (cm), samples filled, samples missing)."""
    err = np.linalg.norm(fill[miss] - truth[miss], axis=-1)
    done = np.isfinite(err)
    return float(err[done].sum()), int(done.sum()), int(err.size)


def rows_for(base: dict, fills: dict, truth: np.ndarray, miss: np.ndarray) -> list[dict]:
    rows = []
    for name, (fill, cpu) in fills.items():
        total, filled, missing = score(fill, truth, miss)
        rows.append({**base, "method": name, "sum_cm": total, "filled": filled, "missing": missing, "cpu_s": cpu})
    return rows


def physical(markers: Markers, labels: list[str]) -> Markers:
    """Keep the markers whose bare label is in ``labels``, in that order."""
    bare = [bare_label(lab) for lab in markers.labels]
    return markers.select([bare.index(lab) for lab in labels])


def load_c3d_group(root: Path, files: tuple[str, ...]) -> list[Markers]:
    """The files' markers restricted to the labels they all share (PiG model outputs drop out)."""
    clips = [read_c3d(root / f) for f in files]
    common = [bare_label(lab) for lab in clips[0].labels]
    for clip in clips[1:]:
        common = [lab for lab in common if lab in {bare_label(x) for x in clip.labels}]
    return [physical(c, common) for c in clips]


def corruptions() -> list[str]:
    return [f"segment-gap:{seg}:{s:g}" for seg in SEGMENTS for s in GAP_SECONDS]


def bench_c3d(root: Path, repeats: int, quick: bool, progress: tqdm) -> tuple[list[dict], list[dict], dict]:
    """Segment gaps in the complete C3D files; rows per (file, corruption, repeat, method)."""
    rows: list[dict] = []
    skipped: list[dict] = []
    info = {}
    groups = {"cmu41": (CMU41[:1] if quick else CMU41, CMU41 + CMU41_DB_ONLY), "pig": (PIG[:1], PIG)}
    for group, (tests, members) in groups.items():
        clips = load_c3d_group(root, members)
        db = MotionDatabase.from_markers(clips, source=group)
        info[group] = {
            "database": list(members),
            "markers": len(db.labels),
            "test_files": list(tests),
            "database_frames": int(len(db.levels[0].clip)),
            "levels": len(db.levels),
            "gapfill_spline_minus_spline_max_cm": 0.0,
        }
        for path in tests:
            clip = clips[members.index(path)]
            for corr in corruptions()[: 2 if quick else None]:
                for rep in range(repeats):
                    progress.update()
                    rng = np.random.default_rng(seed_for("c3d", clip.name, rep, corr))
                    try:
                        noisy = corrupt_markers(clip, corr, rng)
                    except ValueError as exc:
                        skipped.append({"file": path, "corruption": corr, "repeat": rep, "why": str(exc)})
                        continue
                    fills = point_fills(noisy, db, clip.name, POINT_METHODS)
                    diff = np.abs(fills["gapfill-spline"][0] - fills["spline"][0])[~noisy.visible]
                    info[group]["gapfill_spline_minus_spline_max_cm"] = max(
                        info[group]["gapfill_spline_minus_spline_max_cm"], float(np.nanmax(diff))
                    )
                    base = {"group": group, "file": path, "corruption": corr, "repeat": rep}
                    rows += rows_for(base, fills, clip.points, ~noisy.visible)
    return rows, skipped, info


def bench_real_nan(root: Path) -> dict:
    """Real gaps of the tennis-serve twin, database = the other Plug-in-Gait file(s), scored on the twin."""
    gappy, twin = load_c3d_group(root, REAL_NAN)
    others = load_c3d_group(root, PIG)
    labels = [bare_label(lab) for lab in gappy.labels]
    db = MotionDatabase.from_markers([physical(c, labels) for c in others], source="pig")
    vis = gappy.visible
    same = np.abs(gappy.points[vis] - twin.points[vis]).max()
    fills = point_fills(gappy, db, twin.name, POINT_METHODS)
    rows = rows_for({"file": REAL_NAN[0]}, fills, twin.points, ~vis)
    miss = ~vis
    return {
        "file": REAL_NAN[0],
        "truth": REAL_NAN[1],
        "database": [f for f in PIG if f != REAL_NAN[1]],
        "missing_samples": int(miss.sum()),
        "gappy_markers": [gappy.labels[i] for i in np.flatnonzero(miss.any(axis=0))],
        "max_abs_diff_visible_cm": float(same),
        "rows": rows,
    }


@dataclass
class BvhClip:
    """A motion, its joint + End Site positions as Markers, and the point indices of each segment."""

    motion: Motion
    markers: Markers

    def segment_points(self, seg: str) -> list[int]:
        sk = self.motion.skeleton
        joints = skeleton_segment(sk, seg)
        ends = [sk.n_joints + e for e, p in enumerate(sk.end_parents) if p in joints]
        return joints + ends


def bvh_clip(motion: Motion) -> BvhClip:
    sk = motion.skeleton
    pos = joint_positions(motion, end_sites=True)
    labels = list(sk.names) + [f"{sk.names[p]}_End{e}" for e, p in enumerate(sk.end_parents)]
    return BvhClip(motion, Markers(pos, np.ones(pos.shape[:2], dtype=bool), labels, motion.fps, motion.name))


def wrapped_rms(a: np.ndarray, b: np.ndarray) -> float:
    d = (a - b + 180.0) % 360.0 - 180.0
    return float(np.sqrt(np.mean(d**2)))


def bench_bvh_case(corpus: str, clip: BvhClip, db: MotionDatabase, corr: str, rep: int) -> list[dict] | None:
    """Position- and angle-space rows for one segment gap of one clip (None when the clip is too short)."""
    m = clip.markers
    rng = np.random.default_rng(seed_for(corpus, m.name, rep, corr))
    try:
        mask = point_gap_mask(corr, m.n_frames, m.fps, rng, clip.segment_points, m.n_markers, [], m.name)
    except ValueError:
        return None
    noisy = Markers(m.points, ~mask, m.labels, m.fps, m.name)
    fills = point_fills(noisy, db, m.name, BVH_METHODS)
    base = {"corpus": corpus, "file": m.name, "corruption": corr, "repeat": rep}
    rows = [{**r, "space": "positions"} for r in rows_for(base, fills, m.points, mask)]
    motion = clip.motion
    n_j = motion.skeleton.n_joints
    cmask = joint_mask_to_channels(motion, mask[:, :n_j])
    noisy_ch = np.where(cmask, np.nan, motion.channels)
    lerp_ch = lerp_fill(noisy_ch, cmask)
    reference = motion.with_channels(lerp_ch)  # the IK's twist / reference: no truth inside the gap
    angles = {"lerp-angles": lerp_ch, "spline-angles": spline_fill(noisy_ch, cmask)}
    for name, src in (("knn+IK", "knn"), ("knn+offset+IK", "knn+offset"), ("lerp-positions+IK", "lerp")):
        angles[name] = inverse_kinematics(reference, fills[src][0])
    angles["truth-positions+IK"] = inverse_kinematics(reference, m.points)  # the IK's own floor
    for name, ch in angles.items():
        rms = wrapped_rms(ch[cmask], motion.channels[cmask])
        rows.append({**base, "space": "angles", "method": name, "rms_deg": rms, "channels_samples": int(cmask.sum())})
    return rows


def bench_bvh(
    root: Path, repeats: int, n_bandai: int, n_bandai_test: int, quick: bool, progress: tqdm
) -> tuple[list[dict], dict]:
    rows: list[dict] = []
    motion = read_bvh(root / CMU120)
    half = motion.n_frames // 2
    halves = [
        bvh_clip(Motion(motion.skeleton, motion.channels[part], motion.fps, f"01_01 {name}"))
        for part, name in ((slice(0, half), "first half"), (slice(half, None), "second half"))
    ]
    info: dict = {
        "cmu120": {
            "file": CMU120,
            "frames": motion.n_frames,
            "split": f"frames [0, {half}) and [{half}, {motion.n_frames}); each half is filled "
            "with the other half as the database",
        }
    }
    for i, clip in enumerate(halves):
        db = MotionDatabase.from_markers([halves[1 - i].markers], source="cmu120 other half")
        for corr in corruptions()[: 2 if quick else None]:
            for rep in range(repeats):
                progress.update()
                rows += bench_bvh_case("cmu120", clip, db, corr, rep) or []
    files = sorted((root / BANDAI2).glob("*.bvh*"))
    subset = [files[i] for i in np.linspace(0, len(files) - 1, n_bandai).round().astype(int)]
    clips = [bvh_clip(read_bvh(f)) for f in subset]
    db = MotionDatabase.from_markers([c.markers for c in clips], source=f"bandai2 subset of {n_bandai}")
    long_enough = [c for c in clips if c.markers.n_frames >= 3 * c.markers.fps]
    tests = [long_enough[i] for i in np.linspace(0, len(long_enough) - 1, n_bandai_test).round().astype(int)]
    info["bandai2"] = {
        "folder": BANDAI2,
        "subset": n_bandai,
        "subset_rule": "evenly spaced in sorted file order",
        "database_frames": int(len(db.levels[0].clip)),
        "test_files": [c.markers.name for c in tests],
        "test_rule": f"{n_bandai_test} evenly spaced among the subset's files of at least 3 s; "
        "database = the other files of the subset",
    }
    for clip in tests:
        for corr in corruptions()[: 2 if quick else None]:
            progress.update()
            rows += bench_bvh_case("bandai2", clip, db, corr, 0) or []
    return rows, info


def corpus_timing(root: Path) -> dict:
    """Database build, kd-tree build and query times for the whole 41-marker corpus (CPU seconds)."""
    clips = load_c3d_group(root, CMU41 + CMU41_DB_ONLY)
    t0 = time.process_time()
    db = MotionDatabase.from_markers(clips, source="cmu41")
    build = time.process_time() - t0
    from scipy.spatial import cKDTree

    arm = {"LUPA", "LELB", "LFRM", "LWRA", "LWRB", "LFIN"}
    feats = [i for i, lab in enumerate(db.labels) if lab not in arm]
    levels = []
    rng = np.random.default_rng(0)
    for lev, level in enumerate(db.levels):
        rows = np.flatnonzero(level.valid[:, feats].all(axis=1))
        data = level.positions[np.ix_(rows, feats)].reshape(len(rows), -1)
        t0 = time.process_time()
        tree = cKDTree(data)
        t_build = time.process_time() - t0
        queries = data[rng.integers(0, len(rows), 500)] + rng.normal(0, 2.0, (500, data.shape[1]))
        t0 = time.process_time()
        tree.query(queries, k=8)
        t_query = (time.process_time() - t0) / 500
        levels.append(
            {
                "level": lev,
                "rows": int(len(rows)),
                "dims": int(data.shape[1]),
                "tree_build_s": t_build,
                "query_ms_per_frame": 1e3 * t_query,
            }
        )
    return {
        "files": list(CMU41 + CMU41_DB_ONLY),
        "frames": int(sum(c.n_frames for c in clips)),
        "markers": len(db.labels),
        "database_build_s": build,
        "database_mb": db.nbytes / 1e6,
        "full_rate_mb": db.levels[0].nbytes / 1e6,
        "levels": levels,
        "features": "the 35 markers other than the left arm's (a left-arm gap), k = 8; queries = 500 database "
        "poses + N(0, 2 cm) noise per coordinate",
    }


def time_vs_gap(root: Path, repeats: int) -> dict:
    """CPU time of ``fill_gaps`` for left-arm gaps of growing length in one long file."""
    clips = load_c3d_group(root, CMU41 + CMU41_DB_ONLY)
    clip = clips[(CMU41 + CMU41_DB_ONLY).index(TIMING_FILE)]
    db = MotionDatabase.from_markers(clips, source="cmu41")
    points = []
    for s in TIMING_GAPS:
        for rep in range(repeats):
            corr = f"segment-gap:left-arm:{s:g}"
            noisy = corrupt_markers(clip, corr, np.random.default_rng(seed_for("timing", clip.name, rep, corr)))
            t0, w0 = time.process_time(), time.perf_counter()
            _, report = fill_gaps(noisy, db, exclude=clip.name)
            points.append(
                {
                    "gap_s": s,
                    "repeat": rep,
                    "cpu_s": time.process_time() - t0,
                    "wall_s": time.perf_counter() - w0,
                    "tree_build_s": report.build_s,
                    "query_s": report.query_s,
                    "solve_s": report.solve_s,
                    "queries": report.queries,
                    "iterations": report.iterations,
                }
            )
    x = np.array([p["gap_s"] for p in points])
    y = np.array([p["cpu_s"] for p in points])
    slope, intercept = np.polyfit(x, y, 1)
    r2 = 1 - ((y - (slope * x + intercept)) ** 2).sum() / ((y - y.mean()) ** 2).sum()
    return {
        "file": TIMING_FILE,
        "segment": "left-arm",
        "database": "the other 6 files of the 41-marker set",
        "points": points,
        "fit": {"slope_s_per_s": float(slope), "intercept_s": float(intercept), "r2": float(r2)},
    }


def plot_time(timing: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    pts = timing["points"]
    ax.plot([p["gap_s"] for p in pts], [p["cpu_s"] for p in pts], "o", label="fill_gaps CPU time")
    ax.plot([p["gap_s"] for p in pts], [p["tree_build_s"] + p["query_s"] for p in pts], "x", label="of which kd-trees")
    fit = timing["fit"]
    xs = np.array([0, max(TIMING_GAPS)])
    ax.plot(
        xs,
        fit["slope_s_per_s"] * xs + fit["intercept_s"],
        "-",
        label=f"fit {fit['slope_s_per_s']:.3f} s/s + {fit['intercept_s']:.3f} s (R² {fit['r2']:.3f})",
    )
    ax.set_xlabel("gap length (s), left arm missing, 120 Hz")
    ax.set_ylabel("CPU seconds")
    ax.set_title(f"knn fill time vs gap length ({Path(timing['file']).name})")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


def summarise(rows: list[dict], keys: tuple[str, ...]) -> dict[tuple, dict]:
    """Pool rows by ``keys`` (+ method): mean error over the filled missing samples (cm) or RMS over the gap
    channels (deg), fill fraction, mean CPU seconds and number of cases."""
    acc: dict[tuple, dict] = {}
    for r in rows:
        e = acc.setdefault(
            tuple(r[key] for key in keys) + (r["method"],),
            {"sum": 0.0, "filled": 0, "missing": 0, "cpu": 0.0, "cases": 0, "rms": "rms_deg" in r},
        )
        if e["rms"]:
            e["sum"] += r["rms_deg"] ** 2 * r["channels_samples"]
            e["filled"] += r["channels_samples"]
            e["missing"] += r["channels_samples"]
        else:
            e["sum"] += r["sum_cm"]
            e["filled"] += r["filled"]
            e["missing"] += r["missing"]
            e["cpu"] += r["cpu_s"]
        e["cases"] += 1
    out = {}
    for k, e in acc.items():
        mean = e["sum"] / e["filled"] if e["filled"] else None
        out[k] = {
            "value": np.sqrt(mean) if e["rms"] and mean is not None else mean,
            "fill": e["filled"] / e["missing"] if e["missing"] else None,
            "cpu_s": e["cpu"] / e["cases"],
            "cases": e["cases"],
        }
    return out


def table(rows: list[dict], keys: tuple[str, ...], methods: tuple[str, ...], ref: str, unit: str) -> list[str]:
    """Markdown table: one line per key combination, one column per method (ratio to ``ref`` in brackets)."""
    stats = summarise(rows, keys)
    combos = sorted({k[:-1] for k in stats}, key=lambda c: tuple(str(x) for x in c))
    lines = [
        "| " + " | ".join(keys) + " | cases | " + " | ".join(f"{m} {unit}" for m in methods) + " |",
        "|---" * (len(keys) + 1 + len(methods)) + "|",
    ]
    for combo in combos:
        base = stats.get(combo + (ref,), {}).get("value")
        cells = []
        for m in methods:
            s = stats.get(combo + (m,))
            if s is None or s["value"] is None:
                cells.append("—")
                continue
            cell = f"{s['value']:.2f}" + (f" ({s['value'] / base:.2f})" if base else "")
            if s["fill"] is not None and s["fill"] < 0.9995:
                cell += f" [{100 * s['fill']:.0f}% filled]"
            cells.append(cell)
        cases = max(stats[combo + (m,)]["cases"] for m in methods if combo + (m,) in stats)
        lines.append("| " + " | ".join(str(c) for c in combo) + f" | {cases} | " + " | ".join(cells) + " |")
    return lines


def with_parts(rows: list[dict]) -> list[dict]:
    """Add ``segment`` and ``gap_s`` columns parsed from the corruption name."""
    return [
        {**r, "segment": r["corruption"].split(":")[1], "gap_s": float(r["corruption"].split(":")[2])} for r in rows
    ]


def markdown(report: dict) -> str:
    c3d = with_parts(report["c3d"]["rows"])
    bvh = with_parts(report["bvh"]["rows"])
    pos = [r for r in bvh if r["space"] == "positions"]
    ang = [r for r in bvh if r["space"] == "angles"]
    ct = report["corpus_timing"]
    tg = report["time_vs_gap"]
    lines = [
        "# Data-driven gap filling benchmark (`mocapnet.methods.knn`)",
        "",
        f"- command: `{report['command']}`",
        f"- git commit: `{report['git_commit']}`",
        f"- machine: {report['machine']}",
        f"- wall time {report['wall_s']:.0f} s, process CPU time {report['cpu_s']:.0f} s",
        f"- corruptions: `segment-gap:SEG:S`, SEG in {', '.join(SEGMENTS)}, S in "
        f"{', '.join(f'{s:g}' for s in GAP_SECONDS)} s, onsets seeded by `seed_for(corpus, file, repeat, corruption)`; "
        f"repeats: C3D {report['repeats']['c3d']}, cmu120 {report['repeats']['cmu120']}, bandai2 1",
        "- metric: mean distance (cm) of the filled points to the truth over the missing samples, pooled over the "
        "cases of a line; in brackets the ratio to `lerp`; `[x% filled]` when a method left samples unfilled "
        "(its error is over what it filled). Angles: RMS (degrees) of the wrapped difference over the gap's "
        "scored channels, ratio to `lerp-angles`.",
        "- methods: `knn` = the paper's method with default options (k 8, automatic levels: coarsest rate >= 15 Hz, "
        "all points reliable, schedule 0.25, 1 % threshold); `knn+offset` = with our continuity extension "
        "(`offset=True`); `pca` = Gløersen & Federolf 2016 (R2); `lerp`/`spline` = per-coordinate interpolation; "
        "`gapfill-*` = PyPI gapfill " + report["gapfill"]["version"] + ": " + report["gapfill"]["note"],
        f"- reference: {PAPER_NOTE}",
        "",
        "## C3D, 41-marker HDM05 + CMU set (database = the other files of the set, test file left out)",
        "",
        f"Database: {', '.join(report['c3d']['info']['cmu41']['database'])} "
        f"({report['c3d']['info']['cmu41']['database_frames']} frames at full rate, less the test file).",
        "",
    ]
    cmu = [r for r in c3d if r["group"] == "cmu41"]
    lines += table(cmu, ("gap_s",), POINT_METHODS, "lerp", "cm") + [""]
    lines += table(cmu, ("segment", "gap_s"), POINT_METHODS, "lerp", "cm") + [""]
    lines += table(cmu, ("file",), POINT_METHODS, "lerp", "cm") + [""]
    spline_diff = max(g["gapfill_spline_minus_spline_max_cm"] for g in report["c3d"]["info"].values())
    lines += [
        f"`gapfill-spline` and `spline` agree to {spline_diff:.1g} cm on every C3D case (both are "
        "not-a-knot cubic interpolating splines; gapfill's window of visible frames is wide enough).",
        "",
    ]
    lines += ["## C3D, Plug-in-Gait (tennis serve; database = pyCGM Movement_trial, 39 common markers)", ""]
    lines += table([r for r in c3d if r["group"] == "pig"], ("gap_s",), POINT_METHODS, "lerp", "cm") + [""]
    if report["c3d"]["skipped"]:
        short = sorted({(s["file"], s["corruption"].split(":")[-1]) for s in report["c3d"]["skipped"]})
        lines += [
            "Skipped (clip too short for the gap with 1 s visible on each side): "
            + ", ".join(f"`{f}` {s} s" for f, s in short),
            "",
        ]
    real = report["real_nan"]
    lines += [
        f"## Real gaps: `{real['file']}` scored against `{real['truth']}`",
        "",
        f"{real['missing_samples']} missing samples in {', '.join(real['gappy_markers'])}; visible samples of "
        f"the two files differ by at most {real['max_abs_diff_visible_cm']:.3g} cm. Database: "
        f"{', '.join(real['database'])}.",
        "",
    ]
    lines += table(real["rows"], ("file",), POINT_METHODS, "lerp", "cm") + [""]
    band = report["bvh"]["info"]["bandai2"]
    lines += [
        "## BVH joint positions (joints + End Sites)",
        "",
        f"cmu120: {report['bvh']['info']['cmu120']['split']}. bandai2: {band['test_rule']} ({band['subset']} "
        f"files, {band['subset_rule']}; {band['database_frames']} database frames). Segment points: "
        "`skeleton_segment` joints and their End Sites.",
        "",
    ]
    lines += table(pos, ("corpus", "gap_s"), BVH_METHODS, "lerp", "cm") + [""]
    lines += table(pos, ("corpus", "segment"), BVH_METHODS, "lerp", "cm") + [""]
    lines += [
        "## BVH angle space (fill positions, then `inverse_kinematics`; IK twist reference = linearly "
        "interpolated angles)",
        "",
        "`truth-positions+IK` runs the same IK on the true positions: the error the position-to-angle step "
        "adds by itself (twist about each bone and the End-Site-only joints are not determined by "
        "positions).",
        "",
    ]
    lines += table(ang, ("corpus", "gap_s"), ANGLE_METHODS, "lerp-angles", "deg") + [""]
    lines += table(ang, ("corpus", "segment"), ANGLE_METHODS, "lerp-angles", "deg") + [""]
    lines += [
        "## Database and kd-tree times, whole 41-marker corpus",
        "",
        f"{len(ct['files'])} files, {ct['frames']} frames at 120 Hz, {ct['markers']} markers (union of labels). "
        f"Database build (normalisation + {len(ct['levels'])} resolutions): {ct['database_build_s']:.2f} s CPU; "
        f"memory {ct['database_mb']:.1f} MB, full rate alone {ct['full_rate_mb']:.1f} MB "
        f"(ratio {ct['database_mb'] / ct['full_rate_mb']:.2f}). Features: {ct['features']}.",
        "",
        "| level | rows | dims | tree build s | query ms / frame |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {lv['level']} | {lv['rows']} | {lv['dims']} | {lv['tree_build_s']:.3f} | {lv['query_ms_per_frame']:.2f} |"
        for lv in ct["levels"]
    ]
    fit = tg["fit"]
    lines += [
        "",
        "## Fill time against gap length",
        "",
        f"`{tg['file']}`, left arm missing, database: {tg['database']}. CPU seconds of `fill_gaps` (one "
        f"thread): {fit['slope_s_per_s']:.3f} s per second of gap + {fit['intercept_s']:.3f} s "
        f"(least squares, R² {fit['r2']:.3f}); the paper reports about 10 s per second of gap. Plot: "
        "`knn_time_vs_gap.png`.",
        "",
        "| gap s | CPU s (mean) | kd-tree build s | query s | solve s |",
        "|---|---|---|---|---|",
    ]
    for s in TIMING_GAPS:
        p = [x for x in tg["points"] if x["gap_s"] == s]
        means = [np.mean([x[key] for x in p]) for key in ("cpu_s", "tree_build_s", "query_s", "solve_s")]
        lines.append(f"| {s:g} | " + " | ".join(f"{v:.3f}" for v in means) + " |")
    lines += ["", "Per-case rows (file, corruption, repeat, method, error sums, CPU s) are in `knn.json`.", ""]
    return "\n".join(lines)


def rounded(value):
    """``value`` (nested dicts / lists) with floats rounded to 6 significant digits, for a compact JSON."""
    if isinstance(value, float):
        return float(f"{value:.6g}")
    if isinstance(value, dict):
        return {k: rounded(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [rounded(v) for v in value]
    return value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example: nice -n 10 .venv/bin/python scripts/bench_knn.py --quick",
    )
    parser.add_argument(
        "--data-root",
        type=Path,
        default=data_root(),
        help="shared data folder (default: $MOCAPNET_DATA or ../shared/data from the repo root)",
    )
    parser.add_argument("--quick", action="store_true", help="one file per group, two corruptions, one repeat")
    parser.add_argument("--repeats", type=int, default=None, help="C3D repeats (default 5, 1 with --quick)")
    parser.add_argument("--bvh-repeats", type=int, default=None, help="cmu120 repeats (default 3, 1 with --quick)")
    parser.add_argument("--bandai-files", type=int, default=200, help="bandai2 subset size (default 200)")
    parser.add_argument("--bandai-test", type=int, default=None, help="bandai2 test files (default 30, 3 with --quick)")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results", help="output folder")
    args = parser.parse_args(argv)
    repeats = args.repeats or (1 if args.quick else 5)
    bvh_repeats = args.bvh_repeats or (1 if args.quick else 3)
    n_test = args.bandai_test or (3 if args.quick else 30)
    needed = CMU41 + CMU41_DB_ONLY + PIG + REAL_NAN + (CMU120, BANDAI2)
    missing = [f for f in needed if not (args.data_root / f).exists()]
    if missing:
        print(f"error: data not found under {args.data_root}: {', '.join(missing)}", file=sys.stderr)
        return 2
    started, cpu0 = time.time(), time.process_time()
    n_corr = 2 if args.quick else len(corruptions())
    n_c3d = ((1 if args.quick else len(CMU41)) + 1) * n_corr * repeats
    with tqdm(total=n_c3d + 2 * n_corr * bvh_repeats + n_test * n_corr, desc="gaps", unit="case") as progress:
        c3d_rows, skipped, c3d_info = bench_c3d(args.data_root, repeats, args.quick, progress)
        bvh_rows, bvh_info = bench_bvh(args.data_root, bvh_repeats, args.bandai_files, n_test, args.quick, progress)
    real = bench_real_nan(args.data_root)
    timing = corpus_timing(args.data_root)
    tvg = time_vs_gap(args.data_root, 1 if args.quick else 3)
    import gapfill

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
        f"niceness {os.nice(0)}, Python {platform.python_version()}, NumPy {np.__version__}, "
        f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}",
        "repeats": {"c3d": repeats, "cmu120": bvh_repeats},
        "gap_seconds": list(GAP_SECONDS),
        "segments": list(SEGMENTS),
        "gapfill": {
            "version": gapfill.__version__,
            "as_shipped": gapfill_spline_as_shipped(),
            "note": "its spline fill calls np.int (removed in NumPy 1.24) and fails as shipped ("
            + gapfill_spline_as_shipped()
            + "); run here with a temporary alias np.int = int. Rigid-body "
            "cluster: the 3 markers nearest the target (mean distance) among those visible "
            "through its whole gap.",
        },
        "c3d": {"rows": c3d_rows, "skipped": skipped, "info": c3d_info},
        "real_nan": real,
        "bvh": {"rows": bvh_rows, "info": bvh_info},
        "corpus_timing": timing,
        "time_vs_gap": tvg,
    }
    report["wall_s"] = time.time() - started
    report["cpu_s"] = time.process_time() - cpu0
    args.out.mkdir(parents=True, exist_ok=True)
    with atomic_output(args.out / "knn.json") as tmp:
        tmp.write_text(json.dumps(rounded(report), separators=(",", ":")) + "\n")
    text = markdown(report)
    with atomic_output(args.out / "knn.md") as tmp:
        tmp.write_text(text)
    plot_time(tvg, args.out / "knn_time_vs_gap.png")
    for name in ("knn.json", "knn.md", "knn_time_vs_gap.png"):
        (args.out / name).chmod(0o644)  # atomic_output's temporary files are private (0600)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
