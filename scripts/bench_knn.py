"""Benchmark of the data-driven gap filler ``knn`` against interpolation, PCA and ``gapfill``.

* **BVH** (joint space, ``mocapnet.methods.knn_angles``): bandai2 fold 0 and bandai1 fold 0, database =
  bandai2 (for bandai2 fold 0: its training folds only; for bandai1: all of it). ``segment-gap:SEG:S``
  for SEG in left-arm, arms, legs and S in 1, 2, 4 s, scored by ``mocapnet.evaluate.harness.evaluate_angles``
  (``pca`` runs on joint positions and is taken back to angles by IK, as in ``mocapnet evaluate``).
* **C3D** (point space, ``mocapnet.methods.knn``): the complete 41-marker HDM05 + CMU takes, every
  segment, 1, 2, 4 s; database = the other takes of the set. Also PyPI ``gapfill`` (rigid body from the 3
  markers nearest the target among those visible through its gap).
* **Speed**: fill time per second of gap (CPU, one thread) with the whole bandai2 database on bandai1 clips
  with left-arm gaps of 1 to 8 s, and the search time per query frame.

Writes ``benchmarks/results/knn.md`` and ``knn.json``. ``--tune`` instead scores one-at-a-time variations
of the joint-space settings on bandai2 fold-1 clips (database: bandai2 without fold 1; and, to mimic motion
the database lacks, also without the clip's content label) and writes ``knn_tuning.md``. Example::

    OMP_NUM_THREADS=1 nice -n 5 .venv/bin/python scripts/bench_knn.py           # about 7 min on 2 cores
    OMP_NUM_THREADS=1 nice -n 5 .venv/bin/python scripts/bench_knn.py --tune    # about 5 min
    .venv/bin/python scripts/bench_knn.py --clips 4 --out /tmp/knn              # smoke run
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from mocapnet.corpus import data_root, load_corpus
from mocapnet.corrupt import corrupt_markers, corrupt_motion, seed_for
from mocapnet.evaluate.benchmark import REPO, gapfill_rigid_body, git_commit, numpy_int_alias
from mocapnet.evaluate.harness import evaluate_angles
from mocapnet.io.atomic import atomic_output
from mocapnet.io.c3d import read_c3d
from mocapnet.methods import MethodContext, build_method
from mocapnet.methods.knn_angles import ANGLE_DEFAULTS, fill_angles
from mocapnet.methods.knn_database import cached_database
from mocapnet.methods.knn_window import Searcher, WindowSettings
from mocapnet.segments import SEGMENTS

GAP_SECONDS = (1.0, 2.0, 4.0)
BVH_SEGMENTS = ("left-arm", "arms", "legs")
BVH_METHODS = ("knn", "lerp", "spline")
C3D_FILES = (
    "c3d/hdm05/HDM_bd_01-02_01_120.c3d",
    "c3d/hdm05/HDM_bd_05-01_01_120.c3d",
    "c3d/hdm05/HDM_mm_01-02_03_120.c3d",
    "c3d/cmu/85_02.c3d",
    "c3d/cmu/85_12.c3d",
)
C3D_DATABASE_ONLY = ("c3d/cmu/01_01.c3d", "c3d/cmu/02_01.c3d")  # 02_01 is too short for a 4 s gap
C3D_METHODS = ("knn", "pca", "lerp", "spline", "gapfill-rbt")
TIMING_GAPS = (1.0, 2.0, 4.0, 8.0)
TUNE_CORRUPTIONS = ("segment-gap:left-arm:1", "segment-gap:left-arm:4", "segment-gap:legs:1", "segment-gap:legs:2")
TUNE_VARIANTS = (
    {},
    {"k": 8},
    {"k": 32},
    {"speed": 30.0},
    {"speed": 120.0},
    {"speed": None},
    {"distance_gain": 0.0},
    {"distance_gain": 1.0},
    {"fallback": "lerp"},
    {"own": False},
    {"margin_s": 0.6},
)
DONE_WHEN = ("segment-gap:left-arm:1", "segment-gap:left-arm:4", "segment-gap:legs:2")


def bvh_clips(corpus: str, n: int) -> tuple[object, list, list]:
    """Corpus, ``n`` evenly spaced fold-0 test clips of at least 3 s (a 1 s gap with 1 s either side; a clip
    too short for a longer gap is skipped by the harness for that gap) and the training clips."""
    c = load_corpus(corpus, progress=False)
    train, _, test = c.split(0)
    long = [m for m in test if m.duration >= 3.0]
    return c, [long[i] for i in np.linspace(0, len(long) - 1, min(n, len(long))).round().astype(int)], train


def bench_bvh(n_clips: int, repeats: int) -> list[dict]:
    """Rows of ``evaluate_angles`` for both corpora, every BVH corruption, knn/lerp/spline and pca."""
    rows: list[dict] = []
    for name in ("bandai2", "bandai1"):
        corpus, clips, train = bvh_clips(name, n_clips)
        for seg in BVH_SEGMENTS:
            for s in GAP_SECONDS:
                corruption = f"segment-gap:{seg}:{s:g}"
                for methods, learn in ((BVH_METHODS, train), (("pca",), [])):  # pca needs no training clips
                    got, _ = evaluate_angles(corpus, clips, learn, corruption, methods, repeats, progress=False)
                    rows += [{**r, "corpus": name} for r in got]
                print(f"{name} {corruption}: {len(clips)} clips", flush=True)
    return rows


def _cluster(noisy, marker: int) -> np.ndarray:
    """The 3 markers nearest ``marker`` (mean distance) among those visible through its whole gap."""
    gap = ~noisy.visible[:, marker]
    through = np.flatnonzero(noisy.visible[gap].all(axis=0))
    dist = np.nanmean(np.linalg.norm(noisy.points[:, through] - noisy.points[:, [marker]], axis=-1), axis=0)
    return through[np.argsort(dist)[:3]]


def gapfill_rbt(noisy) -> np.ndarray:
    """PyPI ``gapfill`` rigid-body fill of every gappy marker, NaN where it filled nothing."""
    out = noisy.points.copy()
    with numpy_int_alias():
        for i in np.flatnonzero((~noisy.visible).any(axis=0)):
            cluster = _cluster(noisy, i)
            if len(cluster) == 3:
                out[:, i] = gapfill_rigid_body(noisy.points, i, cluster)
    return out


def bench_c3d(root: Path, repeats: int) -> list[dict]:
    """Point error (cm) of every method on every segment gap of the C3D takes."""
    clips = []
    for f in C3D_FILES + C3D_DATABASE_ONLY:
        clip = read_c3d(root / f)
        clips.append(clip.select(np.flatnonzero(clip.visible.all(axis=0))))
    context = MethodContext(train=clips, corpus="c3d")
    built = {m: build_method(m, context, space="points").clean for m in C3D_METHODS if m != "gapfill-rbt"}
    built["gapfill-rbt"] = gapfill_rbt
    rows = []
    for path, truth in zip(C3D_FILES, clips):
        for seg in SEGMENTS:
            for s in GAP_SECONDS:
                corruption = f"segment-gap:{seg}:{s:g}"
                for rep in range(repeats):
                    noisy = corrupt_markers(
                        truth, corruption, np.random.default_rng(seed_for("c3d", truth.name, rep, corruption))
                    )
                    miss = ~noisy.visible
                    for method, clean in built.items():
                        t0 = time.process_time()
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            out = clean(noisy)
                        err = np.linalg.norm(out[miss] - truth.points[miss], axis=-1)
                        rows.append(
                            {
                                "file": path,
                                "corruption": corruption,
                                "repeat": rep,
                                "method": method,
                                "point_err_cm": float(np.nanmean(err)),
                                "filled": float(np.isfinite(err).mean()),
                                "cpu_s": time.process_time() - t0,
                            }
                        )
        print(f"c3d {path} done", flush=True)
    return rows


def bench_speed(n_clips: int) -> dict:
    """CPU seconds of ``fill_angles`` per second of gap, whole bandai2 database, bandai1 clips, one thread."""
    t0 = time.perf_counter()
    db = cached_database("bandai2")
    load_s = time.perf_counter() - t0
    searcher = Searcher(db.points, db.clip, db.describe())
    corpus = load_corpus("bandai1", progress=False)
    long = [m for m in corpus.motions if m.duration >= max(TIMING_GAPS) + 2.5]
    clips = [long[i] for i in np.linspace(0, len(long) - 1, min(n_clips, len(long))).round().astype(int)]
    points = []
    for s in TIMING_GAPS:
        corruption = f"segment-gap:left-arm:{s:g}"
        for m in clips:
            noisy, mask = corrupt_motion(
                m, corruption, np.random.default_rng(seed_for("bandai1", m.name, 0, corruption))
            )
            _, stats = fill_angles(m.with_channels(noisy), mask, db, None, (), searcher)
            frames = int(mask.any(axis=1).sum())
            points.append({"gap_s": s, "cpu_s": stats.total_s, "search_s": stats.search_s, "frames": frames})
    return {"database": db.describe(), "load_s": load_s, "clips": len(clips), "points": points}


def tune(n_clips: int, out: Path) -> str:
    """Mean gap error (degrees) and position error (cm) of each variation of ``ANGLE_DEFAULTS`` on bandai2
    fold-1 clips of at least 7 s, as a markdown table written to ``out``."""
    from mocapnet.corpus import content_label
    from mocapnet.evaluate import metrics
    from mocapnet.methods.baselines import lerp_fill

    db = cached_database("bandai2")
    searcher = Searcher(db.points, db.clip, db.describe())
    _, _, val = load_corpus("bandai2", progress=False).split(1)
    long = [m for m in val if m.duration >= 7.0]
    clips = [long[i] for i in np.linspace(0, len(long) - 1, min(n_clips, len(long))).round().astype(int)]
    held_out = [m.name for m in val]
    results: dict[tuple, list] = {}
    for m in clips:
        same_content = [n for n in db.names if content_label(n) == content_label(m.name)]
        for corruption in TUNE_CORRUPTIONS:
            rng = np.random.default_rng(seed_for("bandai2", m.name, 0, corruption))
            noisy, mask = corrupt_motion(m, corruption, rng)
            outs = {("lerp", mode): lerp_fill(noisy, mask) for mode in ("in", "out")}
            for v, variant in enumerate(TUNE_VARIANTS):
                settings = WindowSettings(**{**ANGLE_DEFAULTS, **variant})
                for mode, exclude in (("in", held_out), ("out", held_out + same_content)):
                    outs[(v, mode)] = fill_angles(m.with_channels(noisy), mask, db, settings, exclude, searcher)[0]
            for key, ch in outs.items():
                results.setdefault(key + (corruption,), []).append(
                    (metrics.gap_err_deg(ch, m.channels, mask), metrics.pos_err_cm(m, ch))
                )
    names = ["lerp"] + [", ".join(f"{k}={v}" for k, v in variant.items()) or "defaults" for variant in TUNE_VARIANTS]
    lines = [
        f"# Joint-space knn settings on bandai2 fold 1 ({len(clips)} clips of at least 7 s, 1 repeat)",
        "",
        f"Defaults: `{WindowSettings(**ANGLE_DEFAULTS)}`. Command: `python scripts/bench_knn.py --tune`. Each cell: "
        "RMS gap error (degrees) / whole-body position error (cm). *in*: database = bandai2 without fold 1; "
        "*out*: also without every clip of the scored clip's content label (motion the database lacks).",
        "",
        "| variant | "
        + " | ".join(f"{c.split(':', 1)[1]} {mode}" for mode in ("in", "out") for c in TUNE_CORRUPTIONS)
        + " |",
        "|---" * (1 + 2 * len(TUNE_CORRUPTIONS)) + "|",
    ]
    for key, name in zip(["lerp", *range(len(TUNE_VARIANTS))], names):
        cells = []
        for mode in ("in", "out"):
            for c in TUNE_CORRUPTIONS:
                vals = np.array(results[(key, mode, c)])
                cells.append(f"{np.sqrt(np.mean(vals[:, 0] ** 2)):.2f} / {vals[:, 1].mean():.3f}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    with atomic_output(out) as tmp:
        tmp.write_text(text)
    return text


def _mean(rows: list[dict], key: str) -> float:
    vals = [r[key] for r in rows if np.isfinite(r[key])]
    return float(np.mean(vals)) if vals else float("nan")


def _table(rows: list[dict], group: str, methods: tuple[str, ...], metric: str, ref: str) -> list[str]:
    """Markdown: one line per value of ``group``, the mean ``metric`` per method (ratio to ``ref``)."""
    lines = [f"| {group} | cases | " + " | ".join(methods) + " |", "|---" * (len(methods) + 2) + "|"]
    for g in sorted({r[group] for r in rows}, key=str):
        sel = [r for r in rows if r[group] == g]
        base = _mean([r for r in sel if r["method"] == ref], metric)
        cells = []
        for m in methods:
            v = _mean([r for r in sel if r["method"] == m], metric)
            cells.append(f"{v:.3f} ({v / base:.2f})")
        lines.append(f"| {g} | {sum(r['method'] == ref for r in sel)} | " + " | ".join(cells) + " |")
    return lines


def _verdicts(bvh: list[dict], c3d: list[dict], speed: dict) -> list[str]:
    """The issue's done-when checks, each with the numbers it compares."""
    out = []
    b1 = [r for r in bvh if r["corpus"] == "bandai1"]
    for corruption in DONE_WHEN:
        sel = [r for r in b1 if r["corruption"] == corruption]
        pos = {m: _mean([r for r in sel if r["method"] == m], "pos_err_cm") for m in ("knn", "lerp", "pca")}
        ang = {m: _mean([r for r in sel if r["method"] == m], "angle_err_deg") for m in ("knn", "lerp")}
        ok = pos["knn"] < min(pos["lerp"], pos["pca"]) and ang["knn"] < ang["lerp"]
        out.append(
            f"- bandai1 `{corruption}`: pos knn {pos['knn']:.3f} cm vs lerp {pos['lerp']:.3f}, pca {pos['pca']:.3f}; "
            f"angle knn {ang['knn']:.3f}° vs lerp {ang['lerp']:.3f}° — **{'met' if ok else 'missed'}**"
        )
    for s in GAP_SECONDS:
        sel = [r for r in c3d if r["gap_s"] == s]
        e = {m: _mean([r for r in sel if r["method"] == m], "point_err_cm") for m in C3D_METHODS}
        ok = e["knn"] < min(e["lerp"], e["spline"], e["gapfill-rbt"])
        out.append(
            f"- C3D whole segments {s:g} s: knn {e['knn']:.2f} cm vs lerp {e['lerp']:.2f}, spline {e['spline']:.2f}, "
            f"gapfill-rbt {e['gapfill-rbt']:.2f} — **{'met' if ok else 'missed'}**"
        )
    worst = max(speed["per_gap"].values())
    out.append(
        f"- fill time per second of gap (whole bandai2 database, one thread): at most {worst:.3f} s/s over "
        f"{', '.join(f'{g:g}' for g in TIMING_GAPS)} s gaps — **{'met' if worst <= 0.2 else 'missed'}** (target 0.2)"
    )
    return out


