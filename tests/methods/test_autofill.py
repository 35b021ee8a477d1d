"""Tests of the rigid-body filler (mocapnet.methods.rigid) and the per-gap auto filler (mocapnet.methods.autofill),
including the plausibility target of issue 10 on every shared take with real gaps."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapnet.clean import CleanOptions, clean_file
from mocapnet.cli import main
from mocapnet.fill import runs
from mocapnet.io.c3d import read_c3d
from mocapnet.methods.autofill import (
    auto_fill,
    fill_plausibility,
    largest_measured_steps,
    match_edges,
    step_ratio,
    summary_table,
)
from mocapnet.methods.registry import build_method
from mocapnet.methods.rigid import distance_spread, kabsch, rigid_fill, rigid_fill_gap, rigid_reach
from mocapnet.motion import Markers
from tests.conftest import SAMPLE_C3D, SAMPLE_C3D_NAN, SHARED

# Every shared take whose markers have real gaps (the benchmark finds the same list by reading every file).
GAPPED_TAKES = (
    "btkdata/ADemo1_rewrite_c3d_pc_integer.c3d",
    "btkdata/DEC_INT.C3D",
    "btkdata/Dec_real.c3d",
    "btkdata/Eb015pi.c3d",
    "btkdata/Eb015vr.c3d",
    "btkdata/Gait.c3d",
    "btkdata/PiG_Motion-FlatFoot-Full.c3d",
    "btkdata/PlugInC3D.c3d",
    "btkdata/Res16bits.c3d",
    "btkdata/TYPE-2.C3D",
    "btkdata/pc_int.c3d",
    "btkdata/pc_real.c3d",
    "btkdata/sgi_int.c3d",
    "btkdata/sgi_real.c3d",
    "cmu/01_01.c3d",
    "ezc3d/BTS.c3d",
    "ezc3d/Vicon.c3d",
    "kineticstoolkit/duplicate_labels.c3d",
    "kineticstoolkit/kinematics_basket_sprint.c3d",
    "kineticstoolkit/kinematics_racing_full.c3d",
    "kineticstoolkit/kinematics_tennis_serve_nan.c3d",
)


def rigid_scene(n_frames: int = 240, fps: float = 120.0, seed: int = 0) -> Markers:
    """Four markers of one rigid body turning and moving, plus two markers on their own smooth paths (cm)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / fps
    body = np.array([[0.0, 0, 0], [12, 0, 0], [0, 9, 0], [3, 4, 10]])
    rot = Rotation.from_rotvec(np.outer(np.sin(2 * t), [0.3, 1.1, 0.5])).as_matrix()
    path = np.stack([80 * t, 20 * np.sin(3 * t), 100 + 5 * t], axis=1)
    rigid = np.einsum("tij,kj->tki", rot, body) + path[:, None]
    free = np.stack(
        [path + np.stack([40 + 30 * np.sin(5 * t + p), 10 * np.cos(4 * t), -30 + 8 * t], 1) for p in (0, 1)], 1
    )
    points = np.concatenate([rigid, free], axis=1) + rng.normal(0, 1e-9, (n_frames, 6, 3))
    return Markers(points, np.ones((n_frames, 6), dtype=bool), [f"m{i}" for i in range(6)], fps, "scene")


def with_gaps(markers: Markers, gaps: dict[int, list[tuple[int, int]]]) -> Markers:
    visible = markers.visible.copy()
    for m, spans in gaps.items():
        for a, b in spans:
            visible[a:b, m] = False
    return Markers(markers.points, visible, markers.labels, markers.fps, markers.name)


def test_kabsch_recovers_rotation_and_translation() -> None:
    rng = np.random.default_rng(1)
    source = rng.normal(size=(5, 3))
    rot = Rotation.random(6, random_state=2).as_matrix()
    shift = rng.normal(size=(6, 3))
    target = np.einsum("lij,kj->lki", rot, source) + shift[:, None]
    got_rot, got_shift = kabsch(source, target, weights=np.array([1.0, 2, 3, 4, 5]))
    np.testing.assert_allclose(got_rot, rot, atol=1e-12)
    np.testing.assert_allclose(got_shift, shift, atol=1e-12)
    assert np.allclose(np.linalg.det(got_rot), 1.0)


def test_rigid_fill_is_exact_for_a_rigid_body_inside_and_at_the_ends() -> None:
    truth = rigid_scene()
    noisy = with_gaps(truth, {0: [(0, 30), (100, 160), (220, 240)]})
    out = rigid_fill(noisy.points, noisy.visible)
    np.testing.assert_allclose(out[:, 0], truth.points[:, 0], atol=1e-6)
    assert np.array_equal(out[noisy.visible], truth.points[noisy.visible])


