"""``mocapnet.sure``: Stein's unbiased risk estimate, the probe divergence and the per-clip mix of two cleaners."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

from mocapnet.sure import PROBE_FLOOR_DEG, PROBE_STEP, divergence, probe, sure_mix, sure_weight


def smooth(width: float):
    """A linear cleaner: a Gaussian of std ``width`` frames along time (nearest-value edges)."""
    return lambda y: gaussian_filter1d(y, width, axis=0, mode="nearest")


def identity(y: np.ndarray) -> np.ndarray:
    return y.copy()


def signal(n_frames: int = 600, n_channels: int = 6) -> np.ndarray:
    t = np.arange(n_frames)[:, None] / 30.0
    return 40.0 * np.sin(2 * np.pi * 0.3 * t * (1 + np.arange(n_channels)) / n_channels)


def test_probe_steps_follow_each_channel_noise_and_repeat_with_the_seed():
    sigma = np.array([2.0, 0.0, 10.0])
    step = probe((50, 3), sigma)
    expected = np.broadcast_to([PROBE_STEP * 2.0, PROBE_FLOOR_DEG, PROBE_STEP * 10], (50, 3))
    np.testing.assert_allclose(np.abs(step), expected)
    np.testing.assert_array_equal(step, probe((50, 3), sigma))
    assert not np.array_equal(step, probe((50, 3), sigma, seed=1))


def test_divergence_of_the_identity_counts_the_observed_samples():
    y = signal()
    observed = np.ones(y.shape, dtype=bool)
    observed[100:130, 2] = False
    step = np.where(observed, probe(y.shape, np.ones(y.shape[1])), 1.0)
    div = divergence(y, y + np.where(observed, step, 0.0), step, observed)
    np.testing.assert_allclose(div, observed.sum(axis=0))


def test_divergence_of_a_linear_smoother_is_close_to_its_trace():
    """For a Gaussian of std 2 frames the trace is about T x its centre tap (0.1995); probes averaged."""
    y = signal(2000, 4)
    f = smooth(2.0)
    observed = np.ones(y.shape, dtype=bool)
    divs = [divergence(f(y), f(y + s), s, observed) for s in (probe(y.shape, np.ones(4), k) for k in range(8))]
    np.testing.assert_allclose(np.mean(divs, axis=0) / len(y), 0.1995, atol=0.01)


def test_sure_weight_finds_the_better_cleaner_on_white_noise():
    """Heavy noise: the smoother wins (f = smoother, g = identity: w = 1); slow motion without noise: the
    identity (w near 0, the smoother only blurs)."""
    rng = np.random.default_rng(0)
    x = signal(3000, 4)
    observed = np.ones(x.shape, dtype=bool)
    f, g = smooth(2.0), identity
    y = x + 3.0 * rng.standard_normal(x.shape)
    mixed, w = sure_mix(y, observed, f(y), g(y), f, g)
    assert w == 1.0
    np.testing.assert_allclose(mixed, f(y), atol=1e-9)
    slow = 40.0 * np.sin(2 * np.pi * np.arange(3000)[:, None] / 3000.0 + np.arange(4))
    mixed, w = sure_mix(slow, observed, smooth(8.0)(slow), slow, smooth(8.0), identity)
    assert w < 0.02


def test_sure_weight_is_near_the_oracle_weight_between_two_smoothers():
    rng = np.random.default_rng(1)
    x = signal(3000, 6)
    y = x + 2.0 * rng.standard_normal(x.shape)
    f, g = smooth(1.0), smooth(6.0)
    observed = np.ones(x.shape, dtype=bool)
    _, w = sure_mix(y, observed, f(y), g(y), f, g)
    d, e = f(y) - g(y), x - g(y)
    oracle = float(np.clip(np.sum(e * d) / np.sum(d * d), 0.0, 1.0))
    assert w == pytest.approx(oracle, abs=0.1)
    error = [np.sqrt(np.mean((g(y) + v * d - x) ** 2)) for v in (w, oracle)]
    assert error[0] <= 1.02 * error[1]


def test_agreeing_cleaners_or_unobserved_differences_leave_the_mean():
    y = signal()
    observed = np.ones(y.shape, dtype=bool)
    assert sure_weight(y, y, y, np.zeros(6), np.zeros(6), np.ones(6), observed) == 0.5
    f = y.copy()
    f[10:20, 1] += 5.0  # they differ only where nothing was observed
    observed[10:20, 1] = False
    assert sure_weight(y, f, y, np.zeros(6), np.zeros(6), np.ones(6), observed) == 0.5


def test_sure_weight_is_clipped_to_the_two_cleaners():
    y = signal()
    observed = np.ones(y.shape, dtype=bool)
    far = y + 1.0
    assert sure_weight(y, far, y + 2.0, np.zeros(6), np.zeros(6), np.zeros(6), observed) == 1.0
    assert sure_weight(y, y + 2.0, far, np.zeros(6), np.zeros(6), np.zeros(6), observed) == 0.0


def test_the_mix_takes_differences_on_the_circle():
    """Outputs either side of ±180: the mix stays near them, not at 0."""
    y = np.full((200, 1), 179.0)
    out_f, out_g = np.full((200, 1), 179.5), np.full((200, 1), -179.5)
    mixed, w = sure_mix(y, np.ones(y.shape, dtype=bool), out_f, out_g, lambda v: out_f, lambda v: out_g)
    assert 0.0 <= w <= 1.0
    assert np.all(np.abs(((mixed + 180.0) % 360.0) - 180.0) >= 179.5 - 1e-9)


def test_a_channel_without_enough_observed_differences_or_with_nan_is_left_out():
    """A NaN channel or one observed on too few frames does not make the weight NaN; with no channel left the
    weight is the plain mean (0.5)."""
    rng = np.random.default_rng(2)
    x = signal(600, 4)
    y = x + 2.0 * rng.standard_normal(x.shape)
    f, g = smooth(2.0), identity
    observed = np.ones(y.shape, dtype=bool)
    _, w_all = sure_mix(y, observed, f(y), g(y), f, g)
    bad = y.copy()
    bad[:, 3] = np.nan
    observed[:, 3] = False
    observed[5:, 2] = False  # 5 frames: 3 second differences, fewer than MIN_DIFFERENCES
    _, w = sure_mix(bad, observed, f(y), g(y), f, g)
    assert np.isfinite(w) and w == pytest.approx(w_all, abs=0.05)
    short = y[:3]
    _, w = sure_mix(short, np.ones(short.shape, dtype=bool), f(short), g(short), f, g)
    assert w == 0.5


def test_noise_is_estimated_from_observed_differences_only():
    """Long linear bridges show no noise; counting them would shrink the estimate."""
    from mocapnet.fill import lerp_fill
    from mocapnet.selfcheck import noise_level

    rng = np.random.default_rng(3)
    y = 2.0 * rng.standard_normal((3000, 3))
    missing = np.zeros(y.shape, dtype=bool)
    for start in range(0, 3000, 120):
        missing[start : start + 60] = True  # half the samples, in 60-frame gaps
    bridged = lerp_fill(y, missing)
    assert noise_level(bridged).max() < 1.0
    np.testing.assert_allclose(noise_level(bridged, 2, ~missing), 2.0, rtol=0.1)
    np.testing.assert_array_equal(noise_level(y, 2, np.ones(y.shape, dtype=bool)), noise_level(y))


def test_noise_estimate_ignores_nan_at_unobserved_samples():
    from mocapnet.selfcheck import noise_level

    y = 2.0 * np.random.default_rng(4).standard_normal((2000, 2))
    observed = np.ones(y.shape, dtype=bool)
    observed[0, 0] = observed[900:950, 1] = False
    holed = np.where(observed, y, np.nan)
    np.testing.assert_allclose(noise_level(holed, 2, observed), noise_level(y, 2, observed))
    assert (noise_level(holed, 2, observed) > 1.5).all()
