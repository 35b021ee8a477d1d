"""EBD's blend with interpolation and its self-check (``mocapnet.nn.ebd.blend_gaps``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from mocapnet.corrupt import corrupt_motion
from mocapnet.fill import lerp_fill, spline_fill
from mocapnet.nn.ebd import (
    GAP_BLEND,
    GAP_LOSS_FLOOR_DEG,
    as_blend,
    blend_gaps,
    channel_speed,
    gap_list,
    gap_means,
    rehearse,
    stand_in_gaps,
)
from mocapnet.nn.train import initial_weights

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


def test_stand_in_gaps_copy_each_gap_onto_observed_frames_apart_from_every_gap():
    mask = gap_mask((300, 6), [(0, 10, [0]), (50, 60, [0]), (100, 130, [1, 2]), (120, 124, [3]), (290, 300, [4])])
    fake, places = stand_in_gaps(mask, 3)
    gaps = gap_list(mask)
    assert len(places) == len(gaps)
    assert not (fake & mask).any()
    for (cols, a, b), mine in zip(gaps, places):
        if a == 0 or b == len(mask):
            assert mine == []  # a gap at the clip's ends has a one-sided interpolation: nothing like it to rehearse
            continue
        assert len(mine) == 3
        for s, e in mine:
            assert e - s == b - a and fake[s:e][:, cols].all()
            assert not mask[s - 1 : e + 1][:, cols].any()  # observed, with an observed frame on each side
    # stand-ins of one gap do not touch each other (each keeps its own observed neighbours)
    starts = sorted(s for s, _ in places[1])
    assert all(b - a >= 12 for a, b in zip(starts, starts[1:]))
    again, _ = stand_in_gaps(mask, 3)
    np.testing.assert_array_equal(fake, again)  # the same clip gets the same stand-ins
    assert not stand_in_gaps(gap_mask((40, 2), [(10, 30, [0])]), 3)[0].any()  # no room: none


def test_near_stand_ins_are_the_nearest_places_a_gaps_length_apart():
    """A gap of at most ``near_frames`` frames gets as stand-ins the nearest free places on either side, nearest
    first, with at least the gap's length of observed frames between each and the gap and between two of them;
    longer gaps get random ones as before."""
    mask = gap_mask((600, 2), [(300, 315, [0, 1])])
    fake, places = stand_in_gaps(mask, 4, near_frames=15)
    # 15 observed frames on each side of the gap, then 16 more between stand-ins (ties: the earlier place first)
    assert places == [[(270, 285), (330, 345), (239, 254), (361, 376)]]
    assert fake.sum() == 4 * 15 * 2 and not (fake & mask).any()
    assert stand_in_gaps(mask, 4, near_frames=np.inf, seed=7)[1] == places  # placed, not drawn
    # a crowded side: a gap near the clip's start leaves room on its far side only
    crowded = gap_mask((200, 1), [(20, 30, [0])])
    (mine,) = stand_in_gaps(crowded, 3, near_frames=10)[1]
    assert mine == [(40, 50), (61, 71), (82, 92)]
    assert stand_in_gaps(crowded, 3, near_frames=9)[1] == stand_in_gaps(crowded, 3)[1]  # 10 frames > 9: random
    assert as_blend({"rehearse_near_s": 0.5}).rehearse_near_s == 0.5
    with pytest.raises(ValueError, match="rehearse_near_s >= 0"):
        as_blend({"rehearse_near_s": -1})
    with pytest.raises(ValueError, match="rehearse_near_s >= 0"):
        as_blend({"rehearse_near_s": float("nan")})


def test_rehearse_seed_places_the_stand_ins_with_that_seed():
    truth = smooth_channels(600)
    mask = gap_mask(truth.shape, [(300, 315, [0, 1])])
    seen = []

    def network(m):
        seen.append(m.copy())
        return truth

    for seed in (0, 1):
        rehearse(np.where(mask, np.nan, truth), mask, FPS, dataclasses.replace(GAP_BLEND, rehearse_seed=seed), network)
        np.testing.assert_array_equal(seen[-1], mask | stand_in_gaps(mask, GAP_BLEND.rehearsals, seed=seed)[0])
    assert not (seen[0] == seen[1]).all()
    assert as_blend({"rehearse_seed": 3}).rehearse_seed == 3
    with pytest.raises(ValueError, match="rehearse_seed"):
        as_blend({"rehearse_seed": -1})
    with pytest.raises(ValueError, match="rehearse_seed must be a whole number"):
        as_blend({"rehearse_seed": 0.5})


def test_rehearsal_keeps_the_network_where_it_wins_on_the_stand_ins_and_interpolates_where_it_loses():
    truth = smooth_channels(600)
    mask = gap_mask(truth.shape, [(100, 120, [0]), (300, 330, [1, 2]), (590, 600, [3])])
    channels = np.where(mask, np.nan, truth)
    blend = dataclasses.replace(GAP_BLEND, rehearsals=2, rehearse_margin=1.0, rehearse_mix=False, speed_factor=np.inf)
    good = rehearse(channels, mask, FPS, blend, lambda m: truth)
    np.testing.assert_array_equal(good, [True, True, True])

    def wrong_on_channel_0(m):  # off by 20° on channel 0, right elsewhere
        return truth + np.where(np.arange(6) == 0, 20.0, 0.0)

    verdict = rehearse(channels, mask, FPS, blend, wrong_on_channel_0)
    np.testing.assert_array_equal(verdict, [False, True, True])  # the end gap has no stand-in: kept
    off = rehearse(channels, mask, FPS, dataclasses.replace(blend, rehearsals=0), wrong_on_channel_0)
    assert off.all()
    # the margin: interpolation must beat the blend by that factor (here it cannot beat it by 1e6)
    assert rehearse(channels, mask, FPS, dataclasses.replace(blend, rehearse_margin=1e-6), wrong_on_channel_0).all()
    # gaps shorter than rehearse_min_s are not rehearsed: the 20-frame gap keeps the blend at 1 s
    short_kept = rehearse(channels, mask, FPS, dataclasses.replace(blend, rehearse_min_s=1.0), wrong_on_channel_0)
    np.testing.assert_array_equal(short_kept, [True, True, True])
    assert not stand_in_gaps(mask, 2, min_frames=31)[0].any() and stand_in_gaps(mask, 2, min_frames=30)[0].any()
    out, fallbacks = blend_gaps(channels, mask, wrong_on_channel_0(mask), FPS, blend, trusted=verdict)
    assert fallbacks == 1
    np.testing.assert_allclose(out[100:120, 0], lerp_fill(channels, mask)[100:120, 0])  # > 0.5 s: lerp
    lerp_error = np.abs(lerp_fill(channels, mask) - truth)[300:330, 1:3]
    assert (np.abs(out - truth)[300:330, 1:3] < lerp_error + 1e-9).all()  # kept: the blend towards the truth


def test_rehearse_mix_keeps_the_share_of_the_correction_that_fits_the_stand_ins():
    """A network that overshoots the truth by 2x everywhere: the least-squares share on the stand-ins is 1/2,
    and that share of the real gaps' correction is the truth itself; a gap without stand-ins keeps it all."""
    from mocapnet.fill import gap_fill

    truth = smooth_channels(600)
    mask = gap_mask(truth.shape, [(100, 120, [0]), (300, 330, [1, 2]), (590, 600, [3])])
    channels = np.where(mask, np.nan, truth)
    full = dataclasses.replace(GAP_BLEND, gate_s=(0.0, 1e-6), taper_s=1e-6, speed_factor=np.inf)
    blend = dataclasses.replace(full, rehearsals=2, rehearse_mix=True)

    def overshoot(m):
        base = gap_fill(np.where(m, np.nan, truth), m, blend.spline_max_s * FPS)
        return base + 2.0 * (truth - base)

    share = rehearse(channels, mask, FPS, blend, overshoot)
    np.testing.assert_allclose(share, [0.5, 0.5, 1.0])
    out, fallbacks = blend_gaps(channels, mask, overshoot(mask), FPS, blend, trusted=share)
    np.testing.assert_allclose(out[:590], truth[:590], atol=1e-9)
    assert fallbacks == 0
    # a network that moves away from the truth keeps none of its correction; an exact one keeps all
    away = rehearse(channels, mask, FPS, blend, lambda m: 2 * gap_fill(np.where(m, np.nan, truth), m, 15) - truth)
    np.testing.assert_allclose(away, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(rehearse(channels, mask, FPS, blend, lambda m: truth), [1.0, 1.0, 1.0])
    # gaps shorter than the gate's end (0.2 s = 6 frames; the network has part of the weight) keep the verdict
    gated = dataclasses.replace(GAP_BLEND, rehearsals=2, rehearse_mix=True, speed_factor=np.inf)
    short = gap_mask(truth.shape, [(100, 104, [0]), (300, 330, [1, 2])])
    shares = rehearse(np.where(short, np.nan, truth), short, FPS, gated, overshoot)
    assert shares[0] in (0.0, 1.0) and 0.0 < shares[1] < 1.0


def test_rehearse_passes_hide_each_stand_in_once_in_lighter_passes():
    """``rehearse_passes=P``: P network passes, each hiding the real gaps and every gap's stand-ins i with
    i mod P = pass (the same stand-ins as one pass, split); together they hide each stand-in exactly once; the
    shares of a network that overshoots by 2x stay 1/2; 1 pass is the single-pass rehearsal; more passes than
    the most stand-ins any gap got run one pass per stand-in."""
    from mocapnet.fill import gap_fill

    truth = smooth_channels(900)
    mask = gap_mask(truth.shape, [(100, 120, [0]), (300, 330, [1, 2]), (890, 900, [3])])
    channels = np.where(mask, np.nan, truth)
    blend = dataclasses.replace(
        GAP_BLEND, gate_s=(0.0, 1e-6), taper_s=1e-6, speed_factor=np.inf, rehearsals=4, rehearse_mix=True
    )
    seen: list[np.ndarray] = []

    def overshoot(m):
        seen.append(m.copy())
        base = gap_fill(np.where(m, np.nan, truth), m, blend.spline_max_s * FPS)
        return base + 2.0 * (truth - base)

    fake, places = stand_in_gaps(mask, 4)
    one = rehearse(channels, mask, FPS, blend, overshoot)
    assert len(seen) == 1 and (seen[0] == (mask | fake)).all()
    seen.clear()
    two = rehearse(channels, mask, FPS, dataclasses.replace(blend, rehearse_passes=2), overshoot)
    assert len(seen) == 2
    np.testing.assert_allclose(two, one)
    np.testing.assert_allclose(two, [0.5, 0.5, 1.0])
    hidden = [m & ~mask for m in seen]
    assert not (hidden[0] & hidden[1]).any() and ((hidden[0] | hidden[1]) == fake).all()
    for k in (0, 1):  # pass k hides stand-ins k and k + 2 of every gap
        expected = np.zeros_like(mask)
        for (cols, _, _), mine in zip(gap_list(mask), places):
            for s, e in mine[k::2]:
                expected[s:e, cols] = True
        assert (hidden[k] == expected).all() and hidden[k].sum() < fake.sum()
    seen.clear()
    rehearse(channels, mask, FPS, dataclasses.replace(blend, rehearse_passes=9), overshoot)
    assert len(seen) == 4
    with pytest.raises(ValueError, match="rehearse_passes"):
        as_blend({"rehearse_passes": 0})
    with pytest.raises(ValueError, match="rehearse_passes must be a whole number"):
        as_blend({"rehearse_passes": 1.5})


def test_rehearse_pool_mixes_each_gaps_share_with_the_clips_pooled_one():
    """A network that overshoots by 2x on channel 0 (share 1/2) and is exact on channels 1-2 (share 1): with
    ``rehearse_pool`` w each gap keeps (1 - w) x its own share + w x the share fitted to every stand-in at once
    (one least-squares fit over all of them, between the two)."""
    from mocapnet.fill import gap_fill

    truth = smooth_channels(600)
    mask = gap_mask(truth.shape, [(100, 120, [0]), (300, 330, [1, 2])])
    channels = np.where(mask, np.nan, truth)
    blend = dataclasses.replace(
        GAP_BLEND, gate_s=(0.0, 1e-6), taper_s=1e-6, speed_factor=np.inf, rehearsals=2, rehearse_mix=True
    )

    def network(m):
        base = gap_fill(np.where(m, np.nan, truth), m, blend.spline_max_s * FPS)
        out = truth.copy()
        out[:, 0] = base[:, 0] + 2.0 * (truth[:, 0] - base[:, 0])
        return out

    own = rehearse(channels, mask, FPS, blend, network)
    np.testing.assert_allclose(own, [0.5, 1.0])
    # pooled by hand: sum of step * residual over sum of step^2 across both gaps' stand-ins
    fake, places = stand_in_gaps(mask, 2)
    both = mask | fake
    base = gap_fill(np.where(both, np.nan, truth), both, blend.spline_max_s * FPS)
    step, resid = network(both) - base, truth - base
    rows = [(np.concatenate([np.arange(s, e) for s, e in p]), cols) for p, (cols, _, _) in zip(places, gap_list(mask))]
    num = sum(float((step[r][:, c] * resid[r][:, c]).sum()) for r, c in rows)
    den = sum(float((step[r][:, c] ** 2).sum()) for r, c in rows)
    for w in (0.5, 1.0):
        pooled = rehearse(channels, mask, FPS, dataclasses.replace(blend, rehearse_pool=w), network)
        np.testing.assert_allclose(pooled, (1 - w) * own + w * min(num / den, 1.0), atol=1e-9)
    with pytest.raises(ValueError, match="rehearse_pool"):
        as_blend({"rehearse_pool": 1.5})


def test_shrunk_share_is_the_fitted_share_less_its_stand_ins_spread():
    """``_shrunk_share``: stand-ins that agree keep the least-squares share; disagreeing ones shrink it by
    ``1 - v / s²`` (v: the ratio's variance from their spread), down to 0; one stand-in gives no spread."""
    from mocapnet.nn.ebd import _share, _shrunk_share

    powers = np.array([2.0, 2.0, 2.0, 2.0])
    assert _shrunk_share(np.array([1.0, 1.0, 1.0, 1.0]), powers) == pytest.approx(0.5)
    fits = np.array([1.6, 0.4, 1.2, 0.8])  # s = 4 / 8 = 0.5; v = 4/3 · (0.36 + 0.36 + 0.04 + 0.04) / 64
    v = 4 / 3 * 0.8 / 64
    assert _shrunk_share(fits, powers) == pytest.approx(0.5 * (1 - v / 0.25))
    assert _shrunk_share(np.array([2.0, -1.0, 1.5, -0.5]), powers) == 0.0  # the spread swamps s = 0.25
    assert _shrunk_share(np.array([-1.0, -1.0]), np.array([1.0, 1.0])) == 0.0
    assert _shrunk_share(np.array([1.0]), np.array([2.0])) == _share(1.0, 2.0)
    assert _shrunk_share(np.array([0.0, 0.0]), np.array([0.0, 0.0])) == 1.0  # no correction: all of it
    assert _shrunk_share(np.array([9.0, 9.0]), np.array([2.0, 2.0])) == 1.0  # clipped


def test_rehearse_shrink_trusts_a_network_less_where_its_stand_ins_disagree():
    """A network exact on every stand-in keeps all of its blend with or without ``rehearse_shrink``; one that is
    exact on some of a gap's stand-ins and overshoots 3x on others keeps less with it than without."""
    from mocapnet.fill import gap_fill

    truth = smooth_channels(900)
    mask = gap_mask(truth.shape, [(400, 430, [0, 1])])
    channels = np.where(mask, np.nan, truth)
    blend = dataclasses.replace(GAP_BLEND, rehearsals=4, rehearse_mix=True, speed_factor=np.inf)
    shrink = dataclasses.replace(blend, rehearse_shrink=True)
    np.testing.assert_allclose(rehearse(channels, mask, FPS, shrink, lambda m: truth), [1.0])
    _, places = stand_in_gaps(mask, 4)
    assert len(places[0]) == 4
    wild = np.zeros(len(truth), dtype=bool)
    for s, e in places[0][:2]:
        wild[s:e] = True

    def uneven(m):  # exact on two stand-ins, 3x the correction on the other two
        base = gap_fill(np.where(m, np.nan, truth), m, blend.spline_max_s * FPS)
        return np.where(wild[:, None], base + 3.0 * (truth - base), truth)

    plain = rehearse(channels, mask, FPS, blend, uneven)[0]
    shrunk = rehearse(channels, mask, FPS, shrink, uneven)[0]
    assert 0.0 <= shrunk < plain < 1.0
    assert as_blend({"rehearse_shrink": 1}).rehearse_shrink is True
    with pytest.raises(ValueError, match="rehearse_shrink must be 0 or 1"):
        as_blend({"rehearse_shrink": 0.5})


def test_short_pool_gives_every_short_gap_one_share_fitted_over_all_their_stand_ins():
    """With ``short_pool`` the gaps shorter than the gate's end keep one share per clip: the least-squares fit of
    the blend's correction over the stand-ins of all of them at once; longer gaps keep their own fitted share."""
    from mocapnet.fill import gap_fill

    truth = smooth_channels(600)
    mask = gap_mask(truth.shape, [(100, 104, [0]), (200, 203, [1]), (400, 405, [2]), (300, 330, [3, 4])])
    channels = np.where(mask, np.nan, truth)
    blend = dataclasses.replace(GAP_BLEND, rehearsals=3, rehearse_mix=True, short_pool=True, speed_factor=np.inf)

    def overshoot(m):  # 10x: short gaps keep only part of the network's correction, so it must be far off
        base = gap_fill(np.where(m, np.nan, truth), m, blend.spline_max_s * FPS)
        return base + 10.0 * (truth - base)

    shares = rehearse(channels, mask, FPS, blend, overshoot)
    fake, places = stand_in_gaps(mask, 3)
    both = mask | fake
    base = gap_fill(np.where(both, np.nan, truth), both, blend.spline_max_s * FPS)
    filled = blend_gaps(np.where(both, np.nan, truth), both, overshoot(both), FPS, blend)[0]
    step, resid = filled - base, truth - base
    rows = [(np.concatenate([np.arange(s, e) for s, e in p]), c) for p, (c, _, _) in zip(places[:3], gap_list(mask))]
    pooled = sum(float((step[r][:, c] * resid[r][:, c]).sum()) for r, c in rows) / sum(
        float((step[r][:, c] ** 2).sum()) for r, c in rows
    )
    assert 0.0 < pooled < 1.0
    np.testing.assert_allclose(shares[:3], [pooled, pooled, pooled], atol=1e-9)
    assert 0.1 <= shares[3] < 0.2  # the long gap's own share: 1/10, a little more where the taper thins the step
    # without it each short gap gets its all-or-nothing verdict
    assert set(rehearse(channels, mask, FPS, dataclasses.replace(blend, short_pool=False), overshoot)[:3]) <= {0, 1}
    away = rehearse(channels, mask, FPS, blend, lambda m: 2 * gap_fill(np.where(m, np.nan, truth), m, 15) - truth)
    np.testing.assert_allclose(away, [0.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(rehearse(channels, mask, FPS, blend, lambda m: truth), [1.0, 1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="short_pool must be 0 or 1"):
        as_blend({"short_pool": 2})


def test_rehearse_option_runs_one_more_pass_and_interpolates_the_gaps_it_rejects(sample, monkeypatch):
    from mocapnet.fill import gap_fill
    from mocapnet.methods.registry import build_method
    from mocapnet.nn import infer

    rng = np.random.default_rng(5)
    noisy, mask = corrupt_motion(sample.with_channels(sample.channels[:900]), "gaps", rng)
    motion = sample.with_channels(noisy)
    plain = build_method("ebd:rehearse=0").clean(motion, mask)  # the shipped EBD, no rehearsal
    passes = []
    run = infer._network_output
    monkeypatch.setattr(infer, "_network_output", lambda *a: passes.append(a[2].sum()) or run(*a))
    rehearsed = build_method("ebd:rehearse=2,rehearse_mix=0").clean(motion, mask)
    assert len(passes) == 2 and passes[1] > passes[0]  # the second pass hides the stand-ins as well
    np.testing.assert_array_equal(rehearsed[~mask], noisy[~mask])
    changed = np.flatnonzero((rehearsed != plain).any(axis=0))
    assert len(changed)  # some gaps went back to interpolation
    base = gap_fill(noisy, mask, GAP_BLEND.spline_max_s * sample.fps)
    for c in changed:  # ... and each changed sample is that interpolation
        moved = rehearsed[:, c] != plain[:, c]
        np.testing.assert_allclose(rehearsed[moved, c], base[moved, c])
    # the shipped share: every sample lies between the blend and the interpolation, observed ones unchanged
    shared = build_method("ebd:rehearse=2").clean(motion, mask)
    np.testing.assert_array_equal(shared[~mask], noisy[~mask])
    lo, hi = np.minimum(plain, base) - 1e-9, np.maximum(plain, base) + 1e-9
    assert ((shared >= lo) & (shared <= hi))[mask].all()
    partial = (np.abs(shared - plain) > 1e-6) & (np.abs(shared - base) > 1e-6)
    assert partial.any()  # some gaps keep part of the correction


def test_rehearse_is_an_ebd_option_of_whole_numbers():
    from mocapnet.methods.registry import build_method
    from mocapnet.nn.ebd import as_blend

    bad_options = ("ebf:rehearse=2", "ebd:rehearse=-1", "ebd:rehearse=1.5", "ebd:rehearse=true")
    bad_options += ("ebd:rehearse_margin=0", "ebd:rehearse_min_s=-1", "ebf-free:rehearse_margin=0.5")
    bad_options += ("ebd:rehearse_min_s=inf", "ebd:rehearse_margin=inf", "ebd:rehearse_margin=true")
    bad_options += ("ebd:rehearse_mix=2", "ebd:rehearse_mix=0.5", "ebf:rehearse_mix=1")
    bad_options += ("ebd:rehearse_shrink=2", "ebd:rehearse_near=-1", "ebd:rehearse_seed=1.5", "ebf:rehearse_seed=1")
    for bad in bad_options:
        with pytest.raises(ValueError, match="rehearse"):
            build_method(bad)
    assert as_blend({"rehearsals": 3}).rehearsals == 3
    assert (
        as_blend({"rehearse_mix": 1}).rehearse_mix is True and as_blend({"rehearse_mix": False}).rehearse_mix is False
    )
    build_method("ebd:rehearse=2,rehearse_mix=1")
    build_method("ebd:rehearse_shrink=1,rehearse_near=0.5,rehearse_seed=2")
    for bad in (
        {"rehearsals": -1},
        {"rehearsals": 2.7},
        {"rehearsals": True},
        {"rehearse_margin": 0.0},
        {"rehearse_min_s": -0.1},
        {"rehearse_mix": 0.5},
    ):
        with pytest.raises(ValueError, match="rehears"):
            as_blend(bad)


def test_gate_end_option_shrinks_the_network_share_of_short_gaps(sample):
    """``ebd:gate_end=S``: gaps shorter than S keep a smaller share of the network's correction to the spline base;
    observed samples never change; a gate that ends before it starts, or the option on a denoiser, is refused."""
    from mocapnet.fill import gap_fill
    from mocapnet.methods.registry import build_method
    from mocapnet.nn.features import scored_index

    motion = sample.with_channels(sample.channels[:600])
    mask = np.zeros_like(motion.channels, dtype=bool)
    mask[300:312, scored_index(motion.skeleton)[12:15]] = True  # one 12-frame gap (0.1 s at 120 fps) of one joint
    base = gap_fill(np.where(mask, np.nan, motion.channels), mask, GAP_BLEND.spline_max_s * motion.fps)
    shipped = build_method("ebd:rehearse=0").clean(motion, mask)
    longer = build_method("ebd:rehearse=0,gate_end=0.5").clean(motion, mask)
    np.testing.assert_array_equal(longer[~mask], motion.channels[~mask])
    moved, moved_less = np.abs(shipped - base)[mask], np.abs(longer - base)[mask]
    assert moved.max() > 1e-3  # the shipped gate (0.2 s) lets the network correct this gap
    # the gate starts at 1/30 s (4 frames at 120 fps): its weight is (12 - 4) / (24 - 4) at 0.2 s, (12 - 4) / (60 - 4)
    np.testing.assert_allclose(moved_less, moved * (8 / 56) / (8 / 20), rtol=1e-6, atol=1e-9)
    for bad in ("ebd:gate_end=0", "ebd:gate_end=-1", "ebd:gate_end=inf", "ebf:gate_end=0.3"):
        with pytest.raises(ValueError, match="gate_end"):
            build_method(bad)
    with pytest.raises(ValueError, match="gate_end 0.01 s must be after"):
        build_method("ebd:gate_end=0.01").clean(motion, mask)


def test_gap_means_average_each_run_of_missing_samples_per_clip_and_channel():
    mask = torch.tensor([[0, 1, 1, 0, 1, 1, 1], [1, 1, 0, 0, 0, 1, 0]], dtype=torch.bool).T[None]  # [1, 7, 2]
    values = torch.arange(14, dtype=torch.float64).reshape(1, 7, 2)
    means = gap_means(torch.cat([values, values + 100]), torch.cat([mask, mask]))  # two clips, same gaps
    expected = torch.tensor([[0, 3, 3, 0, 10, 10, 10], [2, 2, 0, 0, 0, 11, 0]], dtype=torch.float64).T
    assert torch.equal(means[0], expected)
    assert torch.equal(means[1], torch.where(mask[0], expected + 100, 0.0))


def test_relative_gap_loss_weighs_each_gap_by_its_interpolation_error(tiny, sample):
    model = tiny("ebd", sample, gap_loss="relative")
    assert not model.loss_in_degrees
    mask = torch.zeros(1, 8, 2, dtype=torch.bool)
    mask[0, 1:3, 0] = True  # short gap: the interpolation is 1 degree off
    mask[0, 3:7, 1] = True  # long gap: 10 degrees off
    clean = torch.zeros(1, 8, 2)
    filled = torch.where(mask, torch.tensor([1.0, 10.0]), clean)
    pred = torch.where(mask, torch.tensor([0.5, 5.0]), clean)  # both halve their gap's error
    sq, sel = model.loss_terms({"clean": clean, "filled": filled, "mask": mask}, pred)
    assert torch.equal(sel, mask)
    short = 0.25 / (1.0 + GAP_LOSS_FLOOR_DEG**2)
    long = 25.0 / (100.0 + GAP_LOSS_FLOOR_DEG**2)
    assert torch.allclose(sq[mask], torch.tensor([short, short, long, long, long, long]))
    model.hparams.gap_loss = "rms"
    sq, _ = model.loss_terms({"clean": clean, "filled": filled, "mask": mask}, pred)
    short, long = 0.25 / (1.0 + GAP_LOSS_FLOOR_DEG), 25.0 / (10.0 + GAP_LOSS_FLOOR_DEG)
    assert torch.allclose(sq[mask], torch.tensor([short, short, long, long, long, long]))
    with pytest.raises(ValueError, match="gap_loss"):
        tiny("ebd", sample, gap_loss="per-gap")
    assert tiny("ebd", sample).loss_in_degrees


@pytest.mark.parametrize(("before", "after"), [("samples", "rms"), ("rms", "samples"), (None, "relative")])
def test_a_warm_restart_may_change_the_gap_loss(tiny, sample, before, after):
    """``gap_loss`` is how to train, not what the weights mean: ``init_from`` takes a checkpoint trained with
    another one (or none: checkpoints from before the option), weights bit for bit."""
    source = tiny("ebd", sample, **({} if before is None else {"gap_loss": before}))
    theirs = dict(source.hparams)
    if before is None:
        theirs.pop("gap_loss")
    ckpt = {"state_dict": source.state_dict(), "mocapnet_model": "EBD", "hyper_parameters": theirs}
    target = tiny("ebd", sample, gap_loss=after)
    initial_weights(target, ckpt, "source.ckpt")
    for key, value in source.state_dict().items():
        assert torch.equal(target.state_dict()[key], value)


def test_validation_error_stays_in_degrees_whatever_the_gap_loss(tiny, sample):
    mask = torch.zeros(1, 8, 2, dtype=torch.bool)
    mask[0, 2:5, 0] = True
    batch = {"clean": torch.zeros(1, 8, 2), "filled": torch.where(mask, 4.0, 0.0), "mask": mask}
    for kind in ("samples", "relative", "rms"):
        model = tiny("ebd", sample, gap_loss=kind)
        model.predict_batch = lambda b: torch.where(b["mask"], 3.0, 0.0)  # 3 degrees off on the 3 missing samples
        model.on_validation_epoch_start()
        model.validation_step(batch, 0)
        assert model._sse == pytest.approx(27.0) and model._count == 3


def test_short_option_fills_each_gap_with_the_network_made_for_its_length(tiny, sample, tmp_path):
    """``ebd:short=PATH``: the gaps shorter than ``short_max_s`` (0.2 s) come from the second network, the others
    from the first, each as that network gives them alone with the same options; observed samples never change;
    the options are refused on a denoiser, with a time that is not positive, or without ``short``."""
    from mocapnet.methods.neural import SHORT_MAX_S
    from mocapnet.methods.registry import build_method
    from mocapnet.nn.features import scored_index

    model = tiny("ebd", sample).eval()  # untrained: its fill is the interpolation, unlike the shipped network's
    path = tmp_path / "short.ckpt"
    torch.save(
        {"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams), "mocapnet_model": "EBD"}, path
    )
    motion = sample.with_channels(sample.channels[:600])
    cols = scored_index(motion.skeleton)
    mask = gap_mask(motion.channels.shape, [(100, 112, list(cols[12:15])), (300, 360, list(cols[30:33]))])
    short = mask.copy()
    short[300:360] = False  # the 12-frame gap is 0.1 s at 120 fps; the 60-frame one 0.5 s
    assert 12 < SHORT_MAX_S * motion.fps < 60
    pair = build_method(f"ebd:rehearse=0,short={path}").clean(motion, mask)
    long_only = build_method("ebd:rehearse=0").clean(motion, mask)
    short_only = build_method(f"ebd={path}:rehearse=0").clean(motion, mask)
    assert np.abs(long_only - short_only)[short].max() > 1e-3  # the two networks differ on the short gap
    np.testing.assert_array_equal(pair[short], short_only[short])
    np.testing.assert_array_equal(pair[~short], long_only[~short])
    np.testing.assert_array_equal(pair[~mask], motion.channels[~mask])
    for bad in (f"ebf:short={path}", f"ebd:short={path},short_max_s=0", f"ebd={path}:short_max_s=0.5"):
        with pytest.raises(ValueError, match="short"):
            build_method(bad)
    for off in ("off", "none", "false"):
        with pytest.raises(ValueError, match="short"):
            build_method(f"ebd:short={off},short_max_s=0.5")
    with pytest.raises(ValueError, match="short=PATH"):
        build_method("ebd:short=0")
    with pytest.raises(ValueError, match="no short-gap network"):  # the CMU skeleton's shipped ebd has none
        build_method("ebd:short_max_s=0.5").clean(motion, mask)


def test_the_shipped_ebd_brings_its_short_gap_network(tiny, sample, tmp_path, monkeypatch):
    """An index entry ``"short": {"file", "max_s"}`` makes the shipped ``ebd`` a pair: ``ebd`` (and ``ebd+ebf``'s
    raw fill, and the benchmarks' ``ebd-raw``) equal the two networks named by path with ``short=``; the partner
    (``"short_for"``) is never what a method looks up; ``short=off`` runs the main network alone."""
    import shutil

    from mocapnet.evaluate.gap_bins import raw_filler
    from mocapnet.methods.neural import by_gap_length, ebd_raw_filler
    from mocapnet.methods.registry import build_method
    from mocapnet.nn import checkpoints
    from mocapnet.nn.features import scored_index, topology_hash

    real = {e["file"]: e for e in checkpoints.read_index()}
    shutil.copy(checkpoints.CHECKPOINT_DIR / "cmu120_ebd.ckpt", tmp_path / "main.ckpt")
    shutil.copy(checkpoints.CHECKPOINT_DIR / "cmu120_ebf.ckpt", tmp_path / "ebf.ckpt")
    model = tiny("ebd", sample).eval()
    torch.save(
        {"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams), "mocapnet_model": "EBD"},
        tmp_path / "short.ckpt",
    )
    mine = topology_hash(sample.skeleton)
    index = [
        {"file": "short.ckpt", "method": "ebd", "skeleton_hash": mine, "short_for": "main.ckpt"},
        {**real["cmu120_ebd.ckpt"], "file": "main.ckpt", "short": {"file": "short.ckpt", "max_s": 0.2}},
        {**real["cmu120_ebf.ckpt"], "file": "ebf.ckpt"},
    ]
    monkeypatch.setattr(checkpoints, "CHECKPOINT_DIR", tmp_path)
    monkeypatch.setattr(checkpoints, "read_index", lambda: index)
    assert checkpoints.shipped_checkpoint("ebd", sample.skeleton) == tmp_path / "main.ckpt"
    assert checkpoints.shipped_short(sample.skeleton) == (tmp_path / "short.ckpt", 0.2)

    motion = sample.with_channels(sample.channels[:600])
    cols = scored_index(motion.skeleton)
    mask = gap_mask(motion.channels.shape, [(100, 112, list(cols[12:15])), (300, 360, list(cols[30:33]))])
    main, short = str(tmp_path / "main.ckpt"), str(tmp_path / "short.ckpt")
    shipped = build_method("ebd:rehearse=0").clean(motion, mask)
    named = build_method(f"ebd={main}:rehearse=0,short={short}").clean(motion, mask)
    alone = build_method("ebd:rehearse=0,short=off").clean(motion, mask)
    np.testing.assert_array_equal(shipped, named)
    np.testing.assert_array_equal(build_method("ebd:rehearse=0,short=none").clean(motion, mask), alone)
    np.testing.assert_array_equal(alone, build_method(f"ebd={main}:rehearse=0").clean(motion, mask))
    assert np.abs(shipped - alone)[100:112].max() > 1e-3 and np.array_equal(shipped[300:360], alone[300:360])

    raw = raw_filler()(motion, mask)
    pair = by_gap_length(ebd_raw_filler(main)(motion, mask), ebd_raw_filler(short)(motion, mask), mask, 0.2 * 120)
    np.testing.assert_array_equal(raw, pair)
    np.testing.assert_array_equal(raw[~mask], motion.channels[~mask])
    ebf = str(tmp_path / "ebf.ckpt")
    np.testing.assert_array_equal(
        build_method("ebd+ebf").clean(motion, mask),
        build_method(f"ebd+ebf={main},{ebf}:short={short}").clean(motion, mask),
    )


def test_fill_by_gap_length_runs_only_the_networks_it_needs():
    """No short gap: the long fill alone; only short gaps: the short fill alone; both: ``by_gap_length``."""
    from mocapnet.methods.neural import by_gap_length, fill_by_gap_length

    channels = smooth_channels(120, 4)
    calls = []

    def fill(tag: str, offset: float):
        def run() -> np.ndarray:
            calls.append(tag)
            return channels + offset

        return run

    cases = {
        "long only": gap_mask(channels.shape, [(10, 30, [0])]),
        "short only": gap_mask(channels.shape, [(10, 13, [0]), (50, 52, [1, 2])]),
        "both": gap_mask(channels.shape, [(10, 13, [0]), (40, 70, [1])]),
    }
    expected_calls = {"long only": ["long"], "short only": ["short"], "both": ["short", "long"]}
    for name, mask in cases.items():
        calls.clear()
        out = fill_by_gap_length(mask, 6, fill("long", 1.0), fill("short", 2.0))
        assert calls == expected_calls[name], name
        np.testing.assert_array_equal(out[mask], by_gap_length(channels + 1.0, channels + 2.0, mask, 6)[mask])
