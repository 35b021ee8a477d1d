"""PCA gap filling from inter-marker correlations, after Gløersen & Federolf (2016), "Predicting missing
marker trajectories in human motion data using marker intercorrelations", PLoS ONE 11(3): e0152616 — no
database, only the clip itself.

Our reading of their reconstruction strategy R2 (each marker with gaps is rebuilt on its own):

1. Subtract the mean trajectory (per frame, the centroid of the markers that have no gap; of the visible
   markers when every marker has one), so the coordinates move with the subject.
2. For marker i with gaps: markers with gaps farther from i than ``distal_threshold`` × i's mean distance to
   all markers, and markers whose gaps overlap i's, are zeroed (left out); the frames that are complete in
   what is left form N, the frames where i is missing are to be rebuilt.
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

from mocapnet.methods.baselines import lerp_fill
from mocapnet.methods.registry import MethodContext, register
from mocapnet.motion import Markers

_DISTANCE_FRAMES = 500


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of every run of True in a 1-D boolean array."""
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


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
    summed singular values."""
    _, sv, vt = np.linalg.svd(data / np.sqrt(max(len(data) - 1, 1)), full_matrices=False)
    n = int(np.searchsorted(np.cumsum(sv), min_cum_sv * sv.sum()) + 1)
    return vt.T, min(n, len(sv))


def _reconstruct(
    data: np.ndarray, target: int, weights: np.ndarray, rebuild: np.ndarray, min_cum_sv: float
) -> np.ndarray | None:
    """Coordinates ``[R, 3]`` of marker ``target`` in the rows ``rebuild`` of ``data [T, M, 3]`` (NaN where
    missing, left-out markers already zero), from the complete rows; None without two complete rows."""
    flat = data.reshape(len(data), -1)
    complete = np.isfinite(flat).all(axis=1)
    if complete.sum() < 2:
        return None
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
    rebuilt = mean_full + (scores @ v_full.T) * std / w
    return rebuilt[:, cols]


def pca_fill(
    points: np.ndarray,
    visible: np.ndarray,
    weight_scale_cm: float = 20.0,
    missing_weight: float = 0.02,
    distal_threshold: float = 0.5,
    min_cum_sv: float = 0.99,
) -> np.ndarray:
    """Fill the missing samples of ``points [T, M, 3]`` (cm; ``visible [T, M]``) from the clip's own
    inter-marker correlations (module docstring). Returns ``[T, M, 3]`` cm: visible samples unchanged,
    NaN where a marker could not be rebuilt (no two frames complete in the markers it is rebuilt from)."""
    points = np.where(visible[..., None], points, np.nan)
    gapped = np.flatnonzero(~visible.all(axis=0))
    out = points.copy()
    if gapped.size == 0:
        return out
    whole = visible.all(axis=0)
    ref = whole if whole.any() else np.ones(points.shape[1], dtype=bool)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        centre = np.nanmean(points[:, ref], axis=1)  # [T, 3]
    centre = np.nan_to_num(centre)
    rel = points - centre[:, None]
    distances = mean_distances(points, visible, gapped)
    for row, i in enumerate(gapped):
        d = distances[row]
        missing_i = ~visible[:, i]
        data = rel.copy()
        for other in gapped:
            if other == i:
                continue
            far = d[other] > distal_threshold * np.nanmean(d)
            if far or (~visible[missing_i, other]).any():
                data[:, other] = 0.0
        weights = np.exp(-(np.nan_to_num(d, nan=np.inf) ** 2) / (2.0 * weight_scale_cm**2))
        weights[i] = missing_weight
        rebuilt = _reconstruct(data, int(i), weights, missing_i, min_cum_sv)
        if rebuilt is not None:
            out[missing_i, i] = rebuilt + centre[missing_i]
    return out


def fill_remaining_linear(markers: Markers, points: np.ndarray, why: str) -> np.ndarray:
    """Fill the NaN samples of ``points [T, M, 3]`` by linear interpolation in time, warning once per
    marker with the file, the marker and its frame spans (0-based, inclusive) and ``why``."""
    gaps = ~np.isfinite(points).all(axis=-1)
    if not gaps.any():
        return points
    for m in np.flatnonzero(gaps.any(axis=0)):
        spans = ", ".join(f"{a}-{b - 1}" for a, b in _runs(gaps[:, m]))
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
        return fill_remaining_linear(noisy, filled, "pca could not rebuild a marker (too few complete frames)")

    return clean
