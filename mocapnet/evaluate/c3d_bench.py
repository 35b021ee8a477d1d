"""Heavy-occlusion benchmark of C3D gap filling (``scripts/bench_c3d_fill.py``): the per-gap ``auto`` filler
against single fillers and PyPI ``gapfill``.

(a) **Real gaps** (:func:`bench_real`). Every shared C3D take that reads and whose markers have gaps, filled by
    ``auto`` (the default of ``mocapnet clean``) and by ``pca`` (the previous default; gaps PCA cannot rebuild
    are interpolated linearly, as the registered method does). Scored by plausibility: the worst filled step ÷
    the same marker's largest measured step (``autofill.fill_plausibility``, the figure of
    ``shared/tools/c3d-fillcheck.py``), the share of gaps and samples filled.
(b) **Realistic occlusion of complete takes** (:func:`bench_occlusion`). Each complete take (``TARGETS``) is cut
    to a window and given the real missing-sample mask of each occluded take (``MASK_SOURCES``), resampled in
    time to the target's rate, its markers assigned to the target's so that neighbours stay neighbours
    (:func:`transplant_mask`). Errors (cm, Euclidean) against the truth per gap-length bin (``BINS``), on the
    samples ``auto`` filled (it leaves the others missing, so every method is scored on the same samples); a
    method that leaves some of them missing has those interpolated linearly, and how many is reported.
(c) **Synthetic gaps** (:func:`bench_segments`): ``mocapnet.corrupt`` corruptions on the 41-marker takes.

Methods (``METHODS``): ``auto``; the registered point methods ``rigid``, ``pca`` (each with linear
interpolation where it cannot fill), ``spline``, ``lerp``; PyPI ``gapfill`` rigid-body (``gapfill-rbt``: per
gap, the three markers nearest the target visible through the gap and its edges) and spline
(``gapfill-spline``).
"""

from __future__ import annotations

import sys
import time
import warnings
from collections.abc import Callable
from functools import cache
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from mocapnet.corrupt import corrupt_markers
from mocapnet.evaluate.benchmark import gapfill_rigid_body, gapfill_spline, numpy_int_alias
from mocapnet.evaluate.results import fmt, markdown_table
from mocapnet.fill import runs
from mocapnet.io.atomic import MocapFileError
from mocapnet.io.c3d import read_c3d
from mocapnet.methods.autofill import auto_fill, fill_plausibility
from mocapnet.methods.registry import build_method
from mocapnet.motion import Markers

MASK_SOURCES = (
    "c3d/btkdata/Gait.c3d",
    "c3d/ezc3d/BTS.c3d",
    "c3d/kineticstoolkit/kinematics_basket_sprint.c3d",
    "c3d/btkdata/PlugInC3D.c3d",
    "c3d/btkdata/TYPE-2.C3D",
    "c3d/kineticstoolkit/duplicate_labels.c3d",
    "c3d/kineticstoolkit/kinematics_racing_full.c3d",
)
TARGETS = (
    "c3d/hdm05/HDM_bd_01-02_01_120.c3d",
    "c3d/hdm05/HDM_bd_05-01_01_120.c3d",
    "c3d/hdm05/HDM_mm_01-02_03_120.c3d",
    "c3d/cmu/02_01.c3d",
    "c3d/cmu/85_02.c3d",
    "c3d/cmu/85_12.c3d",
    "c3d/kineticstoolkit/kinematics_tennis_serve.c3d",
    "c3d/ezc3d/Qualisys.c3d",
    "c3d/ezc3d/Vicon.c3d",
)
# Part (c): the corruptions of mocapnet.corrupt on the 41-marker takes whose segments it knows.
SEGMENT_TARGETS = (*TARGETS[:3], *TARGETS[4:6])  # CMU 02_01 is too short (2.9 s) for a 2-s gap with 2 s in view
SEGMENT_CORRUPTIONS = ("marker-gap:1", "segment-gap:left-arm:1", "segment-gap:right-leg:2")
# The targets whose cases were looked at while choosing auto's defaults (the rigid residual bounds, PCA and
# interpolation only between two measured edges); the other targets are reported apart as held out.
TUNING_TARGETS = TARGETS[0::2]
BINS = ((0.0, 0.1), (0.1, 0.5), (0.5, 2.0), (2.0, np.inf))
BIN_NAMES = ("<=0.1 s", "0.1-0.5 s", "0.5-2 s", ">2 s")
SINGLE = ("rigid", "pca", "spline", "lerp")  # registered point methods, also auto's candidates
METHODS = ("auto", *SINGLE, "gapfill-rbt", "gapfill-spline")


