"""Gaussian smoothing with each channel's width chosen from the data by leave-one-out cross-validation.

A linear smoother ``y = S x`` has the leave-one-out residual ``(x_t - y_t) / (1 - S_tt)`` at every frame (the
value predicted from the other frames, exactly, for any linear smoother). For a Gaussian kernel ``S_tt`` is its
centre weight ``w0``, so each width's cross-validation score costs one filter pass. Per channel the width with
the smallest mean squared residual wins: heavy noise on slow motion gets a wide kernel, light noise or fast
motion a narrow one, without a noise estimate and without training. Numpy/scipy only.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

#: Candidate widths (std, frames at the clip's own rate): 0.25 (the input kept, within 0.07 %: its neighbours weigh
#: 3e-4 each) and 0.5 to 16 frames in steps of √2. As the width shrinks to 0 the leave-one-out prediction becomes the
#: mean of the two neighbours, so "keep the input" is scored by that prediction's error (noise variance 1.5σ² against
#: the 2σ² of keeping a noisy sample): the rule leans toward keeping the input.
SIGMA_GRID_FRAMES = (0.25, *(float(0.5 * np.sqrt(2.0) ** k) for k in range(11)))
#: Columns handled at a time (the temporaries are ``[T, COLUMN_BLOCK]``: O(T) memory).
COLUMN_BLOCK = 16
#: ``scipy.ndimage.gaussian_filter1d``'s default kernel radius, in standard deviations.
TRUNCATE = 4.0


def centre_weight(sigma: float) -> float:
    """The centre tap of ``gaussian_filter1d``'s normalised kernel of std ``sigma`` (frames)."""
    radius = int(TRUNCATE * sigma + 0.5)
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    return float(1.0 / taps.sum())


def cv_gaussian(
    channels: np.ndarray, grid_frames: tuple[float, ...] = SIGMA_GRID_FRAMES
) -> tuple[np.ndarray, np.ndarray]:
    """``channels [T, C]`` (degrees, any branch; unwrapped along time here) smoothed per channel by the Gaussian
    of ``grid_frames`` (std, frames) with the smallest leave-one-out error → ``(smoothed [T, C] float64 on each
    sample's own branch, chosen std [C] in frames)``. Edges are padded with the nearest value (as
    ``fill.gaussian_smooth``). Channels with fewer than 3 frames are returned unchanged (std 0)."""
    x = np.asarray(channels, dtype=np.float64)
    out, chosen = x.copy(), np.zeros(x.shape[1])
    if len(x) < 3 or not grid_frames:
        return out, chosen
    weights = {s: centre_weight(s) for s in grid_frames}
    for c in range(0, x.shape[1], COLUMN_BLOCK):
        cols = slice(c, c + COLUMN_BLOCK)
        raw = x[:, cols]
        unwrapped = np.unwrap(raw, period=360.0, axis=0)
        best = np.full(unwrapped.shape[1], np.inf)
        for sigma, w0 in weights.items():
            smooth = gaussian_filter1d(unwrapped, sigma, axis=0, mode="nearest", truncate=TRUNCATE)
            score = np.mean(((unwrapped - smooth) / (1.0 - w0)) ** 2, axis=0)
            better = score < best
            if better.any():
                best[better] = score[better]
                chosen[c : c + unwrapped.shape[1]][better] = sigma
                out[:, cols][:, better] = smooth[:, better] + (raw - unwrapped)[:, better]
    return out, chosen
