"""Shared fixtures: the shipped sample clip, the shared data root (tests needing it skip when absent)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mocapnet.corpus import PACKAGE_DATA
from mocapnet.io.bvh import read_bvh

SHARED = Path(os.environ.get("MOCAPNET_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
SAMPLE_BVH = PACKAGE_DATA / "bvh" / "01_01.bvh.gz"
SAMPLE_C3D = PACKAGE_DATA / "c3d" / "kinematics_tennis_serve.c3d"
SAMPLE_C3D_NAN = PACKAGE_DATA / "c3d" / "kinematics_tennis_serve_nan.c3d"


@pytest.fixture(scope="session")
def shared() -> Path:
    if not SHARED.exists():
        pytest.skip(f"shared data not found at {SHARED}")
    return SHARED


@pytest.fixture(scope="session")
def cmu():
    """The shipped CMU clip (120 fps, 31 joints)."""
    return read_bvh(SAMPLE_BVH)


@pytest.fixture(scope="session")
def bandai(shared):
    """One Bandai-Namco clip (30 fps, 22 joints, 6 channels each)."""
    return read_bvh(shared / "bvh/bandai_namco_2/dataset-2_walk_normal_001.bvh.gz")


@pytest.fixture()
def cmu_short(cmu):
    """The first 600 frames of the CMU clip."""
    return cmu.with_channels(cmu.channels[:600])
