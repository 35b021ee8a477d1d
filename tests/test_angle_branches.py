"""Angles across a gap. A file that wraps its rotations at ±180° is made continuous when read, but not through a
gap, whose placeholder values break the chain; a file that stores them continuously says across a gap how far a
joint turned. ``fill.unwrap_observed`` tells the two apart per column, and ``mocapnet clean`` runs it before any
method; the methods themselves take the angles they are given as continuous."""

from __future__ import annotations

import numpy as np
import pytest

from mocapnet.adaptive_smooth import cv_gaussian
from mocapnet.clean import CleanOptions, clean_bvh_file
from mocapnet.corrupt import corrupt_motion
from mocapnet.fill import WRAP_STEP, lerp_fill, unwrap_observed
from mocapnet.io import read_bvh, write_bvh
from mocapnet.kinematics import wrap_deg
from mocapnet.methods.registry import build_method


def test_unwrap_observed_without_gaps_is_the_readers_unwrap():
    stored = wrap_deg(np.cumsum(np.random.default_rng(0).normal(0.0, 40.0, (500, 6)), axis=0))
    rotation = np.array([True, True, False, True, True, True])
    out = unwrap_observed(stored, np.zeros(stored.shape, dtype=bool), rotation)
    np.testing.assert_array_equal(out[:, rotation], np.unwrap(stored[:, rotation], period=360.0, axis=0))
    np.testing.assert_array_equal(out[:, ~rotation], stored[:, ~rotation])
    assert np.abs(np.diff(out[:, rotation], axis=0)).max() <= 180.0


def test_unwrap_observed_joins_a_wrapped_column_and_keeps_a_continuous_one():
    t = np.arange(60, dtype=np.float64)
    mask = np.zeros((60, 1), dtype=bool)
    mask[5:15] = True
    # stored wrapped (160 ... 278 kept within ±180), placeholders 0 in the gap: joined the short way
    truth = 160.0 + 2.0 * t
    stored = np.where(mask, 0.0, wrap_deg(truth)[:, None])
    out = unwrap_observed(stored, mask, [0])
    np.testing.assert_allclose(out[~mask[:, 0], 0], truth[~mask[:, 0]])
    np.testing.assert_allclose(lerp_fill(out, mask)[5:15, 0], truth[5:15])  # 170 ... 188, through 180
    assert np.abs(wrap_deg(lerp_fill(stored, mask)[5:15, 0] - truth[5:15])).max() > 90  # unjoined: through 0
    np.testing.assert_array_equal(stored, np.where(mask, 0.0, wrap_deg(truth)[:, None]))  # the input untouched
    # stored in [0, 360): 348 ... 10 across the gap is a turn of 22° through 360
    zero_based = np.where(mask, 0.0, (340.0 + 2.0 * t)[:, None] % 360.0)
    np.testing.assert_allclose(unwrap_observed(zero_based, mask, [0])[~mask[:, 0], 0], (340.0 + 2.0 * t)[~mask[:, 0]])
    # stored continuously (fits neither window): -20 before the gap, 330 after it is a turn of 350°, kept
    turn = np.where(t < 30, -20.0, 330.0)[:, None]
    long_gap = np.zeros_like(mask)
    long_gap[10:50] = True
    np.testing.assert_array_equal(unwrap_observed(turn, long_gap, [0]), turn)
    # the same edges stored wrapped (-20 and -30): nothing to join, the turn is not in the file
    np.testing.assert_array_equal(unwrap_observed(wrap_deg(turn), long_gap, [0]), wrap_deg(turn))
    # a wrapped column with edges 170 and -176 (stored 184): joined
    edges = np.where(t < 10, 170.0, -176.0)[:, None]
    np.testing.assert_allclose(unwrap_observed(edges, mask, [0])[15:, 0], 184.0)
    # one column stored continuously makes the whole file continuous: the other column's edges are kept too
    both = np.concatenate([turn, edges], axis=1)
    both_mask = np.concatenate([long_gap, mask], axis=1)
    np.testing.assert_array_equal(unwrap_observed(both, both_mask, [0, 1]), both)
    np.testing.assert_allclose(unwrap_observed(both, both_mask, [1])[15:, 1], 184.0)  # column 1 alone may wrap
    # an integer 0/1 mask is a mask
    np.testing.assert_array_equal(unwrap_observed(edges, mask.astype(np.int64), [0]), unwrap_observed(edges, mask, [0]))
    # a wrapped column whose edges differ by less than WRAP_STEP: motion, not a wrap
    swing = np.where(t < 10, -100.0, -100.0 + WRAP_STEP - 1.0)[:, None]
    np.testing.assert_array_equal(unwrap_observed(swing, mask, [0]), swing)
    # inside an observed run a step over 180° is a wrap, as the reader takes it (here between frames 26 and 27)
    runs_wrap = wrap_deg(100.0 + 3.0 * t)[:, None]
    assert np.abs(np.diff(runs_wrap[15:, 0])).max() > 180.0
    out = unwrap_observed(runs_wrap, mask, [0])
    np.testing.assert_allclose(out[~mask[:, 0], 0], (100.0 + 3.0 * t)[~mask[:, 0]])