@cache
def _point_method(name: str) -> Callable[[Markers], np.ndarray]:
    return build_method(name, space="points").clean


def registered_fill(name: str, points: np.ndarray, visible: np.ndarray, like: Markers) -> np.ndarray:
    """The fill ``[T, M, 3]`` cm of the registered points-space method ``name`` (``rigid``, ``pca``, ``spline``,
    ``lerp``) of ``points [T, M, 3]`` where ``visible [T, M]`` is False; labels and rate from ``like``. Its
    warnings (gaps filled linearly) are silenced: the benchmark counts them itself."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return _point_method(name)(Markers(points, visible, like.labels, like.fps, like.name))


def layout(markers: Markers) -> np.ndarray:
    """Each marker's typical position relative to the take's per-frame median marker, in the take's principal
    axes scaled to unit spread, ``[M, 3]`` (NaN rows for markers never measured)."""
    pts = np.where(markers.visible[..., None], markers.points, np.nan)
    seen = markers.visible.any(axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        rel = pts[seen] - np.nanmedian(pts[seen], axis=1, keepdims=True)
        mean = np.nanmedian(rel, axis=0)
    ok = np.isfinite(mean).all(axis=1)
    centred = mean[ok] - mean[ok].mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    coords = centred @ vt.T
    coords /= np.maximum(coords.std(axis=0), 1e-9)
    out = np.full(mean.shape, np.nan)
    out[ok] = coords
    return out


def transplant_mask(source: Markers, target: Markers, length: int, rng: np.random.Generator) -> np.ndarray:
    """A missing-sample mask ``[length, M_target]`` (True = missing) copied from ``source``'s real mask:
    resampled to the target's rate from a random start, its markers assigned to the target's by layout
    (Hungarian assignment on :func:`layout`). Markers the mask leaves with no sample at all stay complete."""
    src_cols = np.flatnonzero(source.visible.any(axis=0))
    src_layout, tgt_layout = layout(source)[src_cols], layout(target)
    reps = int(np.ceil(target.n_markers / len(src_cols)))
    cost = np.linalg.norm(tgt_layout[:, None] - np.tile(src_layout, (reps, 1))[None], axis=-1)
    rows, cols = linear_sum_assignment(np.nan_to_num(cost, nan=1e6))
    assign = np.empty(target.n_markers, dtype=int)
    assign[rows] = src_cols[cols % len(src_cols)]
    span = length / target.fps * source.fps
    start = rng.uniform(0.0, max(source.n_frames - span, 0.0))
    frames = np.minimum((start + np.arange(length) * source.fps / target.fps).astype(int), source.n_frames - 1)
    mask = ~source.visible[np.ix_(frames, assign)]
    mask[:, mask.all(axis=0)] = False
    return mask


def gapfill_fills(points: np.ndarray, visible: np.ndarray) -> tuple[dict[str, np.ndarray], int]:
    """PyPI ``gapfill`` rigid-body (per gap: the 3 nearest markers visible through it and its edges; gaps
    sharing a cluster in one call) and spline fills, ``[T, M, 3]`` with NaN where gapfill left a sample, and
    the number of rigid-body calls that raised (gapfill indexes a second common frame that may not exist)."""
    rbt, spl = points.copy(), points.copy()
    n_frames, failures = len(points), 0
    with numpy_int_alias():
        for i in np.flatnonzero(~visible.all(axis=0)):
            dist = np.nanmean(np.linalg.norm(points - points[:, [i]], axis=-1), axis=0)
            clusters: dict[tuple[int, ...], list[tuple[int, int]]] = {}
            for start, stop in runs(~visible[:, i]):
                through = visible[max(start - 1, 0) : min(stop + 1, n_frames)].all(axis=0)
                through[i] = False
                idx = np.flatnonzero(through)
                cluster = tuple(int(c) for c in idx[np.argsort(dist[idx])[:3]])
                if len(cluster) == 3:
                    clusters.setdefault(cluster, []).append((start, stop))
            for cluster, spans in clusters.items():
                try:
                    track = gapfill_rigid_body(points, int(i), list(cluster))
                except IndexError:
                    failures += 1
                    continue
                for start, stop in spans:
                    rbt[start:stop, i] = track[start:stop]
            spl[:, i] = gapfill_spline(points, int(i))
    return {"gapfill-rbt": rbt, "gapfill-spline": spl}, failures


def method_fills(noisy: Markers) -> tuple[dict[str, np.ndarray], dict[str, float], list[dict], int]:
    """Every method's fill ``[T, M, 3]`` (NaN where it left a sample missing), its CPU seconds (``gapfill``
    for both gapfill fills), auto's per-gap reports and the failed gapfill rigid-body calls."""
    fills, cpu = {}, {}
    t0 = time.process_time()
    auto = auto_fill(noisy)
    cpu["auto"] = time.process_time() - t0
    fills["auto"] = auto.points
    for name in SINGLE:
        t0 = time.process_time()
        fills[name] = registered_fill(name, noisy.points, noisy.visible, noisy)
        cpu[name] = time.process_time() - t0
    t0 = time.process_time()
    gapfilled, failures = gapfill_fills(noisy.points, noisy.visible)
    cpu["gapfill"] = time.process_time() - t0
    return fills | gapfilled, cpu, auto.gaps, failures