def test_rigid_fill_needs_three_rigid_partners_in_view() -> None:
    truth = rigid_scene()
    noisy = with_gaps(truth, {0: [(100, 160)], 1: [(90, 170)], 2: [(150, 151)]})
    spread = distance_spread(noisy.points, noisy.visible)
    assert spread[0, 4] > 2.0 and spread[0, 1] < 1e-6  # the free markers are not rigid with the body
    assert rigid_fill_gap(noisy.points, noisy.visible, spread, 0, 100, 160) is None
    # Partners visible for part of the gap: a rigid fill reaches from each edge as far as three stay in view.
    assert rigid_reach(noisy.visible, spread, 0, 99, 1) == 0
    noisy = with_gaps(truth, {0: [(100, 160)], 2: [(130, 140)]})
    assert rigid_reach(noisy.visible, spread, 0, 99, 1) == 30 and rigid_reach(noisy.visible, spread, 0, 160, -1) == 20


def test_auto_fills_what_it_can_and_reports_the_rest_unfilled() -> None:
    truth = rigid_scene()
    noisy = with_gaps(truth, {0: [(100, 180)], 4: [(0, 40), (120, 125), (150, 230)], 2: [(130, 140)]})
    got = auto_fill(noisy, order=("rigid", "spline", "lerp"))  # PCA could rebuild m4 from m5 here
    by_marker = {(g["marker"], g["first_frame"]): g for g in got.gaps}
    assert by_marker[("m0", 100)]["method"] == "rigid" and by_marker[("m0", 100)]["status"] == "partly filled"
    assert by_marker[("m0", 100)]["unfilled_spans"] == [[130, 139]]
    assert by_marker[("m2", 130)]["method"] == "spline" and by_marker[("m2", 130)]["status"] == "filled"
    assert by_marker[("m4", 120)]["method"] == "spline" and by_marker[("m4", 120)]["ratio"] <= 2.0
    # A free marker's long gap and its leading gap: no rigid partner, too long to interpolate -> left missing.
    for first in (0, 150):
        report = by_marker[("m4", first)]
        assert report["status"] == "unfilled" and report["method"] is None and report["tried"]
        assert np.isnan(got.points[first, 4]).all() and not got.filled[first, 4]
    assert np.array_equal(got.filled, np.isfinite(got.points).all(axis=2) & ~noisy.visible)
    assert np.array_equal(got.points[noisy.visible], truth.points[noisy.visible])
    for span in (slice(100, 130), slice(140, 180)):
        np.testing.assert_allclose(got.points[span, 0], truth.points[span, 0], atol=1e-6)
    json.dumps(got.gaps)
    table = summary_table(got.gaps)
    assert "rigid" in table and "left missing" in table and "m4 frames 150-229" in table


def test_a_fill_that_jumps_falls_back_to_the_next_candidate() -> None:
    truth = rigid_scene()
    noisy = with_gaps(truth, {5: [(100, 130)]})
    got = auto_fill(noisy, limit=1e-3)  # no fill can be that smooth: every candidate is refused
    (report,) = got.gaps
    assert report["status"] == "unfilled" and not got.filled.any()
    assert [t.split(":")[0] for t in report["tried"]] == ["rigid", "pca", "spline", "lerp"]
    assert "rigid partners" in report["tried"][0] and "segment is missing" in report["tried"][1]
    assert all("step ratio" in t for t in report["tried"][2:])
    ok = auto_fill(noisy)
    assert ok.gaps[0]["method"] in ("pca", "spline") and ok.gaps[0]["ratio"] <= 2.0


def test_step_ratio_and_largest_measured_steps() -> None:
    track = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [np.nan] * 3, [np.nan] * 3, [5, 0, 0], [6, 0, 0]])
    assert step_ratio(track, 3, 5, 1.0) == 0.0 or np.isnan(step_ratio(track, 3, 5, 1.0))
    filled = track.copy()
    filled[3:5] = [[2.5, 0, 0], [4.5, 0, 0]]
    assert step_ratio(filled, 3, 5, 1.0) == pytest.approx(2.0)
    pts = np.repeat(track[:, None], 2, axis=1)
    vis = np.isfinite(pts).all(axis=2)
    assert np.isnan(largest_measured_steps(pts, vis)).all()  # fewer than 11 measured steps anywhere


def test_match_edges_meets_both_measured_edges() -> None:
    track = np.full((10, 3), np.nan)
    track[:3] = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]
    track[7:] = [[7, 0, 0], [8, 0, 0], [9, 0, 0]]
    fill = np.array([[3.0, 5, 0], [4, 5, 0], [5, 5, 0], [6, 5, 0]])  # right slope, offset 5 cm in y
    np.testing.assert_allclose(match_edges(fill, track, 3, 7), [[3, 0, 0], [4, 0, 0], [5, 0, 0], [6, 0, 0]])


