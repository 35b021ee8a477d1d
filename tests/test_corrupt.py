import numpy as np
import pytest

from mocapnet.corrupt import (
    ANGLE_CORRUPTIONS,
    corrupt_markers,
    corrupt_motion,
    gap_mask,
    long_gap_mask,
    place_gap,
    seed_for,
)
from mocapnet.io import read_c3d
from mocapnet.kinematics import joint_positions
from mocapnet.segments import marker_segment
from tests.conftest import SAMPLE_C3D


def _rng(k=0):
    return np.random.default_rng(k)


def test_seeds_are_reproducible_and_distinct():
    assert seed_for("bandai2", "a", 0) == seed_for("bandai2", "a", 0)
    assert len({seed_for("bandai2", "a", r) for r in range(5)} | {seed_for("bandai1", "a", 0)}) == 6


@pytest.mark.parametrize("k", [0.1, 0.5, 0.9])
def test_angular_noise_std(cmu, k):
    noisy, mask = corrupt_motion(cmu, f"angular-{k}", _rng())
    scored = cmu.skeleton.scored_mask
    sigma = cmu.channels.std(axis=0)
    live = scored & (sigma > 1.0)
    ratio = (noisy - cmu.channels)[:, live].std(axis=0) / (k * sigma[live])
    assert abs(ratio.mean() - 1) < 0.05 and np.all(np.abs(ratio - 1) < 0.1)
    assert not mask.any()
    np.testing.assert_array_equal(noisy[:, ~scored], cmu.channels[:, ~scored])


def test_zero_noise_is_noop(cmu):
    noisy, _ = corrupt_motion(cmu, "angular-0", _rng())
    np.testing.assert_array_equal(noisy, cmu.channels)
    noisy, _ = corrupt_motion(cmu, "spatial-0cm", _rng())
    np.testing.assert_allclose(noisy, cmu.channels, atol=1e-6)


def test_uniform_noise_std_and_bounds(cmu):
    noisy, _ = corrupt_motion(cmu, "uniform-0.5", _rng())
    sigma = cmu.channels.std(axis=0)
    live = cmu.skeleton.scored_mask & (sigma > 1.0)
    d = (noisy - cmu.channels)[:, live]
    assert abs(d.std(axis=0) / (0.5 * sigma[live]) - 1).mean() < 0.05
    assert np.all(np.abs(d) <= np.sqrt(3) * 0.5 * sigma[live] + 1e-9)


def test_bias_corruptions(cmu):
    sigma = cmu.channels.std(axis=0)
    live = cmu.skeleton.scored_mask & (sigma > 1.0)
    noisy, _ = corrupt_motion(cmu, "bias-const", _rng())
    offset = (noisy - cmu.channels)[:, live].mean(axis=0)
    np.testing.assert_allclose(np.abs(offset) / (0.5 * sigma[live]), 1.0, atol=0.05)
    noisy, _ = corrupt_motion(cmu, "bias-sine", _rng())
    d = (noisy - cmu.channels)[:, live]
    # noise std 0.5σ plus a sine of amplitude 0.5σ (variance 0.125σ²)
    np.testing.assert_allclose(d.std(axis=0).mean() / 1.0, (np.sqrt(0.25 + 0.125) * sigma[live]).mean(), rtol=0.15)


def test_spatial_noise_preserves_bone_lengths(cmu_short, bandai):
    for motion in (cmu_short, bandai):
        noisy, _ = corrupt_motion(motion, "spatial-1cm", _rng())
        clean_pos = joint_positions(motion, end_sites=True)
        noisy_pos = joint_positions(motion, noisy, end_sites=True)
        sk = motion.skeleton
        for j, p in enumerate(sk.parents):
            if p >= 0:
                a = np.linalg.norm(clean_pos[:, j] - clean_pos[:, p], axis=-1)
                b = np.linalg.norm(noisy_pos[:, j] - noisy_pos[:, p], axis=-1)
                assert np.abs(a - b).max() < 1e-3
        moved = np.linalg.norm(noisy_pos - clean_pos, axis=-1)
        assert 0.2 < moved[:, 1:].mean() < 2.0  # the joints did move, by about the noise
        np.testing.assert_array_equal(noisy[:, ~sk.scored_mask], motion.channels[:, ~sk.scored_mask])