def gap_seconds(visible: np.ndarray, fps: float) -> np.ndarray:
    """``[T, M]``: for each missing sample, the length (s) of the gap it belongs to; 0 where visible."""
    out = np.zeros(visible.shape)
    for m in range(visible.shape[1]):
        for start, stop in runs(~visible[:, m]):
            out[start:stop, m] = (stop - start) / fps
    return out


def score_case(truth: Markers, noisy: Markers, case: dict) -> dict:
    """Fill ``noisy`` with every method and add to ``case`` the gap counts and, per gap-length bin and
    method, the summed error (cm) on the samples auto filled (``bins``)."""
    length = noisy.n_frames
    fills, cpu, gaps, failures = method_fills(noisy)
    scored = ~noisy.visible & np.isfinite(fills["auto"]).all(axis=2)
    seconds = gap_seconds(noisy.visible, noisy.fps)
    case.update(
        {
            "frames": length,
            "markers": noisy.n_markers,
            "missing_share": float((~noisy.visible).mean()),
            "gaps": len(gaps),
            "gaps_filled_by_auto": sum(g["status"] == "filled" for g in gaps),
            "gaps_partly_filled_by_auto": sum(g["status"] == "partly filled" for g in gaps),
            "unfilled_samples_in_end_gaps": sum(
                b - a + 1
                for g in gaps
                if g["first_frame"] == 0 or g["last_frame"] == length - 1
                for a, b in g["unfilled_spans"]
            ),
            "auto_methods": {m: sum(g["method"] == m for g in gaps) for m in SINGLE},
            "missing_samples": int((~noisy.visible).sum()),
            "scored_samples": int(scored.sum()),
            "gapfill_rbt_failures": failures,
            "cpu_s": cpu,
            "bins": {},
        }
    )
    auto_err = np.linalg.norm(fills["auto"] - truth.points, axis=-1)
    for name, fill in fills.items():
        have = np.isfinite(fill).all(axis=2)
        left = scored & ~have
        fill = registered_fill("lerp", fill, have, noisy) if left.any() else fill
        err = np.linalg.norm(fill - truth.points, axis=-1)
        for (lo, hi), bin_name in zip(BINS, BIN_NAMES):
            sel = scored & (seconds > lo) & (seconds <= hi)
            own = sel & ~left
            case["bins"].setdefault(bin_name, {})[name] = {
                "sum_cm": float(err[sel].sum()),
                "n": int(sel.sum()),
                "lerp_backfilled": int((left & sel).sum()),
                "own_sum_cm": float(err[own].sum()),
                "auto_on_own_sum_cm": float(auto_err[own].sum()),
            }
        case.setdefault("all_missing_mean_cm", {})[name] = (
            float(np.nanmean(err[~noisy.visible])) if name != "auto" else None
        )
    return case


