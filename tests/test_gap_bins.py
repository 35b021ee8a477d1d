"""Gap errors by gap length and the blend's selection rule (``mocapnet.evaluate.gap_bins``)."""

from __future__ import annotations

import numpy as np
import pytest

from mocapnet.evaluate.gap_bins import FilledClip, bin_errors, fill_clips, headline, ratios, select
from mocapnet.evaluate.metrics import gap_err_deg


def clip_with_gaps() -> FilledClip:
    """Two scored joints of two channels each: joint 0 misses 3 frames, joint 1 misses 20 frames. ``lerp`` is
    off by 1° in every missing sample, ``spline`` by 2°, ``good`` by 0.5° in the short gap and 3° in the long."""
    truth = np.zeros((100, 4))
    mask = np.zeros(truth.shape, dtype=bool)
    mask[10:13, :2] = True
    mask[40:60, 2:] = True
    good = truth + np.where(mask, 0.5, 0.0)
    good[40:60, 2:] = 3.0
    outputs = {"lerp": truth + mask * 1.0, "spline": truth + mask * 2.0, "good": good}
    return FilledClip("a", truth, mask, 30.0, outputs)


def test_bins_pool_each_gap_over_its_channels():
    rows = bin_errors([clip_with_gaps()], ["lerp", "spline", "good"])
    assert [r["gaps"] for r in rows] == [1, 0, 1, 0, 0]
    assert rows[0]["good"] == pytest.approx(0.5) and rows[2]["good"] == pytest.approx(3.0)
    assert rows[0]["lerp"] == pytest.approx(1.0) and rows[2]["spline"] == pytest.approx(2.0)
    assert np.isnan(rows[1]["good"])


def test_headline_is_the_harness_gap_error_and_ratios_use_the_better_reference():
    item = clip_with_gaps()
    assert headline([item], "good") == pytest.approx(gap_err_deg(item.outputs["good"], item.truth, item.mask))
    r = ratios({"gaps": [item]}, "good")
    assert r["gaps"] == pytest.approx(headline([item], "good") / 1.0)
    assert r["bin ≤ 5"] == pytest.approx(0.5) and r["bin 16–30"] == pytest.approx(3.0)
    exact = FilledClip("b", item.truth, item.mask, 30.0, {n: item.truth for n in ("lerp", "spline", "good")})
    assert ratios({"gaps": [exact]}, "good") == {}  # nothing to beat: no ratio rather than 0/0
    exact.outputs["good"] = item.truth + item.mask  # ... but missing what interpolation gets exactly is not let off
    assert ratios({"gaps": [exact]}, "good")["gaps"] == np.inf


def test_select_ranks_near_ties_of_the_worst_ratio_by_the_mean():
    scores = {"a": {"x": 0.90, "y": 0.50}, "b": {"x": 0.903, "y": 0.40}, "c": {"x": 0.95, "y": 0.10}}
    assert select(scores) == "b"
    assert select(scores, tie=0.0) == "a"


def test_fill_clips_uses_protocol_seeds_and_scored_channels(cmu_short):
    calls = []

    def fill(motion, mask):
        calls.append(mask.copy())
        return np.where(mask, 0.0, motion.channels)

    items = fill_clips("sample", [cmu_short], "gaps", 2, {"zero": fill})
    assert len(items) == 2 and not np.array_equal(calls[0], calls[1])
    scored = cmu_short.skeleton.scored_mask
    assert items[0].truth.shape == (600, int(scored.sum()))
    np.testing.assert_array_equal(items[0].mask, calls[0][:, scored])


def test_compare_scores_each_network_blended_and_raw_and_selects_among_the_blended(cmu):
    from mocapnet.evaluate.gap_bins import TUNE, compare, compare_markdown
    from mocapnet.nn.checkpoints import shipped_checkpoint

    path = str(shipped_checkpoint("ebd", cmu.skeleton))
    result = compare("sample", [cmu], {"a": path, "b": path}, repeats=1)
    assert set(result["scores"]) == {"a", "a raw", "b", "b raw"}
    assert result["scores"]["a"] == result["scores"]["b"]  # the same network scores the same
    assert result["scores"]["a"] != result["scores"]["a raw"]  # the blend is applied to one of them only
    assert set(result["errors"]) == set(TUNE) and result["selected"] == "a"
    # this clip's gaps-long hides only joints that never move: no ratio there, every other corruption has one
    assert result["errors"]["gaps-long"]["lerp"] == 0.0
    assert [k for k in TUNE if k in result["scores"]["a"]] == [k for k in TUNE if k != "gaps-long"]
    result |= {"command": "x", "split": "sample"}
    assert "| a raw |" in compare_markdown(result)


def test_plot_draws_one_row_per_corruption_and_bin(tmp_path):
    """``gap_bins.plot`` writes a PNG whose height grows with the rows (headline corruptions + bins)."""
    import struct

    from mocapnet.evaluate.gap_bins import plot

    def row(**extra):
        return {"lerp": 2.0, "spline": 4.0, "ebd-raw": 3.0, "ebd": 1.5, **extra}

    result = {"corpus": "toy", "names": ["lerp", "spline", "ebd-raw", "ebd"], "headline": [row(corruption="gaps")]}
    heights = []
    for n_bins in (1, 6):
        result["bins"] = [row(corruption="gaps", bin=f"{k}", gaps=k + 1) for k in range(n_bins)]
        path = tmp_path / f"bins{n_bins}.png"
        plot(result, path)
        head = path.read_bytes()[:24]
        assert head[:8] == b"\x89PNG\r\n\x1a\n"
        heights.append(struct.unpack(">I", head[20:24])[0])
    assert heights[1] - heights[0] == pytest.approx(5 * 0.38 * 110, abs=2)
