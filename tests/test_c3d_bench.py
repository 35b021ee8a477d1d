"""The C3D fill benchmark's computations (``mocapnet.evaluate.c3d_bench``) on the shipped tennis serve takes."""

from __future__ import annotations

import numpy as np
import pytest

from mocapnet.corrupt import corrupt_markers
from mocapnet.evaluate import c3d_bench
from mocapnet.fill import lerp_fill, runs
from mocapnet.io.c3d import read_c3d
from mocapnet.methods.autofill import fill_plausibility
from mocapnet.motion import Markers
from tests.conftest import SAMPLE_C3D, SAMPLE_C3D_NAN


@pytest.fixture(scope="module")
def serve() -> Markers:
    return read_c3d(SAMPLE_C3D)


@pytest.fixture(scope="module")
def serve_short(serve) -> Markers:
    """The first 6 s of the complete take (gapfill is slow on whole takes)."""
    return Markers(serve.points[:300], serve.visible[:300], serve.labels, serve.fps, serve.name)


@pytest.fixture(scope="module")
def serve_nan() -> Markers:
    return read_c3d(SAMPLE_C3D_NAN)


def test_gap_seconds_gives_each_missing_sample_its_gap_length():
    visible = np.ones((10, 2), dtype=bool)
    visible[2:5, 0] = False  # 3 frames
    visible[0, 1] = visible[9, 1] = False  # two 1-frame gaps at the ends
    seconds = c3d_bench.gap_seconds(visible, fps=10.0)
    expected = np.zeros((10, 2))
    expected[2:5, 0] = 0.3
    expected[[0, 9], 1] = 0.1
    np.testing.assert_allclose(seconds, expected)


def test_transplant_mask_onto_the_same_take_copies_its_mask(serve, serve_nan):
    """Same markers and rate: the assignment is the identity and the mask a window of the source's own."""
    length = 400
    mask = c3d_bench.transplant_mask(serve_nan, serve, length, np.random.default_rng(3))
    assert mask.shape == (length, serve.n_markers)
    missing = ~serve_nan.visible
    windows = [s for s in range(serve_nan.n_frames - length + 1) if (missing[s : s + length] == mask).all()]
    assert windows, "the mask is no window of the source's missing samples"


def test_transplant_mask_keeps_markers_it_would_empty(serve, serve_nan):
    source = Markers(serve_nan.points, serve_nan.visible.copy(), serve_nan.labels, serve_nan.fps, "src")
    source.visible[:, 5] = False  # a marker never seen in the source
    source.visible[0, 5] = True  # (seen once, so it still has a layout)
    mask = c3d_bench.transplant_mask(source, serve, 200, np.random.default_rng(0))
    assert not mask.all(axis=0).any()


def test_registered_fill_is_the_points_lerp(serve):
    noisy = corrupt_markers(serve, "marker-gap:0.5", np.random.default_rng(1))
    got = c3d_bench.registered_fill("lerp", noisy.points, noisy.visible, noisy)
    t, m = noisy.visible.shape
    expected = lerp_fill(noisy.points.reshape(t, m * 3), np.repeat(~noisy.visible, 3, axis=1)).reshape(t, m, 3)
    np.testing.assert_array_equal(got, expected)


def test_score_case_bins_add_up_and_lerp_error_is_exact(serve_short):
    pytest.importorskip("gapfill")
    serve = serve_short
    noisy = corrupt_markers(serve, "segment-gap:left-arm:0.5", np.random.default_rng(2))
    case = c3d_bench.score_case(serve, noisy, {"target": "serve", "mask_source": "synthetic"})
    missing = ~noisy.visible
    assert case["missing_samples"] == int(missing.sum())
    for name in c3d_bench.METHODS:
        assert sum(case["bins"][b][name]["n"] for b in c3d_bench.BIN_NAMES) == case["scored_samples"]
    # every gap is 0.5 s: all scored samples fall in the 0.1-0.5 s bin
    assert case["bins"]["0.1-0.5 s"]["lerp"]["n"] == case["scored_samples"] > 0
    lerp = c3d_bench.registered_fill("lerp", noisy.points, noisy.visible, noisy)
    err = np.linalg.norm(lerp - serve.points, axis=-1)
    assert case["all_missing_mean_cm"]["lerp"] == pytest.approx(err[missing].mean())
    assert case["scored_samples"] <= case["missing_samples"]
    lerp_cell = case["bins"]["0.1-0.5 s"]["lerp"]
    summary = c3d_bench.summarise([case])
    assert summary["all"]["lerp"]["n"] == case["scored_samples"]
    assert summary["all"]["lerp"]["mean_cm"] == pytest.approx(lerp_cell["sum_cm"] / case["scored_samples"])


def test_real_row_and_markdown(serve_short, serve_nan):
    pytest.importorskip("gapfill")
    row = c3d_bench.real_row(serve_nan, "tennis_serve_nan.c3d")
    pca = c3d_bench.registered_fill("pca", serve_nan.points, serve_nan.visible, serve_nan)
    worst, _, _, missing = fill_plausibility(serve_nan, pca)
    assert row["pca"]["worst_ratio"] == worst and row["pca"]["samples_missing"] == missing == 145
    n_gaps = sum(len(runs(~serve_nan.visible[:, m])) for m in range(serve_nan.n_markers))
    assert row["auto"]["gaps"] == n_gaps and row["auto"]["worst_ratio"] <= 2.0
    serve = serve_short
    noisy = corrupt_markers(serve, "marker-gap:1", np.random.default_rng(0))
    occ = c3d_bench.score_case(serve, noisy, {"target": "serve.c3d", "mask_source": "nan.c3d"})
    seg = c3d_bench.score_case(serve, noisy, {"target": "serve.c3d", "corruption": "marker-gap:1"})
    report = {"command": "bench", "git_commit": "0123456789ab", "machine": "test", "wall_s": 1.0, "cpu_s": 1.0,
              "window_s": 8.0, "targets": ["serve.c3d"], "mask_sources": ["nan.c3d"], "gapfill_version": "0.0.7",
              "real": [row], "occlusion": {"cases": [occ], "summary": c3d_bench.summarise([occ]),
                                           "summary_held_out": c3d_bench.summarise([])},
              "segments": {"cases": [seg], "summary": c3d_bench.summarise([seg])}}  # fmt: skip
    text = c3d_bench.markdown(report)
    assert "## (a)" in text and "## (b)" in text and "## (c)" in text
    auto = row["auto"]
    assert (
        f"| tennis_serve_nan.c3d | 1092 × 39 | 0% | {auto['worst_ratio']:.2f} | {auto['gaps_filled']}/{n_gaps} |"
        in text
    )
    assert f"| all | {occ['scored_samples']} | " in text
    assert "auto's worst ratio is ≤ 2 on 1 of 1 takes." in text
