"""Streaming EBF (``mocapnet.nn.stream``): ``EBFStream`` equals windowed mode (tiny and shipped networks, fixed
and running clip statistics), ``EBFStreams`` equals separate streams, the running statistics and their refresh
schedule, and clear errors on bad frames."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mocapnet.nn import onnx_kernel
from mocapnet.nn.base import clip_statistics
from mocapnet.nn.features import ClipArrays, Normaliser, root_angular_velocity, scored_index
from mocapnet.nn.infer import clean_channels, load_model
from mocapnet.nn.stream import EBFStream, EBFStreams, RunningStats, _stats_due

#: Both kernels of the steady state; ONNX Runtime only where the optional packages are installed.
BACKENDS = [
    "numpy",
    pytest.param("onnx", marks=pytest.mark.skipif(not onnx_kernel.available(), reason="onnx/onnxruntime absent")),
]


def _varied(model):
    """``model`` in eval mode; a free kernel's head made to give kernels that differ from frame to frame."""
    if model.hparams.filter_shape == "free":
        with torch.no_grad():
            model.head[-1].weight.normal_(0.0, 0.3)
    return model.eval()


def _run(stream, clip: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """Every ``(frame index, channels)`` a stream gives for ``clip [T, C]``, the flush included."""
    return [item for frame in clip for item in stream.push(frame)] + stream.flush()


def _windowed(model, clip: np.ndarray, sample) -> np.ndarray:
    """Windowed mode on the whole clip ``[T, C]`` (whole-clip statistics for a clip-normalised network; no
    self-check)."""
    mask = np.zeros(clip.shape, bool)
    return clean_channels(model, clip, mask, sample.skeleton, sample.fps, "windowed", change_limit=0.0)


def _clip_stats(clip: np.ndarray, sample) -> tuple[np.ndarray, ...]:
    """``clip_statistics`` of a clip ``[T, C]`` as numpy ``(center, scale, angvel_scale)``."""
    x = torch.as_tensor(clip[:, scored_index(sample.skeleton)], dtype=torch.float32)
    w = torch.as_tensor(root_angular_velocity(sample.skeleton, clip, sample.fps), dtype=torch.float32)
    return tuple(v[0, 0].numpy() for v in clip_statistics(x[None], w[None]).values())


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(
    "kind, length", [("ebf-bias", 12), ("ebf-bias", 31), ("ebf-bias", 75), ("ebf", 75), ("ebf-free", 75)]
)
def test_stream_matches_windowed_mode(kind, length, backend, sample, tiny):
    model = _varied(tiny(kind, sample))
    clip = sample.channels[300 : 300 + length]
    got = _run(EBFStream(model, sample.skeleton, sample.fps, backend=backend), clip)
    assert [i for i, _ in got] == list(range(length))
    np.testing.assert_allclose(np.stack([f for _, f in got]), _windowed(model, clip, sample), atol=1e-4)


@pytest.mark.parametrize("backend", BACKENDS)
def test_shipped_ebf_streams_as_windowed_mode(backend, sample):
    """The kernels with the shipped CMU network's weights (the steady state of 120 frames)."""
    from mocapnet.nn.checkpoints import shipped_checkpoint

    model = load_model(shipped_checkpoint("ebf", sample.skeleton))
    clip = sample.channels[1000:1120]
    got = np.stack([f for _, f in _run(EBFStream(model, sample.skeleton, sample.fps, backend=backend), clip)])
    np.testing.assert_allclose(got, _windowed(model, clip, sample), atol=1e-3)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("length", [20, 80])
@pytest.mark.parametrize(
    "kind, norm, sincos",
    [("ebf-free", "clip", False), ("ebf-free", "both", False), ("ebf-bias", "both", False), ("ebf-free", "both", True)],
)
def test_stream_with_fixed_statistics_matches_windowed_mode(kind, norm, sincos, length, backend, sample, tiny):
    """Given the whole clip's statistics, a clip-normalised stream (``norm="both"``: beside the corpus-normalised
    inputs; the bias in the clip's scales; ``sincos``: the angles' sine and cosine as inputs too) is windowed mode
    on the whole clip."""
    model = _varied(tiny(kind, sample, norm=norm, sincos=sincos))
    clip = sample.channels[300 : 300 + length]
    stats = _clip_stats(clip, sample)
    got = _run(EBFStream(model, sample.skeleton, sample.fps, stats=stats, backend=backend), clip)
    assert [i for i, _ in got] == list(range(length))
    np.testing.assert_allclose(np.stack([f for _, f in got]), _windowed(model, clip, sample), atol=1e-3)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("norm", ["clip", "both"])
def test_stream_with_running_statistics(norm, backend, sample, tiny):
    """Without given statistics the stream uses those of what it has seen: on a stream no longer than one
    window every frame comes out at the flush, with the whole clip's statistics (= windowed mode); on a longer
    one the early frames differ (fewer frames seen) but stay close."""
    model = _varied(tiny("ebf-free", sample, norm=norm))
    for length, tol in ((25, 1e-3), (200, None)):
        clip = sample.channels[300 : 300 + length]
        expected = _windowed(model, clip, sample)
        got = np.stack([f for _, f in _run(EBFStream(model, sample.skeleton, sample.fps, backend=backend), clip)])
        assert np.isfinite(got).all()
        if tol:
            np.testing.assert_allclose(got, expected, atol=tol)
        else:
            idx = scored_index(sample.skeleton)
            spread = np.abs(clip[:, idx] - clip[:, idx].mean(0)).max()
            assert np.abs(got - expected).max() < 0.5 * spread


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("norm", ["clip", "both"])
def test_kernel_follows_the_running_statistics(norm, backend, sample, tiny):
    """With running statistics the kernel's centre frame is the torch modules' on the same window and
    statistics: at every frame for ONNX Runtime (it normalises the whole window each time), at every refresh
    for numpy (which recomputes the window's layer-1 inputs then)."""
    model = _varied(tiny("ebf-free", sample, norm=norm))
    stream = EBFStream(model, sample.skeleton, sample.fps, backend=backend)
    compared = 0
    clip = _noisy(sample, 300, 130)
    clip[:, scored_index(sample.skeleton)] += np.linspace(0.0, 40.0, len(clip))[:, None]  # statistics that drift
    for frame in clip:
        got = stream.push(frame)
        if stream.count > stream.width and (backend == "onnx" or _stats_due(stream.count, stream.width)):
            np.testing.assert_allclose(got[0][1], stream._emit([stream.half])[0][1], atol=1e-4)
            compared += 1
    assert compared == (130 - stream.width if backend == "onnx" else 2)  # numpy: the refreshes at 62 and 124


def test_running_statistics_and_refresh_schedule(sample):
    clip = ClipArrays.from_motion(sample)
    running = RunningStats(clip.scored.shape[1])
    for row, w in zip(clip.scored[:400].astype(np.float64), clip.angvel[:400]):
        running.add(row)
        running.add_angvel(w)
    center, scale, angvel_scale = running.stats()
    norm = Normaliser.fit([clip.scored[:400]], [clip.angvel[:400]])
    np.testing.assert_allclose(center, norm.center, atol=1e-3)
    np.testing.assert_allclose(scale, norm.scale, rtol=1e-3)
    np.testing.assert_allclose(angvel_scale, norm.angvel_scale, rtol=1e-4)
    due = [n for n in range(1, 3000) if _stats_due(n, 31)]
    assert due == [31, 62, 124, 248, 496, 992, 1024, 2048]


@pytest.mark.parametrize("kind, norm", [("ebf-free", "corpus"), ("ebf-bias", "clip"), ("ebf-bias", "both")])
def test_streams_in_lockstep_equal_separate_streams(kind, norm, sample, tiny):
    """Three clips through one ``EBFStreams`` give what three ``EBFStream`` s give; with a clip-normalised
    bias network each stream keeps its own statistics (and bias unit)."""
    model = _varied(tiny(kind, sample, norm=norm))
    clips = [sample.channels[s : s + 70] for s in (0, 900, 2000)]
    stats = [_clip_stats(c, sample) for c in clips] if norm != "corpus" else None
    streams = EBFStreams(model, sample.skeleton, sample.fps, len(clips), stats)
    together: list[list] = [[] for _ in clips]
    for frames in zip(*clips):
        for out, got in zip(together, streams.push(np.stack(frames))):
            out += got
    for out, got in zip(together, streams.flush()):
        out += got
    for i, clip in enumerate(clips):
        alone = _run(EBFStream(model, sample.skeleton, sample.fps, stats[i] if stats else None), clip)
        assert [k for k, _ in together[i]] == [k for k, _ in alone] == list(range(len(clip)))
        np.testing.assert_allclose(np.stack([f for _, f in together[i]]), np.stack([f for _, f in alone]), atol=1e-4)


def test_bad_frames_are_refused_naming_the_frame(sample, tiny):
    stream = EBFStream(_varied(tiny("ebf", sample)), sample.skeleton, sample.fps)
    stream.push(sample.channels[0])
    with pytest.raises(ValueError, match="frame 1: expected"):
        stream.push(sample.channels[1, :-1])
    bad = sample.channels[1].copy()
    bad[5] = np.nan
    with pytest.raises(ValueError, match="frame 1: .*NaN"):
        stream.push(bad)
    streams = EBFStreams(_varied(tiny("ebf", sample)), sample.skeleton, sample.fps, 2)
    with pytest.raises(ValueError, match=r"expected frames \[2, C\]"):
        streams.push(sample.channels[:3])


def test_backend_choice(sample, tiny, monkeypatch):
    model = _varied(tiny("ebf", sample))
    with pytest.raises(ValueError, match="backend must be one of"):
        EBFStream(model, sample.skeleton, sample.fps, backend="torch")
    monkeypatch.setattr(onnx_kernel, "available", lambda: False)
    with pytest.raises(ValueError, match="optional packages onnx and onnxruntime"):
        EBFStream(model, sample.skeleton, sample.fps, backend="onnx")
    auto = EBFStream(model, sample.skeleton, sample.fps)  # falls back to numpy
    assert auto._onnx is None and auto._kernel is not None


def _noisy(sample, start: int, length: int) -> np.ndarray:
    """``length`` frames of the sample clip with white noise (σ 1°) on the scored channels."""
    clip = sample.channels[start : start + length].copy()
    idx = scored_index(sample.skeleton)
    clip[:, idx] += np.random.default_rng(0).normal(0.0, 1.0, (length, len(idx)))
    return clip


@pytest.mark.parametrize("backend", BACKENDS)
def test_self_check_on_one_window_is_the_offline_one(backend, sample, tiny):
    """A stream no longer than one window returns every frame at the flush with the whole clip's noise level
    and RMS change: exactly ``limit_change`` of windowed mode."""
    model = _varied(tiny("ebf-free", sample))
    clip = _noisy(sample, 300, 25)
    got = np.stack(
        [f for _, f in _run(EBFStream(model, sample.skeleton, sample.fps, backend=backend, change_limit=0.5), clip)]
    )
    mask = np.zeros(clip.shape, bool)
    offline = clean_channels(model, clip, mask, sample.skeleton, sample.fps, "windowed", change_limit=0.5)
    assert np.abs(offline - _windowed(model, clip, sample)).max() > 0.1  # the check binds
    np.testing.assert_allclose(got, offline, atol=1e-4)


def test_running_self_check_follows_the_offline_one(sample, tiny):
    """On a longer stream the caps come from the frames seen so far: closer to the offline self-check than the
    unchecked stream is, and with the checkpoint's factor by default."""
    model = _varied(tiny("ebf-free", sample, change_limit=0.5))
    clip = _noisy(sample, 300, 300)
    mask = np.zeros(clip.shape, bool)
    offline = clean_channels(model, clip, mask, sample.skeleton, sample.fps, "windowed")  # the checkpoint's 0.5
    stream = EBFStream(model, sample.skeleton, sample.fps)
    assert stream.check is not None and stream.check.factor == 0.5
    checked = np.stack([f for _, f in _run(stream, clip)])
    plain = np.stack([f for _, f in _run(EBFStream(model, sample.skeleton, sample.fps, change_limit=0.0), clip)])
    assert np.abs(checked - offline).mean() < 0.5 * np.abs(plain - offline).mean()
    with pytest.raises(ValueError, match="change_limit"):
        EBFStream(model, sample.skeleton, sample.fps, change_limit=-1.0)
