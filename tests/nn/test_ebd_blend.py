"""EBD's blend with interpolation and its self-check (``mocapnet.nn.ebd.blend_gaps``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mocapnet.corrupt import corrupt_motion
from mocapnet.fill import lerp_fill, spline_fill
from mocapnet.nn.ebd import GAP_BLEND, blend_gaps, channel_speed

FPS = 30.0
PURE_NETWORK = dataclasses.replace(GAP_BLEND, spline_max_s=0.0, gate_s=(0.0, 0.0), taper_s=0.0, speed_factor=np.inf)


def smooth_channels(n_frames: int = 300, n_channels: int = 6, seed: int = 0) -> np.ndarray:
    """Slow sinusoids, degrees ``[T, C]``."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames)[:, None] / FPS
    return 40.0 * np.sin(2 * np.pi * rng.uniform(0.2, 0.8, n_channels) * t + rng.uniform(0, 6, n_channels))


def gap_mask(shape: tuple[int, int], gaps: list[tuple[int, int, list[int]]]) -> np.ndarray:
    mask = np.zeros(shape, dtype=bool)
    for a, b, cols in gaps:
        mask[a:b, cols] = True
    return mask


def test_observed_samples_never_change(sample):
    rng = np.random.default_rng(1)
    channels = sample.channels[:900]
    for corruption in ("gaps", "gaps-long", "noise+gaps", "segment-gap:left-arm:0.5"):
        noisy, mask = corrupt_motion(sample.with_channels(channels), corruption, rng)
        net = lerp_fill(noisy, mask) + rng.normal(0.0, 20.0, noisy.shape)
        for blend in (GAP_BLEND, PURE_NETWORK):
            out, _ = blend_gaps(noisy, mask, net, sample.fps, blend)
            np.testing.assert_array_equal(out[~mask], noisy[~mask])
            assert np.isfinite(out).all()


def test_pure_network_setting_returns_the_network_fill():
    truth = smooth_channels()
    mask = gap_mask(truth.shape, [(10, 11, [0]), (50, 90, [1, 2]), (200, 230, [3])])
    net = truth + 3.0
    out, fallbacks = blend_gaps(truth, mask, net, FPS, PURE_NETWORK)
    np.testing.assert_allclose(out[mask], net[mask])
    assert fallbacks == 0


def test_one_frame_gaps_keep_the_spline_and_the_weight_tapers_from_the_edges():
    truth = smooth_channels()
    mask = gap_mask(truth.shape, [(20, 21, [0, 1]), (100, 140, [2])])
    net = lerp_fill(truth, mask) + 5.0
    no_check = dataclasses.replace(GAP_BLEND, speed_factor=np.inf)
    out, _ = blend_gaps(truth, mask, net, FPS, no_check)
    np.testing.assert_allclose(out[20, :2], spline_fill(truth, mask)[20, :2])  # gate: 0 for a one-frame gap
    lerp = lerp_fill(truth, mask)[100:140, 2]
    taper = no_check.taper_s * FPS
    weight = (out[100:140, 2] - lerp) / 5.0  # a 40-frame gap starts from lerp with the whole gate
    np.testing.assert_allclose(weight[[0, 1, 20, -2, -1]], [1 / taper, 2 / taper, 1.0, 2 / taper, 1 / taper])


def test_self_check_falls_back_to_interpolation_on_an_unreachable_fill():
    truth = smooth_channels()
    truth[:, 0] = 10.0 * np.sin(2 * np.pi * 0.2 * np.arange(len(truth)) / FPS)  # at most 0.42° per frame
    mask = gap_mask(truth.shape, [(100, 130, [0]), (200, 230, [1])])
    net = lerp_fill(truth, mask)
    net[110:120, 0] += 90.0  # 10 frames from the edges: more than 2 × the channel's 99th-percentile speed × 11
    net[200:230, 1] = truth[200:230, 1]  # the truth is reachable: kept
    out, fallbacks = blend_gaps(truth, mask, net, FPS)
    assert fallbacks == 1
    lerp = lerp_fill(truth, mask)
    np.testing.assert_array_equal(out[100:130, 0], lerp[100:130, 0])
    assert np.abs(out[200:230, 1] - truth[200:230, 1]).max() < 0.5 * np.abs(lerp[200:230, 1] - truth[200:230, 1]).max()


def test_channel_speed_uses_observed_pairs_only():
    channels = np.repeat(np.arange(10.0)[:, None], 2, axis=1)
    channels[5, 0] = 1000.0
    mask = np.zeros(channels.shape, dtype=bool)
    mask[5, 0] = True
    mask[:, 1] = True
    speed = channel_speed(channels, mask, 100.0)
    assert speed[0] == pytest.approx(1.0) and speed[1] == np.inf


@pytest.mark.parametrize("spline_max_s", [0.0, 0.5])
def test_an_untrained_ebd_returns_the_interpolation_it_corrects(tiny, sample, spline_max_s):
    from mocapnet.fill import gap_fill
    from mocapnet.nn.infer import clean_channels, scored_index

    model = tiny("ebd", sample, spline_max_s=spline_max_s).eval()  # the decoder's last layer starts at zero
    rng = np.random.default_rng(3)
    noisy, mask = corrupt_motion(sample.with_channels(sample.channels[:600]), "gaps", rng)
    out = clean_channels(model, noisy, mask, sample.skeleton, sample.fps, gap_blend=None)
    idx = scored_index(sample.skeleton)
    expected = gap_fill(noisy, mask, spline_max_s * sample.fps)[:, idx]
    np.testing.assert_allclose(out[:, idx], expected, atol=1e-3)  # float32 network arithmetic
    if spline_max_s:
        assert not np.allclose(expected[mask[:, idx]], lerp_fill(noisy, mask)[:, idx][mask[:, idx]])


def test_the_blend_stored_with_a_network_is_the_one_it_uses(tiny, sample):
    from mocapnet.nn.ebd import as_blend
    from mocapnet.nn.infer import clean_channels

    assert tiny("ebd", sample).blend() == GAP_BLEND
    stored = {**dataclasses.asdict(PURE_NETWORK), "gate_s": [0.0, 0.0]}
    model = tiny("ebd", sample, gap_blend=stored).eval()
    assert model.blend() == PURE_NETWORK == as_blend(stored)
    rng = np.random.default_rng(4)
    noisy, mask = corrupt_motion(sample.with_channels(sample.channels[:600]), "gaps", rng)
    args = (noisy, mask, sample.skeleton, sample.fps)
    np.testing.assert_array_equal(clean_channels(model, *args), clean_channels(model, *args, gap_blend=PURE_NETWORK))
    with pytest.raises(ValueError, match="gap_blend"):
        clean_channels(model, *args, gap_blend="stored")
    with pytest.raises(ValueError, match="gap_blend"):
        tiny("ebd", sample, gap_blend={"taper": 1.0})
    with pytest.raises(ValueError, match="gate_s"):
        tiny("ebd", sample, gap_blend={"gate_s": [0.1]})