def test_registered_auto_fills_every_sample_for_the_harness() -> None:
    truth = rigid_scene()
    noisy = with_gaps(truth, {4: [(0, 40)], 0: [(50, 60)]})
    out = build_method("auto", space="points").clean(noisy)
    np.testing.assert_allclose(out[50:60, 0], truth.points[50:60, 0], atol=1e-2)  # spline: a 10-frame gap
    with pytest.warns(UserWarning) as record:
        out = build_method("auto:limit=0.001", space="points").clean(noisy)  # every fill refused
    messages = " | ".join(str(w.message) for w in record)
    assert "auto found no plausible fill; marker m4 frames 0-39" in messages and "marker m0 frames 50-59" in messages
    assert np.isfinite(out).all()


def test_clean_cli_prints_table_writes_plot_and_json_details(tmp_path, capsys) -> None:
    out, plot = tmp_path / "filled.c3d", tmp_path / "fills.png"
    assert main(["clean", str(SAMPLE_C3D_NAN), "-o", str(out), "--plot", str(plot)]) == 0
    text = capsys.readouterr().out
    assert "of 145 missing samples" in text and "worst step ratio" in text
    assert plot.stat().st_size > 10_000 and plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    result = clean_file(SAMPLE_C3D_NAN, tmp_path / "again.c3d", CleanOptions())
    gaps = json.loads(json.dumps(result.details["gaps"]))
    assert len(gaps) == 10 and all(g["ratio"] is None or g["ratio"] <= 2.0 for g in gaps)
    assert {"marker", "first_frame", "last_frame", "frames", "method", "ratio", "unfilled_spans"} <= set(gaps[0])
    left = sum(b - a + 1 for g in gaps for a, b in g["unfilled_spans"])
    assert result.samples_filled >= 140 and result.samples_filled + left == 145
    truth, source, filled = read_c3d(SAMPLE_C3D), read_c3d(SAMPLE_C3D_NAN), read_c3d(out)
    new = ~source.visible & filled.visible
    assert new.sum() == result.samples_filled
    assert np.linalg.norm(filled.points - truth.points, axis=-1)[new].mean() < 1.5


def test_other_methods_get_a_gap_report_too(tmp_path) -> None:
    result = clean_file(SAMPLE_C3D_NAN, tmp_path / "pca.c3d", CleanOptions(method="pca"))
    assert {g["method"] for g in result.details["gaps"]} == {"pca"}
    assert all(g["ratio"] is not None for g in result.details["gaps"])


def test_auto_rejects_unknown_options(tmp_path) -> None:
    assert main(["clean", str(SAMPLE_C3D_NAN), "-o", str(tmp_path / "x.c3d"), "--method", "auto:bogus=1"]) == 2
    assert not (tmp_path / "x.c3d").exists()
    with pytest.raises(ValueError, match="unknown auto candidates"):
        auto_fill(read_c3d(SAMPLE_C3D_NAN), order=("rigid", "magic"))


@pytest.mark.parametrize("take", GAPPED_TAKES)
def test_default_clean_of_every_gapped_shared_take_is_plausible(tmp_path, take) -> None:
    """Issue 10: the default clean's worst filled step is at most 2x the marker's largest measured step, and
    every sample it did not fill is reported as such."""
    path = SHARED / "c3d" / take
    if not path.exists():
        pytest.skip(f"shared data not found at {path}")
    out = tmp_path / "out.c3d"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        result = clean_file(path, out, CleanOptions())
    source, written = read_c3d(path), read_c3d(out)
    assert written.labels == source.labels
    worst, where, n_filled, _ = fill_plausibility(source, written.points)
    assert worst <= 2.0, f"{take}: {where}"
    assert n_filled == result.samples_filled
    unfilled = ~source.visible & ~written.visible
    reported = np.zeros_like(unfilled)
    for g in result.details["gaps"]:
        for a, b in g["unfilled_spans"]:
            reported[a : b + 1, g["marker_index"]] = True
        assert g["ratio"] is None or g["ratio"] <= 2.0
    assert np.array_equal(unfilled, reported)
    assert np.array_equal(written.points[source.visible], source.points[source.visible]) or np.allclose(
        written.points[source.visible], source.points[source.visible], atol=1e-3
    )


def test_gap_runs() -> None:
    assert runs(np.array([1, 1, 0, 1, 0, 0, 1], dtype=bool)) == [(0, 2), (3, 4), (6, 7)]
    assert runs(np.zeros(4, dtype=bool)) == []


def test_knn_is_a_candidate_only_with_a_database() -> None:
    path = SHARED / "c3d" / "cmu" / "85_02.c3d"
    if not path.exists():
        pytest.skip(f"shared data not found at {path}")
    clip = read_c3d(path)
    visible = clip.visible.copy()
    visible[300:360, clip.index("RSHO")] = False
    noisy = Markers(clip.points, visible, clip.labels, clip.fps, clip.name)
    without = auto_fill(noisy, order=("knn", "lerp"))
    assert not any(t.startswith("knn") for g in without.gaps for t in g["tried"])
    (report,) = auto_fill(noisy, database=path.parent, order=("knn",)).gaps
    assert report["method"] == "knn" or report["tried"][0].startswith("knn: ")
    assert report["method"] != "knn" or report["ratio"] <= 2.0
