"""Gaussian smoothing with each channel's width chosen from the data by leave-one-out cross-validation.

A linear smoother ``y = S x`` has the leave-one-out residual ``(x_t - y_t) / (1 - S_tt)`` at every frame (the
value predicted from the other frames, exactly, for any linear smoother). For a Gaussian kernel with edges padded
by the nearest value, ``S_tt`` is the kernel's centre weight ``w0`` inside the clip and ``(1 + w0) / 2`` at its
first and last frame (the padding repeats them), so each width's cross-validation score costs one filter pass.
Per channel the width with the smallest mean squared residual over the observed frames wins: heavy noise on slow
motion gets a wide kernel, light noise or fast motion a narrow one, without a noise estimate and without
training. Only widths whose kernel fits in the clip (``2·radius + 1 <= T``) are candidates, so a very short clip
keeps its samples. Numpy/scipy only.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from mocapnet.fill import runs

#: Candidate widths (std, frames at the clip's own rate): ``KEEP`` (0.25: scored as that narrow Gaussian, whose
#: neighbours weigh 3e-4 each; when it wins the channel is returned exactly as it came) and 0.5 to 16 frames in
#: steps of √2. As the width shrinks to 0 the leave-one-out prediction becomes the
#: mean of the two neighbours, so "keep the input" is scored by that prediction's error (noise variance 1.5σ² against
#: the 2σ² of keeping a noisy sample): the rule leans toward keeping the input.
KEEP = 0.25
SIGMA_GRID_FRAMES = (KEEP, *(float(0.5 * np.sqrt(2.0) ** k) for k in range(11)))
#: The widest std (s) the methods may pick: the grid's top at 30 fps, the rate it was chosen at (session 23). A
#: slower clip gets fewer widths (``grid_for_rate``): at 1 fps one frame is a second of motion, and smoothing over
#: 16 of them turned a keyframed arm by 85° (a reviewer's sweep of other vendors' files, session 32).
MAX_SIGMA_S = SIGMA_GRID_FRAMES[-1] / 30.0
#: Columns handled at a time (the temporaries are ``[T, COLUMN_BLOCK]``: O(T) memory).
COLUMN_BLOCK = 16
#: ``scipy.ndimage.gaussian_filter1d``'s default kernel radius, in standard deviations.
TRUNCATE = 4.0


def grid_for_rate(fps: float) -> tuple[float, ...]:
    """The widths (std, frames) of ``SIGMA_GRID_FRAMES`` no wider than ``MAX_SIGMA_S`` at ``fps`` frames per
    second; ``KEEP`` always. At 30 fps and faster, the whole grid."""
    return tuple(s for s in SIGMA_GRID_FRAMES if s == KEEP or s <= MAX_SIGMA_S * fps)


def kernel_radius(sigma: float) -> int:
    """The radius (frames) of ``gaussian_filter1d``'s kernel of std ``sigma`` (frames)."""
    return int(TRUNCATE * sigma + 0.5)


def centre_weight(sigma: float) -> float:
    """The centre tap of ``gaussian_filter1d``'s normalised kernel of std ``sigma`` (frames)."""
    radius = kernel_radius(sigma)
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    return float(1.0 / taps.sum())


def _self_weights(sigma: float, n_frames: int) -> np.ndarray:
    """``S_tt`` ``[T, 1]`` of the Gaussian of std ``sigma`` with nearest-value padding: ``w0``, and ``(1 + w0) / 2``
    at the first and last frame."""
    w0 = centre_weight(sigma)
    out = np.full((n_frames, 1), w0)
    out[[0, -1]] = (1.0 + w0) / 2.0
    return out


