"""EBF, EBD and the NN ablation: shapes, overfitting one batch, checkpoint round trip, modes and streaming."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch

from mocapnet.nn import EBD, EBF, load_model
from mocapnet.nn.infer import clean_channels

KINDS = ("ebf", "ebf-bias", "ebf-free", "bf", "ebd", "nn")


@pytest.mark.parametrize("kind", KINDS)
def test_output_shape_and_gap_handling(kind, sample, tiny, batch):
    model = tiny(kind, sample).eval()
    with torch.no_grad():
        out = model.predict_batch(batch)
    assert out.shape == batch["clean"].shape and torch.isfinite(out).all()
    if kind == "ebd":  # observed samples pass through unchanged
        keep = ~batch["mask"]
        torch.testing.assert_close(out[keep], batch["filled"][keep])


def test_filter_weights_sum_to_one(sample, tiny, batch):
    for kind in ("ebf", "ebf-free"):
        model = tiny(kind, sample).eval()
        with torch.no_grad():
            params = model.filter_params(batch["filled"], batch["angvel"])
            w = model.filter_weights(params)
        assert w.shape == (2, batch["clean"].shape[-1], 40, 31)
        torch.testing.assert_close(w.sum(-1), torch.ones(w.shape[:-1]))


@pytest.mark.parametrize("kind", ("ebf-bias", "ebd"))
def test_tiny_model_overfits_one_batch(kind, sample, tiny, batch):
    model = tiny(kind, sample, dropout=0.0)
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    losses = []
    for _ in range(60):
        sq, sel = model.loss_terms(batch, model.predict_batch(batch))
        loss = (sq * sel).sum() / sel.sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0]


@pytest.mark.parametrize("cls,kind", ((EBF, "ebf-bias"), (EBD, "ebd")))
def test_load_from_checkpoint_gives_identical_outputs(cls, kind, sample, tiny, batch, tmp_path):
    model = tiny(kind, sample).eval()
    trainer = L.Trainer(logger=False, enable_checkpointing=False, enable_progress_bar=False, max_epochs=0)
    trainer.strategy.connect(model)
    path = tmp_path / "m.ckpt"
    trainer.save_checkpoint(path)
    loaded = cls.load_from_checkpoint(path, map_location="cpu").eval()
    with torch.no_grad():
        torch.testing.assert_close(loaded.predict_batch(batch), model.predict_batch(batch), rtol=0, atol=0)
    torch.testing.assert_close(loaded.center, model.center)
    assert type(load_model(path)) is cls


@pytest.mark.parametrize("kind,length", (("ebf", 31), ("ebf-free", 20), ("ebd", 110), ("nn", 50)))
def test_windowed_and_sequence_agree_within_one_window(kind, length, sample, tiny):
    model = tiny(kind, sample).eval()
    clip = sample.with_channels(sample.channels[500 : 500 + length])
    mask = np.zeros(clip.channels.shape, dtype=bool)
    mask[10:18, clip.skeleton.joint_channels(5)] = True
    noisy = clip.channels.copy()
    noisy[mask] = np.nan
    seq = clean_channels(model, noisy, mask, clip.skeleton, clip.fps, "sequence")
    win = clean_channels(model, noisy, mask, clip.skeleton, clip.fps, "windowed")
    np.testing.assert_allclose(win, seq, atol=1e-4)


def test_windowed_mode_is_local(sample, tiny):
    """In windowed mode frame t does not depend on frames beyond t ± 15 (away from the clip ends)."""
    model = tiny("ebf", sample).eval()
    clip = sample.channels[:200]
    no_mask = np.zeros(clip.shape, dtype=bool)
    base = clean_channels(model, clip, no_mask, sample.skeleton, sample.fps, "windowed")
    changed = clip.copy()
    changed[150:, sample.skeleton.scored_mask] += 30.0
    out = clean_channels(model, changed, no_mask, sample.skeleton, sample.fps, "windowed")
    np.testing.assert_allclose(out[:134], base[:134], atol=1e-4)
    assert np.abs(out[148] - base[148]).max() > 1e-3


@pytest.mark.parametrize("method", ["ebf", "ebd"])
def test_chunked_sequence_mode_matches_one_pass(method, sample):
    """Long clips run in overlapping chunks (O(T·C) memory); the shipped models give nearly the one-pass
    result on the sample clip (2,752 frames, 5+ chunks)."""
    from mocapnet.corrupt import corrupt_motion
    from mocapnet.fill import lerp_fill
    from mocapnet.nn.checkpoints import shipped_checkpoint
    from mocapnet.nn.features import root_angular_velocity, scored_index
    from mocapnet.nn.infer import predict_sequence

    model = load_model(shipped_checkpoint(method, sample.skeleton))
    noisy, mask = corrupt_motion(sample, "noise+gaps", np.random.default_rng(0))
    filled, idx = lerp_fill(noisy, mask), scored_index(sample.skeleton)
    angvel = root_angular_velocity(sample.skeleton, filled, sample.fps)
    batch = {
        "filled": torch.as_tensor(filled[:, idx], dtype=torch.float32)[None],
        "mask": torch.as_tensor(mask[:, idx])[None],
        "angvel": torch.as_tensor(angvel, dtype=torch.float32)[None],
    }
    with torch.inference_mode():
        diff = (predict_sequence(model, batch) - model.predict_batch(batch)[0]).abs()
    assert float(diff.max()) < 0.2 and float(diff.pow(2).mean().sqrt()) < 0.005


@pytest.mark.parametrize("kind,norm", [("ebf", "corpus"), ("ebf-bias", "clip"), ("ebf-free", "clip"), ("bf", "both")])
@pytest.mark.parametrize("chunk,overlap,per_group", [(1024, 128, 25), (200, 16, 3), (150, 15, 1)])
def test_ebf_chunked_sequence_mode_equals_running_every_window(kind, norm, chunk, overlap, per_group, sample, tiny):
    """EBF's long-clip path (encoder once per frame, LSTM on the windows, head and filter on the kept cores and
    the filter's ``half`` frames around each group) gives what the whole network gives window by window; the
    overlap may be as short as the filter's half (15 frames), and groups of one window join up too."""
    from mocapnet.nn.base import clip_statistics
    from mocapnet.nn.features import ClipArrays
    from mocapnet.nn.infer import chunk_starts, predict_windows

    model = tiny(kind, sample, norm=norm, sigma_init=6.0).eval()
    with torch.no_grad():  # wide filters that differ from frame to frame, so a frame off anywhere shows
        model.head[-1].weight.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(0))
    clip = ClipArrays.from_motion(sample)
    n = len(clip.scored) - 7  # the last core is a short one
    x = torch.as_tensor(clip.scored[:n] + 2.0 * np.sin(np.arange(n))[:, None], dtype=torch.float32)[None]
    w = torch.as_tensor(clip.angvel[:n], dtype=torch.float32)[None]
    batch = {"filled": x, "mask": torch.zeros_like(x, dtype=torch.bool), "angvel": w} | clip_statistics(x, w)
    starts, cores, width = chunk_starts(n, chunk, overlap)
    with torch.inference_mode():
        fast = model.predict_chunked(batch, starts, cores, width, per_group)
        every = predict_windows(model, batch, starts, cores, width, per_group)
    torch.testing.assert_close(fast, every, atol=1e-4, rtol=0)