@pytest.fixture(scope="module")
def file_with_gaps(cmu, tmp_path_factory):
    """The CMU clip's first 600 frames with noise and two gaps in every other scored rotation channel, each turned
    to 180° at frame 100, inside the first gap (about half of them cross it there: their edges need the join);
    stored wrapped, with placeholder zeros in the gaps."""
    motion = cmu.with_channels(cmu.channels[:600])
    cols = np.flatnonzero(motion.skeleton.scored_mask & motion.skeleton.rotation_mask)[::2]
    turned = motion.channels.copy()
    turned[:, cols] += 180.0 - turned[100, cols]  # each crosses 180 at frame 100
    motion = motion.with_channels(turned)
    noisy, mask = corrupt_motion(motion, "angular-0.5", np.random.default_rng(3))
    mask = mask.copy()
    mask[90:111, cols] = mask[290:311, cols] = True
    rotation = motion.skeleton.rotation_mask
    wrapped = np.where(rotation, wrap_deg(noisy), noisy)
    folder = tmp_path_factory.mktemp("gaps")
    write_bvh(folder / "wrapped.bvh", motion.with_channels(np.where(mask, 0.0, wrapped)))
    np.save(folder / "mask.npy", mask)
    # what the reader makes of the same file without gaps: the angles the methods should see
    continuous = np.where(rotation, np.unwrap(wrapped, period=360.0, axis=0), noisy)
    return motion, continuous, mask, folder


@pytest.mark.parametrize("method", ["lerp", "gaussian-58ms", "ebd"])
def test_clean_with_a_mask_fills_a_wrapped_file_the_short_way(file_with_gaps, method):
    motion, continuous, mask, folder = file_with_gaps
    out = folder / f"{method}.bvh"
    clean_bvh_file(folder / "wrapped.bvh", out, CleanOptions(method=method, mask=str(folder / "mask.npy")))
    got = read_bvh(out, unwrap=False).channels
    stored = read_bvh(folder / "wrapped.bvh", unwrap=False).channels
    want = build_method(method).clean(motion.with_channels(np.where(mask, np.nan, continuous)), mask)
    scored = motion.skeleton.scored_mask
    # the file's 6 decimals, which EBD's network amplifies to ~1e-5; written back in the file's range (±180°)
    np.testing.assert_allclose(wrap_deg(got - want)[:, scored], 0.0, rtol=0, atol=2e-5)
    rotation = motion.skeleton.rotation_mask
    assert got[:, rotation].min() >= -180.0 and got[:, rotation].max() <= 180.0
    if method in ("lerp", "ebd"):  # gap fillers keep observed samples, exactly as the file stores them
        np.testing.assert_array_equal(got[~mask], stored[~mask])


def test_clean_with_a_mask_keeps_a_turn_the_file_stores(cmu_short, tmp_path):
    """A file that stores a column continuously (here -20 before a 60-frame gap, 330 after it): ``clean`` fills
    the turn, not the 10° the other way round (session 24's join in every method did that)."""
    col = int(np.flatnonzero(cmu_short.skeleton.scored_mask & cmu_short.skeleton.rotation_mask)[0])
    channels = cmu_short.channels.copy()
    channels[:, col] = np.interp(np.arange(channels.shape[0]), [199, 260], [-20.0, 330.0])  # -20 before, 330 after
    mask = np.zeros(channels.shape, dtype=bool)
    mask[200:260, col] = True
    stored = np.where(mask, 0.0, channels)
    write_bvh(tmp_path / "turn.bvh", cmu_short.with_channels(stored))
    np.save(tmp_path / "mask.npy", mask)
    options = CleanOptions(method="lerp", mask=str(tmp_path / "mask.npy"))
    clean_bvh_file(tmp_path / "turn.bvh", tmp_path / "out.bvh", options)
    got = read_bvh(tmp_path / "out.bvh", unwrap=False).channels[:, col]
    np.testing.assert_allclose(got[199:261], np.linspace(channels[199, col], channels[260, col], 62), atol=2e-6)


def test_gaussian_cv_does_not_unwrap_inside_an_observed_run(cmu):
    """A step over 180° between observed frames is motion or noise, not a wrap (``read_bvh`` unwrapped the file):
    ``gaussian-cv`` smooths the channel as it is, with no gap to join."""
    motion = cmu.with_channels(cmu.channels[:600])
    noisy, mask = corrupt_motion(motion, "angular-0.5", np.random.default_rng(4))
    scored = np.flatnonzero(motion.skeleton.scored_mask)
    busy = scored[np.argmax(noisy[:, scored].std(axis=0))]
    jumpy = noisy.copy()
    jumpy[300:, busy] += 200.0  # a step of about 200° between frames 299 and 300
    out = build_method("gaussian-cv").clean(motion.with_channels(jumpy), mask)
    np.testing.assert_array_equal(out[:, scored], cv_gaussian(jumpy[:, scored])[0])
    unwrapped = cv_gaussian(jumpy[:, [busy]], period=360.0)[0][:, 0]
    assert np.abs(wrap_deg(out[:, busy] - unwrapped)).max() > 1.0  # unwrapping there would change the result
