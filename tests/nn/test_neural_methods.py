"""The registry adapters of mocapnet.methods.neural (with tiny checkpoints)."""

from __future__ import annotations

from dataclasses import replace

import lightning as L
import numpy as np
import pytest

from mocapnet.corrupt import corrupt_motion
from mocapnet.methods.registry import build_method
from mocapnet.motion import Motion
from mocapnet.nn.checkpoints import shipped_checkpoint


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
