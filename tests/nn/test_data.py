"""Training crops: every training corruption, spatial noise through IK residuals, whole-limb gaps, time warping."""

from __future__ import annotations

import numpy as np
import pytest

from mocapnet.corrupt import window_gap_mask
from mocapnet.fill import runs
from mocapnet.motion import Motion
from mocapnet.nn.data import MotionDataModule, corrupt_window, resample, segment_gap_mask, spatial_level


@pytest.fixture(scope="module")
def module() -> MotionDataModule:
    corruptions = ("none", "angular-0.3", "uniform-0.5", "spatial-1cm", "bias-sine", "segment-gaps", "gaps-long")
    dm = MotionDataModule(corpus="sample", corruptions=corruptions, time_warp=(0.8, 1.25), batch_size=4)
    dm.setup()
    return dm


def test_every_training_corruption_gives_a_crop_and_mask(module: MotionDataModule):
    clip = module.train_clips[0]
    crop = clip.scored[:100].astype(np.float64)
    rng = np.random.default_rng(0)
    spatial = module.spatial[1.0][0][:100]
    for name in ("none", "angular-0.7", "uniform-0.5", "spatial-1cm", "bias-const", "bias-sine", "gaps",
                 "gaps-long", "noise+gaps", "segment-gaps", "noise+segment-gaps"):  # fmt: skip
        noisy, mask = corrupt_window(
            crop, clip.sigma, module.joint_of_channel, 120.0, name, rng, spatial, module.segments
        )
        assert noisy.shape == crop.shape == mask.shape and np.isfinite(noisy).all(), name
        assert mask.any() == ("gaps" in name), name
        assert (np.abs(noisy - crop).max() > 0) == (name not in ("none", "gaps", "gaps-long", "segment-gaps")), name
    with pytest.raises(ValueError, match="not supported"):
        corrupt_window(crop, clip.sigma, module.joint_of_channel, 120.0, "zigzag", rng)
    with pytest.raises(ValueError, match="IK residual"):
        corrupt_window(crop, clip.sigma, module.joint_of_channel, 120.0, "spatial-1cm", rng)
    assert spatial_level("spatial-0.5cm") == 0.5 and spatial_level("angular-0.5") is None


def test_spatial_residual_is_what_ik_does_to_joint_noise(module: MotionDataModule, sample: Motion):
    unit = module.spatial[1.0][0]
    assert unit.shape == module.train_clips[0].scored.shape
    assert 0.1 < float(np.median(np.abs(unit))) < 20.0  # degrees for 1 cm of joint noise


def test_segment_gap_removes_one_whole_limb_for_one_run(module: MotionDataModule):
    rng = np.random.default_rng(3)
    n_joints = int(module.joint_of_channel.max()) + 1
    for _ in range(20):
        mask = segment_gap_mask(200, module.segments, n_joints, 120.0, rng)
        missing = np.flatnonzero(mask.any(axis=0))
        assert any(set(missing) == set(limb) for limb in module.segments)
        assert len(runs(mask[:, missing[0]])) == 1 and not mask[0].any() and not mask[-1].any()
        assert (mask[:, missing] == mask[:, missing[:1]]).all()


def test_segment_gap_places_its_run_as_window_gap_mask_does(module: MotionDataModule):
    """After its limb and length draws, the same rng stream gives the mask of ``corrupt.window_gap_mask`` with
    one visible frame on each side."""
    n_joints = int(module.joint_of_channel.max()) + 1
    for seed in range(40):
        got = segment_gap_mask(200, module.segments, n_joints, 120.0, np.random.default_rng(seed))
        rng = np.random.default_rng(seed)
        limb = module.segments[int(rng.integers(len(module.segments)))]
        length = int(np.clip(round(rng.uniform(0.1, 5.0) * 120.0), 1, 198))
        want = window_gap_mask(200, list(limb), n_joints, length / 120.0, 120.0, rng, margin_s=1 / 120.0)
        np.testing.assert_array_equal(got, want)


def test_time_warped_batches(module: MotionDataModule):
    x = np.arange(20.0)[:, None] * np.array([[1.0, -2.0]])
    np.testing.assert_allclose(resample(x, np.array([0.0, 3.0, 19.0])), x[[0, 3, 19]])
    np.testing.assert_allclose(resample(x, np.array([2.5])), [[2.5, -5.0]])
    rng = np.random.default_rng(0)
    for _ in range(10):
        batch = module.sample_batch(rng)
        n = batch["clean"].shape[1]
        assert batch["filled"].shape == batch["mask"].shape == (4, n, module.n_channels)
        assert batch["angvel"].shape == (4, n, 3) and bool(batch["filled"].isfinite().all())


