"""Gap filling that chooses a filler per gap and checks every fill (``auto``, the default of
``mocapnet clean take.c3d``).

A *gap* is a run of missing frames of one marker. For each gap, candidates are tried in order and the first
whose fill passes the check is kept:

* ``rigid`` — carried with three or more visible markers that stay rigid with it (:mod:`.rigid`; the
  "rigid body fill" of Vicon and Qualisys). Refused when the partners themselves deviate from their rigid
  configuration by more than ``max_residual_cm`` (1 cm RMS over the gap) — ``max_residual_one_edge_cm``
  (0.5 cm) when only one edge of the gap is measured, since no second edge corrects the drift;
* ``pca`` — the clip's inter-marker correlations (:mod:`.pca`; skipped where PCA cannot be trusted, and
  when no marker rigid with the missing one stays in view: with a whole segment missing, PCA filled
  HDM05/CMU arms and legs worse than a straight line);
* ``knn`` — nearest poses of a database of clean takes (only when a database is given);
* ``spline``, ``lerp`` — interpolation in time, only for gaps of at most ``max_interp_s`` seconds (a
  straight line through a long gap passes any speed check and is still made up).

``pca``, ``knn``, ``spline`` and ``lerp`` need both edges of the gap measured: interpolation cannot
extrapolate, and PCA carried from one edge drifted by 17-22 cm on the occlusion benchmark
(``scripts/bench_c3d_fill.py``); a gap that reaches the start or end of the take is filled by ``rigid`` or
not at all. Gaps of at most ``spline_first_s`` seconds try ``spline`` first: over a few frames a marker's
own path predicts it better than its neighbours do. Reconstructions that do not meet the measured edges by
construction (``pca``, ``knn``) are shifted by the offset between their linear extrapolation and the
measured edge samples, blended linearly across the gap.

When no candidate fills the whole gap, ``rigid`` fills what it can from each measured edge: as far into the
gap as three rigid partners stay in view, halving the piece until its partners pass the residual bound.
The rest of the gap stays missing (reported as ``unfilled_spans``).

**Check** (the plausibility figure of ``c3d-fillcheck``): every frame-to-frame step that touches a filled
sample — the steps into and out of the gap included — divided by the largest step the same marker makes
between two measured frames (the largest over all markers when it has at most 10 measured steps). A fill
passes when this ratio is at most ``limit`` (2). A gap no candidate fills plausibly is left missing and
reported, never invented.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from mocapnet.fill import runs
from mocapnet.methods.baselines import lerp_fill, spline_fill
from mocapnet.methods.pca import fill_remaining_linear, pca_fill
from mocapnet.methods.registry import MethodContext, build_method, register
from mocapnet.methods.rigid import (
    distance_stats,
    measured_edges,
    rigid_fill_gap,
    rigid_partners,
    rigid_reach,
)
from mocapnet.motion import Markers

CANDIDATES = ("rigid", "pca", "knn", "spline", "lerp")
INTERPOLATORS = ("spline", "lerp")
# Candidates that need both edges of a gap measured: interpolation cannot extrapolate, and PCA / kNN carried
# from one edge drifted by 17-22 cm on the occlusion benchmark (rigid one-sided fills: 3-8 cm).
NEED_BOTH_EDGES = ("pca", "knn", *INTERPOLATORS)
# Relational check (the constraint matrix of mocapnet.methods.extrapolate, as bounds): in a fill, the
# distance to every visible marker must stay within the range measured between the two, widened on each side
# by BOUND_SLACK of its width plus BOUND_TOLERANCE_CM (occlusions happen in unusual poses: a tight bound
# refused correct 4-frame fills of the tennis serve's shoulder), for at least two markers.
BOUND_TOLERANCE_CM = 2.0
BOUND_SLACK = 0.25
_MIN_MEASURED_STEPS = 10  # a marker with fewer measured steps is compared with the largest of all markers


def largest_measured_steps(points: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Largest frame-to-frame step (cm) of each marker between two measured frames, ``[M]``; the largest of
    all markers for a marker with at most 10 measured steps; NaN when no marker has more."""
    steps = np.linalg.norm(np.diff(np.nan_to_num(points), axis=0), axis=-1)  # [T-1, M]
    both = visible[1:] & visible[:-1]
    enough = both.sum(axis=0) > _MIN_MEASURED_STEPS
    own = np.where(both, steps, 0.0).max(axis=0, initial=0.0)
    overall = own[enough].max() if enough.any() else np.nan
    return np.where(enough, own, overall)


