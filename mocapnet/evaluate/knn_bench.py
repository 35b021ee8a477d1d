"""The benchmark of the data-driven gap filler ``knn`` (issue 12) against interpolation, PCA and ``gapfill``;
``scripts/bench_knn.py`` is its command line.

* **BVH** (joint space, ``mocapnet.methods.knn_angles``): bandai2 fold 0 and bandai1 fold 0, database =
  bandai2 (for bandai2 fold 0: its training folds only; for bandai1: all of it). ``segment-gap:SEG:S`` for
  SEG in left-arm, arms, legs and S in 1, 2, 4 s, scored by ``harness.evaluate_angles`` (``pca`` runs on
  joint positions and is taken back to angles by IK, as in ``mocapnet evaluate``).
* **C3D** (point space, ``mocapnet.methods.knn``): the complete 41-marker HDM05 + CMU takes, every segment,
  1, 2, 4 s, scored by ``harness.score_markers``; database = the other takes of the set. Also PyPI
  ``gapfill`` (rigid body from the 3 markers nearest the target among those visible through its gap).
* **Speed**: CPU seconds per second of gap (one thread) with the whole bandai2 database on bandai1 clips
  with left-arm gaps of 1 to 8 s, and the search time per filled frame.
* **Tuning** (``tune``): variations of the joint-space settings on bandai2 fold-1 clips only, database
  bandai2 without fold 1 (*in*) and also without the clip's content label (*out*: motion the database
  lacks, as on bandai1), scored by ``harness.score_motions`` beside lerp and pca from ``evaluate_angles``.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mocapnet.corpus import content_label, load_corpus
from mocapnet.corrupt import Corruption, corrupt_motion, seed_for
from mocapnet.evaluate.benchmark import gapfill_rigid_body, numpy_int_alias
from mocapnet.evaluate.harness import Evaluation, evaluate_angles, score_markers, score_motions
from mocapnet.evaluate.report import table
from mocapnet.evaluate.results import fmt, markdown_table
from mocapnet.io.c3d import read_c3d
from mocapnet.methods import MethodContext, build_method
from mocapnet.methods.knn_angles import ANGLE_DEFAULTS, fill_angles
from mocapnet.methods.knn_database import cached_database
from mocapnet.methods.knn_window import Searcher, WindowSettings
from mocapnet.motion import Markers, Motion
from mocapnet.segments import SEGMENTS

GAP_SECONDS = (1.0, 2.0, 4.0)
BVH_SEGMENTS = ("left-arm", "arms", "legs")
BVH_METHODS = ("knn", "lerp", "spline", "pca")
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
BVH_CORPORA = ("bandai2", "bandai1")
PARTS = (*BVH_CORPORA, "c3d", "speed")  # what ``run_parts`` can (re)run on its own
DONE_WHEN = ("segment-gap:left-arm:1", "segment-gap:left-arm:4", "segment-gap:legs:2")
TUNE_CORRUPTIONS = ("segment-gap:left-arm:1", "segment-gap:left-arm:4", "segment-gap:legs:1", "segment-gap:legs:2")
TUNE_VARIANTS: tuple[dict, ...] = (
    {},
    {"distance_gain": 6.0},
    {"distance_gain": 12.0},
    {"distance_gain": 24.0},
    {"speed": 30.0},
    {"speed": 30.0, "distance_gain": 12.0},
    {"near_gain": 8.0},
    {"near_gain": 8.0, "distance_gain": 12.0},
    {"max_weight": 0.5},
    {"max_weight": 0.7},
    {"max_weight": 0.5, "speed": 120.0},
    {"max_weight": 0.5, "distance_gain": 0.0},
    {"max_weight": 0.7, "distance_gain": 12.0},
    {"limb_distance": True},
    {"limb_distance": True, "distance_gain": 6.0},
    {"limb_distance": True, "distance_gain": 12.0},
    {"limb_distance": True, "max_weight": 0.7},
    {"limb_distance": True, "max_weight": 0.7, "distance_gain": 6.0},
    {"limb_distance": True, "speed": 120.0, "distance_gain": 6.0},
)
# Round 3 (``--tune --grid plateau``), around the defaults chosen by the grid above.
PLATEAU_VARIANTS: tuple[dict, ...] = (
    {},
    {"plateau_s": 0.25},
    {"plateau_s": 0.5},
    {"plateau_s": 1.0},
    {"plateau_s": 0.5, "max_weight": 0.7},
)
# Third session, round A (``--tune --grid twist``; ``twist="knn"`` was then called ``knn_twist=True``): the
# fallback's twist from the kNN estimate, and the limb gate.
TWIST_VARIANTS: tuple[dict, ...] = (
    {},
    {"twist": "knn"},
    {"twist": "knn", "limb_gate": 10.0},
    {"twist": "knn", "limb_gate": 20.0},
    {"twist": "knn", "k": 32},
    {"twist": "knn", "distance_gain": 9.0},
)
# Round C (``--tune --grid gate``): the limb gate alone, and the fallback's twist from the blend.
GATE_VARIANTS: tuple[dict, ...] = (
    {},
    {"limb_gate": 10.0},
    {"limb_gate": 15.0},
    {"twist": "blend"},
    {"twist": "blend", "limb_gate": 15.0},
)
# Round D (``--tune --grid still``): the gate relative to the limb's own motion.
STILL_VARIANTS: tuple[dict, ...] = (
    {},
    {"still_gate": 1.0},
    {"still_gate": 2.0},
    {"twist": "blend", "still_gate": 1.0},
)
# Fourth session, round E (``--tune --grid fallback``): the PCA fallback keeps the reference's angles of short
# end chains (``short_chain``) and, in gated gaps, the blend's twist (``gated_twist``).
FALLBACK_VARIANTS: tuple[dict, ...] = (
    {},
    {"short_chain": 15.0},
    {"twist": "blend", "short_chain": 15.0},
    {"twist": "blend", "gated_twist": True, "short_chain": 15.0, "still_gate": 1.0},
    {"twist": "blend", "gated_twist": True, "short_chain": 15.0, "still_gate": 2.0},
)
# Fifth session, round F (``--tune --grid pcagate``): the fallback alone where PCA rebuilds the limb in the margins
# better than the neighbours match it (``pca_gate``), and the absolute limb gate again now that the gated fallback
# keeps the blend's twist and short chains (round E).
PCA_GATE_VARIANTS: tuple[dict, ...] = (
    {},
    {"pca_gate": 2.0},
    {"pca_gate": 3.0},
    {"limb_gate": 12.0},
    {"pca_gate": 3.0, "limb_gate": 12.0},
)
# Round G (``--tune --grid forearm``): the PCA fallback keeps the reference's forearm angles too (Bandai at 25 cm:
# LowerArm, whose local angles from PCA's positions inherit the upper arm's twist error), with and without
# ``pca_gate``.
FOREARM_VARIANTS: tuple[dict, ...] = (
    {},
    {"short_chain": 25.0},
    {"short_chain": 25.0, "pca_gate": 3.0},
)
# Sixth session, round H (``--tune --grid pair``): the fallback's positions as the mean of two PCA fills
# (``pca_pair``: every known point, and the ``pca`` baseline's view), its upper arms and thighs turned about their
# bones towards the reference's elbow and knee (``fit_twist``, no point moves), and with them ``pca_gate`` again.
PAIR_VARIANTS: tuple[dict, ...] = (
    {},
    {"pca_pair": True},
    {"fit_twist": 1.0},
    {"pca_pair": True, "fit_twist": 1.0},
    {"pca_pair": True, "pca_gate": 3.0},
    {"pca_pair": True, "fit_twist": 1.0, "pca_gate": 3.0},
)
GRIDS = {
    "main": TUNE_VARIANTS,
    "plateau": PLATEAU_VARIANTS,
    "twist": TWIST_VARIANTS,
    "gate": GATE_VARIANTS,
    "still": STILL_VARIANTS,
    "fallback": FALLBACK_VARIANTS,
    "pcagate": PCA_GATE_VARIANTS,
    "forearm": FOREARM_VARIANTS,
    "pair": PAIR_VARIANTS,
}


def evenly(items: Sequence, n: int) -> list:
    """``n`` evenly spaced items of ``items`` (all of them when there are fewer)."""
    if not items:
        return []
    return [items[i] for i in np.unique(np.linspace(0, len(items) - 1, min(n, len(items))).round().astype(int))]


def bench_bvh(n_clips: int, repeats: int, corpora: Sequence[str] = BVH_CORPORA) -> list[dict]:
    """Rows of ``evaluate_angles`` (plus ``corpus``) for ``corpora`` (bandai2, bandai1) fold 0, ``n_clips`` evenly
    spaced test clips of at least 3 s each (a clip too short for a gap is skipped for that gap), every
    corruption."""
    rows: list[dict] = []
    for name in corpora:
        corpus = load_corpus(name, progress=False)
        train, _, test = corpus.split(0)
        clips = evenly([m for m in test if m.duration >= 3.0], n_clips)
        for seg in BVH_SEGMENTS:
            for s in GAP_SECONDS:
                corruption = f"segment-gap:{seg}:{s:g}"
                got, _ = evaluate_angles(corpus, clips, train, corruption, BVH_METHODS, repeats, progress=False)
                rows += [{**r, "corpus": name} for r in got]
                print(f"{name} {corruption}: {len(clips)} clips", flush=True)
    return rows


def gapfill_rbt(noisy: Markers) -> np.ndarray:
    """PyPI ``gapfill`` rigid-body fill ``[T, M, 3]`` of every gappy marker from the 3 markers nearest it (mean
    distance) among those visible through its whole gap; NaN where it filled nothing."""
    out = noisy.points.copy()
    with numpy_int_alias():
        for i in np.flatnonzero((~noisy.visible).any(axis=0)):
            through = np.flatnonzero(noisy.visible[~noisy.visible[:, i]].all(axis=0))
            dist = np.nanmean(np.linalg.norm(noisy.points[:, through] - noisy.points[:, [i]], axis=-1), axis=0)
            cluster = through[np.argsort(dist)[:3]]
            if len(cluster) == 3:
                out[:, i] = gapfill_rigid_body(noisy.points, i, cluster)
    return out


def bench_c3d(root: Path, repeats: int) -> list[dict]:
    """Rows of ``score_markers`` for every method on every segment gap of the C3D takes (``file`` = path)."""
    clips = []
    for f in C3D_FILES + C3D_DATABASE_ONLY:
        clip = read_c3d(root / f)
        clips.append(clip.select(np.flatnonzero(clip.visible.all(axis=0))))
    context = MethodContext(train=clips, corpus="c3d")
    built = [(m, build_method(m, context, space="points").clean) for m in C3D_METHODS if m != "gapfill-rbt"]
    built.append(("gapfill-rbt", gapfill_rbt))
    rows = []
    for seg in SEGMENTS:
        for s in GAP_SECONDS:
            got, _ = score_markers(
                clips[: len(C3D_FILES)], built, "c3d", Corruption.parse(f"segment-gap:{seg}:{s:g}"), repeats
            )
            rows += got
        print(f"c3d {seg} done", flush=True)
    return rows


def bench_speed(n_clips: int) -> dict:
    """CPU seconds of ``fill_angles`` per second of gap, whole bandai2 database, bandai1 clips, one thread."""
    t0 = time.perf_counter()
    db = cached_database("bandai2")
    load_s = time.perf_counter() - t0
    searcher = Searcher(db.points, db.clip, db.describe())
    clips = evenly([m for m in load_corpus("bandai1", progress=False).motions if m.duration >= 10.5], n_clips)
    per_gap, search_s, frames = {}, 0.0, 0
    for s in TIMING_GAPS:
        cpu = []
        for m in clips:
            c = f"segment-gap:left-arm:{s:g}"
            noisy, mask = corrupt_motion(m, c, np.random.default_rng(seed_for("bandai1", m.name, 0, c)))
            _, stats = fill_angles(m.with_channels(noisy), mask, db, None, (), searcher)
            cpu.append(stats.total_s)
            search_s += stats.search_s
            frames += int(mask.any(axis=1).sum())
        per_gap[f"{s:g}"] = float(np.mean(cpu)) / s
    return {"database": db.describe(), "load_s": load_s, "clips": len(clips), "per_gap": per_gap,
            "query_ms": 1e3 * search_s / frames}  # fmt: skip


def check_parts(parts: Sequence[str], have_previous: bool) -> None:
    """Raise ValueError unless ``parts`` is a non-empty selection of ``PARTS`` and, when it is not all of them,
    an earlier report holds the rest (``have_previous``)."""
    if set(parts) - set(PARTS) or not parts:
        raise ValueError(f"bench_knn: parts must be among {', '.join(PARTS)}; got {', '.join(parts) or 'none'}")
    rest = [p for p in PARTS if p not in parts]
    if rest and not have_previous:
        raise ValueError(f"bench_knn: no earlier report to take {', '.join(rest)} from")


def run_parts(parts: Sequence[str], root: Path, n_clips: int, repeats: int) -> dict:
    """The benchmark's ``parts`` (of ``PARTS``): ``{"bvh": rows, "c3d": rows, "speed": dict}``, only the keys
    asked for (``bvh`` when a corpus is)."""
    check_parts(parts, True)
    out: dict = {}
    if "speed" in parts:
        out["speed"] = bench_speed(10)
    corpora = [c for c in BVH_CORPORA if c in parts]
    if corpora:
        out["bvh"] = bench_bvh(n_clips, repeats, corpora)
    if "c3d" in parts:
        out["c3d"] = bench_c3d(root, repeats)
    return out


def run_record(provenance: dict, n_clips: int, repeats: int, wall_s: float) -> dict:
    """One run's entry of a report's ``runs``: ``provenance`` (``results.provenance``), the clip count,
    repeats, wall time (s) and the joint-space knn defaults it ran with."""
    return {**provenance, "n_clips": n_clips, "repeats": repeats, "wall_s": wall_s,
            "knn_settings": repr(WindowSettings(**ANGLE_DEFAULTS))}  # fmt: skip


def merge_parts(previous: dict | None, fresh: dict, parts: Sequence[str], run: dict) -> dict:
    """A whole report from ``fresh`` (``run_parts`` of ``parts``) and, for the other parts, ``previous`` (an
    earlier report; None when every part was run). ``runs`` lists, per run whose results the report still
    holds, its ``parts`` and ``run`` (provenance, ``wall_s``, ``n_clips``, ``repeats``). Raises ValueError when
    a part is neither run nor in ``previous``."""
    check_parts(parts, previous is not None)
    rest = [p for p in PARTS if p not in parts]
    prev = previous or {}
    earlier = prev.get("runs") or ([{**{k: prev[k] for k in ("command", "git_commit", "machine", "wall_s",
                                                            "n_clips", "repeats")}, "parts": list(PARTS)}]
                                   if rest else [])  # fmt: skip
    runs = [{**r, "parts": [p for p in r["parts"] if p in rest]} for r in earlier]
    runs = [r for r in runs if r["parts"]] + [{**run, "parts": list(parts)}]
    bvh = [r for r in prev.get("bvh", []) if r["corpus"] in rest] + fresh.get("bvh", [])
    report = {**run, "runs": runs, "bvh": bvh}
    for key in ("c3d", "speed"):
        report[key] = fresh[key] if key in parts else prev[key]
    return report


def variant_name(variant: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in variant.items()) or "defaults"


class RepeatSearcher(Searcher):
    """A ``Searcher`` that answers a query it has answered before from memory: tuning variants that change only
    the blend ask the same windows again (same results, one search)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._answers: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def windows(
        self, feats: np.ndarray, weights: np.ndarray, offsets: np.ndarray, length: int, allowed: np.ndarray, k: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """``Searcher.windows``, remembered by a hash of every argument."""
        digest = hashlib.sha1(f"{length},{k}".encode())
        for a in (feats, weights, offsets, allowed):
            digest.update(str(a.dtype).encode() + np.ascontiguousarray(a).tobytes())
        key = digest.hexdigest()
        if key not in self._answers:
            self._answers[key] = super().windows(feats, weights, offsets, length, allowed, k)
        return self._answers[key]


def tune(n_clips: int, variants: Sequence[dict] = TUNE_VARIANTS) -> list[dict]:
    """Rows (``score_motions``, plus ``mode`` in/out) of lerp, pca and every knn of ``variants`` (changes of
    ``ANGLE_DEFAULTS``) on
    ``n_clips`` bandai2 fold-1 clips of at least 7 s (module docstring)."""
    corpus = load_corpus("bandai2", progress=False)
    train, _, val = corpus.split(1)
    clips = evenly([m for m in val if m.duration >= 7.0], n_clips)
    db = cached_database("bandai2")
    searcher = RepeatSearcher(db.points, db.clip, db.describe())
    held_out = {m.name for m in val}  # fold 1

    def knn(settings: WindowSettings, out_mode: bool):
        def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
            label = content_label(noisy.name)
            exclude = held_out | ({n for n in db.names if content_label(n) == label} if out_mode else set())
            return fill_angles(noisy, mask, db, settings, exclude, searcher)[0]

        return clean

    rows = []
    for c in TUNE_CORRUPTIONS:
        base, _ = evaluate_angles(corpus, clips, train, c, ("lerp", "pca"), 1, progress=False)
        for mode in ("in", "out"):
            built = [(variant_name(v), knn(WindowSettings(**{**ANGLE_DEFAULTS, **v}), mode == "out")) for v in variants]
            got, _ = score_motions(clips, built, "bandai2", Corruption.parse(c), 1)
            rows += [{**r, "mode": mode} for r in base + got]
        print(f"tune {c} done", flush=True)
    return rows


def _mean(rows: list[dict], key: str, **where: object) -> float:
    vals = [r[key] for r in rows if all(r[k] == v for k, v in where.items()) and np.isfinite(r[key])]
    return float(np.mean(vals)) if vals else float("nan")


def variants_of(rows: list[dict]) -> list[str]:
    """The knn variants of ``tune`` rows, in order of appearance."""
    return list(dict.fromkeys(r["method"] for r in rows if r["method"] not in ("lerp", "pca")))


def tune_ratios(rows: list[dict]) -> dict[str, list[tuple[float, float]]]:
    """Per knn variant of ``tune`` rows and (corruption, mode) cell: (``pos_err / min(lerp, pca pos_err)``,
    ``RMS gap_err / lerp's RMS gap_err``)."""
    ratios: dict[str, list[tuple[float, float]]] = {}
    for c in TUNE_CORRUPTIONS:
        for mode in ("in", "out"):
            sel = [r for r in rows if r["corruption"] == c and r["mode"] == mode]
            best_pos = min(_mean(sel, "pos_err_cm", method=m) for m in ("lerp", "pca"))
            rms = {m: np.sqrt(_mean([{"g": r["gap_err_deg"] ** 2} for r in sel if r["method"] == m], "g"))
                   for m in {r["method"] for r in sel}}  # fmt: skip
            for v in variants_of(rows):
                ratios.setdefault(v, []).append((_mean(sel, "pos_err_cm", method=v) / best_pos, rms[v] / rms["lerp"]))
    return ratios


def tune_scores(rows: list[dict]) -> dict[str, float]:
    """The selection rule (knn-note): per variant the mean over (corruption, mode) cells of
    ``max(pos_err / min(lerp, pca pos_err), RMS gap_err / lerp's RMS gap_err)``."""
    return {v: float(np.mean([max(cell) for cell in cells])) for v, cells in tune_ratios(rows).items()}


def tune_angle_ratios(rows: list[dict]) -> dict[str, float]:
    """The selection rule's guard (knn-note, third session): per variant the mean over the cells of
    ``RMS gap_err / lerp's RMS gap_err``."""
    return {v: float(np.mean([cell[1] for cell in cells])) for v, cells in tune_ratios(rows).items()}


def tune_markdown(rows: list[dict], report: dict) -> str:
    """Table of ``tune`` rows: per variant and cell RMS gap error (°) / position error (cm), and the score;
    ``report``: the run's ``report.provenance`` and ``wall_s``."""
    scores, angles = tune_scores(rows), tune_angle_ratios(rows)
    cells = [(c, mode) for mode in ("in", "out") for c in TUNE_CORRUPTIONS]
    lines = [
        f"# Joint-space knn settings on bandai2 fold 1 ({len({r['file'] for r in rows})} clips of at least 7 s)",
        "",
        f"- command: `{report['command']}`; git commit `{report['git_commit']}`; {report['machine']}; wall time "
        f"{report['wall_s']:.0f} s",
        "",
        f"Defaults: `{WindowSettings(**ANGLE_DEFAULTS)}`. Each cell: RMS gap error (degrees) / "
        "whole-body position error (cm). *in*: database = bandai2 without fold 1; *out*: also without every "
        "clip of the scored clip's content label (motion the database lacks). score: mean over the cells of "
        "max(pos / better of lerp and pca, gap / lerp); lowest wins (the selection rule of the knn note). "
        "angle ratio: mean over the cells of gap / lerp (third session's guard: at most the defaults').",
        "",
    ]
    body = []
    for m in ["lerp", "pca", *variants_of(rows)]:
        out = []
        for c, mode in cells:
            sel = [r for r in rows if r["corruption"] == c and r["mode"] == mode and r["method"] == m]
            rms = np.sqrt(np.mean([r["gap_err_deg"] ** 2 for r in sel]))
            out.append(f"{rms:.2f} / {_mean(sel, 'pos_err_cm'):.3f}")
        body.append([m, *out, fmt(scores.get(m)), fmt(angles.get(m))])
    head = ["variant", *(f"{c.split(':', 1)[1]} {mode}" for c, mode in cells), "score", "angle ratio"]
    return "\n".join(lines + markdown_table(head, body)) + "\n"


def grid(rows: list[dict], group: str, methods: Sequence[str], metric: str, ref: str = "lerp") -> list[str]:
    """Markdown: one line per value of ``group``, the mean ``metric`` of each method (ratio to ``ref``)."""
    body = []
    for g in sorted({r[group] for r in rows}, key=str):
        sel = [r for r in rows if r[group] == g]
        base = _mean(sel, metric, method=ref)
        cells = [f"{fmt(v)} ({fmt(v / base, 2)})" for v in (_mean(sel, metric, method=m) for m in methods)]
        body.append([g, sum(r["method"] == ref for r in sel), *cells])
    return markdown_table([group, "cases", *methods], body)


def verdicts(bvh: list[dict], c3d: list[dict], speed: dict) -> list[str]:
    """The issue's done-when checks, each with the numbers it compares."""
    out = []
    for c in DONE_WHEN:
        sel = [r for r in bvh if r["corpus"] == "bandai1" and r["corruption"] == c]
        pos = {m: _mean(sel, "pos_err_cm", method=m) for m in ("knn", "lerp", "pca")}
        ang = {m: _mean(sel, "angle_err_deg", method=m) for m in ("knn", "lerp")}
        ok = pos["knn"] < min(pos["lerp"], pos["pca"]) and ang["knn"] < ang["lerp"]
        out.append(
            f"- bandai1 `{c}`: pos knn {pos['knn']:.3f} cm vs lerp {pos['lerp']:.3f}, pca {pos['pca']:.3f}; "
            f"angle knn {ang['knn']:.3f}° vs lerp {ang['lerp']:.3f}° — **{'met' if ok else 'missed'}**"
        )
    for s in GAP_SECONDS:
        e = {m: _mean([r for r in c3d if r["gap_s"] == s], "point_err_cm", method=m) for m in C3D_METHODS}
        ok = e["knn"] < min(e["lerp"], e["spline"], e["gapfill-rbt"])
        out.append(
            f"- C3D whole segments {s:g} s: knn {e['knn']:.2f} cm vs lerp {e['lerp']:.2f}, spline {e['spline']:.2f}, "
            f"gapfill-rbt {e['gapfill-rbt']:.2f} — **{'met' if ok else 'missed'}**"
        )
    worst = max(speed["per_gap"].values())
    out.append(
        f"- fill time per second of gap (whole bandai2 database, one thread): at most {worst:.3f} s/s over "
        f"{', '.join(speed['per_gap'])} s gaps — **{'met' if worst <= 0.2 else 'missed'}** (target 0.2)"
    )
    return out


def markdown(report: dict) -> str:
    """``knn.md`` from the report of ``scripts/bench_knn.py`` (rows, speed, provenance)."""
    bvh, c3d = ([{**r, "gap_s": float(r["corruption"].split(":")[2])} for r in report[k]] for k in ("bvh", "c3d"))
    speed = report["speed"]
    lines = [
        "# Data-driven gap filling benchmark (`knn`)",
        "",
        *(
            f"- {', '.join(r['parts'])}: command `{r['command']}`; git commit `{r['git_commit']}`; {r['machine']}; "
            f"wall time {r['wall_s']:.0f} s; BVH: up to {r['n_clips']} clips per corpus, {r['repeats']} repeat(s), knn "
            f"settings `{r.get('knn_settings', 'the defaults at that commit')}`"
            for r in report["runs"]
        ),
        "- BVH: evenly spaced fold-0 test clips of at least 3 s (as many as the run above says); "
        f"database {speed['database']} (for bandai2 fold 0 only its training "
        "folds 2-4; for bandai1 all of it). Metrics of PROTOCOL.md; ratios in the overview tables are to lerp, "
        "in the per-corruption tables to the better of lerp and spline (the one reference rule).",
        f"- knn settings (BVH), the defaults now: `{WindowSettings(**ANGLE_DEFAULTS)}`, chosen on bandai2 fold 1 "
        "(`knn_tuning.md`, then `knn_tuning_plateau.md`; `knn_tuning_twist.md`, `_gate.md` and `_still.md` changed "
        "nothing; then `knn_tuning_fallback.md`: twist, gated_twist, short_chain, still_gate; "
        "`knn_tuning_pcagate.md` and `_forearm.md` changed nothing; then `knn_tuning_pair.md`: pca_pair, fit_twist, "
        "pca_gate). C3D knn: the registered default (`search=energy`).",
        "",
        "## Done when (issue 12)",
        "",
        *verdicts(bvh, c3d, speed),
    ]
    for corpus in ("bandai2", "bandai1"):
        rows = [r for r in bvh if r["corpus"] == corpus]
        for metric in ("pos_err_cm", "angle_err_deg"):
            lines += ["", f"### {corpus} fold 0, `{metric}` by corruption (ratio to lerp)", ""]
            lines += grid(rows, "corruption", BVH_METHODS, metric)
        lines += ["", f"### {corpus} fold 0, `pos_err_cm` by gap length (ratio to lerp)", ""]
        lines += grid(rows, "gap_s", BVH_METHODS, "pos_err_cm")
    lines += ["", f"## C3D whole-segment gaps ({len(C3D_FILES)} takes scored; database = the other takes incl. "
              f"{', '.join(C3D_DATABASE_ONLY)}), mean error of the filled points, cm (ratio to lerp)", ""]  # fmt: skip
    lines += (
        grid(c3d, "gap_s", C3D_METHODS, "point_err_cm") + [""] + grid(c3d, "corruption", C3D_METHODS, "point_err_cm")
    )
    lines += [
        "",
        f"## Fill time, whole bandai2 database, one thread ({speed['clips']} bandai1 clips, left arm)",
        "",
        f"Database load from the cache {speed['load_s']:.2f} s (once); search {speed['query_ms']:.3f} ms CPU per "
        "filled frame.",
        "",
        *markdown_table(["gap s", "s per second of gap"], [(g, fmt(per)) for g, per in speed["per_gap"].items()]),
        "",
        "## Per corruption (`mocapnet.evaluate.report.table`)",
    ]
    for space, name, rows in [("angles", c, [r for r in bvh if r["corpus"] == c]) for c in ("bandai2", "bandai1")] + [
        ("points", "c3d", c3d)
    ]:
        for c in sorted({r["corruption"] for r in rows}):
            sel = [r for r in rows if r["corruption"] == c]
            methods = C3D_METHODS if space == "points" else BVH_METHODS
            ev = Evaluation(name, c, space, list(methods), sel, repeats=report["repeats"])
            lines += ["", f"### {name} `{c}`", "", table(ev, markdown=True)]
    return "\n".join(lines) + "\n"