def markdown(report: dict) -> str:
    bvh, c3d = ([{**r, "gap_s": float(r["corruption"].split(":")[2])} for r in report[k]] for k in ("bvh", "c3d"))
    speed = report["speed"]
    lines = [
        "# Data-driven gap filling benchmark (`knn`)",
        "",
        f"- command: `{report['command']}`",
        f"- git commit: `{report['git_commit']}`; machine: {report['machine']}",
        f"- wall time {report['wall_s']:.0f} s",
        f"- BVH: {report['n_clips']} clips per corpus (fold-0 test clips of at least 3 s, evenly spaced; a clip too "
        "short for a gap with 1 s either side is skipped for that gap: see `cases`), "
        f"{report['repeats']} repeat(s); database bandai2 ({speed['database']}; for bandai2 fold 0 only its "
        "training folds 2-4, for bandai1 all of it). Metrics of PROTOCOL.md: `pos_err_cm` (whole body, all "
        "frames), `angle_err_deg` (all frames, scored channels), `gap_err_deg` (missing samples). Ratios to lerp.",
        f"- knn settings (BVH): {WindowSettings(**ANGLE_DEFAULTS)}, chosen on bandai2 fold-1 clips "
        "(database without fold 1, and without the clip's content label to mimic motion the database lacks); "
        "the clip's own fully observed windows compete with the database's.",
        "- C3D knn: the registered default (`search=energy`: the paper's per-frame kd-tree + energy "
        "minimisation, k 16, the take's own frames join the database, blend with lerp at 150 cm/s; chosen on "
        "the Plug-in-Gait tennis serve, not on these takes).",
        "",
        "## Done when (issue 12)",
        "",
        *_verdicts(bvh, c3d, speed),
    ]
    for corpus in ("bandai2", "bandai1"):
        rows = [r for r in bvh if r["corpus"] == corpus]
        methods = BVH_METHODS + ("pca",)
        for metric in ("pos_err_cm", "angle_err_deg", "gap_err_deg"):
            lines += ["", f"### {corpus} fold 0, `{metric}` by corruption", ""]
            lines += _table(rows, "corruption", methods, metric, "lerp")
        lines += ["", f"### {corpus} fold 0, `pos_err_cm` by gap length (segments {', '.join(BVH_SEGMENTS)})", ""]
        lines += _table(rows, "gap_s", methods, "pos_err_cm", "lerp")
    lines += [
        "",
        f"## C3D whole-segment gaps, 41-marker HDM05 + CMU ({len(C3D_FILES)} takes scored, {report['repeats']} "
        f"repeat(s), database = the other takes incl. {', '.join(C3D_DATABASE_ONLY)})",
        "",
        "Mean distance (cm) of the filled points to the truth over the missing samples; ratio to lerp.",
        "",
    ]
    lines += _table(c3d, "gap_s", C3D_METHODS, "point_err_cm", "lerp")
    lines += [""] + _table(c3d, "corruption", C3D_METHODS, "point_err_cm", "lerp")
    lines += [
        "",
        "CPU seconds per case (mean): "
        + ", ".join(f"{m} {_mean([r for r in c3d if r['method'] == m], 'cpu_s'):.3f}" for m in C3D_METHODS),
    ]
    lines += [
        "",
        f"## Fill time, whole bandai2 database, one thread ({speed['clips']} bandai1 clips, left arm)",
        "",
        f"Database load from the cache {speed['load_s']:.2f} s (once). "
        f"Search (one window search per gap, whole database): {speed['query_ms']:.3f} ms CPU per filled frame.",
        "",
        "| gap s | CPU s per gap (mean) | s per second of gap |",
        "|---|---|---|",
    ]
    for g, per in speed["per_gap"].items():
        lines.append(f"| {g} | {per * float(g):.3f} | {per:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clips", type=int, default=60, help="BVH clips per corpus (default 60)")
    parser.add_argument("--repeats", type=int, default=1, help="repeats per clip and corruption (default 1)")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results", help="output folder")
    parser.add_argument("--tune", action="store_true", help="score setting variations on bandai2 fold 1 instead")
    args = parser.parse_args(argv)
    if args.tune:
        print(tune(20, args.out / "knn_tuning.md"))
        return 0
    root = data_root()
    missing = [
        f
        for f in C3D_FILES + C3D_DATABASE_ONLY + ("bvh/bandai_namco_1", "bvh/bandai_namco_2")
        if not (root / f).exists()
    ]
    if missing:
        print(f"error: data not found under {root}: {', '.join(missing)}", file=sys.stderr)
        return 2
    started = time.time()
    speed = bench_speed(10)
    per_gap = {}
    for g in TIMING_GAPS:
        pts = [p for p in speed["points"] if p["gap_s"] == g]
        per_gap[f"{g:g}"] = float(np.mean([p["cpu_s"] for p in pts])) / g
    speed["per_gap"] = per_gap
    speed["query_ms"] = 1e3 * sum(p["search_s"] for p in speed["points"]) / sum(p["frames"] for p in speed["points"])
    bvh = bench_bvh(args.clips, args.repeats)
    c3d = bench_c3d(root, args.repeats)
    report = {
        "command": shlex.join(
            ["python", os.path.relpath(sys.argv[0], REPO), *(sys.argv[1:] if argv is None else argv)]
        ),
        "git_commit": git_commit(),
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs shared, OMP_NUM_THREADS="
        f"{os.environ.get('OMP_NUM_THREADS', 'unset')}, NumPy {np.__version__}",
        "n_clips": args.clips,
        "repeats": args.repeats,
        "bvh": bvh,
        "c3d": c3d,
        "speed": speed,
        "wall_s": time.time() - started,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    with atomic_output(args.out / "knn.json") as tmp:
        tmp.write_text(json.dumps(report, separators=(",", ":"), default=float) + "\n")
    text = markdown(report)
    with atomic_output(args.out / "knn.md") as tmp:
        tmp.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