def test_mirror_adds_each_training_clip_mirrored_and_leaves_validation_alone(module: MotionDataModule):
    mirrored = MotionDataModule(
        corpus="sample", corruptions=("angular-0.3", "spatial-1cm"), mirror=True, batch_size=4, seed=1
    )
    mirrored.setup()
    names = [c.name for c in mirrored.train_clips]
    assert names == [c.name for c in module.train_clips] + [f"{c.name}#mirror" for c in module.train_clips]
    assert len(mirrored.spatial[1.0]) == len(names) and len(mirrored.val_batches) == len(module.val_batches)
    original, flipped = mirrored.train_clips
    labels = mirrored.channel_labels
    # CMU's frames are world-aligned: the right upper arm's Z rotation is the left one's, negated
    left, right = labels.index("LeftArm.Zrotation"), labels.index("RightArm.Zrotation")
    np.testing.assert_allclose(flipped.scored[:, right], -original.scored[:, left], atol=1e-4)
    batch = mirrored.sample_batch(np.random.default_rng(0))
    assert np.isfinite(batch["filled"].numpy()).all()


def _crop_module(workers: int, counter: int = 0) -> MotionDataModule:
    dm = MotionDataModule(corpus="sample", batch_size=2, steps_per_epoch=5, num_workers=workers)
    dm.setup()
    dm.load_state_dict({"epoch_counter": counter})
    return dm


def _epoch(dm: MotionDataModule) -> list[np.ndarray]:
    return [batch["filled"].numpy() for batch in dm.train_dataloader()]


@pytest.mark.parametrize("workers", [0, 2])
def test_training_batches_are_reproducible_per_epoch_and_resume(workers: int):
    """Each epoch draws ``steps_per_epoch`` batches from ``(seed, rank, epoch[, workers, worker])``: the same
    for a fresh module, other ones next epoch, and a module resumed at epoch 1 draws epoch 1's; with workers
    the batches are shared out among them (and differ from the single-process stream)."""
    dm = _crop_module(workers)
    unread = iter(dm.train_dataloader())  # Lightning may make an iterator it never reads: no epoch spent
    assert dm.state_dict() == {"epoch_counter": 0}
    del unread
    first, second = _epoch(dm), _epoch(dm)
    assert len(first) == len(second) == 5 and dm.state_dict() == {"epoch_counter": 2}
    assert not any(np.array_equal(a, b) for a, b in zip(first, second))
    for a, b in zip(first, _epoch(_crop_module(workers))):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(second, _epoch(_crop_module(workers, counter=1))):
        np.testing.assert_array_equal(a, b)
    if workers:
        assert not any(np.array_equal(a, b) for a, b in zip(first, _epoch(_crop_module(0))))
    with pytest.raises(ValueError, match="num_workers"):
        MotionDataModule(corpus="sample", num_workers=-1)


def _limb_module(**kw) -> MotionDataModule:
    kw = {"corruptions": ("spatial-1cm",), "limb_mix": 1.0, **kw}
    dm = MotionDataModule(corpus="sample", mirror=True, batch_size=2, **kw)
    dm.setup()
    return dm


def test_limb_mixing_takes_one_limb_from_another_clip_crop():
    """``limb_from_another_clip``: exactly one limb's channels change, to the other clip's channels at the given
    (fractional, time-warped) frames, with that clip's sigma, centre and scale and spatial residual rows; the rest
    and the root's angular-velocity scale stay the crop's own; the inputs are not changed."""
    from mocapnet.nn.data import resample

    dm = _limb_module()
    length, rate = 40, 1.13
    offsets = np.arange(length) * rate
    need = int(np.ceil((length - 1) * rate)) + 1
    spans = np.maximum(dm.lengths - need + 1, 0).astype(np.float64)
    crop = np.full((length, dm.n_channels), 1000.0)
    sigma = np.full(dm.n_channels, -1.0)
    norm = dm.clip_norms[0]
    spatial = np.zeros((length, dm.n_channels))
    rng = np.random.default_rng(5)
    mixed, mixed_sigma, mixed_norm, mixed_spatial = dm.limb_from_another_clip(
        0, crop, sigma, norm, spatial, 1.0, spans, offsets, np.random.default_rng(5)
    )
    assert (crop == 1000.0).all() and (sigma == -1.0).all() and not spatial.any()  # inputs untouched
    changed = (mixed != 1000.0).any(axis=0)
    assert any(np.array_equal(changed, np.isin(dm.joint_of_channel, limb)) for limb in dm.segments)
    # the same draws as the method: the other clip (never clip 0 itself: clip 1, its mirror, has room), its start
    weights = spans.copy()
    weights[0] = 0.0
    j = int(rng.choice(len(dm.train_clips), p=weights / weights.sum()))
    assert j == 1
    positions = np.minimum(int(rng.integers(0, spans[j])) + offsets, len(dm.train_clips[j].scored) - 1)
    expected = resample(dm.train_clips[j].scored.astype(np.float64), positions)
    np.testing.assert_allclose(mixed[:, changed], expected[:, changed], atol=1e-9)
    np.testing.assert_array_equal(mixed_sigma[changed], dm.train_clips[j].sigma[changed])
    assert (mixed_sigma[~changed] == -1.0).all()
    for field in ("center", "scale"):
        np.testing.assert_array_equal(getattr(mixed_norm, field)[changed], getattr(dm.clip_norms[j], field)[changed])
        np.testing.assert_array_equal(getattr(mixed_norm, field)[~changed], getattr(norm, field)[~changed])
    np.testing.assert_array_equal(mixed_norm.angvel_scale, norm.angvel_scale)
    rows = np.round(positions).astype(np.int64)
    np.testing.assert_array_equal(mixed_spatial[:, changed], dm.spatial[1.0][j][rows][:, changed])
    assert not mixed_spatial[:, ~changed].any()


