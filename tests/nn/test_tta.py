"""Test-time augmentation and blending of the learned cleaners (``mocapnet.methods.neural``: options ``tta``
and ``blend``), with tiny checkpoints on the shipped sample clip."""

from __future__ import annotations

import numpy as np
import pytest

from mocapnet.corrupt import corrupt_motion
from mocapnet.kinematics import wrap_deg
from mocapnet.methods.neural import augmented_pass, tta_mean, tta_passes, warp_positions
from mocapnet.methods.registry import build_method
from mocapnet.motion import Motion
from mocapnet.nn.features import root_angular_velocity, scored_index
from mocapnet.nn.infer import clean_channels, load_model

from .test_neural_methods import save


@pytest.fixture
def clip(sample: Motion) -> Motion:
    return sample.with_channels(sample.channels[:200])


@pytest.fixture
def ebf_path(clip, tiny, tmp_path) -> str:
    return save(tiny("ebf-free", clip), tmp_path / "ebf.ckpt")


def noisy_copy(clip: Motion, corruption: str = "angular-0.5", seed: int = 0) -> tuple[Motion, np.ndarray]:
    noisy, mask = corrupt_motion(clip, corruption, np.random.default_rng(seed))
    return clip.with_channels(noisy), mask


def circular_close(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    """``a`` and ``b`` equal up to whole turns (degrees)."""
    np.testing.assert_allclose(wrap_deg(a - b), 0.0, atol=atol)


def test_tta_option_parses_into_passes():
    assert tta_passes(None) == tta_passes("none") == ((False, 1.0),)
    assert tta_passes("reverse") == ((False, 1.0), (True, 1.0))
    assert tta_passes("warp") == ((False, 1.0), (False, 0.9), (False, 1.1))
    both = tta_passes("reverse+warp")
    assert len(both) == 6 and both[0] == (False, 1.0) and set(both) == set(tta_passes("warp+reverse"))
    for bad in ("flip", "reverse+reverse", "reverse,warp", ""):
        with pytest.raises(ValueError, match="tta must be"):
            tta_passes(bad)


def test_bad_tta_and_blend_options_are_refused(clip, tiny, tmp_path, ebf_path):
    with pytest.raises(ValueError, match="ebf: tta must be"):
        build_method(f"ebf={ebf_path}:tta=flip")
    with pytest.raises(KeyError, match="unknown method 'nope'"):
        build_method(f"ebf={ebf_path}:blend=nope")
    ebd = save(tiny("ebd", clip), tmp_path / "ebd.ckpt")
    with pytest.raises(ValueError, match="blend is for the denoisers"):
        build_method(f"ebd={ebd}:blend=gaussian-58ms")


def test_reversed_clip_has_the_negated_root_angular_velocity(clip):
    """The reversed pass's root input: turning from frame t to t-1 is the turn from t-1 to t undone, so the
    reversed clip's angular velocity at s is minus the original's at T-s (frame 0 copies frame 1)."""
    forward = root_angular_velocity(clip.skeleton, clip.channels, clip.fps)
    backward = root_angular_velocity(clip.skeleton, clip.channels[::-1], clip.fps)
    assert np.abs(forward).max() > 0.1
    np.testing.assert_allclose(backward[1:], -forward[::-1][:-1], atol=1e-9)


def test_reverse_tta_is_the_mean_of_both_directions(clip, ebf_path):
    noisy, mask = noisy_copy(clip, "noise+gaps", seed=1)
    out = build_method(f"ebf={ebf_path}:tta=reverse").clean(noisy, mask)
    model, sk = load_model(ebf_path), clip.skeleton
    plain = clean_channels(model, noisy.channels, mask, sk, clip.fps)
    backward = clean_channels(model, noisy.channels[::-1], mask[::-1], sk, clip.fps)[::-1]
    idx = scored_index(sk)
    assert out.shape == clip.channels.shape and np.isfinite(out).all()
    circular_close(out[:, idx], tta_mean([plain[:, idx], backward[:, idx]]), atol=1e-9)
    assert np.abs(out[:, idx] - plain[:, idx]).max() > 1e-3  # the reversed pass is not the plain one
    unscored = ~sk.scored_mask
    np.testing.assert_array_equal(out[:, unscored], plain[:, unscored])
    observed = ~mask[:, unscored]
    np.testing.assert_array_equal(out[:, unscored][observed], noisy.channels[:, unscored][observed])


@pytest.mark.parametrize("tta", ["reverse", "reverse+warp"])
def test_reverse_tta_is_time_symmetric(clip, ebf_path, tta):
    """With the reversed pass, cleaning a reversed clip gives the cleaned clip reversed, and a palindromic clip
    (one that reads the same backwards) comes out palindromic."""
    clean = build_method(f"ebf={ebf_path}:tta={tta}").clean
    noisy, mask = noisy_copy(clip)
    out = clean(noisy, mask)
    out_reversed = clean(noisy.with_channels(noisy.channels[::-1]), mask[::-1])
    circular_close(out_reversed[::-1], out, atol=1e-6)
    palindrome = np.concatenate([noisy.channels, noisy.channels[-2::-1]])
    out = clean(noisy.with_channels(palindrome), np.zeros(palindrome.shape, dtype=bool))
    circular_close(out[::-1], out, atol=1e-6)
    plain = build_method(f"ebf={ebf_path}").clean  # alone, the network is not time-symmetric
    flipped = plain(noisy.with_channels(noisy.channels[::-1]), mask[::-1])[::-1]
    assert np.abs(flipped - plain(noisy, mask)).max() > 1e-3


def test_warp_pass_round_trips_across_the_wrap(clip):
    """A warped pass of a cleaner that changes nothing gives its input back: ends kept exactly, channels
    crossing ±180° unwrapped before interpolation (a ramp is interpolated exactly)."""
    for n, rate in ((200, 0.9), (200, 1.1), (7, 0.9), (3, 1.1)):
        positions = warp_positions(n, rate)
        assert positions[0] == 0.0 and positions[-1] == n - 1
        assert len(positions) == max(2, round((n - 1) / rate) + 1)
    t = np.arange(120, dtype=np.float64)[:, None]
    ramps = np.concatenate([170.0 + 0.5 * t, -3.0 * t, 10.0 + 0.0 * t], axis=1)
    ramps = wrap_deg(ramps)  # the first crosses +180 → -180 at frame 20
    mask = np.zeros(ramps.shape, dtype=bool)
    idx = np.arange(3)
    seen = []

    def identity(channels: np.ndarray, gaps: np.ndarray) -> np.ndarray:
        seen.append(len(channels))
        return channels.copy()

    for reverse in (False, True):
        for rate in (0.9, 1.1):
            circular_close(augmented_pass(identity, ramps, mask, idx, reverse, rate), ramps, atol=1e-9)
    assert seen == [round(119 / 0.9) + 1, round(119 / 1.1) + 1] * 2


def test_warp_tta_keeps_shape_and_unscored_channels(clip, ebf_path):
    noisy, mask = noisy_copy(clip, "noise+gaps", seed=2)
    out = build_method(f"ebf={ebf_path}:tta=warp").clean(noisy, mask)
    plain = build_method(f"ebf={ebf_path}").clean(noisy, mask)
    assert out.shape == clip.channels.shape and np.isfinite(out).all()
    unscored = ~clip.skeleton.scored_mask
    np.testing.assert_array_equal(out[:, unscored], plain[:, unscored])
    idx = scored_index(clip.skeleton)
    change = np.abs(wrap_deg(out[:, idx] - plain[:, idx]))
    assert 1e-4 < change.max() < 90.0


def test_blend_is_the_circular_mean_with_the_partner(clip, ebf_path):
    noisy, mask = noisy_copy(clip)
    out = build_method(f"ebf={ebf_path}:blend=gaussian-58ms").clean(noisy, mask)
    net = build_method(f"ebf={ebf_path}").clean(noisy, mask)
    smooth = build_method("gaussian-58ms").clean(noisy, mask)
    idx = scored_index(clip.skeleton)
    circular_close(out[:, idx], tta_mean([net[:, idx], smooth[:, idx]]), atol=1e-9)
    unscored = ~clip.skeleton.scored_mask
    np.testing.assert_array_equal(out[:, unscored], net[:, unscored])


def test_anchor_option_caps_each_channel_near_the_anchor_method(clip, ebf_path):
    """``anchor=gaussian-cv``: the network's own self-check is replaced by one that caps each scored channel's RMS
    distance from gaussian-cv's output at ``limit`` x the input's noise; unscored channels stay the input's."""
    from mocapnet.fill import lerp_fill
    from mocapnet.selfcheck import noise_level

    noisy, mask = noisy_copy(clip)
    idx = scored_index(clip.skeleton)
    free = build_method(f"ebf={ebf_path}:limit=0").clean(noisy, mask)
    anchored = build_method(f"ebf={ebf_path}:anchor=gaussian-cv,limit=0.2").clean(noisy, mask)
    smooth = build_method("gaussian-cv").clean(noisy, mask)
    distance = np.sqrt((wrap_deg(anchored - smooth)[:, idx] ** 2).mean(axis=0))
    cap = 0.2 * noise_level(lerp_fill(noisy.channels, mask)[:, idx])
    assert (distance <= cap + 1e-9).all()
    free_distance = np.sqrt((wrap_deg(free - smooth)[:, idx] ** 2).mean(axis=0))
    assert (free_distance > cap + 1e-6).any()  # the cap did bind somewhere
    unscored = np.setdiff1d(np.arange(clip.channels.shape[1]), idx)
    np.testing.assert_array_equal(anchored[:, unscored], free[:, unscored])


def test_noise_order_option_caps_each_change_at_the_noise_seen_by_that_order(clip, ebf_path):
    """``noise_order=4``: the network's own self-check is replaced by one whose cap is ``limit`` x the noise
    estimated from 4th differences; ``noise_order=2`` is the network's own check; bad orders are refused."""
    from mocapnet.fill import lerp_fill
    from mocapnet.selfcheck import noise_level

    noisy, mask = noisy_copy(clip)
    idx = scored_index(clip.skeleton)
    seen = lerp_fill(noisy.channels, mask)[:, idx]
    free = build_method(f"ebf={ebf_path}:limit=0").clean(noisy, mask)
    fourth = build_method(f"ebf={ebf_path}:noise_order=4,limit=0.2").clean(noisy, mask)
    change = np.sqrt((wrap_deg(fourth - lerp_fill(noisy.channels, mask))[:, idx] ** 2).mean(axis=0))
    cap = 0.2 * noise_level(seen, 4)
    assert (change <= cap + 1e-9).all()
    assert (np.sqrt((wrap_deg(free[:, idx] - seen) ** 2).mean(axis=0)) > cap + 1e-6).any()  # the cap bound
    second = build_method(f"ebf={ebf_path}:noise_order=2,limit=0.2").clean(noisy, mask)
    np.testing.assert_array_equal(second, build_method(f"ebf={ebf_path}:limit=0.2").clean(noisy, mask))
    for bad in ("noise_order=5", "noise_order=true"):
        with pytest.raises(ValueError, match="noise_order"):
            build_method(f"ebf={ebf_path}:{bad}")


def test_blend_weight_option_weighs_the_network_against_the_partner(clip, ebf_path):
    """``blend_weight=1`` is the network alone, ``0`` the partner alone, ``0.5`` the circular mean; unscored
    channels stay the network's."""
    noisy, mask = noisy_copy(clip)
    idx = scored_index(clip.skeleton)
    net = build_method(f"ebf={ebf_path}").clean(noisy, mask)
    smooth = build_method("gaussian-cv").clean(noisy, mask)

    def weighted(weight: object) -> np.ndarray:
        return build_method(f"ebf={ebf_path}:blend=gaussian-cv,blend_weight={weight}").clean(noisy, mask)

    np.testing.assert_array_equal(weighted(1), net)
    circular_close(weighted(0)[:, idx], smooth[:, idx], atol=1e-9)
    circular_close(weighted(0.5)[:, idx], tta_mean([net[:, idx], smooth[:, idx]]), atol=1e-9)
    unscored = ~clip.skeleton.scored_mask
    np.testing.assert_array_equal(weighted(0.3)[:, unscored], net[:, unscored])


def test_sure_blend_weight_is_the_one_sure_chooses(sample):
    """The shipped cmu120 network on its own sample clip with angular noise: ``blend_weight=sure`` gives exactly
    ``sure_blend``'s output, whose weight lies strictly between the two cleaners and repeats for the same input."""
    from mocapnet.methods.neural import sure_blend

    clip = sample.with_channels(sample.channels[:600])
    noisy, mask = noisy_copy(clip)
    idx = scored_index(clip.skeleton)
    network = build_method("ebf").clean
    partner = build_method("gaussian-cv").clean
    out, w = sure_blend(noisy, mask, idx, lambda m: network(m, mask), lambda m: partner(m, mask))
    assert 0.05 < w < 0.95
    net, smooth = network(noisy, mask), partner(noisy, mask)
    circular_close(out[:, idx], net[:, idx] + (1 - w) * wrap_deg(smooth[:, idx] - net[:, idx]), atol=1e-9)
    for _ in range(2):  # the same again: the probes are seeded
        via_option = build_method("ebf:blend=gaussian-cv,blend_weight=sure").clean(noisy, mask)
        np.testing.assert_array_equal(via_option, out)


def test_sure_blend_ignores_what_missing_samples_hold(clip, ebf_path):
    """Noise and gaps: the output is the same whether the missing samples hold NaN or other values, and finite."""
    noisy, mask = noisy_copy(clip, "noise+gaps")
    assert mask.any()
    method = build_method(f"ebf={ebf_path}:blend=gaussian-cv,blend_weight=sure")
    as_nan = noisy.with_channels(np.where(mask, np.nan, noisy.channels))
    as_junk = noisy.with_channels(np.where(mask, 123.0, noisy.channels))
    out = method.clean(as_nan, mask)
    np.testing.assert_array_equal(out, method.clean(as_junk, mask))
    assert out.shape == clip.channels.shape and np.isfinite(out[:, scored_index(clip.skeleton)]).all()


def test_bad_blend_weights_are_refused_by_name(ebf_path):
    with pytest.raises(ValueError, match="ebf: blend_weight weighs a blend"):
        build_method(f"ebf={ebf_path}:blend_weight=sure")
    with pytest.raises(ValueError, match="ebd: blend_weight is for the denoisers"):
        build_method("ebd:blend_weight=sure")
    for bad in ("1.5", "-0.1", "best", "true"):
        with pytest.raises(ValueError, match="ebf: blend_weight must be sure or a number"):
            build_method(f"ebf={ebf_path}:blend=gaussian-cv,blend_weight={bad}")
