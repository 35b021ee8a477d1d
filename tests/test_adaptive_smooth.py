"""Gaussian smoothing with per-channel widths chosen by leave-one-out cross-validation
(mocapnet.adaptive_smooth, method gaussian-cv)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

from mocapnet.adaptive_smooth import COLUMN_BLOCK, KEEP, SIGMA_GRID_FRAMES, TRUNCATE, centre_weight, cv_gaussian

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
    y, sigma = cv_gaussian(wrapped, period=360.0)
    direct, _ = cv_gaussian(noisy)
    np.testing.assert_allclose((y - direct + 180.0) % 360.0 - 180.0, 0.0, atol=1e-9)
    assert np.all(np.abs(y - wrapped) < 10)  # each sample stays on its own branch
    assert sigma[0] > 1.0


def test_choice_equals_brute_force_leave_one_out_with_the_explicit_smoother():
    """For each width, S = the filter applied to the identity (nearest-value edges); the exact leave-one-out error
    (x - S x) / (1 - diag S) over all frames picks the same width per channel, and the output is S x."""
    rng = np.random.default_rng(4)
    n = 60
    x = np.cumsum(rng.normal(size=(n, 5)), axis=0) + rng.normal(0, [0.0, 0.3, 1.0, 3.0, 0.1], (n, 5))
    y, chosen = cv_gaussian(x)
    fits = [s for s in SIGMA_GRID_FRAMES if 2 * int(TRUNCATE * s + 0.5) + 1 <= n]
    smoothers = {s: gaussian_filter1d(np.eye(n), s, axis=0, mode="nearest", truncate=TRUNCATE) for s in fits}
    scores = np.array([(((x - S @ x) / (1 - np.diag(S))[:, None]) ** 2).mean(0) for S in smoothers.values()])
    expected = np.array(fits)[scores.argmin(axis=0)]
    np.testing.assert_array_equal(chosen, expected)
    assert (chosen == KEEP).any() and (chosen > KEEP).any()
    for c, sigma in enumerate(chosen):
        expected_out = x[:, c] if sigma == KEEP else smoothers[sigma] @ x[:, c]  # a kept channel comes back as it is
        np.testing.assert_allclose(y[:, c], expected_out, atol=1e-9)


def test_column_blocks_give_what_each_column_gets_alone():
    rng = np.random.default_rng(5)
    x = np.cumsum(rng.normal(size=(200, 2 * COLUMN_BLOCK + 5)), axis=0) + rng.normal(
        0, 2.0, (200, 2 * COLUMN_BLOCK + 5)
    )
    y, chosen = cv_gaussian(x)
    for c in range(x.shape[1]):
        alone, sigma = cv_gaussian(x[:, c : c + 1])
        np.testing.assert_array_equal(y[:, c : c + 1], alone)
        assert chosen[c] == sigma[0]
    assert len(set(chosen)) > 1


def test_short_clips_keep_their_samples():
    """A width is a candidate only where its kernel fits in the clip: 1-4 frames keep the input exactly, whatever
    their content."""
    rng = np.random.default_rng(6)
    for n in (1, 2, 3, 4):
        x = rng.normal(0, 30.0, (n, 4))
        y, sigma = cv_gaussian(x)
        assert (sigma <= 0.25).all()
        np.testing.assert_array_equal(y, x)


def test_bad_arguments_and_unusable_channels():
    x = np.cumsum(np.random.default_rng(7).normal(size=(50, 3)), axis=0)
    for grid in ((0.0,), (-1.0,), (0.1,), (float("nan"),)):
        with pytest.raises(ValueError, match="width"):
            cv_gaussian(x, grid)
    with pytest.raises(ValueError, match=r"\[T, C\]"):
        cv_gaussian(x[:, 0])
    with pytest.raises(ValueError, match="observed"):
        cv_gaussian(x, observed=np.ones((50, 2), dtype=bool))
    x[10, 1] = np.nan
    observed = np.ones_like(x, dtype=bool)
    observed[:, 2] = False  # nothing to score on
    y, sigma = cv_gaussian(x, observed=observed)
    np.testing.assert_array_equal(y[:, 1:], x[:, 1:])
    assert sigma[1] == sigma[2] == 0 and sigma[0] > 0


def test_gaps_across_the_wrap_are_bridged_the_short_way():
    from mocapnet.evaluate.bvh_bench import synthetic
    from mocapnet.fill import unwrap_observed
    from mocapnet.methods.registry import build_method

    base = synthetic(4, chain=True)
    truth = np.repeat(base.channels[:1], 300, axis=0)
    scored = np.flatnonzero(base.skeleton.scored_mask)
    truth[:, scored[0]] = 150.0 + np.linspace(0, 60, 300)  # passes 180 at frame 150
    wrapped = (truth + 180.0) % 360.0 - 180.0
    mask = np.zeros_like(truth, dtype=bool)
    mask[140:160, scored[0]] = True
    stored = np.where(mask, np.nan, wrapped)  # as a file wraps it; ``mocapnet clean`` unwraps it with the mask
    given = unwrap_observed(stored, mask, base.skeleton.rotation_mask)
    out = build_method("gaussian-cv").clean(type(base)(base.skeleton, given, base.fps, "turn"), mask)
    error = (out[:, scored[0]] - truth[:, scored[0]] + 180.0) % 360.0 - 180.0
    assert np.abs(error).max() < 0.01  # a straight turn, bridged through 180 (not through 0: 170 degrees off)


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


def test_the_width_grid_is_capped_in_seconds_below_30_fps():
    """``grid_for_rate``: the whole grid at 30 fps and faster (where it was chosen), at most ``MAX_SIGMA_S`` of
    motion below (at 1 fps a frame is a second), ``KEEP`` always."""
    from mocapnet.adaptive_smooth import KEEP, MAX_SIGMA_S, SIGMA_GRID_FRAMES, grid_for_rate

    assert grid_for_rate(30.0) == grid_for_rate(120.0) == SIGMA_GRID_FRAMES
    assert grid_for_rate(1.0) == (KEEP, 0.5)
    assert grid_for_rate(0.1) == (KEEP,)
    assert max(grid_for_rate(10.0)) <= MAX_SIGMA_S * 10.0 < min(set(SIGMA_GRID_FRAMES) - set(grid_for_rate(10.0)))
