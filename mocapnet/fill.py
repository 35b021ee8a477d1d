"""Fill and smoothing primitives on arrays ``[T, C]`` (mask True = missing), shared by the methods
(``mocapnet.methods``) and the networks (``mocapnet.nn``), which both sit above this module. Pure functions in
the style of ``scipy.ndimage``: arrays in, arrays out, no state."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import gaussian_filter1d


def runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of every run of True in a 1-D boolean array (Python ints)."""
    edges = np.diff(np.concatenate([[0], np.asarray(flags).astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def gaussian_smooth(channels: np.ndarray, sigma_s: float | np.ndarray, fps: float) -> np.ndarray:
    """Gaussian smoothing along time of ``channels [T, C]`` with std ``sigma_s`` seconds (scalar or ``[C]``).

    Edges are padded with the nearest value. ``sigma_s = 0`` returns the input.
    """
    sig = np.broadcast_to(np.asarray(sigma_s, dtype=np.float64) * fps, (channels.shape[1],))
    if sig.size and sig[0] > 0 and (sig == sig[0]).all():  # one σ for every channel: one filter call, no copy
        return gaussian_filter1d(np.asarray(channels, dtype=np.float64), sigma=sig[0], axis=0, mode="nearest")
    out = channels.astype(np.float64, copy=True)
    for value in np.unique(sig):
        if value <= 0:
            continue
        cols = sig == value
        out[:, cols] = gaussian_filter1d(channels[:, cols], sigma=value, axis=0, mode="nearest")
    return out


def mask_groups(mask: np.ndarray) -> dict[bytes, np.ndarray]:
    """Columns of ``mask [T, C]`` grouped by identical missing pattern (channels of one joint share one)."""
    groups: dict[bytes, list[int]] = {}
    for c in np.flatnonzero(mask.any(axis=0)):
        groups.setdefault(np.packbits(mask[:, c]).tobytes(), []).append(c)
    return {k: np.array(v) for k, v in groups.items()}


def gap_list(mask: np.ndarray) -> list[tuple[np.ndarray, int, int]]:
    """The gaps of ``mask [T, C]`` as ``(channels, first frame, end frame)``: each run of missing frames of the
    channels that miss together (``mask_groups``), group by group in time order."""
    return [(cols, a, b) for cols in mask_groups(mask).values() for a, b in runs(mask[:, cols[0]])]


#: A step (degrees) across a gap above which the gap is taken to hide a wrap (e.g. 179 → -179), not motion: a
#: gap's two edges are joined the shorter way round the circle when they differ by more than this.
WRAP_STEP = 270.0


def join_gaps(
    channels: np.ndarray, mask: np.ndarray, period: float = 360.0, wrap_step: float = WRAP_STEP
) -> tuple[np.ndarray, np.ndarray]:
    """Angles ``channels [T, C]`` (degrees; any value where ``mask [T, C]`` is True) with each run of observed
    samples after a gap shifted by a multiple of ``period`` so it starts within ``period / 2`` of where the run
    before the gap ended, wherever the two differ by more than ``wrap_step`` (a gap hides a wrap: a file stored
    in [-180, 180) whose reader could not unwrap through the gap's placeholder values). Observed runs are
    continuous by convention (``read_bvh`` unwraps along time) and are never unwrapped inside: steps between
    neighbouring observed frames, however large, stay as they are. Returns ``(joined [T, C], offsets [T, C])``
    with ``channels = joined + offsets`` on observed samples; a missing sample's offset is that of the observed
    sample before it (after it, before the first), 0 in columns never observed."""
    joined = np.array(channels, dtype=np.float64, copy=True)
    offsets = np.zeros_like(joined)
    t = np.arange(joined.shape[0])
    for cols in mask_groups(mask).values():
        seen = t[~mask[:, cols[0]]]
        if seen.size < 2:
            continue
        across = np.flatnonzero(np.diff(seen) > 1)  # observed neighbours with a gap between them
        if not across.size:
            continue
        step = joined[seen[across + 1]][:, cols] - joined[seen[across]][:, cols]  # [gaps, cols]
        turns = np.where(np.abs(step) > wrap_step, np.round(step / period), 0.0)
        if not turns.any():
            continue
        shift = np.zeros((seen.size, cols.size))
        shift[across + 1] = turns * period
        run_offset = np.cumsum(shift, axis=0)  # per observed sample, how far its run moves
        holder = np.clip(np.searchsorted(seen, t, side="right") - 1, 0, None)  # the observed sample at or before
        offsets[:, cols] = run_offset[holder]
        joined[:, cols] -= offsets[:, cols]
    return joined, offsets


def join_columns(channels: np.ndarray, mask: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """``join_gaps`` on the angle ``columns`` (bool ``[C]`` or indices) of ``channels [T, C]`` only: ``(joined
    [T, C], offsets [T, C])`` (offsets 0 outside ``columns``; add them back to what is computed from the joined
    channels), or ``(channels, None)`` when no gap there hides a wrap (nothing to copy or add)."""
    if not mask[:, columns].any():
        return channels, None
    joined_cols, offsets_cols = join_gaps(channels[:, columns], mask[:, columns])
    if not offsets_cols.any():
        return channels, None
    joined = np.array(channels, dtype=np.float64, copy=True)
    joined[:, columns] = joined_cols
    offsets = np.zeros(joined.shape)
    offsets[:, columns] = offsets_cols
    return joined, offsets


def lerp_fill(channels: np.ndarray, mask: np.ndarray, period: float | None = None) -> np.ndarray:
    """Linear interpolation over the masked samples of ``channels [T, C]`` (mask True = missing).

    Missing samples before the first / after the last observed one take the nearest observed value.
    Columns with no observed sample are left as they are. ``period`` (360 for angles in degrees): a gap whose
    edges differ by more than ``WRAP_STEP`` is bridged the shorter way round the circle (170 to -170 through 180,
    not through 0; ``join_gaps``), each filled sample on the branch of the observed sample before its gap.
    """
    if period is not None:
        joined, offsets = join_gaps(channels, mask, period)
        return np.where(mask, lerp_fill(joined, mask) + offsets, channels)  # observed samples bit for bit
    out = np.array(channels, dtype=np.float64, copy=True)
    t = np.arange(out.shape[0])
    for cols in mask_groups(mask).values():
        miss = mask[:, cols[0]]
        if miss.all():
            continue
        seen, gaps = t[~miss], t[miss]
        for c in cols:
            out[miss, c] = np.interp(gaps, seen, out[~miss, c])
    return out


def lerp_fill_angles(channels: np.ndarray, mask: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """``lerp_fill`` of ``channels [T, C]``, the columns where ``angles [C]`` is True (degrees) with
    ``period=360`` (a gap that hides a wrap bridged the shorter way round), the others plainly."""
    joined, offsets = join_columns(channels, mask, angles)
    filled = lerp_fill(joined, mask)
    return filled if offsets is None else np.where(mask, filled + offsets, channels)


def gap_fill(
    channels: np.ndarray,
    mask: np.ndarray,
    spline_max: float,
    interpolated: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Interpolation of the masked samples of ``channels [T, C]`` chosen per gap: each run of missing samples
    of a column that is at most ``spline_max`` frames long takes ``spline_fill``'s value, longer runs (and every
    run when ``spline_max < 1``) take ``lerp_fill``'s. The starting point of EBD's fill and of its blend
    (``mocapnet.nn.ebd``): short gaps are best bridged by a cubic, long ones by a line. ``interpolated``:
    ``(lerp_fill, spline_fill)`` of ``channels`` when the caller has them, else computed here (the spline only
    on columns with a short gap). Angles with a gap that may hide a wrap: join them first (``join_gaps``)."""
    out = lerp_fill(channels, mask) if interpolated is None else np.array(interpolated[0], dtype=np.float64)
    if spline_max < 1:
        return out
    short = np.zeros(mask.shape, dtype=bool)
    for cols, a, b in gap_list(mask):
        if b - a <= spline_max:
            short[a:b, cols] = True
    cols = np.flatnonzero(short.any(axis=0))
    if cols.size:
        spline = spline_fill(channels[:, cols], mask[:, cols]) if interpolated is None else interpolated[1][:, cols]
        out[:, cols] = np.where(short[:, cols], spline, out[:, cols])
    return out


def spline_fill(channels: np.ndarray, mask: np.ndarray, period: float | None = None) -> np.ndarray:
    """Cubic-spline interpolation (scipy ``CubicSpline``, not-a-knot) over masked samples of ``[T, C]``;
    falls back to linear where fewer than 4 samples are observed, and holds values beyond the ends.
    ``period`` as in ``lerp_fill``."""
    if period is not None:
        joined, offsets = join_gaps(channels, mask, period)
        return np.where(mask, spline_fill(joined, mask) + offsets, channels)
    out = np.array(channels, dtype=np.float64, copy=True)
    t = np.arange(out.shape[0])
    for cols in mask_groups(mask).values():
        miss = mask[:, cols[0]]
        seen = ~miss
        if seen.sum() < 4:
            out[:, cols] = lerp_fill(out[:, cols], mask[:, cols])
            continue
        spline = CubicSpline(t[seen], out[seen][:, cols], axis=0)
        inside = miss & (t > t[seen][0]) & (t < t[seen][-1])
        out[np.ix_(inside, cols)] = spline(t[inside])
        out[:, cols] = lerp_fill(out[:, cols], mask[:, cols] & ~inside[:, None])
    return out