def test_spatial_ends_moves_hands_more(cmu_short):
    noisy, _ = corrupt_motion(cmu_short, "spatial-ends", _rng())
    moved = np.linalg.norm(joint_positions(cmu_short, noisy) - joint_positions(cmu_short), axis=-1).mean(axis=0)
    names = cmu_short.skeleton.names
    assert moved[names.index("LeftHand")] > moved[names.index("Spine1")]


def test_gap_statistics():
    fps, n = 30.0, 200_000
    mask = gap_mask(n, 4, fps, _rng())
    assert not mask[0].any() and not mask[-1].any()
    frac = mask.mean(axis=0)
    assert np.all(np.abs(frac - 0.1) < 0.01)
    col = mask[:, 0].astype(int)
    starts = np.flatnonzero(np.diff(col) == 1) + 1
    ends = np.flatnonzero(np.diff(col) == -1) + 1
    lengths = ends - starts[: len(ends)]
    assert lengths.min() >= 1 and lengths.max() <= 2 * fps
    # exponential with mean 0.5 s, clipped to [1 frame, 2 s]
    sample = np.clip(np.round(_rng(1).exponential(0.5 * fps, 100_000)), 1, 2 * fps)
    assert abs(lengths.mean() - sample.mean()) < 0.05 * sample.mean()


def test_long_gaps():
    for k in range(20):
        mask = long_gap_mask(900, np.arange(5, 15), 20, 30.0, _rng(k))
        tracks = np.flatnonzero(mask.any(axis=0))
        assert 1 <= len(tracks) <= 3 and set(tracks) <= set(range(5, 15))
        for t in tracks:
            assert 60 <= mask[:, t].sum() <= 150


def test_place_gap_onsets_cover_the_range_inside_the_margins():
    rng = _rng(5)
    onsets = set()
    for _ in range(400):
        mask = np.zeros((30, 4), dtype=bool)
        place_gap(mask, [1, 3], 7, 4, rng)
        rows = np.flatnonzero(mask.any(axis=1))
        assert len(rows) == 7 and (rows == rows[0] + np.arange(7)).all()
        assert (mask[:, [1, 3]].any(axis=1) == mask.any(axis=1)).all() and not mask[:, [0, 2]].any()
        onsets.add(int(rows[0]))
    assert onsets == set(range(4, 30 - 4 - 7 + 1))


@pytest.mark.parametrize("name", [c for c in ANGLE_CORRUPTIONS if "gap" in c])
def test_gap_corruptions_mark_whole_joints(bandai, name):
    noisy, mask = corrupt_motion(bandai, name, _rng(3))
    assert mask.any()
    assert np.isnan(noisy[mask]).all() and np.isfinite(noisy[~mask]).all()
    assert not mask[:, ~bandai.skeleton.scored_mask].any()
    sk = bandai.skeleton
    for j in sk.scored_joints:
        cols = sk.joint_channels(j)[sk.scored_mask[sk.joint_channels(j)]]
        assert (mask[:, cols] == mask[:, cols[:1]]).all()


def test_all_corruptions_are_deterministic(cmu_short):
    for name in ANGLE_CORRUPTIONS:
        a = corrupt_motion(cmu_short, name, _rng(7))
        b = corrupt_motion(cmu_short, name, _rng(7))
        np.testing.assert_array_equal(a[0], b[0])


def test_segment_gap_on_markers():
    m = read_c3d(SAMPLE_C3D)
    out = corrupt_markers(m, "segment-gap:left-arm:2", _rng())
    idx = marker_segment(m.labels, "left-arm")
    assert len(idx) == 6
    missing = ~out.visible
    assert set(np.flatnonzero(missing.any(axis=0))) == set(idx)
    rows = np.flatnonzero(missing.any(axis=1))
    assert len(rows) == 100 and rows[0] >= 50 and rows[-1] < m.n_frames - 50
    with pytest.raises(ValueError, match="too short"):
        corrupt_markers(m, "segment-gap:legs:30", _rng())
    with pytest.raises(ValueError, match="bad point corruption"):
        corrupt_markers(m, "segment-gap:tail:1", _rng())


def test_unknown_corruption(cmu_short):
    with pytest.raises(ValueError, match="unknown corruption 'angular'"):
        corrupt_motion(cmu_short, "angular", _rng())
