"""The registry adapters of mocapnet.methods.neural (with tiny checkpoints)."""

from __future__ import annotations

from dataclasses import replace

import lightning as L
import numpy as np
import pytest

from mocapnet.corrupt import corrupt_motion
from mocapnet.methods.registry import build_method
from mocapnet.motion import Motion
from mocapnet.nn.checkpoints import read_index, shipped_checkpoint


def save(model, path) -> str:
    trainer = L.Trainer(logger=False, enable_checkpointing=False, enable_progress_bar=False, max_epochs=0)
    trainer.strategy.connect(model)
    trainer.save_checkpoint(path)
    return str(path)


@pytest.fixture
def clip(sample: Motion) -> Motion:
    return sample.with_channels(sample.channels[:240])


def other_skeleton(motion: Motion) -> Motion:
    sk = replace(motion.skeleton, names=tuple(n + "_b" for n in motion.skeleton.names))
    return Motion(sk, motion.channels, motion.fps, "renamed")


def test_ebf_method_changes_only_scored_channels(clip, tiny, tmp_path):
    path = save(tiny("ebf", clip), tmp_path / "ebf.ckpt")
    noisy, mask = corrupt_motion(clip, "noise+gaps", np.random.default_rng(0))
    for text in (f"ebf={path}", f"ebf:mode=windowed,checkpoints={path}"):
        out = build_method(text).clean(clip.with_channels(noisy), mask)
        assert out.shape == clip.channels.shape and np.isfinite(out).all()
        unscored = ~clip.skeleton.scored_mask
        np.testing.assert_array_equal(out[:, unscored], noisy[:, unscored])


def test_ebd_ebf_pipeline_and_ebd_keeps_observed_samples(clip, tiny, tmp_path):
    ebd = save(tiny("ebd", clip), tmp_path / "ebd.ckpt")
    ebf = save(tiny("ebf", clip), tmp_path / "ebf.ckpt")
    noisy, mask = corrupt_motion(clip, "gaps-long", np.random.default_rng(1))
    filled = build_method(f"ebd={ebd}").clean(clip.with_channels(noisy), mask)
    np.testing.assert_array_equal(filled[~mask], noisy[~mask])
    assert np.isfinite(filled).all()
    both = build_method(f"ebd+ebf={ebd},{ebf}").clean(clip.with_channels(noisy), mask)
    assert np.isfinite(both).all()


def test_wrong_checkpoint_class_and_bad_mode_are_refused(clip, tiny, tmp_path):
    ebd = save(tiny("ebd", clip), tmp_path / "ebd.ckpt")
    with pytest.raises(ValueError, match="EBD network"):
        build_method(f"ebf={ebd}")
    with pytest.raises(ValueError, match="mode"):
        build_method(f"ebd:mode=fast,checkpoints={ebd}")
    with pytest.raises(FileNotFoundError):
        build_method("ebf=/nonexistent.ckpt")


def test_other_skeleton_is_refused_naming_both(clip, tiny, tmp_path):
    path = save(tiny("ebf", clip), tmp_path / "ebf.ckpt")
    other = other_skeleton(clip)
    clean = build_method(f"ebf={path}").clean
    with pytest.raises(ValueError, match="trained on corpus 'sample'.*this motion's skeleton is 31 joints"):
        clean(other, np.zeros(other.channels.shape, dtype=bool))
    with pytest.raises(LookupError, match="no shipped 'ebf' checkpoint for this skeleton, 31 joints"):
        shipped_checkpoint("ebf", other.skeleton)


NEURAL_METHODS = {"ebf", "ebf-paper", "ebf-bias", "ebf-free", "ebd", "ebd+ebf", "bf", "nn"}


def test_method_names_are_pinned():
    import mocapnet.methods.neural  # noqa: F401  (registers the names)
    from mocapnet.methods.registry import available

    names = {spec.name for spec in available()}
    assert NEURAL_METHODS <= names
    help_of = {spec.name: spec.help for spec in available()}
    assert "no bias" in help_of["ebf-paper"] and "free-shape" in help_of["ebf-free"]
    for entry in read_index():
        if entry.get("ebf"):
            assert f"{entry['corpus']}: {entry['method']} ({entry['recipe']}" in help_of["ebf"]


@pytest.mark.parametrize(
    "kind, accepted",
    [
        ("ebf", {"ebf", "ebf-paper"}),
        ("ebf-bias", {"ebf", "ebf-bias"}),
        ("ebf-free", {"ebf", "ebf-free"}),
        ("bf", {"bf"}),
        ("ebd", {"ebd"}),
    ],
)
def test_variant_names_check_the_checkpoint(kind, accepted, clip, tiny, tmp_path):
    path = save(tiny(kind, clip), tmp_path / f"{kind}.ckpt")
    for method in ("ebf", "ebf-paper", "ebf-bias", "ebf-free", "bf", "ebd"):
        if method in accepted:
            build_method(f"{method}={path}")
        else:
            with pytest.raises(ValueError, match=f"not {method}$"):
                build_method(f"{method}={path}")


def test_shipped_variants_and_best_ebf(sample):
    entries = read_index()
    for entry in entries:
        assert entry["method"] in NEURAL_METHODS - {"ebf", "ebd+ebf"}
    per_skeleton = {}
    for entry in entries:
        if entry.get("ebf"):
            assert entry["method"] in ("ebf-paper", "ebf-bias", "ebf-free")
            per_skeleton[entry["skeleton_hash"]] = per_skeleton.get(entry["skeleton_hash"], 0) + 1
    assert per_skeleton and set(per_skeleton.values()) == {1}
    best = shipped_checkpoint("ebf", sample.skeleton)
    entry = next(e for e in entries if e["file"] == best.name)
    assert shipped_checkpoint(entry["method"], sample.skeleton) == best


def test_ebd_never_changes_observed_samples(clip, sample, tiny, tmp_path):
    longer = clip.with_channels(sample.channels[:600])
    path = save(tiny("ebd", clip), tmp_path / "ebd.ckpt")
    for corruption in ("noise+gaps", "gaps", "segment-gap:left-arm:0.5"):
        noisy, mask = corrupt_motion(longer, corruption, np.random.default_rng(3))
        for text in (f"ebd={path}", f"ebd={path}:mode=windowed", "ebd"):
            out = build_method(text).clean(longer.with_channels(noisy), mask)
            np.testing.assert_array_equal(out[~mask], noisy[~mask])
            assert np.isfinite(out).all()


@pytest.mark.parametrize("method", ["ebf", "ebd"])
def test_a_shipped_network_checks_the_frame_rate_of_every_clip(clip, method):
    """The shipped network is loaded once per skeleton, but each clip's frame rate is checked: a 30 fps clip of
    the rig after a 120 fps one still hears that the network counts frames at 120 fps."""
    import warnings

    clean = build_method(method).clean
    noisy, mask = corrupt_motion(clip, "gaps", np.random.default_rng(2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        clean(clip.with_channels(noisy), mask)
    slow = replace(clip.with_channels(noisy), fps=30.0)
    for _ in range(2):
        with pytest.warns(UserWarning, match="was trained at 120 fps; this motion is at 30 fps"):
            clean(slow, mask)
