"""A file's rotations made continuous for cleaning and written back as it stores them (``mocapnet.branches``):
Euler flips near gimbal lock, wraps, and unchanged samples kept exactly."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapnet.branches import StoredBranches, flip_states, flip_triples, triple_columns
from mocapnet.clean import CleanOptions, clean_bvh_file
from mocapnet.io import read_bvh, write_bvh
from mocapnet.kinematics import euler_to_matrix, wrap_deg
from tests.io.test_bvh import GOOD


def geodesic_deg(a: np.ndarray, b: np.ndarray, seq: str) -> np.ndarray:
    """Angle (degrees) of the rotation between Euler triples ``a`` and ``b`` ``[T, 3]``."""
    rel = np.einsum("tji,tjk->tik", euler_to_matrix(a, seq), euler_to_matrix(b, seq))
    return np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)))


@pytest.mark.parametrize("seq", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_the_flipped_triple_is_the_same_rotation(seq):
    x = np.random.default_rng(0).uniform(-180.0, 180.0, (50, 3))
    np.testing.assert_allclose(euler_to_matrix(flip_triples(x), seq), euler_to_matrix(x, seq), atol=1e-12)


def canonical_flipping(cmu_short, seq_cols=None):
    """The CMU clip with one joint's rotation made to pass near gimbal lock and stored as canonical Euler angles
    (middle angle within ±90°, as scipy and many exporters give them): its stored triple flips where the smooth
    rotation crosses the lock. Returns (motion with the stored angles, joint's columns, order, true triples)."""
    sk = cmu_short.skeleton
    cols = triple_columns(sk)[5]
    seq = "".join(sk.channel_labels[c].split(".")[-1][0] for c in cols)
    t = np.arange(cmu_short.n_frames) / cmu_short.fps
    truth = np.stack([40.0 * np.sin(1.3 * t), 89.0 + 6.0 * np.sin(2.1 * t), 30.0 * np.cos(0.7 * t)], axis=1)
    stored = Rotation.from_matrix(euler_to_matrix(truth, seq)).as_euler(seq, degrees=True)
    channels = cmu_short.channels.copy()
    channels[:, cols] = stored
    return cmu_short.with_channels(channels), cols, seq, truth


def test_flip_states_follow_the_exporters_flips(cmu_short):
    motion, cols, seq, truth = canonical_flipping(cmu_short)
    stored = motion.channels[:, cols]
    jumps = np.abs(wrap_deg(np.diff(stored, axis=0))).sum(axis=1) > 180.0
    assert jumps.sum() >= 4  # the stored triple flips several times
    state = flip_states(stored, np.ones(len(stored), dtype=bool))
    assert (np.diff(state.astype(int)) != 0).sum() == jumps.sum()
    continuous = np.where(state[:, None], flip_triples(stored), stored)
    assert np.abs(wrap_deg(np.diff(continuous, axis=0))).sum(axis=1).max() < 20.0
    np.testing.assert_allclose(geodesic_deg(continuous, truth, seq), 0.0, atol=1e-4)  # arccos near 1


@pytest.mark.parametrize("method", ["gaussian-58ms", "gaussian-cv", "lerp"])
def test_clean_smooths_through_euler_flips_and_writes_the_files_branches(cmu_short, tmp_path, method):
    """Cleaning a file whose stored Euler triple flips near gimbal lock: the joint is smoothed as it moves (its
    rotation stays within a few degrees of the truth; channel by channel it was turned by up to 180°), and every
    sample the method leaves alone is written exactly as stored, the root included."""
    motion, cols, seq, truth = canonical_flipping(cmu_short)
    write_bvh(tmp_path / "in.bvh", motion)
    stored = read_bvh(tmp_path / "in.bvh", unwrap=False).channels
    mask = np.zeros(stored.shape, dtype=bool)
    mask[300:310, cols] = True
    np.save(tmp_path / "mask.npy", mask)
    options = CleanOptions(method=method, mask=str(tmp_path / "mask.npy") if method == "lerp" else None)
    clean_bvh_file(tmp_path / "in.bvh", tmp_path / "out.bvh", options)
    got = read_bvh(tmp_path / "out.bvh", unwrap=False).channels
    assert geodesic_deg(got[:, cols], truth, seq).max() < 3.0
    assert np.abs(got[:, cols[1]]).max() <= 90.0  # written as the exporter writes: the middle angle within ±90°
    scored = motion.skeleton.scored_mask
    np.testing.assert_array_equal(got[:, ~scored], stored[:, ~scored])  # the root and context joints, as stored
    if method == "lerp":
        np.testing.assert_array_equal(got[~mask], stored[~mask])
    rotation = motion.skeleton.rotation_mask
    assert got[:, rotation].min() >= -180.0 and got[:, rotation].max() <= 180.0  # the file's own range


def test_restore_inverts_of_and_keeps_a_continuously_stored_column(cmu_short):
    motion, cols, _, _ = canonical_flipping(cmu_short)
    stored = motion.channels.copy()
    stored[:, 10] = np.linspace(-20.0, 700.0, len(stored))  # a column stored continuously, far beyond one turn
    mask = np.zeros(stored.shape, dtype=bool)
    mask[100:160, [10, *cols]] = True
    branches, continuous = StoredBranches.of(stored, mask, motion.skeleton)
    np.testing.assert_array_equal(branches.restore(continuous)[~mask], stored[~mask])
    filled = continuous.copy()
    filled[mask] = np.nan
    from mocapnet.fill import lerp_fill

    out = branches.restore(lerp_fill(filled, mask))
    np.testing.assert_allclose(out[100:160, 10], stored[100:160, 10], atol=1e-9)  # the turn it stores, kept


LEG = GOOD  # a root and one ZXY leg joint


def test_a_flip_inside_a_gap_is_joined_from_the_observed_frames_not_the_placeholders(tmp_path):
    """The exporter flips the leg's triple inside a masked gap that holds zeros: the flipped run is joined to the
    last observed frame before the gap (a review found it read the placeholder there and filled a full turn)."""
    from mocapnet.io.bvh import parse_bvh

    t = np.arange(60)
    truth = np.stack([178.0 + 0.4 * (t - 25), 80.3 + 20.0 * t / 60, np.full(60, 20.0)], axis=1)  # X crosses 90
    stored = np.zeros((60, 9))
    stored[:, 6:9] = Rotation.from_matrix(euler_to_matrix(truth, "ZXY")).as_euler("ZXY", degrees=True)
    mask = np.zeros(stored.shape, dtype=bool)
    mask[25:35, 6:9] = True
    stored[mask] = 0.0
    motion = parse_bvh(LEG, "leg.bvh", cm_per_unit=1.0)
    write_bvh(tmp_path / "in.bvh", motion.with_channels(stored))
    np.save(tmp_path / "mask.npy", mask)
    clean_bvh_file(
        tmp_path / "in.bvh", tmp_path / "out.bvh", CleanOptions(method="lerp", mask=str(tmp_path / "mask.npy"))
    )
    got = read_bvh(tmp_path / "out.bvh", unwrap=False, cm_per_unit=1.0).channels
    assert geodesic_deg(got[:, 6:9], truth, "ZXY").max() < 1.0
    assert np.abs(got[:, 7]).max() <= 90.0  # the fill flips where the exporter would have
    np.testing.assert_array_equal(
        got[~mask], read_bvh(tmp_path / "in.bvh", unwrap=False, cm_per_unit=1.0).channels[~mask]
    )


def test_a_file_kept_within_0_to_360_keeps_every_column_there():
    """The range is the file's: in a 0-360 file a column observed only within [0, 10] gets a fill below 0 written
    as 359.8, not -0.2."""
    from mocapnet.io.bvh import parse_bvh

    skeleton = parse_bvh(LEG, "leg.bvh", cm_per_unit=1.0).skeleton
    stored = np.zeros((20, 9))
    stored[:, 3:6] = 200.0  # the root's rotations: the file's angles lie within [0, 360]
    stored[:, 6] = np.linspace(0.0, 10.0, 20)
    mask = np.zeros(stored.shape, dtype=bool)
    mask[8:12, 6] = True
    branches, continuous = StoredBranches.of(stored, mask, skeleton)
    cleaned = continuous.copy()
    cleaned[8:12, 6] = -0.2
    out = branches.restore(cleaned)
    np.testing.assert_allclose(out[8:12, 6], 359.8)
    np.testing.assert_array_equal(out[~mask], stored[~mask])


def test_a_joint_masked_in_every_frame_passes_through_without_a_warning():
    import warnings

    from mocapnet.io.bvh import parse_bvh

    skeleton = parse_bvh(LEG, "leg.bvh", cm_per_unit=1.0).skeleton
    stored = np.zeros((10, 9))
    mask = np.zeros(stored.shape, dtype=bool)
    mask[:, 6:9] = True
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # 'mocapnet clean' printed numpy's empty-mean warnings before its error
        branches, continuous = StoredBranches.of(stored, mask, skeleton)
        np.testing.assert_array_equal(branches.restore(continuous)[~mask], stored[~mask])
