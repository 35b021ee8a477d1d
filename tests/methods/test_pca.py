"""PCA gap filling (mocapnet.methods.pca) where most markers have overlapping gaps: no divide warnings, NaN
(not garbage) where PCA cannot be trusted, a centre that does not jump when markers come and go."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapnet.io.c3d import read_c3d
from mocapnet.methods.pca import _kept_markers, moving_centre, pca_fill
from mocapnet.methods.registry import build_method
from mocapnet.motion import Markers
from tests.conftest import SAMPLE_C3D, SHARED


@pytest.fixture(scope="module")
def tennis() -> Markers:
    return read_c3d(SAMPLE_C3D)


def test_no_complete_marker_and_no_runtime_warning(tennis) -> None:
    """Every marker has a gap (a staircase of overlapping gaps): PCA rebuilds the markers it can without a
    warning, and those fills are close to the truth."""
    pts = tennis.points[:400]
    visible = np.ones(pts.shape[:2], dtype=bool)
    for m in range(pts.shape[1]):
        start = 10 * m
        visible[start : start + 25, m] = False
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = pca_fill(pts, visible)
    miss = ~visible
    done = miss & np.isfinite(out).all(axis=2)
    assert done.sum() > 0.7 * miss.sum()
    assert np.linalg.norm(out - pts, axis=-1)[done].mean() < 3.0
    assert np.array_equal(out[visible], pts[visible])


def test_untrustworthy_markers_are_nan_not_garbage(tennis) -> None:
    """A marker missing while every other marker is missing too, or with fewer than ``min_frames`` frames
    shared with the others, is left NaN."""
    pts = tennis.points[:300]
    visible = np.ones(pts.shape[:2], dtype=bool)
    visible[:60] = False  # nobody in view for the first 60 frames
    visible[60:, 0] = False  # marker 0 seen only in those 60 frames? No: never seen with anyone else
    visible[:60, 0] = True
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = pca_fill(pts, visible)
    assert np.isnan(out[60:, 0]).all()  # marker 0 never measured together with another marker
    assert np.isnan(out[:60, 1:]).all()  # nothing in view to rebuild from
    assert np.array_equal(out[visible], pts[visible])


def test_kept_markers_drops_the_markers_that_cost_most_frames() -> None:
    visible = np.ones((100, 4), dtype=bool)
    visible[:50, 0] = False  # target missing in the first half
    visible[50:95, 1] = False  # marker 1 missing in most of the second half
    kept = np.array([False, True, True, True])
    got, complete = _kept_markers(visible, 0, kept, min_frames=20)
    assert got.tolist() == [False, False, True, True] and complete.sum() == 50
    got, complete = _kept_markers(visible, 0, kept, min_frames=60)  # impossible: every marker dropped
    assert not got.any()


def test_moving_centre_does_not_jump_when_a_marker_vanishes() -> None:
    t = np.arange(100.0)
    pts = np.stack([np.stack([t + dx, 0 * t + dy, 0 * t], 1) for dx, dy in ((0, 0), (10, 0), (0, 10))], 1)
    visible = np.ones((100, 3), dtype=bool)
    visible[:30, 1] = False
    visible[60:, 2] = False
    centre = moving_centre(pts, visible)
    steps = np.linalg.norm(np.diff(centre, axis=0), axis=1)
    assert steps.max() < 1.2  # the subject moves 1 cm per frame; a naive centroid jumps by 3-5 cm
    naive = np.nanmean(np.where(visible[..., None], pts, np.nan), axis=1)
    assert np.linalg.norm(np.diff(naive, axis=0), axis=1).max() > 3.0


@pytest.mark.parametrize("take", ["btkdata/Gait.c3d", "ezc3d/BTS.c3d", "kineticstoolkit/kinematics_basket_sprint.c3d"])
def test_heavily_occluded_takes_give_no_warning_and_no_teleport(take) -> None:
    """Issue 10: PCA leaked 'invalid value encountered in divide' and wrote 1.7-6.9 m jumps on these takes."""
    path = SHARED / "c3d" / take
    if not path.exists():
        pytest.skip(f"shared data not found at {path}")
    markers = read_c3d(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        out = pca_fill(markers.points, markers.visible)
    rebuilt = ~markers.visible & np.isfinite(out).all(axis=2)
    span = np.nanmax(markers.points, axis=(0, 1)) - np.nanmin(markers.points, axis=(0, 1))
    assert (np.abs(out[rebuilt] - np.nanmean(markers.points, axis=(0, 1))) < span).all()


def test_registered_pca_says_what_it_could_not_rebuild(tennis) -> None:
    pts = tennis.points[:200]
    visible = np.ones(pts.shape[:2], dtype=bool)
    visible[:, 0] = False
    visible[:5, 0] = True
    visible[:5, 1:] = False  # marker 0 is never seen with another marker
    noisy = Markers(pts, visible, tennis.labels, tennis.fps, "stairs")
    with pytest.warns(
        UserWarning, match=rf"stairs: pca cannot be trusted for this marker.*{tennis.labels[0]} frames 5-199"
    ):
        out = build_method("pca", space="points").clean(noisy)
    assert np.isfinite(out).all()
