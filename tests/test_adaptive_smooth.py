"""Gaussian smoothing with per-channel widths chosen by leave-one-out cross-validation
(mocapnet.adaptive_smooth, method gaussian-cv)."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from mocapnet.adaptive_smooth import SIGMA_GRID_FRAMES, TRUNCATE, centre_weight, cv_gaussian

FPS = 30.0


def _sines(freqs_hz: tuple[float, ...], n: int = 3000, amplitude: float = 30.0) -> np.ndarray:
    t = np.arange(n) / FPS
    return np.stack([amplitude * np.sin(2 * np.pi * f * t) for f in freqs_hz], axis=1)


def test_the_residual_scored_is_the_exact_leave_one_out_error():
    """(x_t - y_t) / (1 - w0) equals x_t minus the kernel-weighted mean of the other frames (away from the edges)."""
    rng = np.random.default_rng(1)
    x = rng.normal(size=400)
    for sigma in (0.5, 2.0):
        radius = int(TRUNCATE * sigma + 0.5)
        taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
        w0 = centre_weight(sigma)
        assert w0 == taps[radius] / taps.sum()
        y = gaussian_filter1d(x, sigma, mode="nearest", truncate=TRUNCATE)
        t = np.arange(radius, len(x) - radius)
        others = taps.copy()
        others[radius] = 0.0
        loo = np.array([x[i - radius : i + radius + 1] @ others for i in t]) / others.sum()
        np.testing.assert_allclose((x[t] - y[t]) / (1 - w0), x[t] - loo, atol=1e-10)


def test_slow_noisy_channels_get_wide_kernels_and_fast_clean_ones_are_kept():
    rng = np.random.default_rng(0)
    truth = _sines((0.3, 3.0, 0.3))
    x = truth + rng.normal(0, [2.0, 0.05, 0.05], truth.shape)  # slow + heavy noise, fast + light, slow + light
    y, sigma = cv_gaussian(x)
    assert sigma[0] >= 2.0 and sigma[1] == SIGMA_GRID_FRAMES[0]
    error, noise = np.sqrt(((y - truth) ** 2).mean(0)), np.sqrt(((x - truth) ** 2).mean(0))
    assert error[0] < 0.4 * noise[0]  # the heavy noise is mostly removed
    assert error[1] < 1.05 * noise[1]  # the fast motion is not smoothed away (a 0.5-frame kernel would: 1.0°)
    assert error[2] <= 1.01 * noise[2]


def test_channels_are_smoothed_across_the_wrap_and_returned_on_their_own_branch():
    rng = np.random.default_rng(2)
    truth = 170.0 + np.linspace(0, 40, 600)[:, None]  # crosses 180
    noisy = truth + rng.normal(0, 1.0, truth.shape)
    wrapped = (noisy + 180.0) % 360.0 - 180.0
    y, sigma = cv_gaussian(wrapped)
    direct, _ = cv_gaussian(noisy)
    np.testing.assert_allclose((y - direct + 180.0) % 360.0 - 180.0, 0.0, atol=1e-9)
    assert np.all(np.abs(y - wrapped) < 10)  # each sample stays on its own branch
    assert sigma[0] > 1.0


def test_short_inputs_come_back_unchanged():
    x = np.array([[1.0, 2.0], [3.0, 5.0]])
    y, sigma = cv_gaussian(x)
    np.testing.assert_array_equal(y, x)
    assert (sigma == 0).all()


def test_gaussian_cv_method_fills_gaps_and_changes_only_scored_channels():
    from mocapnet.evaluate.bvh_bench import synthetic
    from mocapnet.methods.registry import build_method

    base = synthetic(4, chain=True)
    rng = np.random.default_rng(3)
    frames = np.repeat(base.channels[:1], 300, axis=0) + _sines((0.5,) * base.channels.shape[1], n=300, amplitude=20)
    motion = type(base)(base.skeleton, frames + rng.normal(0, 1.0, frames.shape), base.fps, "jitter")
    mask = np.zeros_like(frames, dtype=bool)
    mask[100:110, base.skeleton.scored_mask] = True
    out = build_method("gaussian-cv").clean(motion, mask)
    scored = base.skeleton.scored_mask
    np.testing.assert_array_equal(out[:, ~scored], motion.channels[:, ~scored])
    assert np.isfinite(out).all()
    seen = ~mask[:, scored]
    error, noise = (out - frames)[:, scored][seen], (motion.channels - frames)[:, scored][seen]
    assert np.sqrt((error**2).mean()) < 0.6 * np.sqrt((noise**2).mean())
