"""How much of a denoiser to trust on one clip, from the clip alone: Stein's unbiased risk estimate (SURE).

For white noise of variance ``σ_c²`` on channel ``c`` of ``y = x + n`` and a denoiser ``f``, the squared error
``‖f(y) − x‖²`` is estimated without ``x`` by ``‖y − f(y)‖² − N σ_c² + 2 σ_c² div_c f(y)``, where ``div_c`` is the sum
of ``∂f_tc/∂y_tc`` over the channel's samples (Stein 1981). The divergence of a black box is estimated from
random ±1 probes ``b`` (Ramani, Blu & Unser 2008), ``div_c ≈ Σ_t b_tc (f(y + ε b) − f(y))_tc / ε``, averaged over
``PROBES`` of them.

``sure_weight`` uses it to mix two cleaners of one clip, ``g + w (f − g)``: the ``w`` in [0, 1] that minimises the
estimated error pooled over the channels is a closed form (the estimate is quadratic in ``w``). A learned filter
``f`` mixed so with a training-free smoother ``g`` leans on ``g`` where the network is out of its depth (motion
it never saw) and on ``f`` where it is not. The estimate is exact in expectation only for white noise of known
variance; here the variance is the self-check's estimate from the input (``selfcheck.noise_level``), and noise
that is not white (slow drifts, noise shared by channels, noise through IK that follows the pose) misleads it —
the weight stays between the two cleaners' outputs whatever it estimates. A cleaner that picks among discrete
settings (``gaussian-cv``'s widths) jumps where a probe changes its pick; SURE assumes no jumps, and the probes
count them as slope (a review measured 1.8× the spread of the estimate with the widths held fixed, the mean
nearly unchanged). Numpy only; angles in degrees, differences wrapped.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from mocapnet.kinematics import wrap_deg
from mocapnet.selfcheck import noise_level, observed_stencils

#: Probe step as a fraction of each channel's estimated noise σ (small enough to see the local slope, large
#: enough for float32 networks), and its floor in degrees.
PROBE_STEP = 0.1
PROBE_FLOOR_DEG = 1e-3
#: Seed of the first ±1 probe (the k-th uses ``PROBE_SEED + k``): the same input always gets the same weight.
PROBE_SEED = 0
#: Probes whose divergences are averaged: one probe's weight varies by ±0.14 from probe to probe (bandai2 fold-1
#: clips, angular-0.5); four gave the error of eight there (``benchmarks/EXPERIMENTS.md``, session 29).
PROBES = 4
#: Observed differences a channel needs for its noise estimate to count (fewer: left out of the weight).
MIN_DIFFERENCES = 8


def probe(shape: tuple[int, int], sigma: np.ndarray, seed: int = PROBE_SEED) -> np.ndarray:
    """A perturbation ``[T, C]`` (degrees): random ±1 per sample times the step ``max(PROBE_STEP·σ_c,
    PROBE_FLOOR_DEG)`` of its channel (``sigma [C]``, degrees); the same for the same ``seed``."""
    signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=shape)
    return signs * np.maximum(PROBE_STEP * np.asarray(sigma, dtype=np.float64), PROBE_FLOOR_DEG)


def divergence(out: np.ndarray, probed_out: np.ndarray, step: np.ndarray, counted: np.ndarray) -> np.ndarray:
    """Per-channel divergence ``[C]`` of a cleaner from its output ``out [T, C]`` on the input and
    ``probed_out [T, C]`` on the input plus a probe (``probe``): ``Σ_t Δout_tc / step_tc`` over the ``counted [T, C]``
    samples (``b·Δ/ε`` with ``b = ±1``). ``step [T, C]``: the probe, non-zero wherever ``counted``."""
    ratio = wrap_deg(probed_out - out) / np.where(counted, step, 1.0)
    return np.sum(np.where(counted, ratio, 0.0), axis=0)


def sure_weight(
    noisy: np.ndarray,
    f: np.ndarray,
    g: np.ndarray,
    div_f: np.ndarray,
    div_g: np.ndarray,
    variance: np.ndarray,
    counted: np.ndarray,
) -> float:
    """The weight ``w`` in [0, 1] of ``f`` in the mix ``g + w (f − g)`` that minimises SURE pooled over the
    ``counted [T, C]`` samples (bool; only their channels' ``div`` and ``variance`` enter). ``noisy``, ``f``, ``g``:
    ``[T, C]`` degrees (the input and the two cleaners' outputs); ``div_f``, ``div_g``: ``[C]`` (``divergence``);
    ``variance``: ``[C]`` noise variance (deg²). 0.5 when the two outputs agree on every counted sample (nothing to
    choose) or the estimate is not finite."""
    d = np.where(counted, wrap_deg(f - g), 0.0)
    r = np.where(counted, wrap_deg(noisy - g), 0.0)
    spread = float(np.sum(d * d))
    if not spread > 1e-12:
        return 0.5
    channels = counted.any(axis=0)
    penalty = float(np.sum(np.where(channels, variance * (div_f - div_g), 0.0)))
    w = (float(np.sum(r * d)) - penalty) / spread
    return float(np.clip(w, 0.0, 1.0)) if np.isfinite(w) else 0.5


def sure_mix(
    noisy: np.ndarray,
    observed: np.ndarray,
    out_f: np.ndarray,
    out_g: np.ndarray,
    f: Callable[[np.ndarray], np.ndarray],
    g: Callable[[np.ndarray], np.ndarray],
    order: int = 2,
) -> tuple[np.ndarray, float]:
    """``(out_f + (1 − w) (out_g − out_f), w)``: the outputs ``out_f``, ``out_g`` ``[T, C]`` (degrees) of two cleaners
    ``f``, ``g`` (``[T, C] -> [T, C]``) on ``noisy [T, C]`` mixed with the SURE weight ``w`` of ``f``
    (``sure_weight``). The noise variance per channel comes from the differences of ``order`` of ``noisy``'s
    ``observed [T, C]`` samples (``selfcheck.noise_level``); the divergences from ``PROBES`` probes of those samples
    (each cleaner runs once more per probe, on ``noisy`` plus the probe; missing samples are not probed). Samples
    where the input or an output is not finite are left out; a channel counts when it keeps at least
    ``MIN_DIFFERENCES`` differences of ``order`` on such samples; with none, ``w`` is 0.5 (the plain mean). The
    result is on ``out_f``'s branch of the circle."""
    ok = np.asarray(observed, dtype=bool) & np.isfinite(noisy) & np.isfinite(out_f) & np.isfinite(out_g)
    sigma = noise_level(noisy, order, ok)
    enough = observed_stencils(ok, order).sum(axis=0) >= MIN_DIFFERENCES
    counted = ok & enough
    if not counted.any():
        w = 0.5
    else:
        div_f = np.zeros(noisy.shape[1])
        div_g = np.zeros(noisy.shape[1])
        for k in range(PROBES):
            step = np.where(counted, probe(noisy.shape, sigma, PROBE_SEED + k), 0.0)
            div_f += divergence(out_f, f(noisy + step), step, counted) / PROBES
            div_g += divergence(out_g, g(noisy + step), step, counted) / PROBES
        w = sure_weight(noisy, out_f, out_g, div_f, div_g, sigma**2, counted)
    return out_f + (1.0 - w) * wrap_deg(out_g - out_f), w
