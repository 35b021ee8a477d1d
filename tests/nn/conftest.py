"""Fixtures for the network tests: tiny models, the shipped sample clip and a synthetic batch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mocapnet.corpus import load_corpus
from mocapnet.motion import Motion
from mocapnet.nn import EBD, EBF, WindowMLP
from mocapnet.nn.features import ClipArrays, Normaliser, topology_hash

TINY = {"hidden": 8, "code": 8, "width": 16}


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)
    torch.manual_seed(0)


@pytest.fixture(scope="session")
def sample() -> Motion:
    """The CMU clip shipped in the package (2,752 frames, 120 fps, 90 scored channels)."""
    return load_corpus("sample", progress=False).motions[0]


def make_tiny(kind: str, motion: Motion, **overrides) -> EBF | EBD | WindowMLP:
    """A tiny model of ``kind`` (ebf, ebf-bias, ebf-free, bf, ebd, nn) fitted to ``motion``'s skeleton;
    ``overrides`` go to the constructor."""
    n = int(motion.skeleton.scored_mask.sum())
    meta = {"skeleton_hash": topology_hash(motion.skeleton), "fps": motion.fps, "corpus": "sample", **overrides}
    if kind == "ebd":
        model = EBD(n, **TINY, **meta)
    elif kind == "nn":
        model = WindowMLP(n, widths=(16, 16, 16, 16, 16), **meta)
    else:
        extra = {"ebf-bias": {"bias": True}, "ebf-free": {"filter_shape": "free"}, "bf": {"encoder_layers": 0}}
        model = EBF(n, **TINY, **extra.get(kind, {}), **meta)
    clip = ClipArrays.from_motion(motion)
    model.set_normaliser(Normaliser.fit([clip.scored], [clip.angvel]))
    return model


@pytest.fixture
def tiny():
    """The ``make_tiny`` factory."""
    return make_tiny


@pytest.fixture
def batch(sample: Motion) -> dict[str, torch.Tensor]:
    """Two noisy 40-frame crops of the sample clip with a gap on a few channels."""
    clip = ClipArrays.from_motion(sample)
    rng = np.random.default_rng(0)
    clean = np.stack([clip.scored[100:140], clip.scored[900:940]]).astype(np.float32)
    noisy = clean + rng.standard_normal(clean.shape).astype(np.float32) * 0.5 * clip.sigma.astype(np.float32)
    mask = np.zeros(clean.shape, dtype=bool)
    mask[:, 10:25, 3:6] = True
    angvel = np.stack([clip.angvel[100:140], clip.angvel[900:940]])
    return {
        "filled": torch.as_tensor(noisy),
        "mask": torch.as_tensor(mask),
        "clean": torch.as_tensor(clean),
        "angvel": torch.as_tensor(angvel),
    }
