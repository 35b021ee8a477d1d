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


def gap_lengths(mask: np.ndarray) -> np.ndarray:
    """``[T, C]`` int: each missing sample of ``mask [T, C]`` holds the length (frames) of its gap
    (``gap_list``), each observed sample 0."""
    lengths = np.zeros(mask.shape, dtype=np.int64)
    for cols, a, b in gap_list(mask):
        lengths[a:b, cols] = b - a
    return lengths


#: A step (degrees) across a gap above which the gap is taken to hide a wrap (e.g. 179 → -179), not motion, in a
#: file that may wrap its angles (``unwrap_observed``).
WRAP_STEP = 270.0


def turn_range_low(lowest: np.ndarray | float, highest: np.ndarray | float) -> np.ndarray:
    """The lower end (degrees) of the one-turn range a file that wraps its angles stores angles from ``lowest`` to
    ``highest`` in (broadcast): -180 for [-180, 180] (values within [0, 180] fit both), 0 for [0, 360], NaN for
    neither (stored continuously)."""
    lo, hi = np.asarray(lowest), np.asarray(highest)
    return np.where((lo >= -180.0) & (hi <= 180.0), -180.0, np.where((lo >= 0.0) & (hi <= 360.0), 0.0, np.nan))


def _fits_a_turn(values: np.ndarray) -> bool:
    """Whether angles ``values`` (degrees) lie within [-180, 180] or within [0, 360], as a file that wraps stores
    them (True for none)."""
    return not values.size or bool(np.isfinite(turn_range_low(values.min(), values.max())))


def unwrap_observed(channels: np.ndarray, mask: np.ndarray, columns: np.ndarray, copy: bool = True) -> np.ndarray:
    """Angles ``channels [T, C]`` as a file stores them (degrees; any value where ``mask [T, C]`` is True) made
    continuous along time in the ``columns`` (bool ``[C]`` or indices) without reading the masked samples, whose
    placeholder values would break the chain. Between neighbouring observed frames a step of more than 180° is
    a wrap, as ``np.unwrap`` and ``read_bvh`` take it. Across a gap, where the file cannot say how far a joint turned:

    - when the observed values of every column fit one of the two storage conventions, within [-180°, 180°] or
      within [0°, 360°], the file may wrap its angles: a gap is joined the shorter way round when its edges differ
      by more than ``WRAP_STEP`` (179 → -179 and 358 → 2 are turns of 2° and 4°). A turn of more than 270°
      hidden in a gap is then invisible in the file and filled the short way too;
    - when some column fits neither (e.g. -20 and 330), the file stores its angles continuously, so every gap's
      edges say how far the joint turned (-20 → 330 across a gap is a turn of 350°) and are kept.

    Returns float64 channels (``copy=False``: ``channels`` itself when it is float64, changed in place); masked
    samples move with the observed sample before them (after them, before the first). A column without a masked
    sample gets ``np.unwrap(period=360)``, bit for bit the unwrap ``read_bvh`` does."""
    out = np.array(channels, dtype=np.float64, copy=True) if copy else np.asarray(channels, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    columns = np.asarray(columns)
    cols = np.flatnonzero(columns) if columns.dtype == bool else columns.astype(np.intp)
    if out.shape[0] < 2 or not cols.size:
        return out
    from mocapnet.io.bvh import unwrap_rotations

    gapped = mask[:, cols].any(axis=0)
    wrapped = gapped.any() and all(_fits_a_turn(out[~mask[:, c], c]) for c in cols)  # as stored, before unwrapping
    whole = np.zeros(out.shape[1], dtype=bool)
    whole[cols[~gapped]] = True
    unwrap_rotations(out, whole)  # a column without a gap: read_bvh's own unwrap
    t = np.arange(out.shape[0])
    for c in cols[gapped]:
        seen = t[~mask[:, c]]
        if seen.size < 2:
            continue
        values = out[seen, c]
        step = np.diff(values)
        across = np.diff(seen) > 1
        wrapped_step = np.mod(step + 180.0, 360.0) - 180.0  # np.unwrap's rule, ties included
        wrapped_step[(wrapped_step == -180.0) & (step > 0)] = 180.0
        turns = np.round((step - wrapped_step) / 360.0)
        in_run = ~across & (np.abs(step) >= 180.0)
        joined = across & (np.abs(step) > WRAP_STEP) if wrapped else np.zeros_like(across)
        fix = np.where(in_run | joined, turns, 0.0)
        if not fix.any():
            continue
        shift = np.concatenate([[0.0], np.cumsum(fix)]) * 360.0  # per observed sample
        holder = np.clip(np.searchsorted(seen, t, side="right") - 1, 0, None)  # the observed sample at or before
        out[:, c] -= shift[holder]
    return out


def lerp_fill(channels: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Linear interpolation over the masked samples of ``channels [T, C]`` (mask True = missing).

    Missing samples before the first / after the last observed one take the nearest observed value.
    Columns with no observed sample are left as they are. Angles are bridged as they are given: make them
    continuous first (``unwrap_observed``, as ``mocapnet clean`` does with a mask).
    """
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
    on columns with a short gap)."""
    out = lerp_fill(channels, mask) if interpolated is None else np.array(interpolated[0], dtype=np.float64)
    if spline_max < 1:
        return out
    lengths = gap_lengths(mask)
    short = (lengths > 0) & (lengths <= spline_max)
    cols = np.flatnonzero(short.any(axis=0))
    if cols.size:
        spline = spline_fill(channels[:, cols], mask[:, cols]) if interpolated is None else interpolated[1][:, cols]
        out[:, cols] = np.where(short[:, cols], spline, out[:, cols])
    return out


def spline_fill(channels: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Cubic-spline interpolation (scipy ``CubicSpline``, not-a-knot) over masked samples of ``[T, C]``;
    falls back to linear where fewer than 4 samples are observed, and holds values beyond the ends. Angles as
    in ``lerp_fill``."""
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
