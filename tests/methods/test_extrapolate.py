"""Tests of the streaming extrapolator (mocapnet.methods.extrapolate)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from mocapnet.methods import build_method
from mocapnet.methods.extrapolate import Extrapolator, extrapolate, predict_next
from mocapnet.motion import Markers

pytestmark = pytest.mark.filterwarnings("error")  # no RuntimeWarning (NaN, division) on any path

FPS = 120.0
DATA = Path(os.environ.get("MOCAPNET_DATA", Path(__file__).resolve().parents[2].parent / "shared" / "data"))
TENNIS_FILE = DATA / "c3d" / "kineticstoolkit" / "kinematics_tennis_serve.c3d"


def _circle(n_frames: int) -> np.ndarray:
    """``[T, 3]`` cm: uniform motion (2 rad/s) on a 15 cm circle in a tilted plane."""
    t = np.arange(n_frames) / FPS
    e1 = np.array([1.0, 0.2, 0.1]) / np.linalg.norm([1.0, 0.2, 0.1])
    e2 = np.cross(e1, [0.3, 0.1, 1.0])
    e2 /= np.linalg.norm(e2)
    return np.array([3.0, -2.0, 50.0]) + 15.0 * (np.cos(2 * t)[:, None] * e1 + np.sin(2 * t)[:, None] * e2)


def _line(n_frames: int) -> np.ndarray:
    """``[T, 3]`` cm: constant velocity (30, -10, 5) cm/s."""
    t = np.arange(n_frames) / FPS
    return np.array([1.0, 2.0, 3.0]) + t[:, None] * np.array([30.0, -10.0, 5.0])


def _stream_one(traj: np.ndarray, mode: str, visible_frames: int) -> np.ndarray:
    """Push a one-marker trajectory ``[T, 3]``, visible for the first ``visible_frames``; returns ``[T, 3]``."""
    ex = Extrapolator(["m"], FPS, mode)
    return np.array([ex.push(p[None], np.array([k < visible_frames]))[0] for k, p in enumerate(traj)])


@pytest.mark.parametrize(
    ("shape", "mode"), [("circle", "circular"), ("circle", "blend"), ("line", "linear"), ("line", "blend")]
)
def test_exact_circle_and_line_for_two_seconds(shape: str, mode: str) -> None:
    seen = int(FPS)
    traj = (_circle if shape == "circle" else _line)(seen + int(2 * FPS))
    out = _stream_one(traj, mode, seen)
    assert np.abs(out[seen:] - traj[seen:]).max() < 1e-6


def test_linear_cannot_follow_circle() -> None:
    """Sanity check of the circle test itself: a straight-line guess leaves the circle."""
    traj = _circle(int(3 * FPS))
    assert np.abs(_stream_one(traj, "linear", int(FPS))[int(FPS) :] - traj[int(FPS) :]).max() > 10


@pytest.mark.parametrize("mode", ["linear", "circular", "blend"])
def test_static_and_collinear_samples_give_no_nan(mode: str) -> None:
    static = np.tile([[4.0, 5.0, 6.0]], (19, 3, 1))
    assert np.array_equal(predict_next(static, 1 / FPS, 9, mode), static[0])
    t = np.arange(400) / FPS
    falling = np.array([0.0, 0.0, 200.0]) - 490.0 * (t**2)[:, None] * np.array([0.0, 0.0, 1.0])
    out = _stream_one(falling, mode, 60)
    assert np.isfinite(out).all()
    assert np.abs(out[:, :2]).max() < 1e-9  # stays on the vertical line


def _random_walk_markers(n_frames: int = 300, n_markers: int = 6, seed: int = 0) -> Markers:
    rng = np.random.default_rng(seed)
    pts = np.cumsum(rng.normal(0, 0.3, (n_frames, n_markers, 3)), axis=0) + rng.normal(0, 30, (1, n_markers, 3))
    vis = np.ones((n_frames, n_markers), dtype=bool)
    vis[100:160, 1] = False
    vis[130:200, 2:4] = False
    vis[250:260, 0] = False
    return Markers(pts, vis, [f"m{i}" for i in range(n_markers)], FPS, "walk")


@pytest.mark.parametrize(
    ("mode", "cm"), [("hold", False), ("linear", False), ("circular", False), ("blend", False), ("blend", True)]
)
def test_visible_untouched_and_streaming_equals_whole_array(mode: str, cm: bool) -> None:
    markers = _random_walk_markers()
    whole = extrapolate(markers, mode, cm)
    assert np.isfinite(whole).all()
    assert np.array_equal(whole[markers.visible], markers.points[markers.visible])
    ex = Extrapolator(markers.labels, markers.fps, mode, cm)
    streamed = np.array([ex.push(p, v) for p, v in zip(markers.points, markers.visible)])
    np.testing.assert_allclose(streamed, whole, rtol=0, atol=1e-9)


def test_constraint_matrix_pulls_prediction_to_rigid_distance() -> None:
    """B circles a static A at 20 cm; C moves freely (not rigid to B). With B missing, the linear guess
    drifts off the circle; the corrector puts it back within the seen distance bounds to A."""
    n = int(3 * FPS)
    t = np.arange(n) / FPS
    a = np.zeros((n, 3))
    b = 20.0 * np.stack([np.cos(3 * t), np.sin(3 * t), np.zeros(n)], axis=1)
    c = np.stack([60 * np.sin(t), 40.0 + 0 * t, 10 * t], axis=1)
    vis = np.ones((n, 3), dtype=bool)
    vis[int(FPS) :, 1] = False
    markers = Markers(np.stack([a, b, c], axis=1), vis, ["A", "B", "C"], FPS)
    gap = ~vis[:, 1]
    plain = np.linalg.norm(extrapolate(markers, "linear")[gap, 1], axis=1)
    fixed = np.linalg.norm(extrapolate(markers, "linear", constraint_matrix=True)[gap, 1], axis=1)
    assert np.abs(plain - 20).max() > 5
    assert np.abs(fixed - 20).max() < 1e-6


def test_constraint_half_step_between_two_predicted_markers() -> None:
    """Two missing markers that were rigid (10 cm apart) are each moved half way back to 10 cm."""
    ex = Extrapolator(["a", "b"], FPS, "hold", constraint_matrix=True)
    ex.warm_up(np.tile([[[0.0, 0, 0], [10.0, 0, 0]]], (40, 1, 1)))
    x = np.array([[-2.0, 0, 0], [12.0, 0, 0]])
    ex._correct(x, np.zeros(2, dtype=bool), np.array([0, 1]))
    np.testing.assert_allclose(x, [[0.0, 0, 0], [10.0, 0, 0]], atol=1e-12)


def test_marker_missing_at_first_frame() -> None:
    markers = _random_walk_markers()
    vis = markers.visible.copy()
    vis[:20, 5] = False
    vis[:, 4] = False  # never visible
    gappy = Markers(markers.points, vis, markers.labels, markers.fps)
    out = extrapolate(gappy)
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(out[:20, 5], np.tile(markers.points[20, 5], (20, 1)))
    np.testing.assert_allclose(out[0, 4], out[0, :4].mean(axis=0))  # centroid of the markers with data
    ex = Extrapolator(gappy.labels, FPS)
    assert np.isfinite(ex.push(gappy.points[0], vis[0])).all()


def test_bad_input_shapes_raise() -> None:
    ex = Extrapolator(["a", "b"], FPS)
    with pytest.raises(ValueError, match=r"\[2, 3\]"):
        ex.push(np.zeros((3, 3)), np.ones(3, dtype=bool))
    with pytest.raises(ValueError, match="frame 1"):
        ex.warm_up(np.array([np.zeros((2, 3)), np.full((2, 3), np.nan)]))
    with pytest.raises(ValueError, match="mode"):
        Extrapolator(["a"], FPS, "quadratic")


def test_registered_methods_run_on_real_c3d() -> None:
    if not TENNIS_FILE.exists():
        pytest.skip(f"shared data not found: {TENNIS_FILE}")
    from mocapnet.corrupt import corrupt_markers, seed_for
    from mocapnet.io.c3d import read_c3d

    clean = read_c3d(TENNIS_FILE)
    corr = "segment-gap:right-arm:1"
    noisy = corrupt_markers(clean, corr, np.random.default_rng(seed_for("test", TENNIS_FILE.name, 0, corr)))
    miss = ~noisy.visible
    errors = {}
    for text in (
        "hold",
        "extrapolate-linear",
        "extrapolate-circular",
        "extrapolate",
        "extrapolate+cm",
        "extrapolate+cm:backlog=30,threshold_cm=10",
    ):
        method = build_method(text)
        assert method.space == "points"
        out = method.clean(noisy)
        assert out.shape == clean.points.shape and np.isfinite(out).all()
        assert np.array_equal(out[noisy.visible], clean.points[noisy.visible])
        errors[text] = np.linalg.norm(out[miss] - clean.points[miss], axis=1).mean()
    assert errors["extrapolate+cm"] == errors["extrapolate+cm:backlog=30,threshold_cm=10"]
    with pytest.raises(ValueError, match="threshold_cm"):
        build_method("extrapolate:threshold_cm=5")
