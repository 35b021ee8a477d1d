"""PCA gap filling from inter-marker correlations, after Gløersen & Federolf (2016), "Predicting missing
marker trajectories in human motion data using marker intercorrelations", PLoS ONE 11(3): e0152616 — no
database, only the clip itself.

Our reading of their reconstruction strategy R2 (each marker with gaps is rebuilt on its own):

1. Subtract the mean trajectory (per frame, the centroid of the markers that have no gap; when every marker
   has one, the centroid of the visible markers each shifted by its mean offset — :func:`moving_centre` —
   so the centre does not jump when markers appear or vanish), so the coordinates move with the subject.
2. For marker i with gaps: markers with gaps farther from i than ``distal_threshold`` × i's mean distance to
   all markers, and markers whose gaps overlap i's, are zeroed (left out); the frames that are complete in
   what is left form N, the frames where i is missing are to be rebuilt. When N has fewer than
   ``min_frames`` frames, further markers are left out (those whose gaps cost N most first); when still
   fewer, or fewer than ``min_markers`` markers remain, i is not rebuilt (NaN: PCA cannot be trusted there
   and says so rather than extrapolating from two frames).
3. Every column is normalised by the mean and standard deviation over N and weighted by
   ``exp(-d² / (2 σ²))`` (d = the marker's mean distance to i, σ = ``weight_scale_cm``); marker i itself
   gets the small weight ``missing_weight``.
4. PCA of N (principal vectors V1) and of N with marker i zeroed (V0); both keep the first components
   whose singular values sum to ``min_cum_sv`` of the total (the larger of the two counts).
5. A frame with i missing (i zeroed) is rebuilt as ``M V0 T V1ᵀ`` with ``T = V1ᵀ V0`` (Federolf 2013,
   eq. 1, in the form of the authors' published MATLAB code: its scores on V0 are taken as scores on the
   matching vectors of V1, T fixing signs and mixing); only marker i's coordinates are kept (un-weighted,
   un-normalised). The algebraic change of basis ``M V0 V0ᵀ V1 V1ᵀ`` was worse on two of three clips
   we tried (tennis serve, HDM05), better on one (CMU 85_02).

Distances are mean distances over (at most 500 evenly spaced) frames where both markers are visible.
Units are cm throughout (σ = 20 cm is the published 200 mm).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

from mocapnet.fill import runs
from mocapnet.methods.baselines import lerp_fill
from mocapnet.methods.registry import MethodContext, register
from mocapnet.motion import Markers

_DISTANCE_FRAMES = 500


def mean_distances(points: np.ndarray, visible: np.ndarray, markers: np.ndarray) -> np.ndarray:
    """Mean distance (cm) from each of ``markers`` to every point, ``[len(markers), M]``, over at most 500
    evenly spaced frames of ``points [T, M, 3]`` where both are visible (NaN if never together)."""
    step = max(1, len(points) // _DISTANCE_FRAMES)
    pts, vis = points[::step], visible[::step]
    dist = np.linalg.norm(pts[:, markers, None] - pts[:, None], axis=-1)  # [T', G, M]
    both = vis[:, markers, None] & vis[:, None]
    with np.errstate(invalid="ignore"):
        return np.where(both, dist, 0.0).sum(axis=0) / both.sum(axis=0)


def _principal(data: np.ndarray, min_cum_sv: float) -> tuple[np.ndarray, int]:
    """Principal vectors ``[C, C']`` (columns) of ``data [N, C]`` and how many reach ``min_cum_sv`` of the
    summed singular values. From the eigenvectors of the ``[C, C]`` scatter matrix (singular values are the
    square roots of its eigenvalues): the same vectors as an SVD of ``data``, for a fraction of the work when
    ``N`` is thousands of frames."""
    values, vectors = np.linalg.eigh(data.T @ data / max(len(data) - 1, 1))
    order = np.argsort(values)[::-1][: min(len(data), data.shape[1])]
    sv = np.sqrt(np.maximum(values[order], 0.0))
    n = int(np.searchsorted(np.cumsum(sv), min_cum_sv * sv.sum()) + 1)
    return vectors[:, order], min(n, len(sv))


def _reconstruct(
    data: np.ndarray, target: int, weights: np.ndarray, rebuild: np.ndarray, min_cum_sv: float
) -> np.ndarray:
    """Coordinates ``[R, 3]`` of marker ``target`` in the rows ``rebuild`` of ``data [T, M, 3]`` (NaN where
    missing, left-out markers already zero), from the rows complete in ``data`` (the caller makes sure there
    are enough). Only the target's columns are un-weighted, so no column of weight 0 is ever divided by."""
    flat = data.reshape(len(data), -1)
    complete = np.isfinite(flat).all(axis=1)
    cols = slice(3 * target, 3 * target + 3)
    n_full = flat[complete]
    n_zero = n_full.copy()
    n_zero[:, cols] = 0.0
    m_zero = np.nan_to_num(flat[rebuild])
    m_zero[:, cols] = 0.0
    mean_full, mean_zero = n_full.mean(axis=0), n_zero.mean(axis=0)
    std = n_full.std(axis=0)
    std[std == 0] = 1.0
    w = np.repeat(weights, 3)
    v_full, n1 = _principal((n_full - mean_full) / std * w, min_cum_sv)
    v_zero, n0 = _principal((n_zero - mean_zero) / std * w, min_cum_sv)
    n = max(n0, n1)
    v_full, v_zero = v_full[:, :n], v_zero[:, :n]
    scores = ((m_zero - mean_zero) / std * w) @ v_zero @ (v_full.T @ v_zero)
    return mean_full[cols] + (scores @ v_full[cols].T) * std[cols] / w[cols]


def moving_centre(points: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Mean trajectory ``[T, 3]`` (cm) of ``points [T, M, 3]``: the centroid of the markers that are never
    missing; when every marker has gaps, the centroid of the visible markers each shifted by its mean offset
    from that centroid (two refinements), so the centre does not jump when a marker appears or vanishes.
    Frames with no visible marker are interpolated linearly in time (held beyond the ends)."""
    whole = visible.all(axis=0)
    if whole.any():
        return points[:, whole].mean(axis=1)
    seen = visible.any(axis=1)
    if not seen.any():
        raise ValueError("no marker is visible in any frame")
    count = np.maximum(visible.sum(axis=1), 1)[:, None]
    pts = np.where(visible[..., None], points, 0.0)
    centre = pts.sum(axis=1) / count
    for _ in range(2):
        rel = np.where(visible[..., None], points - centre[:, None], 0.0)
        offset = rel.sum(axis=0) / np.maximum(visible.sum(axis=0), 1)[:, None]  # [M, 3]
        centre = np.where(visible[..., None], points - offset, 0.0).sum(axis=1) / count
    if not seen.all():
        centre = lerp_fill(centre, np.repeat(~seen[:, None], 3, axis=1))
    return centre


def _kept_markers(visible: np.ndarray, target: int, kept: np.ndarray, min_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Drop markers from ``kept [M]`` (bool; markers visible wherever ``target`` is missing) until at least
    ``min_frames`` frames have ``target`` and every kept marker visible: each round drops the marker whose
    removal completes the most frames (else the one missing most often where ``target`` is seen). Returns
    the kept mask and the complete frames ``[T]``."""
    kept = kept.copy()
    seen = visible[:, target]
    while True:
        absent = ~visible[:, kept]
        complete = seen & ~absent.any(axis=1)
        if complete.sum() >= min_frames or not kept.any():
            return kept, complete
        idx = np.flatnonzero(kept)
        single = seen & (absent.sum(axis=1) == 1)
        gain = absent[single].sum(axis=0)
        if not gain.any():
            gain = absent[seen].sum(axis=0)
        kept[idx[int(np.argmax(gain))]] = False


def pca_fill(
    points: np.ndarray,
    visible: np.ndarray,
    weight_scale_cm: float = 20.0,
    missing_weight: float = 0.02,
    distal_threshold: float = 0.5,
    min_cum_sv: float = 0.99,
    min_frames: int = 20,
    min_markers: int = 3,
) -> np.ndarray:
    """Fill the missing samples of ``points [T, M, 3]`` (cm; ``visible [T, M]``) from the clip's own
    inter-marker correlations (module docstring). Returns ``[T, M, 3]`` cm: visible samples unchanged, NaN
    where PCA cannot be trusted: a marker is rebuilt only from markers visible wherever it is missing, and
    only when at least ``min_frames`` frames show it together with them and at least ``min_markers`` of them
    carry weight; markers are dropped (most harmful first) until enough frames are complete."""
    points = np.where(visible[..., None], points, np.nan)
    gapped = np.flatnonzero(~visible.all(axis=0) & visible.any(axis=0))
    out = points.copy()
    if gapped.size == 0:
        return out
    centre = moving_centre(points, visible)
    rel = points - centre[:, None]
    distances = mean_distances(points, visible, gapped)
    for row, i in enumerate(gapped):
        d = distances[row]
        missing_i = ~visible[:, i]
        weights = np.exp(-(np.nan_to_num(d, nan=np.inf) ** 2) / (2.0 * weight_scale_cm**2))
        kept = visible[missing_i].all(axis=0) & (weights > 0)
        with np.errstate(invalid="ignore"):
            far = d > distal_threshold * np.nanmean(d)
        kept &= ~(far & ~visible.all(axis=0))
        kept[i] = False
        kept, complete = _kept_markers(visible, int(i), kept, min_frames)
        if kept.sum() < min_markers or complete.sum() < min_frames:
            continue
        kept[i] = True
        data = np.where(kept[None, :, None], rel, 0.0)  # left-out markers zero; kept ones NaN where missing
        weights[i] = missing_weight
        out[missing_i, i] = _reconstruct(data, int(i), weights, missing_i, min_cum_sv) + centre[missing_i]
    return out


def fill_remaining_linear(markers: Markers, points: np.ndarray, why: str) -> np.ndarray:
    """Fill the NaN samples of ``points [T, M, 3]`` by linear interpolation in time, warning once per
    marker with the file, the marker and its frame spans (0-based, inclusive) and ``why``."""
    gaps = ~np.isfinite(points).all(axis=-1)
    if not gaps.any():
        return points
    for m in np.flatnonzero(gaps.any(axis=0)):
        spans = ", ".join(f"{a}-{b - 1}" for a, b in runs(gaps[:, m]))
        warnings.warn(
            f"{markers.name or 'markers'}: {why}; marker {markers.labels[m]} frames {spans} filled by linear "
            "interpolation",
            stacklevel=3,
        )
    t, m, _ = points.shape
    return lerp_fill(points.reshape(t, m * 3), np.repeat(gaps, 3, axis=1)).reshape(t, m, 3)


@register(
    "pca",
    "points",
    help="Gløersen & Federolf 2016 PCA of inter-marker correlations (no database); options weight_scale_cm, "
    "missing_weight, distal_threshold, min_cum_sv",
)
def _pca(
    context: MethodContext,
    weight_scale_cm: float = 20.0,
    missing_weight: float = 0.02,
    distal_threshold: float = 0.5,
    min_cum_sv: float = 0.99,
) -> Callable[[Markers], np.ndarray]:
    """``pca`` for the harness: markers it cannot rebuild are filled linearly with a warning."""

    def clean(noisy: Markers) -> np.ndarray:
        filled = pca_fill(noisy.points, noisy.visible, weight_scale_cm, missing_weight, distal_threshold, min_cum_sv)
        return fill_remaining_linear(
            noisy, filled, "pca cannot be trusted for this marker (too few frames or markers in view with it)"
        )

    return clean