def step_ratio(track: np.ndarray, start: int, stop: int, reference_cm: float) -> float:
    """Worst step ÷ ``reference_cm`` among the steps of ``track [T, 3]`` (cm) that touch frames
    ``start .. stop-1`` (the steps into and out of them included; steps to a NaN sample are skipped).
    NaN when no step can be measured or there is no reference."""
    lo, hi = max(start - 1, 0), min(stop + 1, len(track))
    steps = np.linalg.norm(np.diff(track[lo:hi], axis=0), axis=-1)
    steps = steps[np.isfinite(steps)]
    if steps.size == 0 or not reference_cm > 0:
        return float("nan")
    return float(steps.max() / reference_cm)


def fill_plausibility(markers: Markers, result: np.ndarray) -> tuple[float, dict | None, int, int]:
    """The plausibility of a whole fill, as ``shared/tools/c3d-fillcheck.py`` measures it: over every marker,
    the worst step touching a sample that was missing in ``markers`` and is finite in ``result [T, M, 3]``
    (cm), ÷ that marker's largest measured step. Returns ``(worst ratio, where, samples filled, samples
    missing)``; ``where`` names the marker, the frame the step ends at and both steps in cm (None when
    nothing was filled; the ratio is then 0)."""
    reference = largest_measured_steps(markers.points, markers.visible)
    have = np.isfinite(result).all(axis=2)
    filled = ~markers.visible & have
    steps = np.linalg.norm(np.diff(np.where(have[..., None], result, 0.0), axis=0), axis=-1)
    touch = (filled[1:] | filled[:-1]) & have[1:] & have[:-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = np.where(touch, steps / reference, 0.0)
    worst, where = 0.0, None
    if touch.any():
        k, m = np.unravel_index(int(np.nanargmax(np.where(touch, ratios, -1.0))), ratios.shape)
        worst = float(ratios[k, m])
        where = {
            "marker": markers.labels[m],
            "frame": int(k + 1),
            "step_cm": round(float(steps[k, m]), 3),
            "largest_measured_cm": round(float(reference[m]), 3),
        }
    return worst, where, int(filled.sum()), int((~markers.visible).sum())


def match_edges(fill: np.ndarray, track: np.ndarray, start: int, stop: int) -> np.ndarray:
    """Shift a reconstruction ``fill [L, 3]`` of frames ``start .. stop-1`` so that its linear extrapolation
    meets the measured samples of ``track [T, 3]`` at ``start - 1`` and ``stop``; the two offsets are
    blended linearly across the gap (one offset when one edge is measured). Gaps of one frame get the mean
    offset of the fill to its measured neighbours."""
    n = len(fill)
    offsets, where = [], []
    if start > 0 and np.isfinite(track[start - 1]).all():
        guess = 2 * fill[0] - fill[1] if n > 1 else fill[0]
        offsets.append(track[start - 1] - guess)
        where.append(0.0)
    if stop < len(track) and np.isfinite(track[stop]).all():
        guess = 2 * fill[-1] - fill[-2] if n > 1 else fill[-1]
        offsets.append(track[stop] - guess)
        where.append(1.0)
    if not offsets:
        return fill
    if len(offsets) == 1 or n == 1:
        return fill + np.mean(offsets, axis=0)
    w = (np.arange(1, n + 1) / (n + 1))[:, None]
    return fill + (1.0 - w) * offsets[0] + w * offsets[1]


@dataclass
class AutoFill:
    """Result of :func:`auto_fill`: ``points [T, M, 3]`` cm (NaN where a gap was left missing), ``filled
    [T, M]`` (True where a missing sample got a value) and one JSON-able report per gap (``gaps``)."""

    points: np.ndarray
    filled: np.ndarray
    gaps: list[dict]


class _Candidates:
    """Lazily computed whole-take fills and the per-gap rigid fill for :func:`auto_fill`."""

    def __init__(
        self, markers: Markers, database: str | None, rigid_options: dict, max_residual_cm: tuple[float, float]
    ) -> None:
        self.markers = markers
        self.points = markers.points
        self.visible = markers.visible
        self.database = database
        self.rigid_options = rigid_options
        self.max_residual_cm = max_residual_cm
        self._whole: dict[str, np.ndarray] = {}

    @cached_property
    def distances(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(spread, low, high)`` ``[M, M]`` (cm) of every marker pair (``rigid.distance_stats``), computed
        once."""
        return distance_stats(self.points, self.visible)

    def bounds_violation(self, fill: np.ndarray, marker: int, start: int, stop: int) -> float:
        """How far (cm) a fill ``[stop - start, 3]`` of ``marker`` leaves the range of distances measured
        between it and each other marker (widened by ``BOUND_SLACK`` of its width), where that marker is
        visible: the second largest over the markers (0: never)."""
        _, low, high = self.distances
        low, high = low[marker], high[marker]
        near = np.isfinite(low)
        near[marker] = False
        if not near.any():
            return 0.0
        others = self.points[start:stop][:, near]  # [L, K, 3], NaN where not visible
        d = np.linalg.norm(others - fill[:, None], axis=-1)
        slack = BOUND_SLACK * (high[near] - low[near])
        over = np.fmax(low[near] - slack - d, d - high[near] - slack)  # [L, K], NaN where not visible
        worst = np.sort(np.nanmax(np.where(np.isnan(over), -np.inf, over), axis=0))[::-1]  # per marker
        # The second worst marker decides: one visible marker out of place (a swapped or ghost sample)
        # does not veto a fill that agrees with all the others.
        return float(max(worst[min(1, len(worst) - 1)], 0.0))

    def whole(self, name: str) -> np.ndarray:
        if name not in self._whole:
            pts, vis = self.points, self.visible
            t, m, _ = pts.shape
            flat, mask = pts.reshape(t, m * 3), np.repeat(~vis, 3, axis=1)
            if name == "pca":
                out = pca_fill(pts, vis)
            elif name == "knn":
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    knn = build_method(f"knn:database={self.database}", space="points")
                    out = knn.clean(self.markers)
            elif name == "spline":
                out = spline_fill(flat, mask).reshape(t, m, 3)
            else:
                out = lerp_fill(flat, mask).reshape(t, m, 3)
            self._whole[name] = out
        return self._whole[name]

    def fill(self, name: str, marker: int, start: int, stop: int) -> tuple[np.ndarray | None, dict]:
        """The candidate ``name``'s fill ``[stop - start, 3]`` of one gap and facts about it, or None and
        ``{"reason": ...}``."""
        if name == "rigid":
            gate = self.max_residual_cm[len(measured_edges(self.visible, marker, start, stop)) > 1]
            got = rigid_fill_gap(
                self.points,
                self.visible,
                self.distances[0],
                marker,
                start,
                stop,
                max_residual_cm=gate,
                **self.rigid_options,
            )
            if got is None:
                return None, {"reason": "fewer than 3 rigid partners visible through the gap"}
            if got.residual_cm > gate:
                return None, {"reason": f"rigid partners deform by {got.residual_cm:.2f} cm RMS > {gate:g} cm"}
            labels = [self.markers.labels[p] for p in got.partners]
            return got.points, {"partners": labels, "fit_residual_cm": round(got.residual_cm, 3)}
        if name == "pca":
            max_std_cm = self.rigid_options["max_std_cm"]
            if not len(rigid_partners(self.visible, self.distances[0], marker, start, stop, max_std_cm=max_std_cm)):
                return None, {"reason": "no marker rigid with it stays in view (its segment is missing)"}
        fill = self.whole(name)[start:stop, marker]
        if not np.isfinite(fill).all():
            why = "PCA cannot be trusted here (too few frames or markers)" if name == "pca" else "no fill"
            return None, {"reason": why}
        if name in ("pca", "knn"):
            fill = match_edges(fill, self.points[:, marker], start, stop)
        return fill, {}


def _order(seconds: float, order: Sequence[str], spline_first_s: float) -> list[str]:
    if seconds <= spline_first_s and "spline" in order:
        return ["spline", *[c for c in order if c != "spline"]]
    return list(order)


def auto_fill(
    markers: Markers,
    database: str | os.PathLike | None = None,
    limit: float = 2.0,
    max_interp_s: float = 0.5,
    spline_first_s: float = 0.1,
    order: Sequence[str] = CANDIDATES,
    max_std_cm: float = 2.0,
    max_partners: int = 6,
    max_residual_cm: float = 1.0,
    max_residual_one_edge_cm: float = 0.5,
) -> AutoFill:
    """Fill each gap of ``markers`` with the first candidate of ``order`` whose fill passes the checks
    (module docstring), else with rigid pieces from its measured edges, leaving the rest missing.

    Parameters
    ----------
    markers : points ``[T, M, 3]`` cm, ``visible [T, M]``.
    database : folder of clean C3D takes of the same marker set; enables the ``knn`` candidate.
    limit : largest accepted step ratio (worst filled step ÷ the marker's largest measured step).
    max_interp_s : longest gap (seconds) that ``spline`` / ``lerp`` may fill.
    spline_first_s : gaps up to this long (seconds) try ``spline`` first.
    order : candidates in the order they are tried (subset of ``CANDIDATES``).
    max_std_cm, max_partners : rigid partners' largest distance spread (cm) and how many are used.
    max_residual_cm, max_residual_one_edge_cm : a rigid fill whose partners deviate from their rigid
        configuration by more than this (RMS over the gap, cm) is refused; the second bound is for fills
        carried from one measured edge (gap at the end of the take, or part of a gap), which no second edge
        corrects.

    Returns
    -------
    :class:`AutoFill`; each gap report holds ``marker``, ``marker_index``, ``first_frame`` and
    ``last_frame`` (0-based take frames, inclusive), ``frames``, ``seconds``, ``status`` (``filled``,
    ``partly filled`` or ``unfilled``), ``method``, ``ratio`` (the plausibility figure of what was filled;
    null when nothing was), ``filled_frames``, ``unfilled_spans`` (``[first, last]`` frame pairs left
    missing), ``tried`` (why candidates were refused) and, for rigid fills, ``partners`` and
    ``fit_residual_cm``.
    """
    unknown = [c for c in order if c not in CANDIDATES]
    if unknown:
        raise ValueError(f"unknown auto candidates {unknown}; choose from {CANDIDATES}")
    if not limit > 0:
        raise ValueError(f"limit must be positive, got {limit}")
    points, visible = markers.points, markers.visible
    n_frames = markers.n_frames
    reference = largest_measured_steps(points, visible)
    candidates = _Candidates(
        markers,
        str(database) if database else None,
        {"max_std_cm": max_std_cm, "max_partners": max_partners},
        (max_residual_one_edge_cm, max_residual_cm),
    )
    out = points.copy()
    filled = np.zeros(visible.shape, dtype=bool)
    gaps: list[dict] = []

    def accept(m: int, start: int, stop: int, name: str, report: dict, note: bool = True) -> bool:
        fill, info = candidates.fill(name, m, start, stop)
        if fill is None:
            if note:
                report["tried"].append(f"{name}: {info['reason']}")
            return False
        trial = out[:, m].copy()
        trial[start:stop] = fill
        ratio = step_ratio(trial, start, stop, reference[m])
        if not ratio <= limit:
            if note:
                report["tried"].append(f"{name}: step ratio {ratio:.2f} > {limit:g}")
            return False
        outside = candidates.bounds_violation(fill, m, start, stop)
        if outside > BOUND_TOLERANCE_CM:
            if note:
                report["tried"].append(f"{name}: {outside:.1f} cm outside a distance range measured to another marker")
            return False
        out[start:stop, m] = fill
        filled[start:stop, m] = True
        worst = max(ratio, report["ratio"] or 0.0)
        report.update(method=name, ratio=round(worst, 3), **info)
        return True

    for m in np.flatnonzero(~visible.all(axis=0)):
        m = int(m)
        for start, stop in runs(~visible[:, m]):
            report = gap_report(markers, m, start, stop)
            gaps.append(report)
            if not visible[:, m].any():
                report["tried"].append("never measured in this take")
                continue
            seconds = report["seconds"]
            two_sided = start > 0 and stop < n_frames
            for name in _order(seconds, order, spline_first_s):
                if name == "knn" and candidates.database is None:
                    continue
                if name in NEED_BOTH_EDGES and not two_sided:
                    report["tried"].append(f"{name}: gap reaches the end of the take")
                elif name in INTERPOLATORS and seconds > max_interp_s:
                    report["tried"].append(f"{name}: gap longer than {max_interp_s:g} s")
                elif accept(m, start, stop, name, report):
                    break
            else:
                if "rigid" in order:
                    for a, b in _rigid_pieces(candidates, m, start, stop, max_std_cm):
                        # Shorter and shorter pieces next to the edge until the partners stay rigid enough.
                        n = b - a
                        while n and not accept(m, *((a, a + n) if a == start else (b - n, b)), "rigid", report, False):
                            n //= 2
            _finish(report, filled[start:stop, m], start)
    return AutoFill(out, filled, gaps)


def _rigid_pieces(candidates: _Candidates, marker: int, start: int, stop: int, max_std_cm: float) -> list[tuple]:
    """Parts of the gap ``[start, stop)`` next to a measured edge through which three rigid partners stay
    visible (``[start, stop)`` pairs; the later piece is dropped where the two would overlap)."""
    spread = candidates.distances[0]
    visible = candidates.visible
    pieces = []
    if start > 0:
        n = min(rigid_reach(visible, spread, marker, start - 1, 1, max_std_cm), stop - start)
        if n:
            pieces.append((start, start + n))
    if stop < len(visible):
        n = min(rigid_reach(visible, spread, marker, stop, -1, max_std_cm), stop - start)
        if n and (not pieces or pieces[0][1] <= stop - n):
            pieces.append((stop - n, stop))
    return pieces


def gap_report(markers: Markers, marker: int, start: int, stop: int) -> dict:
    """A fresh report of the gap ``[start, stop)`` of ``marker``: nothing filled yet."""
    return {
        "marker": markers.labels[marker],
        "marker_index": marker,
        "first_frame": start,
        "last_frame": stop - 1,
        "frames": stop - start,
        "seconds": round((stop - start) / markers.fps, 4),
        "status": "unfilled",
        "method": None,
        "ratio": None,
        "filled_frames": 0,
        "unfilled_spans": [[start, stop - 1]],
        "tried": [],
    }


def _finish(report: dict, filled: np.ndarray, start: int) -> None:
    """Set a report's status, filled frame count and unfilled spans (first, last; inclusive) from ``filled``
    (the gap's frames, True where filled)."""
    report["filled_frames"] = int(filled.sum())
    report["unfilled_spans"] = [[start + a, start + b - 1] for a, b in runs(~filled)]
    report["status"] = "filled" if filled.all() else "partly filled" if filled.any() else "unfilled"


def describe_fill(markers: Markers, result: np.ndarray, method: str) -> list[dict]:
    """Per-gap reports (as :func:`auto_fill` writes them) for a fill ``result [T, M, 3]`` made by one
    ``method``, with the step ratio of the samples it filled."""
    reference = largest_measured_steps(markers.points, markers.visible)
    have = np.isfinite(result).all(axis=2)
    gaps = []
    for m in np.flatnonzero(~markers.visible.all(axis=0)):
        for start, stop in runs(~markers.visible[:, m]):
            report = gap_report(markers, int(m), start, stop)
            _finish(report, have[start:stop, m], start)
            if report["filled_frames"]:
                ratio = step_ratio(np.where(have[:, m, None], result[:, m], np.nan), start, stop, reference[m])
                report.update(method=method, ratio=round(ratio, 3) if np.isfinite(ratio) else None)
            gaps.append(report)
    return gaps


def summary_table(gaps: Sequence[dict], limit: float = 2.0, shown: int = 8, first_frame: int = 0) -> str:
    """A short text table of per-gap reports: per method the gaps it filled (wholly or in part), samples and
    worst step ratio; the gaps with samples left missing; then the ``shown`` longest missing spans with the
    reasons the first candidates gave, numbered as in the file (take frame 0 is file frame ``first_frame``)."""
    lines = [f"{'method':14s} {'gaps':>6s} {'samples':>8s} {'worst step ratio':>17s}"]
    methods = [*CANDIDATES, *sorted({g["method"] for g in gaps if g["method"]} - set(CANDIDATES))]
    for name in methods:
        rows = [g for g in gaps if g["method"] == name]
        if not rows:
            continue
        ratios = [g["ratio"] for g in rows if g["ratio"] is not None]
        worst = f"{max(ratios):.2f}" if ratios else "-"
        flag = " (over the limit)" if ratios and max(ratios) > limit else ""
        lines.append(f"{name:14s} {len(rows):6d} {sum(g['filled_frames'] for g in rows):8d} {worst:>17s}{flag}")
    left = [g for g in gaps if g["unfilled_spans"]]
    if left:
        n_left = sum(b - a + 1 for g in left for a, b in g["unfilled_spans"])
        lines.append(f"{'left missing':14s} {len(left):6d} {n_left:8d} {'-':>17s}")
    spans = sorted(((b - a + 1, a, b, g) for g in left for a, b in g["unfilled_spans"]), key=lambda x: -x[0])
    for n, a, b, g in spans[:shown]:
        why = "; ".join(g["tried"][:2]) or "no candidate"
        lines.append(f"  missing {g['marker']} frames {a + first_frame}-{b + first_frame} ({n} frames): {why}")
    if len(spans) > shown:
        lines.append(f"  … and {len(spans) - shown} shorter spans left missing")
    return "\n".join(lines)


def plot_fills(
    path: str | os.PathLike,
    markers: Markers,
    points: np.ndarray,
    gaps: Sequence[dict],
    max_markers: int = 12,
) -> int:
    """Write a PNG of the filled markers' x, y, z (cm) against time (s): measured samples in colour, filled
    spans highlighted green, spans left missing shaded red; at most ``max_markers`` markers (most filled
    samples first). Returns the number of markers drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    touched: dict[int, int] = {}
    for g in gaps:
        touched[g["marker_index"]] = touched.get(g["marker_index"], 0) + g["filled_frames"]
    chosen = sorted(touched, key=lambda m: -touched[m])[:max_markers]
    chosen = sorted(chosen) or [0]
    t = np.arange(markers.n_frames) / markers.fps
    fig, axes = plt.subplots(len(chosen), 1, figsize=(11, 1.8 * len(chosen) + 0.6), sharex=True, squeeze=False)
    for ax, m in zip(axes[:, 0], chosen):
        measured = np.where(markers.visible[:, m, None], points[:, m], np.nan)
        for k, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
            ax.plot(t, measured[:, k], color=colour, lw=1.0, label="xyz"[k] if m == chosen[0] else None)
            ax.plot(t, points[:, m, k], color=colour, lw=1.0, ls=":", alpha=0.9)
        for g in gaps:
            if g["marker_index"] != m:
                continue
            if g["filled_frames"]:
                ax.axvspan(g["first_frame"] / markers.fps, (g["last_frame"] + 1) / markers.fps, color="tab:green",
                           alpha=0.18, lw=0)  # fmt: skip
            for a, b in g["unfilled_spans"]:
                ax.axvspan(a / markers.fps, (b + 1) / markers.fps, color="white", lw=0)
                ax.axvspan(a / markers.fps, (b + 1) / markers.fps, color="tab:red", alpha=0.12, lw=0)
        ax.set_ylabel(markers.labels[m], rotation=0, ha="right", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=3)
    axes[-1, 0].set_xlabel("time (s); solid = measured, dotted = filled; green = filled span, red = left missing")
    more = len(touched) - len(chosen)
    fig.suptitle(
        f"{markers.name or 'take'}: filled markers (cm)" + (f"; {more} more markers not shown" if more > 0 else ""),
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return len(chosen)


@register(
    "auto",
    "points",
    help="per gap: rigid-body, pca, knn (with database=), spline or lerp, the first whose fill passes the checks "
    "(worst filled step <= limit x the marker's largest measured step, distances to the other markers within "
    "their measured ranges, rigid partners rigid); gaps nothing fills plausibly are interpolated linearly with "
    "a warning here (mocapnet clean leaves them missing); options database, limit, max_interp_s, spline_first_s",
)
def _auto(
    context: MethodContext,
    database: str | None = None,
    limit: float = 2.0,
    max_interp_s: float = 0.5,
    spline_first_s: float = 0.1,
) -> Callable[[Markers], np.ndarray]:
    """``auto`` for the harness interface (every sample filled): unfilled gaps are interpolated linearly with
    a warning naming them."""

    def clean(noisy: Markers) -> np.ndarray:
        got = auto_fill(noisy, database, limit, max_interp_s, spline_first_s)
        return fill_remaining_linear(noisy, got.points, "auto found no plausible fill")

    return clean
