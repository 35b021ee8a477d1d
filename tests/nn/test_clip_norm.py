"""Per-clip input normalisation (``model.norm=clip``): the statistics, the invariance it buys, training crops
normalised as their whole clip, chunked sequence mode and that corpus-normalised checkpoints behave as before
(streaming with clip statistics: test_stream.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mocapnet.corrupt import additive_noise
from mocapnet.kinematics import wrap_deg
from mocapnet.nn.base import NORM_KEYS, clip_statistics
from mocapnet.nn.data import as_batch, crop_statistics
from mocapnet.nn.features import ClipArrays, Normaliser, scored_index
from mocapnet.nn.infer import CHUNK, OVERLAP, clean_channels, predict_sequence
from mocapnet.selfcheck import limit_change, noise_level


def _clip_model(tiny, sample, kind="ebf-free", **overrides):
    model = tiny(kind, sample, norm="clip", **overrides).eval()
    if kind == "ebf-free":
        with torch.no_grad():
            model.head[-1].weight.normal_(0.0, 0.3)  # kernels that differ from frame to frame
    return model


def test_clip_statistics_are_the_normaliser_of_one_clip(sample):
    clip = ClipArrays.from_motion(sample)
    norm = Normaliser.fit([clip.scored], [clip.angvel])
    got = clip_statistics(torch.as_tensor(clip.scored, dtype=torch.float64), torch.as_tensor(clip.angvel))
    np.testing.assert_allclose(got["center"][0].numpy(), norm.center, atol=1e-3)
    np.testing.assert_allclose(got["scale"][0].numpy(), norm.scale, rtol=1e-3)
    np.testing.assert_allclose(got["angvel_scale"][0].numpy(), norm.angvel_scale, rtol=1e-5)


def test_clip_norm_output_follows_the_clips_amplitude(sample, tiny):
    """Scaling a clip's deviations from its centre by a (and its angular velocity by b) scales the cleaned
    deviations by a: the network sees the same inputs, and the filter is linear."""
    model = _clip_model(tiny, sample, kind="ebf-bias")
    clip = ClipArrays.from_motion(sample)
    x = torch.as_tensor(clip.scored[200:320])[None]
    w = torch.as_tensor(clip.angvel[200:320])[None]
    center = clip_statistics(x, w)["center"]
    with torch.no_grad():
        base = model(x, w)
        scaled = model(center + 0.5 * (x - center), 0.7 * w)
    torch.testing.assert_close(scaled, center + 0.5 * (base - center), atol=2e-3, rtol=1e-4)
    corpus = tiny("ebf-bias", sample).eval()
    with torch.no_grad():
        assert (
            float((corpus(center + 0.5 * (x - center), 0.7 * w) - center - 0.5 * (corpus(x, w) - center)).abs().max())
            > 1e-2
        )


def test_crop_statistics_match_the_whole_noisy_clip(sample):
    """A training crop is normalised as its whole clip, noise included, would be (within a few percent)."""
    clip = ClipArrays.from_motion(sample)
    norm = Normaliser.fit([clip.scored], [clip.angvel])
    clean = clip.scored.astype(np.float64)
    noisy = additive_noise("angular-0.9", clean, clip.sigma, sample.fps, np.random.default_rng(0))
    whole = clip_statistics(torch.as_tensor(noisy), torch.as_tensor(clip.angvel, dtype=torch.float64))
    crop = crop_statistics(norm, clean[500:531], noisy[500:531], 1.25)
    ratio = crop["scale"][0] / whole["scale"][0].numpy()
    assert abs(np.median(ratio) - 1.0) < 0.03 and ratio.min() > 0.7 and ratio.max() < 1.4
    np.testing.assert_allclose(crop["angvel_scale"][0], norm.angvel_scale * 1.25)
    batch = as_batch(noisy[None], np.zeros((1, *noisy.shape), bool), clean[None], clip.angvel[None])
    for key in NORM_KEYS:  # a batch without given statistics carries those of its whole clips
        torch.testing.assert_close(batch[key], whole[key].float()[None])


def test_chunked_sequence_mode_keeps_the_whole_clips_statistics(sample, tiny):
    model = _clip_model(tiny, sample)
    n = CHUNK + 2 * OVERLAP + 300
    clip = ClipArrays.from_motion(sample)
    x, w = torch.as_tensor(clip.scored[:n])[None], torch.as_tensor(clip.angvel[:n])[None]
    batch = {"filled": x, "mask": torch.zeros_like(x, dtype=torch.bool), "angvel": w} | clip_statistics(x, w)
    with torch.inference_mode():
        diff = (predict_sequence(model, batch) - model(x, w)[0]).abs()
    assert float(diff.max()) < 0.2 and float(diff.pow(2).mean().sqrt()) < 0.01


def test_corpus_normalised_models_ignore_clip_statistics(sample, tiny, batch):
    """norm=corpus (every checkpoint before this option) normalises with its buffers, whatever the batch holds."""
    model = tiny("ebf-bias", sample).eval()
    assert model.hparams.norm == "corpus"
    with torch.no_grad():
        plain = model(batch["filled"], batch["angvel"])
        other = {"center": torch.zeros(2, 1, 90), "scale": torch.ones(2, 1, 90), "angvel_scale": torch.ones(2, 1, 3)}
        torch.testing.assert_close(model.predict_batch(batch | other), plain)


def test_unknown_norm_and_bias_bound_are_refused(sample, tiny):
    with pytest.raises(ValueError, match="norm must be one of"):
        tiny("ebf", sample, norm="batch")
    with pytest.raises(ValueError, match="bias_bound"):
        tiny("ebf-bias", sample, bias_bound=0.0)


def test_noise_level_sees_white_noise_not_smooth_motion():
    t = np.arange(600) / 30.0
    motion = 40.0 * np.sin(2 * np.pi * 0.5 * t)[:, None] * np.ones((1, 3))
    noise = np.random.default_rng(0).standard_normal(motion.shape) * np.array([0.2, 1.0, 3.0])
    np.testing.assert_allclose(noise_level(motion + noise), [0.2, 1.0, 3.0], rtol=0.15)
    curvature = 1.4826 * 40.0 * (np.pi / 30.0) ** 2 / np.sqrt(6.0)  # MAD <= the largest second difference
    assert noise_level(motion).max() < curvature and noise_level(motion[:2]).tolist() == [0.0, 0.0, 0.0]


def test_limit_change_caps_each_channels_change_at_its_noise_level():
    rng = np.random.default_rng(1)
    noisy = np.cumsum(rng.standard_normal((300, 2)) * 0.1, axis=0) + rng.standard_normal((300, 2)) * 0.5
    cleaned = noisy.copy()
    cleaned[:, 0] = noisy[:, 0].mean()  # changes far more than the noise: pulled back
    cleaned[:, 1] += rng.standard_normal(300) * 0.1  # changes less: kept
    out = limit_change(noisy, cleaned, 1.5)
    rms = np.sqrt(np.mean((out - noisy) ** 2, axis=0))
    np.testing.assert_allclose(rms[0], 1.5 * noise_level(noisy)[0], rtol=1e-9)
    np.testing.assert_allclose(out[:, 1], cleaned[:, 1], atol=1e-12)


def test_clean_channels_applies_the_self_check_only_when_asked(sample, tiny):
    model = tiny("ebf-free", sample).eval()
    clip = sample.channels[:200]
    no_mask = np.zeros(clip.shape, bool)
    plain = clean_channels(model, clip, no_mask, sample.skeleton, sample.fps, change_limit=0.0)
    checked = clean_channels(model, clip, no_mask, sample.skeleton, sample.fps, change_limit=1.0)
    idx = scored_index(sample.skeleton)
    np.testing.assert_allclose(checked[:, idx], limit_change(clip[:, idx], plain[:, idx], 1.0), atol=1e-9)
    assert np.abs(checked - plain).max() > 1e-3


def test_the_checkpoints_change_limit_is_the_default(sample, tiny):
    clip = sample.channels[:200]
    no_mask = np.zeros(clip.shape, bool)
    checked = tiny("ebf-free", sample, change_limit=1.0).eval()
    plain = tiny("ebf-free", sample).eval()
    plain.load_state_dict(checked.state_dict())
    by_default = clean_channels(checked, clip, no_mask, sample.skeleton, sample.fps)
    asked = clean_channels(plain, clip, no_mask, sample.skeleton, sample.fps, change_limit=1.0)
    np.testing.assert_allclose(by_default, asked, atol=1e-9)
    with pytest.raises(ValueError, match="change_limit"):
        tiny("ebf", sample, change_limit=-1.0)


def test_wrap_deg_is_the_same_formula_on_tensors_and_arrays():
    x = (np.random.default_rng(0).normal(0.0, 400.0, 1000) * np.repeat([1.0, 1e-6, 1e4, 1.0], 250)).astype(np.float32)
    x[:4] = [180.0, -180.0, 540.0, -0.0]
    t = wrap_deg(torch.from_numpy(x))
    assert t.dtype == torch.float32
    np.testing.assert_array_equal(t.numpy(), wrap_deg(x))
    np.testing.assert_array_equal(t.numpy(), (torch.remainder(torch.from_numpy(x) + 180.0, 360.0) - 180.0).numpy())


def test_norm_both_feeds_corpus_then_clip_inputs_and_cleans(sample, tiny, batch, tmp_path):
    """``norm="both"``: the encoder input is the corpus-normalised features followed by the clip-normalised ones;
    it trains on batches with clip statistics and cleans a clip offline in both modes (streaming: test_stream.py)."""
    from mocapnet.nn.base import n_inputs

    both = tiny("ebf-free", sample, norm="both").eval()
    corpus, clip = tiny("ebf-free", sample), tiny("ebf-free", sample, norm="clip")
    n = batch["filled"].shape[-1]
    assert both.encoder[0].in_features == n_inputs(n, "both") == 2 * (n + 3)
    stats = clip_statistics(batch["filled"], batch["angvel"])
    features = both.features(batch["filled"], batch["angvel"], stats)
    torch.testing.assert_close(features[..., : n + 3], corpus.features(batch["filled"], batch["angvel"]))
    torch.testing.assert_close(features[..., n + 3 :], clip.features(batch["filled"], batch["angvel"], stats))
    both.train()
    loss = both.training_step(batch | stats, 0)
    loss.backward()
    assert torch.isfinite(loss) and both.encoder[0].weight.grad.abs().sum() > 0
    both.eval()
    noisy = sample.channels + np.random.default_rng(1).normal(0.0, 0.5, sample.channels.shape)
    mask = np.zeros(noisy.shape, dtype=bool)
    for mode in ("sequence", "windowed"):
        out = clean_channels(both, noisy, mask, sample.skeleton, sample.fps, mode)
        assert out.shape == noisy.shape and np.isfinite(out).all()
    with pytest.raises(ValueError, match="norm must be one of"):
        tiny("ebf-free", sample, norm="neither")


def _round_trip_cleans_alike(model, sample, path):
    """Save ``model`` as a checkpoint at ``path``, load it back, check both clean a noisy sample alike (finite, same
    shape) in both modes; return the loaded network."""
    from mocapnet.nn.infer import load_model

    model.eval()
    torch.save(
        {"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams), "mocapnet_model": "EBF"}, path
    )
    loaded = load_model(path)
    noisy = sample.channels + np.random.default_rng(1).normal(0.0, 0.5, sample.channels.shape)
    mask = np.zeros(noisy.shape, dtype=bool)
    for mode in ("sequence", "windowed"):
        out = clean_channels(model, noisy, mask, sample.skeleton, sample.fps, mode)
        np.testing.assert_allclose(clean_channels(loaded, noisy, mask, sample.skeleton, sample.fps, mode), out)
        assert out.shape == noisy.shape and np.isfinite(out).all()
    return loaded


@pytest.mark.parametrize("norm", ["corpus", "both"])
def test_sincos_appends_the_angles_sine_and_cosine_and_round_trips(sample, tiny, batch, norm, tmp_path):
    """``sincos=True``: the encoder input is the plain one followed by sin and cos of the raw angles (2C more
    columns, for any ``norm``); it trains, cleans in both modes and survives a checkpoint round trip."""
    from mocapnet.nn.base import n_inputs

    plain, model = tiny("ebf-free", sample, norm=norm), tiny("ebf-free", sample, norm=norm, sincos=True).eval()
    n = batch["filled"].shape[-1]
    assert model.encoder[0].in_features == n_inputs(n, norm, sincos=True) == n_inputs(n, norm) + 2 * n
    stats = clip_statistics(batch["filled"], batch["angvel"])
    features = model.features(batch["filled"], batch["angvel"], stats)
    width = n_inputs(n, norm)
    torch.testing.assert_close(features[..., :width], plain.features(batch["filled"], batch["angvel"], stats))
    rad = torch.deg2rad(batch["filled"])
    torch.testing.assert_close(features[..., width:], torch.cat([rad.sin(), rad.cos()], -1))
    model.train()
    loss = model.training_step(batch | stats, 0)
    loss.backward()
    assert torch.isfinite(loss) and model.encoder[0].weight.grad[:, width:].abs().sum() > 0
    assert _round_trip_cleans_alike(model, sample, tmp_path / "sincos.ckpt").hparams.sincos is True


@pytest.mark.parametrize("norm", ["clip", "both"])
def test_ebd_takes_clip_statistics_and_keeps_observed_samples(sample, tiny, batch, norm):
    """An EBD with ``norm`` clip or both: its input widens as EBF's does (plus the mask), the correction is in
    units of the clip's scale, it trains on batches with clip statistics, and cleaning changes only missing
    samples (sequence and windowed)."""
    from mocapnet.nn.base import n_inputs

    model = tiny("ebd", sample, norm=norm)
    n = batch["filled"].shape[-1]
    assert model.encoder[0].in_features == n_inputs(n, norm) + n
    with torch.no_grad():
        model.decoder[-1].bias.fill_(1.0)  # a correction of one scale everywhere
    stats = clip_statistics(batch["filled"], batch["angvel"])
    out = model.predict_batch(batch | stats)
    torch.testing.assert_close(out[batch["mask"]], (batch["filled"] + stats["scale"])[batch["mask"]])
    loss = model.training_step(batch | stats, 0)
    loss.backward()  # the decoder's last layer starts at zero, so the first gradient reaches only it
    assert torch.isfinite(loss) and model.decoder[-1].weight.grad.abs().sum() > 0
    model.eval()
    noisy = sample.channels.copy()
    mask = np.zeros(noisy.shape, dtype=bool)
    mask[200:230, scored_index(sample.skeleton)[:6]] = True
    noisy[mask] = np.nan
    for mode in ("sequence", "windowed"):
        cleaned = clean_channels(model, noisy, mask, sample.skeleton, sample.fps, mode)
        assert np.array_equal(cleaned[~mask], sample.channels[~mask]) and np.isfinite(cleaned).all()


@pytest.mark.parametrize("norm", ["clip", "both"])
def test_nn_ablation_takes_clip_statistics(sample, tiny, batch, norm):
    """The NN ablation with ``norm`` clip or both (EBF's recipe as it is): its input widens as EBF's does, its
    output follows a shift of the clip exactly (the clip's own centre; a corpus-normalised one does not), it trains
    on batches with clip statistics and cleans in both modes."""
    from mocapnet.nn.base import n_inputs

    model = tiny("nn", sample, norm=norm)
    n, k = batch["filled"].shape[-1], 2 * model.hparams.half + 1
    assert model.net[0].in_features == n_inputs(n, norm) * k
    with torch.no_grad():
        model.net[-1].bias.normal_(0.0, 0.1)  # the last layer starts at zero: make the output depend on the input
    model.eval()
    filled, angvel = batch["filled"], batch["angvel"]
    shift = torch.linspace(-5.0, 5.0, n)
    moved = model(filled + shift, angvel) - model(filled, angvel)
    if norm == "clip":
        torch.testing.assert_close(moved, shift.expand_as(moved), atol=1e-3, rtol=0)
    corpus = tiny("nn", sample).eval()
    with torch.no_grad():
        corpus.net[-1].bias.copy_(model.net[-1].bias)
    assert not torch.allclose(corpus(filled + shift, angvel) - corpus(filled, angvel), shift.expand_as(moved), atol=0.1)
    model.train()
    loss = model.training_step(batch | clip_statistics(filled, angvel), 0)
    loss.backward()
    assert torch.isfinite(loss) and model.net[-1].weight.grad.abs().sum() > 0
    model.eval()
    noisy = sample.channels[:300] + np.random.default_rng(0).normal(0.0, 1.0, sample.channels[:300].shape)
    no_gaps = np.zeros(noisy.shape, dtype=bool)
    for mode in ("sequence", "windowed"):
        assert np.isfinite(clean_channels(model, noisy, no_gaps, sample.skeleton, sample.fps, mode)).all()
    with pytest.raises(ValueError, match="norm"):
        tiny("nn", sample, norm="neither")


def test_frame_deltas_are_wrapped_central_differences_in_channel_scales():
    """A ramp of 3°/frame crossing ±180: first difference 3 (wrapped, not -357) ÷ scale inside, half that at the
    ends (the step beyond counts as 0); second difference 0 inside, ∓3 ÷ scale at the ends."""
    from mocapnet.nn.base import frame_deltas

    ramp = torch.as_tensor(wrap_deg(170.0 + 3.0 * np.arange(8.0)))[:, None]  # [T, 1], crosses +180
    got = frame_deltas(ramp, torch.tensor([2.0]))
    np.testing.assert_allclose(got[1:-1, 0].numpy(), 1.5)
    np.testing.assert_allclose(got[1:-1, 1].numpy(), 0.0, atol=1e-12)
    np.testing.assert_allclose(got[[0, -1], 0].numpy(), 0.75)
    np.testing.assert_allclose(got[[0, -1], 1].numpy(), [1.5, -1.5])
    assert float(frame_deltas(ramp * 0 + torch.arange(8.0)[:, None] * 100, torch.tensor([1.0])).max()) == 8.0


@pytest.mark.parametrize("deltas", ["add", "only"])
def test_delta_inputs_train_clean_round_trip_and_refuse_streaming(sample, tiny, batch, deltas, tmp_path):
    """``deltas="add"``: the plain input followed by ``frame_deltas`` (2C more columns); ``"only"``: the angular
    velocity and the deltas, no angle (pose-free: a clip shifted by a constant pose gives the same input). Either
    trains, cleans in both modes, survives a checkpoint round trip, and a stream refuses it by name."""
    from mocapnet.nn.base import frame_deltas, n_inputs
    from mocapnet.nn.stream import EBFStream

    n = batch["filled"].shape[-1]
    plain, model = tiny("ebf-free", sample, norm="clip"), tiny("ebf-free", sample, norm="clip", deltas=deltas).eval()
    stats = clip_statistics(batch["filled"], batch["angvel"])
    features = model.features(batch["filled"], batch["angvel"], stats)
    assert model.encoder[0].in_features == features.shape[-1] == n_inputs(n, "clip", deltas=deltas)
    expected = plain.features(batch["filled"], batch["angvel"], stats)
    if deltas == "only":
        expected = expected[..., n:]  # the angular velocity alone
        shifted = wrap_deg(batch["filled"] + torch.linspace(-90.0, 90.0, n))
        torch.testing.assert_close(model.features(shifted, batch["angvel"], stats), features, atol=2e-3, rtol=0)
    torch.testing.assert_close(features[..., : features.shape[-1] - 2 * n], expected)
    torch.testing.assert_close(features[..., -2 * n :], frame_deltas(batch["filled"], stats["scale"]))
    model.train()
    loss = model.training_step(batch | stats, 0)
    loss.backward()
    assert torch.isfinite(loss) and model.encoder[0].weight.grad[:, -2 * n :].abs().sum() > 0
    assert _round_trip_cleans_alike(model, sample, tmp_path / "deltas.ckpt").hparams.deltas == deltas
    with pytest.raises(ValueError, match="delta inputs"):
        EBFStream(model, sample.skeleton, sample.fps)
    with pytest.raises(ValueError, match="deltas must be one of"):
        tiny("ebf-free", sample, deltas="both")
    for pose in ({"norm": "both"}, {"sincos": True}):
        with pytest.raises(ValueError, match="pose-free"):
            tiny("ebf-free", sample, deltas="only", **pose)