def cv_gaussian(
    channels: np.ndarray,
    grid_frames: tuple[float, ...] = SIGMA_GRID_FRAMES,
    observed: np.ndarray | None = None,
    period: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``channels [T, C]`` (continuous along time: positions, or angles as ``read_bvh`` gives them;
    ``period=360``: angles stored wrapped, unwrapped here from 180° — on noisy angles that takes noise for wraps;
    the methods take angles as given, and ``mocapnet clean`` unwraps a file once as it reads it,
    ``fill.unwrap_observed``) smoothed per channel by the Gaussian
    of ``grid_frames`` (std, frames, each ≥ 0.25) with the smallest leave-one-out error → ``(smoothed [T, C]
    float64 on each sample's own branch, chosen std [C] in frames)``. ``observed [T, C]`` (bool): the frames whose
    residuals are scored (default all; e.g. not the samples a gap filler made up). Edges are padded with the
    nearest value (as ``fill.gaussian_smooth``). Widths whose kernel does not fit in the clip are skipped; a
    channel no width fits, one with a non-finite value or one without a scored frame comes back unchanged (std 0);
    a channel where ``KEEP`` wins comes back exactly as it came (std ``KEEP``).
    """
    x = np.asarray(channels, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"cv_gaussian: channels must be [T, C], got shape {x.shape}")
    if any(not (np.isfinite(s) and s >= 0.25) for s in grid_frames):
        raise ValueError(f"cv_gaussian: every width must be a number of frames >= 0.25, got {grid_frames}")
    if observed is not None and np.shape(observed) != x.shape:
        raise ValueError(f"cv_gaussian: observed {np.shape(observed)} does not match channels {x.shape}")
    n = len(x)
    out, chosen = x.copy(), np.zeros(x.shape[1])
    fits = [s for s in grid_frames if 2 * kernel_radius(s) + 1 <= n]
    divisors = {s: 1.0 - _self_weights(s, n) for s in fits}
    for c in range(0, x.shape[1], COLUMN_BLOCK):
        cols = slice(c, c + COLUMN_BLOCK)
        raw, picked = x[:, cols], chosen[cols]  # picked: a view of this block's widths
        unwrapped = raw if period is None else np.unwrap(raw, period=period, axis=0)
        weight = np.ones(raw.shape) if observed is None else np.asarray(observed[:, cols], dtype=np.float64)
        counted = weight.sum(axis=0)
        best = np.full(raw.shape[1], np.inf)
        usable = np.isfinite(raw).all(axis=0) & (counted > 0)
        for sigma in fits:
            smooth = gaussian_filter1d(unwrapped, sigma, axis=0, mode="nearest", truncate=TRUNCATE)
            score = (weight * ((unwrapped - smooth) / divisors[sigma]) ** 2).sum(axis=0) / np.maximum(counted, 1.0)
            better = usable & (score < best)
            if better.any():
                best[better] = score[better]
                picked[better] = sigma
                out[:, cols][:, better] = smooth[:, better] + (raw - unwrapped)[:, better]
        kept = picked == KEEP
        out[:, cols][:, kept] = raw[:, kept]
    return out, chosen


def cv_gaussian_runs(
    points: np.ndarray, visible: np.ndarray, grid_frames: tuple[float, ...] = SIGMA_GRID_FRAMES
) -> tuple[np.ndarray, np.ndarray]:
    """Marker trajectories ``points [T, M, 3]`` (any length unit; NaN where missing) smoothed along each run of
    ``visible [T, M]`` frames of each marker on its own, by ``cv_gaussian`` (each axis its own width; gaps are
    not bridged, so nothing made up enters a smoothed sample) → ``(smoothed [T, M, 3], chosen std [T, M, 3] in
    frames: 0 where not visible or where no width fits the run, ``KEEP`` where the run's axis is returned as it
    came)``. Samples of a kept axis are the input exactly."""
    pts = np.asarray(points, dtype=np.float64)
    vis = np.asarray(visible, dtype=bool)
    if pts.ndim != 3 or pts.shape[2] != 3 or vis.shape != pts.shape[:2]:
        raise ValueError(f"cv_gaussian_runs: points must be [T, M, 3] and visible [T, M], got {pts.shape}, {vis.shape}")
    out, chosen = pts.copy(), np.zeros(pts.shape)
    for m in range(pts.shape[1]):
        for a, b in runs(vis[:, m]):
            out[a:b, m], chosen[a:b, m] = cv_gaussian(pts[a:b, m], grid_frames, period=None)
    return out, chosen