def _progress(text: str, show: bool) -> None:
    if show:
        print(text, file=sys.stderr, flush=True)


def bench_segments(root: Path, seed: int, progress: bool = False) -> dict:
    """Part (c): whole-segment and single-marker gaps (``mocapnet.corrupt``) on the 41-marker HDM05/CMU takes."""
    cases = []
    for t_index, target_name in enumerate(SEGMENT_TARGETS):
        truth = read_c3d(root / target_name)
        truth = truth.select(np.flatnonzero(truth.visible.all(axis=0)))
        for c_index, corruption in enumerate(SEGMENT_CORRUPTIONS):
            noisy = corrupt_markers(truth, corruption, np.random.default_rng([seed, t_index, c_index]))
            case = score_case(truth, noisy, {"target": target_name, "corruption": corruption})
            cases.append(case)
            _progress(f"  {Path(target_name).name} {corruption}: auto filled {case['scored_samples']}/"
                      f"{case['missing_samples']} samples", progress)  # fmt: skip
    return {"cases": cases, "summary": summarise(cases)}


def occlusion_case(
    full: Markers, source: Markers, window_s: float, rng: np.random.Generator
) -> tuple[Markers, Markers]:
    """(truth, noisy): a random window of at most ``window_s`` seconds of the complete take ``full`` (no longer
    than ``source``) and the same window under ``source``'s transplanted mask."""
    length = int(min(full.n_frames, round(window_s * full.fps), round(source.n_frames / source.fps * full.fps)))
    start = int(rng.integers(0, full.n_frames - length + 1))
    window = slice(start, start + length)
    truth = Markers(full.points[window], full.visible[window], full.labels, full.fps, full.name)
    mask = transplant_mask(source, truth, length, rng)
    return truth, Markers(truth.points, ~mask, truth.labels, truth.fps, truth.name)


def bench_occlusion(root: Path, window_s: float, seed: int, targets: tuple[str, ...], progress: bool = False) -> dict:
    """Part (b): per (target, mask source) case, each method's summed error and sample count per bin."""
    sources = {name: read_c3d(root / name) for name in MASK_SOURCES}
    cases = []
    for t_index, target_name in enumerate(targets):
        full = read_c3d(root / target_name)
        full = full.select(np.flatnonzero(full.visible.all(axis=0)))
        for s_index, (source_name, source) in enumerate(sources.items()):
            truth, noisy = occlusion_case(full, source, window_s, np.random.default_rng([seed, t_index, s_index]))
            case = score_case(truth, noisy, {"target": target_name, "mask_source": source_name})
            cases.append(case)
            _progress(f"  {Path(target_name).name} x {Path(source_name).name}: {noisy.n_frames} frames, "
                      f"{case['missing_share']:.0%} missing, auto filled {case['gaps_filled_by_auto']}/{case['gaps']} "
                      f"gaps, {sum(case['cpu_s'].values()):.1f} s", progress)  # fmt: skip
    held_out = [c for c in cases if c["target"] not in TUNING_TARGETS]
    return {"cases": cases, "summary": summarise(cases), "summary_held_out": summarise(held_out)}


def summarise(cases: list[dict]) -> dict:
    """Mean error (cm) per method and bin over every case's scored samples, and overall (``all``)."""
    out = {}
    for bin_name in (*BIN_NAMES, "all"):
        names = BIN_NAMES if bin_name == "all" else (bin_name,)
        row = {}
        for name in METHODS:
            cells = [c["bins"][b][name] for c in cases for b in names]
            n = sum(cell["n"] for cell in cells)
            back = sum(cell["lerp_backfilled"] for cell in cells)
            n_own = n - back
            row[name] = {
                "mean_cm": sum(cell["sum_cm"] for cell in cells) / n if n else None,
                "n": n,
                "lerp_backfilled": back,
                "own_mean_cm": sum(cell["own_sum_cm"] for cell in cells) / n_own if n_own else None,
                "auto_on_own_mean_cm": sum(cell["auto_on_own_sum_cm"] for cell in cells) / n_own if n_own else None,
            }
        out[bin_name] = row
    return out