def test_gaussian_ratio_loss_divides_each_crop_by_the_reference_gaussians_error(tiny, sample, batch):
    """``loss="gaussian_ratio"``: each crop's squared errors divided by the mean squared error of gaussian-58ms
    (at the model's fps) on that noisy crop plus ``RATIO_FLOOR_DEG``²; ``"samples"`` leaves them in degrees²."""
    from scipy.ndimage import gaussian_filter1d

    from mocapnet.nn.ebf import RATIO_FLOOR_DEG, RATIO_REFERENCE_S

    model = tiny("ebf-free", sample, loss="gaussian_ratio")
    assert not model.loss_in_degrees and tiny("ebf-free", sample).loss_in_degrees
    pred = batch["clean"] + 1.0
    sq, sel = model.loss_terms(batch, pred)
    plain, same = tiny("ebf-free", sample).loss_terms(batch, pred)
    assert sel.all() and same.all() and torch.allclose(plain, torch.ones_like(plain))
    sigma = RATIO_REFERENCE_S * sample.fps
    noisy, clean = batch["filled"].double().numpy(), batch["clean"].double().numpy()
    assert sigma * 4 > model.hparams.half  # the sample clip is at 120 fps: the filter's own taps would cut it short
    for b in range(len(noisy)):  # the reference: a Gaussian with edges padded by the nearest frame
        ref = gaussian_filter1d(noisy[b], sigma, axis=0, mode="nearest")  # gaussian-58ms: cut at 4 sigma
        expected = 1.0 / (float(((ref - clean[b]) ** 2).mean()) + RATIO_FLOOR_DEG**2)
        assert torch.allclose(sq[b], torch.full_like(sq[b], expected), rtol=1e-4)
    assert sq[0, 0, 0] != sq[1, 0, 0]  # one weight per crop
    with pytest.raises(ValueError, match="loss must be one of"):
        tiny("ebf", sample, loss="ratio")
    with pytest.raises(ValueError, match="fps"):
        tiny("ebf", sample, loss="gaussian_ratio", fps=0.0)
