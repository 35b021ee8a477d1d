"""The extrapolation benchmark's computations (``mocapnet.evaluate.extrapolate_bench``)."""

from __future__ import annotations

import numpy as np
import pytest

from mocapnet.corpus import PACKAGE_DATA
from mocapnet.corrupt import Corruption
from mocapnet.evaluate import extrapolate_bench as bench
from mocapnet.fill import lerp_fill


@pytest.fixture(scope="module")
def serve() -> bench.Clip:
    """The shipped tennis serve as a benchmark clip (39 complete Plug-in-Gait markers, 50 Hz)."""
    (clip,) = bench.load_clips(PACKAGE_DATA, ("c3d/kinematics_tennis_serve.c3d",))
    return clip


def test_exact_circle_and_line_are_predicted_exactly():
    result = bench.synthetic_check(fps=60.0, seconds=1.0)
    assert result["circle_circular_max_err_cm"] < 1e-6
    assert result["line_linear_max_err_cm"] < 1e-6
    assert result["circle_linear_max_err_cm"] > 1.0  # the check can fail


def test_corruptions_parse_and_cover_every_length_and_limb():
    parsed = [Corruption.parse(c) for c in bench.corruptions()]
    assert {(c.kind, c.level) for c in parsed} == {
        (k, s) for k in ("marker-gap", "segment-gap") for s in bench.GAP_SECONDS
    }
    assert {c.segment for c in parsed if c.kind == "segment-gap"} == set(bench.SEGMENTS)


def test_score_clip_accumulates_errors_and_fill_counts(serve):
    pytest.importorskip("gapfill")
    acc: dict = {}
    per_file: dict = {}
    bench.score_clip(serve, "marker-gap:0.5", 0, acc, per_file)
    assert {k[3] for k in acc} == set(bench.METHODS)
    assert {k[:3] for k in acc} == {("c3d", "marker-gap", 0.5)}
    assert {k[0] for k in per_file} == {serve.file}
    noisy = bench.corrupt(serve, "marker-gap:0.5", 0)
    miss = ~noisy.visible
    end = int(np.flatnonzero(miss.any(axis=1)).max()) + 1
    t, m = miss.shape
    lerp = lerp_fill(noisy.points.reshape(t, m * 3), np.repeat(miss, 3, axis=1)).reshape(t, m, 3)
    err = np.linalg.norm(lerp[:end][miss[:end]] - serve.markers.points[:end][miss[:end]], axis=1)
    total, filled, missing = acc[("c3d", "marker-gap", 0.5, "lerp")]
    assert (filled, missing) == (err.size, int(miss.sum()))
    assert total == pytest.approx(err.sum())
    for method in bench.STREAMING:  # causal methods fill every missing sample
        assert acc[("c3d", "marker-gap", 0.5, method)][1] == missing
    rows = bench.summarise(acc)
    lerp_row = next(r for r in rows if r["method"] == "lerp")
    assert lerp_row["mean_err_cm"] == pytest.approx(err.mean()) and lerp_row["filled_fraction"] == 1.0
    assert all(0.0 <= r["filled_fraction"] <= 1.0 for r in rows)


def test_rbt_cluster_picks_the_most_rigid_markers(serve):
    noisy = bench.corrupt(serve, "marker-gap:0.5", 1)
    target = int(np.flatnonzero((~noisy.visible).any(axis=0))[0])
    pool = [j for j in range(noisy.n_markers) if j != target]
    cluster = bench.rbt_cluster(noisy, target, pool)
    spread = bench.distance_spread(noisy.points, target)
    assert len(cluster) == 3 and target not in cluster
    assert max(spread[cluster]) <= min(np.delete(spread, cluster + [target]))


def test_report_markdown_and_plot(shared, tmp_path):
    """A small run on shared data: latency, markdown and plot."""
    pytest.importorskip("gapfill")
    (clip,) = bench.load_clips(shared, bench.QUICK_FILES[:1])
    acc: dict = {}
    for corruption in ("marker-gap:0.25", "segment-gap:left-arm:0.25"):
        bench.score_clip(clip, corruption, 0, acc, {})
    latency = bench.latency(shared, n_markers=5)
    assert set(latency["methods"]) == {name for name, _, _ in bench.LATENCY_MODES}
    assert latency["methods"]["hold"]["median_ratio_to_hold"] == 1.0
    report = {"command": "bench", "git_commit": "0123abc", "machine": "test", "wall_s": 1.0, "repeats": 1,
              "clips": [{"path": "c3d/x.c3d", "markers": 41, "frames": 100, "fps": 120.0}], "skipped": [],
              "summary": bench.summarise(acc), "gapfill": {"version": "0.0.7", "note": "note"},
              "synthetic": bench.synthetic_check(fps=30.0, seconds=0.5), "latency": latency}  # fmt: skip
    text = bench.markdown(report)
    lerp = next(r for r in report["summary"] if r["method"] == "lerp" and r["corruption"] == "marker-gap")
    assert "| 0.25 | " in text and f"{lerp['mean_err_cm']:.2f} (1.00)" in text
    assert "## C3D — `segment-gap` (mean error, cm)" in text and "## Per-frame latency" in text
    bench.plot(report, tmp_path / "plot.png")
    assert (tmp_path / "plot.png").read_bytes()[:4] == b"\x89PNG"