def shared_gapped_takes(root: Path) -> list[Path]:
    """Every shared C3D file that reads and has at least one gap in a marker that has some data."""
    found = []
    for path in sorted((root / "c3d").rglob("*")):
        if path.suffix.lower() != ".c3d" or path.stat().st_size == 0:
            continue
        try:
            markers = read_c3d(path)
        except MocapFileError:
            continue
        used = markers.visible.any(axis=0)
        if not markers.visible[:, used].all():
            found.append(path)
    return found


def real_row(markers: Markers, take: str) -> dict:
    """Part (a) for one take: plausibility, samples filled and CPU seconds of ``auto`` and ``pca``, and
    auto's gaps (those of markers measured somewhere) by outcome and filler."""
    row = {"take": take, "frames": markers.n_frames, "markers": markers.n_markers,
           "missing_share": float(1.0 - markers.visible[:, markers.visible.any(axis=0)].mean())}  # fmt: skip
    for name in ("auto", "pca"):
        t0 = time.process_time()
        got = auto_fill(markers) if name == "auto" else None
        fill = got.points if got else registered_fill("pca", markers.points, markers.visible, markers)
        cpu = time.process_time() - t0
        worst, where, n_filled, n_missing = fill_plausibility(markers, fill)
        row[name] = {"worst_ratio": worst, "worst_at": where, "samples_filled": n_filled,
                     "samples_missing": n_missing, "cpu_s": cpu}  # fmt: skip
        if got:
            row[name]["gaps"] = len([g for g in got.gaps if g["tried"] != ["never measured in this take"]])
            row[name]["gaps_filled"] = sum(g["status"] == "filled" for g in got.gaps)
            row[name]["methods"] = {m: sum(g["method"] == m for g in got.gaps) for m in SINGLE}
    return row


def bench_real(root: Path, progress: bool = False) -> list[dict]:
    """Part (a): plausibility of auto and pca on every shared take with real gaps."""
    rows = []
    for path in shared_gapped_takes(root):
        row = real_row(read_c3d(path), str(path.relative_to(root)))
        rows.append(row)
        _progress(f"  {row['take']}: auto worst {row['auto']['worst_ratio']:.2f}, pca worst "
                  f"{row['pca']['worst_ratio']:.2f}", progress)  # fmt: skip
    return rows


def bins_table(summary: dict) -> list[str]:
    """Markdown lines: mean error (cm) per gap-length bin and method, auto ÷ the best single filler, auto ÷
    gapfill rigid-body."""
    body = []
    for bin_name in (*BIN_NAMES, "all"):
        row = summary[bin_name]
        singles = [row[m]["mean_cm"] for m in METHODS if m != "auto" and row[m]["mean_cm"] is not None]
        auto, gf = row["auto"]["mean_cm"], row["gapfill-rbt"]["mean_cm"]
        best = min(singles) if singles else None
        ratio = auto / best if auto is not None and best else None
        vs_gf = auto / gf if auto is not None and gf else None
        body.append([bin_name, row["auto"]["n"], *(fmt(row[m]["mean_cm"], 2) for m in METHODS), fmt(ratio), fmt(vs_gf)])
    return markdown_table(["gap length", "n", *METHODS, "auto ÷ best single", "auto ÷ gapfill-rbt"], body)


def _case_sums(case: dict) -> tuple[dict[str, float], str]:
    """Each method's summed error (cm) over a case's scored samples, and the best single filler."""
    sums = {m: sum(case["bins"][b][m]["sum_cm"] for b in BIN_NAMES) for m in METHODS}
    return sums, min((m for m in METHODS if m != "auto"), key=lambda m: sums[m])