def test_sample_batch_feeds_the_mixed_crop_and_its_statistics(monkeypatch):
    """With ``limb_mix=1`` every crop of a batch is the mixed one and carries the mixed clip statistics (its scale:
    the mixed clip's, widened by the crop's noise, ``crop_statistics``)."""
    from mocapnet.nn.data import crop_statistics

    dm = _limb_module(time_warp=(0.8, 1.25))
    made = []
    original = dm.limb_from_another_clip

    def recording(*args):
        out = original(*args)
        made.append(out)
        return out

    monkeypatch.setattr(dm, "limb_from_another_clip", recording)
    batch = dm.sample_batch(np.random.default_rng(2))
    assert len(made) == 2
    for b, (crop, _, norm, _) in enumerate(made):
        np.testing.assert_allclose(batch["clean"][b].numpy(), crop, atol=1e-3)
        rate = float(batch["angvel_scale"][b, 0, 0] / dm.clip_norms[0].angvel_scale[0])  # both crops: clip 0 or 1
        stats = crop_statistics(norm, crop, batch["filled"][b].numpy().astype(np.float64), rate)
        np.testing.assert_allclose(batch["scale"][b].numpy(), stats["scale"], rtol=1e-4)
    off = MotionDataModule(corpus="sample", mirror=True, batch_size=2, limb_mix=0.0)
    off.setup()
    monkeypatch.setattr(off, "limb_from_another_clip", lambda *a: pytest.fail("limb_mix=0 must not mix"))
    assert np.isfinite(off.sample_batch(np.random.default_rng(2))["filled"].numpy()).all()


def test_limb_mix_is_checked():
    for bad in (-0.1, 1.5, True, "half"):
        with pytest.raises(ValueError, match="limb_mix must be a probability"):
            MotionDataModule(corpus="sample", limb_mix=bad)
    cases = [
        ((), 1.0, "is empty; give names from the training corruptions \\(gaps\\), or null"),
        (("gaps-long",), 1.0, "gaps-long not among the training corruptions \\(gaps\\)"),
        ("gaps", 1.0, "must be a list of names, e.g. '\\[gaps\\]'"),
        (("gaps",), 0.0, "limb_mix is 0"),
    ]
    for names, prob, message in cases:
        with pytest.raises(ValueError, match=message):
            MotionDataModule(corpus="sample", corruptions=("gaps", "gaps"), limb_mix=prob, limb_mix_corruptions=names)


def test_limb_mix_corruptions_naming_every_corruption_draws_as_the_default():
    """Listing every training corruption mixes as the default (None) does, with the same random draws."""
    corruptions = ("gaps", "angular-0.5")
    default = _limb_module(corruptions=corruptions, limb_mix=0.5)
    listed = _limb_module(corruptions=corruptions, limb_mix=0.5, limb_mix_corruptions=corruptions)
    for a, b in zip(_batches(default), _batches(listed)):
        for key in a:
            np.testing.assert_array_equal(a[key].numpy(), b[key].numpy())


def _batches(dm: MotionDataModule, n: int = 3) -> list[dict]:
    rng = np.random.default_rng(4)
    return [dm.sample_batch(rng) for _ in range(n)]


def test_limb_mix_corruptions_mixes_only_those_crops(monkeypatch):
    """``limb_mix_corruptions``: crops drawn with a listed corruption are mixed (with ``limb_mix=1``, every one),
    the others never; each crop's corruption is the one ``sample_batch`` drew for it."""
    from mocapnet.nn import data as data_module

    dm = _limb_module(corruptions=("gaps", "angular-0.5"), limb_mix_corruptions=("gaps",))
    drawn, mixed = [], []
    corrupt = data_module.corrupt_window
    original = dm.limb_from_another_clip

    def recording_corrupt(clean, sigma, joints, fps, corruption, *rest):
        drawn.append(corruption)
        return corrupt(clean, sigma, joints, fps, corruption, *rest)

    def recording_mix(*args):
        mixed.append(len(drawn))  # the crop about to be corrupted
        return original(*args)

    monkeypatch.setattr(data_module, "corrupt_window", recording_corrupt)
    monkeypatch.setattr(dm, "limb_from_another_clip", recording_mix)
    rng = np.random.default_rng(3)
    for _ in range(6):
        dm.sample_batch(rng)
    assert set(drawn) == {"gaps", "angular-0.5"}
    assert mixed == [i for i, c in enumerate(drawn) if c == "gaps"]
