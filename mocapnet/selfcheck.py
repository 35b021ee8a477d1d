"""The self-check of the denoisers: a cleaned clip is pulled back toward its input on every channel that it
changed by much more than the noise that channel shows. Numpy only (EBF's checkpoints store their factor,
``change_limit``; the ``gaussian-58ms+check`` baseline uses it too).
"""

from __future__ import annotations

import warnings
from math import comb

import numpy as np

from mocapnet.kinematics import wrap_deg

#: Orders of difference ``noise_level`` estimates white noise from (2: the shipped self-check's).
NOISE_ORDERS = (2, 3, 4)
#: Columns the self-check handles at a time (its temporaries are ``[T, COLUMN_BLOCK]``: O(T) memory).
COLUMN_BLOCK = 8


def observed_stencils(observed: np.ndarray, order: int = 2) -> np.ndarray:
    """``[T - order, C]`` bool: the differences of ``order`` whose ``order + 1`` samples are all observed
    (``observed [T, C]`` bool)."""
    ok = np.asarray(observed, dtype=bool)
    return np.logical_and.reduce([ok[k : len(ok) - order + k] for k in range(order + 1)])


def noise_level(x: np.ndarray, order: int = 2, observed: np.ndarray | None = None) -> np.ndarray:
    """Standard deviation ``[C]`` (degrees) of white noise that ``x [T, C]`` (degrees) shows, from its differences of
    ``order`` (2, 3 or 4; ``C(2n, n)·σ²`` for white noise, 6σ² at order 2): ``1.4826·MAD / √C(2n, n)``, robust to
    spikes; the motion's own curvature can only raise it, less at a higher order (fast bandai2 ``run`` clips, clean:
    0.958° at order 2, 0.429° at order 4; ``scripts/check_noise_estimate.py``). ``observed [T, C]`` (bool): only
    differences of observed samples count (``observed_stencils``; a linear bridge over a gap shows no noise and
    would pull the estimate down), whatever the unobserved samples hold (NaN too). Zeros for fewer than
    ``order + 1`` frames, or a channel with no such difference."""
    if order not in NOISE_ORDERS:
        raise ValueError(f"noise order must be one of {NOISE_ORDERS}, got {order!r}")
    out = np.zeros(x.shape[1])
    if len(x) <= order:
        return out
    valid = None if observed is None else observed_stencils(observed, order)
    if observed is not None:  # unobserved values (NaN, say) must not reach unwrap, which carries them forward
        x = np.where(observed, x, 0.0)
    for c in range(0, x.shape[1], COLUMN_BLOCK):
        cols = slice(c, c + COLUMN_BLOCK)
        d = np.diff(np.unwrap(x[:, cols], period=360.0, axis=0), n=order, axis=0)
        if valid is None:
            d -= np.median(d, axis=0)
            mad = np.median(np.abs(d, out=d), axis=0)
        else:
            d[~valid[:, cols]] = np.nan
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a channel without an observed difference
                d -= np.nanmedian(d, axis=0)
                mad = np.nan_to_num(np.nanmedian(np.abs(d), axis=0))
        out[cols] = 1.4826 * mad / np.sqrt(comb(2 * order, order))
    return out


def limit_change(
    noisy: np.ndarray, cleaned: np.ndarray, factor: float, anchor: np.ndarray | None = None, order: int = 2
) -> np.ndarray:
    """The self-check: ``cleaned [T, C]`` moved back toward ``noisy [T, C]`` (degrees) on each channel whose RMS
    change exceeds ``factor`` × its ``noise_level``, so that it changes by exactly that much. A denoiser has no
    business changing a channel by much more than the noise it shows (on nearly clean input a learned filter
    otherwise smooths away real motion). ``anchor [T, C]``: measure and cap the distance from it instead (e.g. a
    training-free smoother's output); the cap is still from ``noisy``'s noise, estimated from differences of
    ``order`` (``noise_level``). Returns a new array; works ``COLUMN_BLOCK`` columns at a time."""
    cap = factor * noise_level(noisy, order)
    base = noisy if anchor is None else anchor
    out = np.empty(np.broadcast_shapes(noisy.shape, cleaned.shape))
    for c in range(0, out.shape[1], COLUMN_BLOCK):
        cols = slice(c, c + COLUMN_BLOCK)
        change = wrap_deg(cleaned[:, cols] - base[:, cols])
        rms = np.sqrt(np.mean(change**2, axis=0))
        change *= np.where(rms > cap[cols], cap[cols] / np.maximum(rms, 1e-12), 1.0)
        out[:, cols] = base[:, cols] + change
    return out