def _real_section(real: list[dict]) -> list[str]:
    body = []
    for r in real:
        a, p, at = r["auto"], r["pca"], r["pca"]["worst_at"]
        where = (
            f"{at['marker']} fr {at['frame']}: {at['step_cm']:.1f} vs {at['largest_measured_cm']:.1f} cm" if at else ""
        )
        share = a["samples_filled"] / max(a["samples_missing"], 1)
        mix = "/".join(str(a["methods"][m]) for m in SINGLE)
        body.append([r["take"], f"{r['frames']} × {r['markers']}", f"{r['missing_share']:.0%}",
                     f"{a['worst_ratio']:.2f}", f"{a['gaps_filled']}/{a['gaps']}", f"{share:.0%}", mix,
                     f"{p['worst_ratio']:.1f}", where])  # fmt: skip
    over = [r["take"] for r in real if r["auto"]["worst_ratio"] > 2.0]
    head = ["take", "frames × markers", "missing", "auto worst", "auto gaps filled", "auto samples filled",
            "auto rigid/pca/spline/lerp", "pca worst", "pca worst at"]  # fmt: skip
    return [
        "## (a) Shared takes with real gaps: plausibility of the default clean",
        "",
        "Worst filled step ÷ the same marker's largest measured step (≤ 2 is the target; `c3d-fillcheck`'s "
        "figure), share of gaps wholly filled and of missing samples filled. `auto` = the new default (rigid/pca/"
        "spline/lerp = gaps it filled, wholly or in part, with each); `pca` = the previous default method as it "
        "is now (PCA with this change's fix, linear interpolation where PCA cannot be trusted: a constant over "
        "gaps at the ends of a take, which scores 0 here).",
        "",
        *markdown_table(head, body),
        "",
        f"auto's worst ratio is ≤ 2 on {len(real) - len(over)} of {len(real)} takes"
        + (f"; over 2 on: {', '.join(over)}." if over else "."),
    ]


def _occlusion_section(report: dict) -> list[str]:
    occ = report["occlusion"]
    cases, summary = occ["cases"], occ["summary"]
    held = sorted({c["target"] for c in cases} - set(TUNING_TARGETS))
    own = [[m, summary["all"][m]["n"] - summary["all"][m]["lerp_backfilled"], fmt(summary["all"][m]["own_mean_cm"], 2),
            fmt(summary["all"][m]["auto_on_own_mean_cm"], 2)] for m in METHODS[1:]]  # fmt: skip
    missing, scored = sum(c["missing_samples"] for c in cases), sum(c["scored_samples"] for c in cases)
    per_case = []
    for c in cases:
        sums, best = _case_sums(c)
        n = c["scored_samples"]
        cells = [f"{sums['auto'] / n:.2f}", f"{sums[best] / n:.2f} ({best})"] if n else ["—", "—"]
        per_case.append([Path(c["target"]).name, Path(c["mask_source"]).name, f"{c['missing_share']:.0%}",
                         f"{c['gaps_filled_by_auto']}/{c['gaps']}", *cells])  # fmt: skip
    return [
        "## (b) Complete takes under real occlusion masks: error against the truth (cm)",
        "",
        f"{len(cases)} cases ({len(report['targets'])} complete takes × {len(report['mask_sources'])} masks, "
        f"windows ≤ {report['window_s']:g} s). Mean error over the samples `auto` filled, by the length of the gap "
        "the sample belongs to; n = samples. Methods other than auto fill every gap (their error on all missing "
        "samples is in `c3d_fill.json.gz`).",
        "",
        *bins_table(summary),
        "",
        f"Held out (targets not looked at while choosing auto's defaults: {', '.join(Path(t).name for t in held)}):",
        "",
        *bins_table(occ["summary_held_out"]),
        "",
        "Each single filler on the samples it filled itself (no linear back-fill) against auto on the same "
        "samples (mean cm, all gap lengths; n = samples):",
        "",
        *markdown_table(["method", "n", "method cm", "auto cm"], own),
        "",
        f"auto filled {sum(c['gaps_filled_by_auto'] for c in cases)} of {sum(c['gaps'] for c in cases)} gaps wholly "
        f"and {sum(c['gaps_partly_filled_by_auto'] for c in cases)} in part ({scored} of {missing} missing samples, "
        f"{scored / max(missing, 1):.0%}); it left the rest missing and reported them: "
        f"{sum(c['unfilled_samples_in_end_gaps'] for c in cases)} of the {missing - scored} samples left are in gaps "
        "that reach the start or end of the window. gapfill-rbt left "
        f"{summary['all']['gapfill-rbt']['lerp_backfilled']} of the scored samples unfilled (no cluster of three "
        "markers visible through the gap, or a gap at the start or end); they were interpolated linearly for its "
        "score.",
        "",
        "Per case (target × mask): missing share, gaps auto filled, auto's mean error vs the best single "
        "filler on the same samples.",
        "",
        *markdown_table(
            ["target", "mask from", "missing", "gaps filled", "auto cm", "best single cm (method)"], per_case
        ),  # fmt: skip
    ]


