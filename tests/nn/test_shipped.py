"""The checkpoints shipped in mocapnet/checkpoints: they load, are small, and beat the baselines on the
shipped sample clip's test segment (its last 15 %, never used for training or model selection)."""

from __future__ import annotations

import numpy as np
import pytest

from mocapnet.corpus import time_segments
from mocapnet.corrupt import corrupt_motion
from mocapnet.evaluate.metrics import angle_err_deg, gap_err_deg
from mocapnet.methods.registry import build_method
from mocapnet.motion import Motion
from mocapnet.nn import EBD, EBF, WindowMLP
from mocapnet.nn.checkpoints import CHECKPOINT_DIR, read_index, shipped_checkpoint
from mocapnet.nn.features import topology_hash

CLASSES = {"EBF": EBF, "EBD": EBD, "WindowMLP": WindowMLP}


@pytest.fixture(scope="module")
def test_segment(sample: Motion) -> Motion:
    return time_segments(sample, (0.7, 0.15))[2]


@pytest.mark.parametrize("entry", read_index(), ids=lambda e: e["file"])
def test_index_entries_load_and_are_small(entry):
    path = CHECKPOINT_DIR / entry["file"]
    assert path.stat().st_size < 2_100_000
    model = CLASSES[entry["class"]].load_from_checkpoint(path, map_location="cpu")
    assert model.hparams.skeleton_hash == entry["skeleton_hash"]
    assert model.hparams.n_channels == entry["scored_channels"]


def test_sample_skeleton_has_ebf_and_ebd(sample):
    for method in ("ebf", "ebd"):
        path = shipped_checkpoint(method, sample.skeleton)
        assert path.exists() and topology_hash(sample.skeleton) in {e["skeleton_hash"] for e in read_index()}


def test_shipped_ebf_beats_gaussian_on_sample(test_segment):
    noisy, mask = corrupt_motion(test_segment, "angular-0.5", np.random.default_rng(0))
    scored = test_segment.skeleton.scored_mask
    errors = {}
    for method in ("gaussian-58ms", "gaussian-125ms", "ebf", "ebf:mode=windowed"):
        out = build_method(method).clean(test_segment.with_channels(noisy), mask)
        errors[method] = angle_err_deg(out, test_segment.channels, scored)
    best_gaussian = min(errors["gaussian-58ms"], errors["gaussian-125ms"])
    assert errors["ebf"] < best_gaussian, errors
    assert errors["ebf:mode=windowed"] < best_gaussian, errors


def test_shipped_ebd_beats_lerp_on_sample(test_segment):
    noisy, mask = corrupt_motion(test_segment, "gaps", np.random.default_rng(0))
    lerp = build_method("lerp").clean(test_segment.with_channels(noisy), mask)
    ebd = build_method("ebd").clean(test_segment.with_channels(noisy), mask)
    assert gap_err_deg(ebd, test_segment.channels, mask) < gap_err_deg(lerp, test_segment.channels, mask)
