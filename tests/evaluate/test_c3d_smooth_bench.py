"""The C3D denoising benchmark's bookkeeping (mocapnet.evaluate.c3d_smooth_bench) on the C3D take shipped in
the package: scores, summary and the results table."""

from __future__ import annotations

import numpy as np

from mocapnet.evaluate import c3d_smooth_bench as bench
from tests.conftest import SAMPLE_C3D


def test_run_scores_every_method_and_level_and_summarizes():
    report = bench.run(SAMPLE_C3D.parent, (SAMPLE_C3D.name,), levels=(0.0, 2.0))
    rows = report["rows"]
    assert [r["level_mm"] for r in rows] == [0.0, 2.0]
    clean, noisy = rows
    assert clean["noisy"] == 0.0 and 0 <= clean["gaussian-cv"] < clean["gaussian-10ms"]
    assert abs(noisy["noisy"] - 2.0) < 0.05  # 2 mm of white noise per coordinate, measured back
    assert noisy["gaussian-cv"] < noisy["noisy"] and noisy["own_noise_mm"] > 0
    summary = report["summary"]
    assert "cv_over_best_fixed" not in summary["0"]
    best = summary["2"]["best_fixed"]
    assert best == min((k for k in noisy if k.endswith("ms")), key=noisy.get)
    np.testing.assert_allclose(summary["2"]["cv_over_best_fixed"], noisy["gaussian-cv"] / noisy[best])
    text = bench.markdown({"command": "c", "git_commit": "g", "machine": "m"} | report)
    assert "| 2 | 2.0" in text and SAMPLE_C3D.name in text


def test_fixed_gaussian_never_bridges_a_gap():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(50, 2, 3))
    visible = np.ones((50, 2), dtype=bool)
    visible[20:25, 0] = False
    points[~visible] = np.nan
    out = bench.fixed_gaussian_runs(points, visible, 2.0)
    assert np.isnan(out[20:25, 0]).all() and np.isfinite(out[visible]).all()
    np.testing.assert_allclose(out[:20, 0], bench.fixed_gaussian_runs(points[:20], visible[:20], 2.0)[:, 0])
