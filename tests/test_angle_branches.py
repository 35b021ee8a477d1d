"""A gap can hide a wrap: a BVH that stores a turning root in [-180, 180) is unwrapped along time when read, but
not through a gap whose placeholder samples break the chain. Every angle method joins such a gap the shorter way
round the circle (``fill.join_gaps``), so it gives the same angles whichever branch the runs after a gap are on."""

from __future__ import annotations

import numpy as np
import pytest

from mocapnet.adaptive_smooth import cv_gaussian
from mocapnet.corrupt import corrupt_motion
from mocapnet.fill import join_gaps, lerp_fill, runs, spline_fill
from mocapnet.kinematics import wrap_deg
from mocapnet.methods.knn_angles import fill_angles
from mocapnet.methods.knn_database import SkeletonDatabase
from mocapnet.methods.registry import build_method
from mocapnet.motion import Motion

METHODS = [
    "lerp",
    "spline",
    "gaussian-58ms",
    "gaussian-125ms",
    "gaussian-58ms+check",
    "gaussian-cv",
    "ebf",
    "ebd",
    "ebd+ebf",
]


@pytest.fixture(scope="module")
def corrupted(cmu):
    """The CMU clip's first 600 frames with noise, and two gaps in every other scored channel; in ``moved`` the
    runs of those channels after each gap are stored on other branches (+360 after the first, -360 after the
    second): the same angles."""
    motion = cmu.with_channels(cmu.channels[:600])
    noisy, mask = corrupt_motion(motion, "angular-0.5", np.random.default_rng(3))
    cols = np.flatnonzero(motion.skeleton.scored_mask)[::2]
    mask = mask.copy()
    mask[90:111, cols] = mask[290:311, cols] = True
    noisy = np.where(mask, np.nan, noisy)
    moved = noisy.copy()
    moved[111:290, cols] += 360.0
    moved[311:, cols] -= 360.0
    return motion, noisy, moved, mask


@pytest.mark.parametrize("method", METHODS)
def test_angle_methods_join_a_gap_that_hides_a_wrap(corrupted, method):
    motion, noisy, moved, mask = corrupted
    clean = build_method(method).clean
    plain = clean(motion.with_channels(noisy), mask)
    joined = clean(motion.with_channels(moved), mask)
    scored = motion.skeleton.scored_mask
    np.testing.assert_allclose(wrap_deg(joined - plain)[:, scored], 0.0, atol=1e-6)
    seen = ~mask & scored
    # each observed sample stays on the branch the file gave it and changes by what it did on the plain branches
    np.testing.assert_allclose((joined - moved)[seen], (plain - noisy)[seen], atol=1e-6)
    if method in ("lerp", "spline", "ebd"):  # gap fillers keep observed samples bit for bit
        np.testing.assert_array_equal(joined[seen], moved[seen])


def test_join_gaps_moves_only_runs_after_a_gap_that_hides_a_wrap():
    t = np.arange(40, dtype=np.float64)
    truth = 160.0 + 2.0 * t  # 160 … 238, stored wrapped: it crosses +180 at t = 10
    stored = wrap_deg(truth)[:, None]
    mask = np.zeros_like(stored, dtype=bool)
    mask[5:15] = True
    for fill in (lerp_fill, spline_fill):
        out = fill(stored, mask, 360.0)
        np.testing.assert_allclose(out[5:15, 0], truth[5:15])  # the branch of frame 4: 170 … 188, through 180
        np.testing.assert_array_equal(out[~mask[:, 0]], stored[~mask[:, 0]])
        assert np.abs(wrap_deg(fill(stored, mask)[5:15, 0] - truth[5:15])).max() > 90  # without: through 0
    joined, offsets = join_gaps(stored, mask)
    np.testing.assert_allclose(joined[~mask[:, 0], 0], truth[~mask[:, 0]])
    np.testing.assert_array_equal(offsets[:15, 0], 0.0)
    np.testing.assert_array_equal(offsets[15:, 0], -360.0)
    # inside an observed run nothing is unwrapped, however large the step (the reader unwrapped the file)
    jumpy = stored.copy()
    jumpy[20:] += 300.0  # a step of 300° between observed frames 19 and 20, after the gap
    joined_jumpy = join_gaps(jumpy, mask)[0]
    np.testing.assert_allclose(joined_jumpy[20, 0] - joined_jumpy[19, 0], jumpy[20, 0] - jumpy[19, 0])
    np.testing.assert_allclose(
        joined_jumpy[~mask[:, 0], 0], joined[~mask[:, 0], 0] + np.where(t >= 20, 300.0, 0.0)[~mask[:, 0]]
    )
    # a gap whose edges differ by less than WRAP_STEP is motion, not a wrap
    swing = np.concatenate([np.zeros(5), np.full(35, 200.0)])[:, None]
    np.testing.assert_array_equal(join_gaps(swing, mask)[1], 0.0)


def test_knn_gives_the_same_fill_whatever_branch_the_run_after_a_gap_is_on(cmu):
    """kNN joins a gap that hides a wrap before it searches (its features come from the filled base): the same
    angles with the run after the gap one branch up give the same fill, observed samples kept bit for bit."""
    parts = [Motion(cmu.skeleton, cmu.channels[a : a + 400], cmu.fps, f"part{a}") for a in (0, 900, 1800)]
    truth = parts[1]
    db = SkeletonDatabase.from_motions(parts)
    noisy, mask = corrupt_motion(truth, "segment-gap:left-arm:1", np.random.default_rng(0))
    cols = np.flatnonzero(mask.any(axis=0))
    _, end = runs(mask[:, cols[0]])[0]
    moved = noisy.copy()
    moved[end:, cols] += 360.0
    plain = fill_angles(truth.with_channels(noisy), mask, db)[0]
    joined = fill_angles(truth.with_channels(moved), mask, db)[0]
    scored = truth.skeleton.scored_mask
    np.testing.assert_allclose(wrap_deg(joined - plain)[:, scored], 0.0, atol=1e-6)
    np.testing.assert_array_equal(joined[~mask], moved[~mask])


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