def _segments_section(seg: dict) -> list[str]:
    body = []
    for c in seg["cases"]:
        sums, best = _case_sums(c)
        n = c["scored_samples"]
        cells = [f"{sums['auto'] / n:.2f}", f"{sums[best] / n:.2f} ({best})"] if n else ["—", "—"]
        body.append([Path(c["target"]).name, c["corruption"], f"{n}/{c['missing_samples']}", *cells])
    return [
        "## (c) Synthetic gaps of `mocapnet.corrupt` on the 41-marker HDM05/CMU takes",
        "",
        f"{', '.join(SEGMENT_CORRUPTIONS)} on {', '.join(Path(t).name for t in SEGMENT_TARGETS)} (whole takes, one "
        f"seed each). auto filled {sum(c['scored_samples'] for c in seg['cases'])} of "
        f"{sum(c['missing_samples'] for c in seg['cases'])} missing samples; scored as in (b).",
        "",
        *bins_table(seg["summary"]),
        "",
        *markdown_table(["target", "corruption", "samples auto filled", "auto cm", "best single cm (method)"], body),
    ]


def gapfill_note(report: dict) -> str:
    """How PyPI gapfill was run and how often its rigid-body fill raised."""
    failures = sum(c["gapfill_rbt_failures"] for part in ("occlusion", "segments") for c in report[part]["cases"])
    return (
        f"PyPI gapfill {report['gapfill_version']}, run with a temporary alias np.int = int (it calls np.int, "
        f"removed in NumPy 1.24). Its rigid-body fill raised IndexError in {failures} calls (a cluster sharing "
        "one measured frame with the target); those gaps count as left missing by it."
    )


def markdown(report: dict) -> str:
    """The results file ``c3d_fill.md`` of a report made by :func:`run` plus ``report.provenance``."""
    head = [
        "# C3D gap filling under heavy occlusion (`scripts/bench_c3d_fill.py`)",
        "",
        f"Command: `{report['command']}` at commit `{report['git_commit'][:10]}`; {report['machine']}; wall "
        f"{report['wall_s']:.0f} s, CPU {report['cpu_s']:.0f} s.",
        "",
    ]
    parts = [_real_section(report["real"]), _occlusion_section(report), _segments_section(report["segments"])]
    return "\n".join(head + [line for part in parts for line in [*part, ""]] + [gapfill_note(report), ""])


def run(
    root: Path, window_s: float = 8.0, seed: int = 0, targets: tuple[str, ...] = TARGETS, progress: bool = False
) -> dict:
    """Parts (a), (b) and (c) on the data under ``root``, with their settings and wall / CPU seconds."""
    import gapfill

    started, cpu0 = time.time(), time.process_time()
    report = {
        "window_s": window_s,
        "seed": seed,
        "targets": list(targets),
        "mask_sources": list(MASK_SOURCES),
        "gapfill_version": gapfill.__version__,
        "real": bench_real(root, progress),
        "occlusion": bench_occlusion(root, window_s, seed, tuple(targets), progress),
        "segments": bench_segments(root, seed, progress),
    }
    return report | {"wall_s": time.time() - started, "cpu_s": time.process_time() - cpu0}
